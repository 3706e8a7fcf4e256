"""Helpers of the axes tests: unique virtual channels, cells with other profiles (imported by name:
this folder is not a package, so ``conftest`` itself is not imported by the tests)."""

from __future__ import annotations

import dataclasses
import threading
import time
import uuid
from collections.abc import Sequence
from typing import ClassVar

import can
from can.interfaces.virtual import VirtualBus

from pvtflow.service.config import CellConfig


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


def listening_bus(interface: str, channel: str) -> can.BusABC:
    """One more node on a cell's bus that only listens (on the simulated wire it takes the medium as
    the cell opened it: clock, bit rate and SYNC period)."""
    named = {"node_name": f"observer {uuid.uuid4().hex[:6]}"} if interface == "simwire" else {}
    return can.Bus(interface=interface, channel=channel, receive_own_messages=False, **named)


class BusObserver(can.Listener):
    """A third node on a cell's bus that only listens: every frame with its arrival time."""

    def __init__(self, channel: str, interface: str = "virtual") -> None:
        self.frames: list[tuple[float, int, bytes]] = []  # (time.monotonic(), COB-ID, data)
        self.bus = listening_bus(interface, channel)
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


class FlakyBus(VirtualBus):
    """A test double of the CAN interface: python-can's virtual bus whose transmit path can be made
    to fail (``fail(channel, seconds)``: ``can.CanOperationError`` as socketcan raises it on a full
    queue, ENOBUFS) and whose controller state can be set (``set_state``). Opened as the python-can
    interface ``pvtflow_test_flaky`` (registered below)."""

    failing_until: ClassVar[dict[str, float]] = {}
    failing_from: ClassVar[dict[str, float]] = {}
    states: ClassVar[dict[str, can.BusState]] = {}
    refused: ClassVar[dict[str, int]] = {}

    @classmethod
    def fail(cls, channel: str, seconds: float, after: float = 0.0) -> None:
        """Refuse every frame on ``channel`` for ``seconds``, from ``after`` seconds from now."""
        now = time.monotonic()
        cls.failing_from[channel] = now + after
        cls.failing_until[channel] = now + after + seconds

    @classmethod
    def failing(cls, channel: str) -> bool:
        """The transmit queue of ``channel`` is full now."""
        return cls.failing_from.get(channel, 0.0) <= time.monotonic() < cls.failing_until.get(channel, 0.0)

    @classmethod
    def set_state(cls, channel: str, state: can.BusState) -> None:
        cls.states[channel] = state

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if FlakyBus.failing(self.channel_id):
            FlakyBus.refused[self.channel_id] = FlakyBus.refused.get(self.channel_id, 0) + 1
            raise can.CanOperationError("Failed to transmit: [Errno 105] No buffer space available")
        super().send(msg, timeout)

    @property
    def state(self) -> can.BusState:
        return FlakyBus.states.get(self.channel_id, can.BusState.ACTIVE)


class KernelTask(can.broadcastmanager.RestartableCyclicTaskABC):
    """A cyclic send timed outside the master's threads, as the kernel's broadcast manager does it:
    its own virtual bus on the channel (the kernel's socket), absolute deadlines."""

    def __init__(self, channel: str, msgs: Sequence[can.Message], period: float) -> None:
        super().__init__(msgs, period)
        self.bus = VirtualBus(channel=channel)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            for msg in self.messages:
                self.bus.send(msg)
            deadline += self.period
            self._stop.wait(max(0.0, deadline - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(1.0)
        self.bus.shutdown()


class KernelCyclicBus(VirtualBus):
    """A test double of an interface that sends cyclically by itself (socketcan's BCM): the python-can
    interface ``pvtflow_test_kernel``."""

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message],
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: object = None,
    ) -> KernelTask:
        task = KernelTask(self.channel_id, msgs, period)
        if autostart:
            task.start()
        return task


# what python-can's plugin entry point does for an installed interface
for _name, _cls in (("pvtflow_test_flaky", "FlakyBus"), ("pvtflow_test_kernel", "KernelCyclicBus")):
    can.interfaces.BACKENDS[_name] = ("axes_rig", _cls)
can.interfaces.VALID_INTERFACES = can.util.VALID_INTERFACES = frozenset(can.interfaces.BACKENDS)
