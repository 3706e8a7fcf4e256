"""Halting a run: every axis on the same SYNC, or by SDO when SYNC fails, a part of ``AxisGroup``.

Any fault, or ``stop()``, sends the halt controlword to every axis through the synchronous RPDO
before the next SYNC; a drive without a ramp of its own gets the master's braking setpoints
(``axes.drive.stop_ramp``) instead. When the master cannot keep SYNC, every axis is quick stopped by SDO
(``axes.master.bus.quick_stop``). The run ends once every axis is at rest or the halt times out. The methods
work on ``AxisGroup``'s state (``axes.master.group.axis_group``).
"""

from __future__ import annotations

import time

import can

from pvtflow.axes.drive.cia402 import PowerState, Statusword, decode_state
from pvtflow.axes.master.bus.faults import BusFault
from pvtflow.axes.master.bus.quick_stop import QuickStop
from pvtflow.axes.master.group.feeder import SetpointFeeder
from pvtflow.axes.master.group.outcome import EventKind, Result
from pvtflow.axes.master.link import AxisLink

_TARGET_REACHED = int(Statusword.TARGET_REACHED)


class GroupHalt:
    """AxisGroup's halt, quick stop and stop (mixed into ``AxisGroup``)."""

    def _halt(self, result: Result, message: str, link: AxisLink | None) -> None:
        """Halt every axis on the next SYNC and stop feeding (called with the lock held)."""
        t0 = time.perf_counter()
        sync = self.bus.sync
        with sync.lock:
            if sync.cyclic_producing:
                sync.cyclic.halt(quick=result is not Result.STOPPED)  # its feeders as these below
            unsent = []
            for lk, profile, feeder in zip(self.links, self.profiles, self._feeders, strict=True):
                if not profile.ramps_by_itself and isinstance(feeder, SetpointFeeder):
                    # no ramp of its own: braking setpoints within 0x60C5 / 0x6085 (axes.drive.stop_ramp)
                    feeder.decelerate(profile.stop_records(feeder, quick=result is not Result.STOPPED))
                    continue
                feeder.enabled = False
                try:
                    lk.send_controlword(profile.halt_controlword())
                except can.CanError as exc:  # the bus is gone: the drives stop on the master's heartbeat loss
                    unsent.append(f"node {lk.node_id}: {exc}")
            halt_sync = sync.count + 1
            fault_sync = sync.count  # the SYNC period in which the event was seen
        res = self._result(result, message, link)
        res.fault_sync = fault_sync
        res.halt_sync = halt_sync
        res.halt_latency_s = time.perf_counter() - t0
        self._ending = res
        self._halted_at = time.monotonic()
        self._halt_deadline = halt_sync + int(self.halt_timeout_ms / self.bus.config.sync_period_ms)
        lost = f" (not sent to {'; '.join(unsent)}: those drives stop on the master's heartbeat loss)" if unsent else ""
        self._event(EventKind.HALTED, f"all axes halted: {message}{lost}", link)

    def _quick_stop(self, result: Result, message: str, link: AxisLink | None, fault: BusFault | None = None) -> None:
        """The master cannot keep SYNC: no more SYNC, every axis quick stopped by SDO, NMT stop for
        the drives that do not confirm (``axes.master.bus.quick_stop``); the run ends when that is done (called
        with the SYNC lock and the group lock held). ``fault``: the bus's report that caused it, told
        as its event once the requests are out."""
        sync = self.bus.sync
        for feeder in self._feeders:
            feeder.enabled = False
        res = self._result(result, message, link)
        res.fault_sync = sync.count
        self._ending = res  # before the requests: their confirmations end the run (_quick_stopped)
        self._halted_at = time.monotonic()
        self._halt_deadline = None
        # the requests first (no SYNC can go out meanwhile: the SYNC lock is held), the rest after
        self.last_quick_stop = self.bus.quick_stop([lk.node_id for lk in self.links], message, self._quick_stopped)
        sync.stop()
        self.readiness.forget()
        if fault is not None:
            self._event(EventKind(fault.kind.value), fault.message, link)
        self._event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)

    def _quick_stop_too(self, message: str, link: AxisLink | None, fault: BusFault) -> None:
        """A halt by the synchronous RPDO is under way and SYNC fails: quick stop by SDO as well."""
        self._halt_deadline = None
        self.last_quick_stop = self.bus.quick_stop([lk.node_id for lk in self.links], message, self._quick_stopped)
        self.bus.sync.stop()
        self._event(EventKind(fault.kind.value), fault.message, link)
        self._event(EventKind.HALTED, f"all axes quick stopped by SDO (no SYNC): {message}", link)

    def _quick_stopped(self, stop: QuickStop) -> None:
        """Every drive confirmed the quick stop or was sent NMT stop (the quick stop's thread)."""
        ending = self._ending
        if ending is None:
            return
        ending.halt_latency_s = stop.latency_s
        ending.message = f"{ending.message}; {stop.describe()}"
        if stop.nmt_stopped or stop.unsent:
            self.configuration.forget()  # NMT STOPPED: the next start configures again
        self._end(ending)

    def _check_halted(self, n: int) -> None:
        assert self._ending is not None
        if self._halt_deadline is None:
            return  # quick stopped by SDO: the quick stop ends the run (_quick_stopped)
        if n < (self._ending.halt_sync or 0):
            return
        elapsed = n - (self._start_sync or n) - 1  # a stop ramp is over once its drive held its end one SYNC
        still = [
            lk
            for lk, feeder in zip(self.links, self._feeders, strict=True)
            if decode_state(lk.statusword) == PowerState.OPERATION_ENABLED
            and (not lk.statusword & _TARGET_REACHED or (feeder.enabled and not feeder.finished(elapsed, False)))
        ]
        if not still or n >= self._halt_deadline:
            self.bus.sync.stop()
            self._end(self._ending)

    def stop(self, reason: str = "stop requested") -> None:
        """Halt all axes on the next SYNC (any thread). The run then ends with Result.STOPPED; a
        start still configuring the drives does not start the motion."""
        if self._starting:
            self._stop_request = reason
        if self.state.holder is not self:  # a homing holds the cell
            self.state.stop(reason)
        sync = self.bus.sync
        with sync.lock, self._lock:
            if not self._running or self._ending is not None:
                return
            if not sync.running and not sync.lockstep:  # no SYNC to carry the halt word
                self._quick_stop(Result.STOPPED, reason, None)
            else:
                self._halt(Result.STOPPED, reason, None)
