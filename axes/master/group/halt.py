"""Halting a run: every axis on the same SYNC, or by SDO when SYNC fails.

Any fault, or ``stop()``, sends the halt controlword to every axis through the synchronous RPDO
before the next SYNC; a drive without a ramp of its own gets the master's braking setpoints
(``axes.drive.stop_ramp``) instead. When the master cannot keep SYNC, every axis is quick stopped by SDO
(``axes.master.bus.quick_stop``). The run ends once every axis is at rest or the halt times out.
``Halting`` is a part of one ``Run`` (axes/master/group/run.py) and owns how that run ends.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Sequence
from typing import Protocol

import can

from pvtflow.axes.drive.cia402 import PowerState, Statusword, decode_state
from pvtflow.axes.master.bus.faults import BusFault
from pvtflow.axes.master.bus.quick_stop import QuickStop
from pvtflow.axes.master.group.feeder import Feeder, SetpointFeeder
from pvtflow.axes.master.group.outcome import EventKind, Result, RunResult
from pvtflow.axes.master.group.run_state import RunParts
from pvtflow.axes.master.link import AxisLink

_TARGET_REACHED = int(Statusword.TARGET_REACHED)


class HaltedRun(Protocol):
    """What a halt needs of its run (``axes.master.group.run.Run``)."""

    @property
    def feeders(self) -> Sequence[Feeder]: ...

    @property
    def start_sync(self) -> int | None: ...

    def result(self, result: Result, message: str, link: AxisLink | None = None) -> RunResult: ...

    def end(self, result: RunResult) -> None: ...


class Halting:
    """How one run ends once something stops it: ``ending`` (the result it will end with),
    ``halted_at`` (time.monotonic() of the halt), ``deadline`` (the SYNC by which the halt must be
    over; None: quick stopped by SDO, whose confirmations end the run), ``quick_stop``."""

    def __init__(self, parts: RunParts, run: HaltedRun) -> None:
        self._parts = parts
        # its run owns it: a weak reference, so that a run left behind is freed at once, not by the collector
        self._run = weakref.proxy(run)
        self.ending: RunResult | None = None
        self.halted_at: float | None = None
        self.deadline: int | None = None
        self.quick_stop: QuickStop | None = None  # the quick stop by SDO, if the run needed one

    def halt(self, result: Result, message: str, link: AxisLink | None) -> None:
        """Halt every axis on the next SYNC and stop feeding (called with the group lock held)."""
        t0 = time.perf_counter()
        parts, run = self._parts, self._run
        sync = parts.bus.sync
        quick = result is not Result.STOPPED
        with sync.lock:
            if sync.cyclic_producing:
                sync.cyclic.halt(quick=quick)  # its feeders as these below
            unsent = []
            for lk, profile, feeder in zip(parts.links, parts.profiles, run.feeders, strict=True):
                if not profile.ramps_by_itself and isinstance(feeder, SetpointFeeder):
                    # no ramp of its own: braking setpoints within 0x60C5 / 0x6085 (axes.drive.stop_ramp)
                    feeder.decelerate(profile.stop_records(feeder, quick=quick))
                    continue
                feeder.disable()
                try:
                    lk.send_controlword(profile.halt_controlword())
                except can.CanError as exc:  # the bus is gone: the drives stop on the master's heartbeat loss
                    unsent.append(f"node {lk.node_id}: {exc}")
            halt_sync = sync.count + 1
            fault_sync = sync.count  # the SYNC period in which the event was seen
        res = run.result(result, message, link)
        res.fault_sync = fault_sync
        res.halt_sync = halt_sync
        res.halt_latency_s = time.perf_counter() - t0
        self.ending = res
        self.halted_at = time.monotonic()
        self.deadline = halt_sync + int(parts.halt_timeout_ms / parts.bus.config.sync_period_ms)
        lost = f" (not sent to {'; '.join(unsent)}: those drives stop on the master's heartbeat loss)" if unsent else ""
        parts.event(EventKind.HALTED, f"all axes halted: {message}{lost}", link)

    def quick(self, result: Result, message: str, link: AxisLink | None, fault: BusFault | None = None) -> None:
        """The master cannot keep SYNC: no more SYNC, every axis quick stopped by SDO, NMT stop for
        the drives that do not confirm (``axes.master.bus.quick_stop``); the run ends when that is done (called
        with the SYNC lock and the group lock held). ``fault``: the bus's report that caused it, told
        as its event once the requests are out."""
        parts, run = self._parts, self._run
        sync = parts.bus.sync
        for feeder in run.feeders:
            feeder.disable()
        res = run.result(result, message, link)
        res.fault_sync = sync.count
        self.ending = res  # before the requests: their confirmations end the run (_quick_stopped)
        self.halted_at = time.monotonic()
        self.deadline = None
        # the requests first (no SYNC can go out meanwhile: the SYNC lock is held), the rest after
        self._send_quick_stop(message)
        parts.readiness.forget()
        if fault is not None:
            parts.event(EventKind(fault.kind.value), fault.message, link)
        parts.event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)

    def quick_too(self, message: str, link: AxisLink | None, fault: BusFault) -> None:
        """A halt by the synchronous RPDO is under way and SYNC fails: quick stop by SDO as well."""
        self.deadline = None
        self._send_quick_stop(message)
        self._parts.event(EventKind(fault.kind.value), fault.message, link)
        self._parts.event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)

    def _send_quick_stop(self, message: str) -> None:
        bus = self._parts.bus
        self.quick_stop = bus.quick_stop([lk.node_id for lk in self._parts.links], message, self._quick_stopped)
        bus.sync.stop()

    def _quick_stopped(self, stop: QuickStop) -> None:
        """Every drive confirmed the quick stop or was sent NMT stop (the quick stop's thread)."""
        ending = self.ending
        if ending is None:
            return
        ending.halt_latency_s = stop.latency_s
        ending.message = f"{ending.message}; {stop.describe()}"
        if stop.nmt_stopped or stop.unsent:
            self._parts.configuration.forget()  # NMT STOPPED: the next start configures again
        self._run.end(ending)

    def check(self, n: int) -> None:
        """After SYNC ``n`` answered while halting: the run ends once every axis is at rest (its
        target reached, its stop ramp over) or the halt's deadline has passed."""
        assert self.ending is not None
        if self.deadline is None:
            return  # quick stopped by SDO: the quick stop ends the run (_quick_stopped)
        if n < (self.ending.halt_sync or 0):
            return
        run = self._run
        elapsed = n - (run.start_sync or n) - 1  # a stop ramp is over once its drive held its end one SYNC
        still = [
            lk
            for lk, feeder in zip(self._parts.links, run.feeders, strict=True)
            if decode_state(lk.statusword) == PowerState.OPERATION_ENABLED
            and (not lk.statusword & _TARGET_REACHED or (feeder.enabled and not feeder.finished(elapsed, False)))
        ]
        if not still or n >= self.deadline:
            self._parts.bus.sync.stop()
            run.end(self.ending)
