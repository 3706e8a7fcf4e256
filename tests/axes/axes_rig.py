"""Helpers of the axes tests: unique virtual channels, cells with other profiles (imported by name:
this folder is not a package, so ``conftest`` itself is not imported by the tests)."""

from __future__ import annotations

import dataclasses
import time
import uuid

import can

from service.config import CellConfig


def unique_channel(prefix: str = "axes") -> str:
    return f"{prefix}-{uuid.uuid4().hex[:12]}"


def with_profiles(cell: CellConfig, profiles: dict[str, dict[str, object]], sync_period_ms: float) -> CellConfig:
    """The cell with some axes switched to another profile (and the SYNC period set)."""
    axes = []
    for a in cell.axes:
        change = profiles.get(a.joint)
        axes.append(dataclasses.replace(a, **change) if change else a)  # type: ignore[arg-type]
    bus = dataclasses.replace(cell.bus, sync_period_ms=sync_period_ms)
    return dataclasses.replace(cell, axes=tuple(axes), bus=bus)


class BusObserver(can.Listener):
    """A third node on a virtual bus that only listens: every frame with its arrival time."""

    def __init__(self, channel: str) -> None:
        self.frames: list[tuple[float, int, bytes]] = []  # (time.monotonic(), COB-ID, data)
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.02)

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))

    def on(self, cob_id: int, since: float = 0.0) -> list[bytes]:
        """The data of the frames on ``cob_id`` that arrived after ``since``."""
        return [data for t, cid, data in list(self.frames) if cid == cob_id and t > since]

    def emcy_nodes(self, code: int) -> set[int]:
        """The nodes that sent an EMCY (0x80 + node id) with this error code."""
        return {
            cid - 0x80
            for _, cid, data in list(self.frames)
            if 0x81 <= cid <= 0xFF and len(data) >= 2 and int.from_bytes(data[:2], "little") == code
        }

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()
