"""``pvtflow serve --live``: a WebSocket client (the Foxglove protocol) subscribes to the service's channels
and receives a motion's messages, as Foxglove would."""

from __future__ import annotations

import dataclasses
import json
import socket
import struct
import threading
import time
import uuid

import pytest
from axes_programs import program
from websockets.sync.client import connect

from pvtflow.axes.canbus.clock import Clock
from pvtflow.service.api import ExecuteRequest
from pvtflow.service.live import LiveServer
from pvtflow.service.motion import MotionService

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: subscription id (u32), log time (u64), payload


class Client:
    """Subscribes to every channel the server advertises; keeps what arrives, by topic. A subscription the
    server answers with "Unknown channel ID" (the Foxglove SDK's server can advertise a channel to a client
    that connects while it is being added, and not know it yet when the subscription comes) is asked
    again, as a viewer that wants the channel does."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.ws = None
        self.topics: dict[int, str] = {}  # subscription id -> topic
        self.schemas: dict[str, str] = {}
        self.received: dict[str, list[tuple[int, dict]]] = {}
        self.server_info: dict | None = None
        self.channels: dict[int, str] = {}  # channel id -> topic, as advertised
        self.retries = 0  # subscriptions asked again after "Unknown channel ID"
        self._closed = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        with connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
            self.ws = ws
            while not self._closed.is_set():
                try:
                    frame = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                if isinstance(frame, str):
                    self._on_text(json.loads(frame))
                elif frame[0] == MESSAGE_DATA:
                    sub, log_time = struct.unpack_from("<IQ", frame, 1)
                    self.received.setdefault(self.topics[sub], []).append((log_time, json.loads(frame[13:])))

    def _on_text(self, msg: dict) -> None:
        if msg["op"] == "serverInfo":
            self.server_info = msg
        elif msg["op"] == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["id"]] = ch["topic"]
                self.schemas[ch["topic"]] = ch["schemaName"]
            self._subscribe([ch["id"] for ch in msg["channels"]])
        elif msg["op"] == "status" and msg.get("message", "").startswith("Unknown channel ID:"):
            unknown = [c for c in self.channels if msg["message"].split(":")[-1].strip() == str(c)]
            self.retries += len(unknown)
            if self.retries <= 50:  # a channel that stays unknown is the server's fault: the test then fails
                self._subscribe(unknown)

    def _subscribe(self, channel_ids: list[int]) -> None:
        subs = []
        for channel in channel_ids:
            sub = len(self.topics) + 1
            self.topics[sub] = self.channels[channel]
            subs.append({"id": sub, "channelId": channel})
        assert self.ws is not None
        if subs:
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def close(self) -> None:
        self._closed.set()
        self.thread.join(5)


def wait_for(predicate, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_a_websocket_client_subscribes_and_receives_a_motions_messages(arm6, tmp_path):
    cell = dataclasses.replace(arm6, bus=dataclasses.replace(arm6.bus, channel=f"live-{uuid.uuid4().hex[:10]}"))
    first = program(cell.ordered_axes(), 1500, spacing_ms=10, cell="arm6")
    ends = [int(a.records[-1, 0]) for a in first.axes]
    back = program(cell.ordered_axes(), 1500, spacing_ms=10, cell="arm6", starts=ends, sign=-1)
    live = LiveServer(0).start()
    assert live.url.startswith("ws://127.0.0.1:")
    client = Client(live.url)
    try:
        with MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, live=live) as svc:
            assert wait_for(lambda: client.server_info is not None)
            # the first motion advertises the channels; the client subscribes to them as they come
            svc.execute(ExecuteRequest(program=first.to_json(), wait=True))
            assert wait_for(lambda: "/axis/joint_1/actual" in client.topics.values())
            reply = svc.execute(ExecuteRequest(program=back.to_json(), wait=True))
            assert reply["outcome"]["result"] == "finished"
            assert svc.journal_entry(reply["motion_id"]).recording is None  # live only: no file
            assert wait_for(
                lambda: (
                    any(m["name"] == "finished" for _, m in client.received.get("/events", [])[-3:])
                    and len(client.received.get("/axis/joint_1/actual", [])) > 100
                )
            )
    finally:
        client.close()
        live.stop()
    actual = [m for _, m in client.received["/axis/joint_1/actual"]]
    assert actual[-1]["position_qc"] == back.axes[0].records[-1, 0]
    errors = [m["following_error_qc"] for m in actual if m["following_error_qc"] is not None]
    assert errors and max(abs(e) for e in errors) <= 2.0
    assert client.schemas["/events"] == "foxglove.Log"
    assert client.schemas["/tf"] == "foxglove.FrameTransforms"
    assert "/axis/joint_1/planned" in client.received and "/can" in client.received
    times = [t for t, _ in client.received["/sync"]]
    assert times == sorted(times) and times[-1] > times[0]  # on the bus's clock, in order


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_serve_refuses_a_live_port_in_use_in_one_line(capsys):
    from pvtflow.service.cli import main

    taken = LiveServer(0).start()
    try:
        assert main(["serve", "--live", str(taken.port), "--port", str(free_port())]) == 2
    finally:
        taken.stop()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pvtflow serve: --live {taken.port}: cannot serve on 127.0.0.1:")
    assert "Address already in use" in err[0]


def test_a_viewer_opened_between_motions_sees_the_robot_at_rest(arm6, tmp_path):
    import numpy as np
    import pinocchio as pin

    cell = dataclasses.replace(arm6, bus=dataclasses.replace(arm6.bus, channel=f"live-{uuid.uuid4().hex[:10]}"))
    live = LiveServer(0).start()
    client = None
    topics = ("/robot_description", "/joint_states", "/tf", "/axis/joint_1/actual")
    try:
        with MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, live=live) as svc:
            client = Client(live.url)  # no motion ran, none runs
            assert wait_for(lambda: all(len(client.received.get(t, [])) >= 2 for t in topics))
            counts = svc.positions_qc()
            joints = svc.to_joint(counts)
    finally:
        if client is not None:
            client.close()
        live.stop()
    names = [a.joint for a in cell.ordered_axes()]
    actual = client.received["/axis/joint_1/actual"][-1][1]
    assert actual["position_qc"] == counts[0] and actual["planned_qc"] is None
    assert actual["state"] == "SWITCH ON DISABLED" or actual["state"].isupper()
    states = client.received["/joint_states"][-1][1]
    assert states["name"] == names and states["position"] == joints
    assert "<robot" in client.received["/robot_description"][-1][1]["data"]
    # the links where Pinocchio puts them for the drives' positions
    model = cell.model
    q = np.zeros(model.dof)
    for joint, value in zip(names, joints, strict=True):
        q[model.index(joint)] = value
    data = model.model.createData()
    pin.framesForwardKinematics(model.model, data, q)
    transforms = {t["child_frame_id"]: t for t in client.received["/tf"][-1][1]["transforms"]}
    tool = data.oMf[model.model.getFrameId("tool0")]
    assert [transforms["tool0"]["translation"][k] for k in "xyz"] == pytest.approx(list(tool.translation), abs=1e-12)
    assert client.schemas["/tf"] == "foxglove.FrameTransforms"
