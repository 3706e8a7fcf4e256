"""Where the service's publications go: one ``publish(topic, payload)`` the server sets once it is up.

``publish`` is called from the bus threads (progress, events) and must not block: the server queues the
payloads to zenoh. Until a server sets its own, publications go nowhere.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from pvtflow.axes.master.group.outcome import EventKind
from pvtflow.axes.master.homing import HomingEventKind
from pvtflow.service.motion.runs import ServiceEventKind

Publish = Callable[[str, dict[str, Any]], None]


def _no_publish(topic: str, payload: dict[str, Any]) -> None:
    del topic, payload


class Outbox:
    """The cell's publications: the target they go to, and the shape of an event."""

    def __init__(self, cell: str, publish: Publish | None = None) -> None:
        self.cell = cell
        self.target: Publish = publish or _no_publish

    def send_to(self, target: Publish) -> None:
        """Publications go to ``target`` from now on (the server's queue to zenoh)."""
        self.target = target

    def publish(self, topic: str, payload: dict[str, Any]) -> None:
        self.target(topic, payload)

    def event_payload(
        self, kind: EventKind | ServiceEventKind | HomingEventKind, message: str, **extra: Any
    ) -> dict[str, Any]:
        return {
            "cell": self.cell,
            "kind": kind,
            "message": message,
            "time": time.time(),
            "joint": None,
            "node_id": None,
            "motion_id": None,
            **extra,
        }

    def event(self, kind: EventKind | ServiceEventKind | HomingEventKind, message: str, **extra: Any) -> None:
        self.publish("events", self.event_payload(kind, message, **extra))
