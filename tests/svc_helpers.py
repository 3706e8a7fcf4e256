"""Helpers of the service and end-to-end tests: a cell's MotionService on simulated drives, served on a free loopback
port by a real zenoh session, and a real zenoh client session connected to it.

Every zenoh session here is a peer with explicit tcp/127.0.0.1 endpoints and multicast and gossip
scouting off; every cell gets its own virtual CAN channel, so tests never see each other.
"""

from __future__ import annotations

import dataclasses
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from jsonschema import Draft202012Validator

from pvtflow.axes.canbus.clock import Clock
from pvtflow.service.api import reply_schema
from pvtflow.service.config import CellConfig
from pvtflow.service.motion import MotionService
from pvtflow.service.request_cmd import Client
from pvtflow.service.server import Server, peer_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# the deadline of plans in tests that are not about deadlines (the API's largest): a time-optimal plan
# takes 20-100 ms, and a loaded host (3-7 busy processes on 2 cores) pushed some past the cells' 200 ms
UNHURRIED_BUDGET_MS = 60000.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def on_own_channel(cell: CellConfig) -> CellConfig:
    bus = dataclasses.replace(cell.bus, channel=f"svc-{cell.name}-{uuid.uuid4().hex[:10]}")
    return dataclasses.replace(cell, bus=bus)


def wait_until(predicate: Callable[[], bool], timeout: float = 10.0, poll: float = 0.005) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll)
    return predicate()


def check_reply(op: str, data: Any) -> None:
    """Every reply and publication follows its documented JSON Schema."""
    Draft202012Validator(reply_schema(op)).validate(data)


@dataclass
class Collector:
    """Everything published on pvtflow/<cell>/{state,telemetry,events}, in arrival order."""

    samples: dict[str, list[dict[str, Any]]] = field(
        default_factory=lambda: {"state": [], "telemetry": [], "events": []}
    )
    lock: threading.Lock = field(default_factory=threading.Lock)
    subscribers: list[Any] = field(default_factory=list)

    def add(self, topic: str) -> Callable[[str, dict[str, Any]], None]:
        def on(cell: str, data: dict[str, Any]) -> None:
            del cell
            with self.lock:
                self.samples[topic].append(data)

        return on

    def get(self, topic: str) -> list[dict[str, Any]]:
        with self.lock:
            return list(self.samples[topic])

    def events(self, kind: str, motion_id: str | None = None) -> list[dict[str, Any]]:
        return [
            e
            for e in self.get("events")
            if e["kind"] == kind and (motion_id is None or e.get("motion_id") == motion_id)
        ]


@dataclass
class Served:
    cell: CellConfig
    service: MotionService
    server: Server
    client: Client
    endpoint: str
    journal_dir: Path

    def follow(self) -> Collector:
        col = Collector()
        for topic in ("state", "telemetry", "events"):
            col.subscribers.append(self.client.follow(self.cell.name, topic, col.add(topic)))
        time.sleep(0.1)  # let the subscriptions reach the service
        return col

    def request(self, op: str, payload: Any = None, timeout: float = 20.0) -> Any:
        return self.client.request(self.cell.name, op, payload, timeout)

    @property
    def sim(self) -> Any:
        return self.service.sim


@contextmanager
def served_cell(
    cell: CellConfig,
    journal_dir: Path,
    zconfig: Any = None,
    client: Client | None = None,
    port: int | None = None,
    client_zconfig: Any = None,
) -> Iterator[Served]:
    """A cell's service on its own CAN channel and loopback port, with a client connected to it
    (``client``, or a new one: a client of the endpoint, or one made from ``client_zconfig``)."""
    cell = on_own_channel(cell)
    endpoint = f"tcp/127.0.0.1:{port or free_port()}"
    service = MotionService(cell, journal_dir=journal_dir, clock=Clock.LOCKSTEP).open()
    server = None
    own_client = client is None
    try:
        server = Server(service, zconfig or peer_config(listen=[endpoint]), idle_telemetry_s=0.5).start()
        c = client or (Client(client_zconfig) if client_zconfig is not None else Client(connect=endpoint))
        try:
            wait_until(lambda: cell.name in c.alive(cell.name, timeout=0.5), timeout=5.0)
            yield Served(cell, service, server, c, endpoint, journal_dir)
        finally:
            if own_client:
                c.close()
    finally:
        if server is not None:
            server.close()
        service.close()


def nothing_moved(served: Served) -> None:
    """No drive took a record or left its start, the journal has no motion, the cell is idle."""
    for drive in served.sim:
        assert drive.records_received == 0, f"node {drive.node_id} got records"
        assert not drive.ip_active
        assert drive.faults == []
    assert served.service.journal.recent(10) == []
    assert served.service.state == "idle"
    assert not served.service.running


# --- moves that the arm6 cell plans and runs (joint units, the cell's joint order) -----------------------
SHORT_TARGET = [0.3, -0.2, 0.3, -0.2, 0.3, -0.2]


def long_tour(cell: CellConfig) -> list[list[float]]:
    """About 2 s of motion through 5 waypoints (the demo's tour): long enough to stop in the middle."""
    from pvtflow.service.demo_cmd import tour

    lim = cell.joint_limits()
    return tour(np.asarray(lim.lower), np.asarray(lim.upper), 4)
