"""Homing a cell's axes (CiA 402 homing mode 6), stage by stage, on the cell's SYNC.

An incremental encoder does not know where the axis is at power-on: position 0 is wherever the motor
stood, so a program, the 0x607D limits and every plan "from the current position" mean nothing until
the axis is referenced. Each axis with a ``HomingConfig`` has its method, speeds, acceleration and
home offset written at configuration (``Profile.write_homing``); ``CellHoming.run(stages)`` then homes
the axes in the cell's order: the axes of one stage together (a gantry's Z first, then X and Y).

For each stage: every axis of it OPERATION ENABLED with bits 4 and 8 low (SDO), 0x6060 = 6 (SDO),
then the start word (bit 4 rising) through the synchronous RPDO, so that the stage starts on one
SYNC; the SYNC then runs (lockstep in simulation, the wall clock on a real cell) and every answer is
judged from the synchronous TPDO's statusword: bit 12 with bit 10 (homing attained, at rest) is
done, bit 13 a homing error, a fault bit a drive fault; a stage that is not done within its axes'
``timeout_s`` (of SYNC periods) is a timeout. A homing error, a fault, an EMCY, a lost drive or
``stop()`` halts every axis of the cell (bit 8, on the next SYNC) and ends the homing there: nothing
of the later stages moves. Afterwards every axis is back in interpolated position mode (0x6060 = 7)
and is enabled afresh by the next start. An axis that attained its home must read its home offset
there (0x6064 = 0x607C, maxon's 0x2081 on the EPOS2, ``_confirm``), else it is not homed. The
cell then counts an axis homed until its drive boots again (boot-up message, NMT reset, power loss)
or its heartbeat is lost (``CellRunState.homed``). A homing holds the cell (``CellRunState.claim``)
as a program run does: one activity at a time, and a stop of the cell's group reaches it there.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

import can

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import (
    CONTROLWORD_ENABLE_OPERATION,
    CONTROLWORD_HALT_HOMING,
    CONTROLWORD_START_HOMING,
    PowerState,
    Statusword,
    decode_state,
)
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.master.bus.faults import BusFault, FaultKind
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.master.link import AxisLink, DriveError

if TYPE_CHECKING:
    from pvtflow.axes.master.group.axis_group import AxisGroup

_ATTAINED = int(Statusword.HOMING_ATTAINED)
_HOMING_ERROR = int(Statusword.HOMING_ERROR)
_TARGET_REACHED = int(Statusword.TARGET_REACHED)
_FAULT = int(Statusword.FAULT)
ENABLED_WORD = int(CONTROLWORD_ENABLE_OPERATION)  # 0x000F
START_WORD = CONTROLWORD_START_HOMING  # 0x001F: a rising bit 4 starts homing
HALT_WORD = CONTROLWORD_HALT_HOMING  # 0x011F
HALT_TIMEOUT_S = 5.0  # of drive time: how long the halted axes may take to stand still
WALL_GRACE_S = 10.0  # beyond the SYNC-counted timeout: a cell whose SYNC stalls is given up


HomingResult = Result  # a homing ends like a run when a drive or the bus fails: one enum (axes.master.group.outcome)


class HomingEventKind(StrEnum):
    """What a homing reports as it goes (``CellHoming(on_event=...)``)."""

    HOMING = "homing"  # a stage started
    HOMED = "homed"  # a stage's axes are homed
    HALTED = "halted"  # every axis was halted: the homing ends


class HomingRequestError(ValueError):
    """A homing request that names what the cell does not have (nothing moves)."""


@dataclass
class AxisHoming:
    """One axis after a homing: its method, whether it is homed, how long its stage took (drive time,
    from the start SYNC to the SYNC that reported it attained and at rest) and where it stands."""

    joint: str
    node_id: int
    method: int
    homed: bool = False
    time_s: float | None = None
    position_qc: int | None = None
    statusword: int = 0

    def to_json(self) -> dict[str, object]:
        return {
            "joint": self.joint,
            "node_id": self.node_id,
            "method": self.method,
            "homed": self.homed,
            "time_s": self.time_s,
            "position_qc": self.position_qc,
            "statusword": self.statusword,
        }


@dataclass
class HomingOutcome:
    result: HomingResult
    message: str
    joint: str | None = None  # the axis that ended it (None: all / none)
    node_id: int | None = None
    stages: list[list[str]] = field(default_factory=list)
    axes: list[AxisHoming] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.result.ok

    def to_json(self) -> dict[str, object]:
        return {
            "result": self.result.value,
            "message": self.message,
            "joint": self.joint,
            "node_id": self.node_id,
            "stages": self.stages,
            "axes": [a.to_json() for a in self.axes],
        }


def homing_stages(
    axes: Sequence[AxisConfig], order: Sequence[Sequence[str]] | None = None, joints: Iterable[str] | None = None
) -> list[list[str]]:
    """The stages to home ``joints`` (None: every axis with homing) in: the cell's ``order`` (stages
    of joint names), the axes of its stages that are asked for, in that order; without an order, one
    axis at a time in the cell's order. Raises HomingRequestError for a joint the cell does not have
    or that has nothing to home."""
    homing = [a.joint for a in axes if a.homing is not None]
    known = {a.joint for a in axes}
    if joints is None:
        wanted = set(homing)
    else:
        wanted = set()
        for joint in joints:
            if joint not in known:
                raise HomingRequestError(f"unknown axis {joint!r} (the cell has {', '.join(a.joint for a in axes)})")
            if joint not in homing:
                raise HomingRequestError(f"axis {joint!r} has no homing: nothing to home (an absolute encoder)")
            wanted.add(joint)
    plan = [list(stage) for stage in order] if order else [[j] for j in homing]
    placed = {j for stage in plan for j in stage}
    plan += [[j] for j in homing if j not in placed]  # an order that leaves some out: those after it, one by one
    return [kept for stage in plan if (kept := [j for j in stage if j in wanted])]


class CellHoming:
    """Homes the axes of one ``AxisGroup``; ``run(stages)`` blocks, ``stop(reason)`` from any thread."""

    def __init__(
        self, group: AxisGroup, on_event: Callable[[HomingEventKind, str, str | None], None] | None = None
    ) -> None:
        self.group = group
        self.bus = group.bus
        self.on_event = on_event
        self._lock = threading.RLock()
        self._done = threading.Event()
        self._stage: list[int] = []  # indices into group.links
        self._start_sync = 0
        self._attained: dict[int, int] = {}  # link index -> the SYNC that reported it attained
        self._timeout_syncs = 0
        self._ending: HomingOutcome | None = None
        self._halt_deadline: int | None = None
        self._stop_request: str | None = None
        self._active = False

    # --- the run -----------------------------------------------------------------------------------
    def run(self, stages: Sequence[Sequence[str]]) -> HomingOutcome:
        group = self.group
        by_joint = {link.joint: i for i, link in enumerate(group.links)}
        plan = [[by_joint[j] for j in stage] for stage in stages]
        report = {
            i: AxisHoming(group.links[i].joint, group.links[i].node_id, self._method(i))
            for stage in plan
            for i in stage
        }
        names = [[group.links[i].joint for i in stage] for stage in plan]
        outcome = HomingOutcome(HomingResult.HOMED, "", stages=names, axes=list(report.values()))
        group.state.claim(self, "a program or a homing is already running on this cell")
        self.bus.on_fault(self._on_fault)
        touched: list[int] = []
        try:
            try:
                group.configure_if_needed()
            except DriveError as exc:
                return self._outcome(outcome, HomingResult.CONFIGURATION_ERROR, str(exc), exc.node_id)
            for stage in plan:
                touched += stage
                ending = self._home_stage(stage, report)
                if ending is not None:
                    outcome.result, outcome.message = ending.result, ending.message
                    outcome.joint, outcome.node_id = ending.joint, ending.node_id
                    break
                ending = self._confirm(stage)
                if ending is not None:
                    outcome.result, outcome.message, outcome.joint, outcome.node_id = ending
                    break
                for i in stage:
                    group.state.mark_homed(i)
                    report[i].homed = True
                self._event(HomingEventKind.HOMED, f"{', '.join(group.links[i].joint for i in stage)} homed", None)
            else:
                outcome.message = f"homed {', '.join(' + '.join(s) for s in names)}" if names else "nothing to home"
        finally:
            self._leave_homing_mode(touched, report)
            self.bus.remove_fault_callback(self._on_fault)
            group.state.release(self)
        return outcome

    def _confirm(self, stage: list[int]) -> tuple[HomingResult, str, str, int] | None:
        """Each axis of a stage that attained its home reads its 0x6064 there: it must read the cell's
        ``offset_qc`` (within the group's start tolerance), written where the drive defines the
        position at home (``Profile.home_position_object``: CiA 402's 0x607C; maxon's 0x2081, its
        0x607C being a move past the reference). A drive that reads anything else is not homed, and
        says why."""
        for i in stage:
            link = self.group.links[i]
            homing = link.config.homing
            if homing is None:
                continue
            try:
                position = link.read(od.POSITION_ACTUAL_VALUE, 0, "i")
            except DriveError as exc:
                return HomingResult.HOMING_ERROR, str(exc), link.joint, link.node_id
            if abs(position - homing.offset_qc) > self.group.start_tolerance_qc:
                where = self.group.profiles[i].home_position_object
                name = "home offset" if where == od.HOME_OFFSET else "home position"
                return (
                    HomingResult.HOMING_ERROR,
                    f"{link.joint} reads 0x6064 = {position} qc at its home, not its {name} "
                    f"0x{where:04X} = {homing.offset_qc} qc: the drive defines it otherwise (or holds "
                    f"another value); not homed",
                    link.joint,
                    link.node_id,
                )
        return None

    def _method(self, i: int) -> int:
        homing = self.group.links[i].config.homing
        return homing.method if homing is not None else 0

    def _outcome(
        self, outcome: HomingOutcome, result: HomingResult, message: str, node_id: int | None
    ) -> HomingOutcome:
        outcome.result, outcome.message, outcome.node_id = result, message, node_id
        link = next((lk for lk in self.group.links if lk.node_id == node_id), None)
        outcome.joint = link.joint if link is not None else None
        return outcome

    def _home_stage(self, stage: list[int], report: dict[int, AxisHoming]) -> HomingOutcome | None:
        """One stage: enable, mode 6, start on one SYNC, wait for every axis attained (or the end)."""
        links = [self.group.links[i] for i in stage]
        try:
            for link in links:  # a fault is acknowledged by someone (recover), never reset behind their back
                if decode_state(link.read_statusword()).is_fault:
                    return HomingOutcome(
                        HomingResult.DRIVE_FAULT,
                        f"axis {link.joint} (node {link.node_id}) is in FAULT "
                        f"(statusword 0x{link.statusword:04X}): recover first",
                        link.joint,
                        link.node_id,
                    )
            for link in links:
                link.reach(PowerState.OPERATION_ENABLED)
                link.write_controlword(ENABLED_WORD)  # bits 4 and 8 low: the start is a rising edge
                link.write(od.MODES_OF_OPERATION, 0, od.HOMING_MODE, "b")
                shown = link.read(od.MODES_OF_OPERATION_DISPLAY, 0, "b")
                if shown != od.HOMING_MODE:
                    raise DriveError(link.node_id, f"0x6061 shows mode {shown} after 0x6060 = {od.HOMING_MODE}")
        except DriveError as exc:
            link = next(lk for lk in links if lk.node_id == exc.node_id)
            return HomingOutcome(HomingResult.CONFIGURATION_ERROR, str(exc), link.joint, link.node_id)
        timeout_s = max(lk.config.homing.timeout_s for lk in links if lk.config.homing is not None)
        sync = self.bus.sync
        period_ms = self.bus.config.sync_period_ms
        with self._lock:
            if self._stop_request is not None:
                return HomingOutcome(HomingResult.STOPPED, self._stop_request)
            self._stage = stage
            self._attained = {}
            self._ending = None
            self._halt_deadline = None
            self._timeout_syncs = max(1, round(timeout_s * 1000.0 / period_ms))
            self._done.clear()
        names = ", ".join(lk.joint for lk in links)
        sync.keep_period()
        with sync.lock, self._lock:
            self._active = True
            self._start_sync = sync.count + 1
            for link in links:
                link.send_controlword(START_WORD)  # synchronous RPDO: every axis starts on the same SYNC
            sync.add_listener(self._on_sync)
            self.bus.watch.arm_sync_watch()
            sync.start()
        self._event(HomingEventKind.HOMING, f"homing {names} from SYNC {self._start_sync}", None)
        deadline = time.monotonic() + timeout_s + HALT_TIMEOUT_S + WALL_GRACE_S
        try:
            while not self._done.wait(0.05):
                if time.monotonic() > deadline:
                    with sync.lock, self._lock:
                        if self._ending is None:
                            self._halt(HomingResult.TIMEOUT, f"homing {names}: the SYNC stalled", None)
                        self._end()
        except KeyboardInterrupt:  # Ctrl-C in the thread that waits: halt every axis before leaving
            self.stop("interrupted")
            self._done.wait(HALT_TIMEOUT_S + WALL_GRACE_S)
            sync.remove_listener(self._on_sync)
            raise
        sync.remove_listener(self._on_sync)
        self.bus.watch.disarm_sync_watch()
        for i in stage:
            n = self._attained.get(i)
            report[i].time_s = None if n is None else (n - self._start_sync) * period_ms / 1000.0
        return self._ending if self._ending is not None and not self._ending.ok else None

    # --- SYNC and faults (the bus's threads) -----------------------------------------------------
    def _on_sync(self, n: int) -> None:
        with self._lock:
            if not self._active or n < self._start_sync:
                return
            if self._ending is not None:
                self._check_halted(n)
                return
            for i in self._stage:
                link = self.group.links[i]
                sw = link.statusword
                if sw & _FAULT:
                    why = f"statusword 0x{sw:04X} ({decode_state(sw).value})"
                    if link.last_emcy is not None:
                        why += f", last EMCY 0x{link.last_emcy[0]:04X} {link.last_emcy[1]}"
                    self._halt(
                        HomingResult.DRIVE_FAULT, f"axis {link.joint} (node {link.node_id}) faulted: {why}", link
                    )
                    return
                if sw & _HOMING_ERROR:
                    self._halt(
                        HomingResult.HOMING_ERROR,
                        f"axis {link.joint} (node {link.node_id}): homing error (statusword 0x{sw:04X})",
                        link,
                    )
                    return
                if sw & _ATTAINED and sw & _TARGET_REACHED and i not in self._attained:
                    self._attained[i] = n
            if len(self._attained) == len(self._stage):
                self._ending = HomingOutcome(HomingResult.HOMED, "stage homed")
                self._end()
            elif n - self._start_sync >= self._timeout_syncs:
                waiting = [self.group.links[i].joint for i in self._stage if i not in self._attained]
                ms = self._timeout_syncs * self.bus.config.sync_period_ms
                self._halt(HomingResult.TIMEOUT, f"{', '.join(waiting)} not homed within {ms / 1000.0:g} s", None)

    def _on_fault(self, fault: BusFault) -> None:
        if fault.kind.warning or fault.kind is FaultKind.SYNC_GAP:
            # a drive in homing mode searches on its own: SYNC only paces the master's reading of it
            # (a SYNC that stops altogether is SYNC_STOPPED, or LOST_SYNC when nobody answers)
            return
        kind = {
            FaultKind.EMCY: HomingResult.EMCY,
            FaultKind.HEARTBEAT: HomingResult.HEARTBEAT_LOST,
            FaultKind.NMT: HomingResult.HEARTBEAT_LOST,
        }.get(fault.kind, HomingResult.LOST_SYNC)  # LOST_SYNC, and the master's own SYNC failures
        link = next((lk for lk in self.group.links if lk.node_id == fault.node_id), None)
        with self.bus.sync.lock, self._lock:
            if not self._active or self._ending is not None:
                return
            self._halt(kind, fault.message, link)
            if fault.kind.sync_failed:  # the halt word waits for a SYNC that will not come
                self.bus.quick_stop([lk.node_id for lk in self.group.links], fault.message)
            if kind in (HomingResult.HEARTBEAT_LOST, HomingResult.LOST_SYNC):
                self._end()  # a drive that is gone answers no SYNC: do not wait for it to stand still

    def stop(self, reason: str = "stop requested") -> None:
        """Halt every axis on the next SYNC; the homing ends STOPPED (any thread)."""
        with self.bus.sync.lock, self._lock:
            self._stop_request = reason
            if self._active and self._ending is None:
                self._halt(HomingResult.STOPPED, reason, None)

    def _halt(self, result: HomingResult, message: str, link: AxisLink | None) -> None:
        """Every axis of the cell halts (bit 8) on the next SYNC; called with the SYNC lock held."""
        unsent = []
        for lk in self.group.links:
            try:
                lk.send_controlword(HALT_WORD)
            except can.CanError as exc:
                unsent.append(f"node {lk.node_id}: {exc}")
        lost = f" (not sent to {'; '.join(unsent)})" if unsent else ""
        self._ending = HomingOutcome(result, message, link.joint if link else None, link.node_id if link else None)
        self._halt_deadline = self.bus.sync.count + max(
            1, round(HALT_TIMEOUT_S * 1000.0 / self.bus.config.sync_period_ms)
        )
        self._event(HomingEventKind.HALTED, f"all axes halted: {message}{lost}", link)

    def _check_halted(self, n: int) -> None:
        moving = [
            i
            for i in self._stage
            if decode_state(self.group.links[i].statusword) is PowerState.OPERATION_ENABLED
            and not self.group.links[i].statusword & _TARGET_REACHED
        ]
        if not moving or (self._halt_deadline is not None and n >= self._halt_deadline):
            self._end()

    def _end(self) -> None:
        self._active = False
        self.bus.sync.stop()
        self._done.set()

    # --- afterwards --------------------------------------------------------------------------------
    def _leave_homing_mode(self, touched: list[int], report: dict[int, AxisHoming]) -> None:
        """Every axis that was in homing mode: back to interpolated position mode, bits 4 and 8 low,
        and its position and statusword read (the outcome's); every axis is enabled afresh at the
        next start (its buffer cleared: a halt may have left it anything)."""
        group = self.group
        for i in touched:
            link = group.links[i]
            try:
                sw = link.read_statusword()
                report[i].statusword = sw
                report[i].position_qc = link.read_position()
                if decode_state(sw) is PowerState.OPERATION_ENABLED:
                    link.write_controlword(ENABLED_WORD)
                link.write(od.MODES_OF_OPERATION, 0, od.INTERPOLATED_POSITION_MODE, "b")
            except DriveError:
                continue  # a drive that is gone is configured again before its next use
        group.state.readiness.forget()  # its mode changed: every axis is enabled afresh at the next start

    def _event(self, kind: HomingEventKind, message: str, link: AxisLink | None) -> None:
        if self.on_event is not None:
            self.on_event(kind, message, link.joint if link is not None else None)
