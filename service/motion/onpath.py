"""The on-path stop, ``pause``, ``resume`` and ``override``: the running motion changed from ``t0`` on (issue 37).

The motion's path is what the drives make of its program (``planner.program_motion``); a change re-times the
rest of it (``planner.onpath_stop``), turns that into records from where each drive's held records end
(``planner.onpath_program``) and replaces the feeders' records not yet sent (``axes.master.splice``), all
while the group's lock is held. What cannot be made in time, or would not validate, is a quick stop instead
(stop, pause) or refused with nothing changed (override). Faults and lost SYNC never come here: the axis
group halts them the quick way.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.master.splice import SpliceAt, SpliceRefusedError, record_grid_ms
from pvtflow.planner.build import BuildError, build_program
from pvtflow.planner.knots import KnotOptions
from pvtflow.planner.limits import JointLimits
from pvtflow.planner.onpath_program import (
    BACK_RAMP_SHARES,
    JERK_SHARES,
    RAMP_SHARES,
    REJOIN_JERK_SHARES,
    WINDOW_JERK_RATIO,
    ChangeError,
    NoJoinError,
    NoRampError,
    back_to_plan_on_grid,
    brake_on_grid,
    brake_with_jerk_on_grid,
    change_start_ms,
    changed_program,
    jerk_resume_from_rest,
    on_grid,
    override_on_grid,
    records_jerk_ratio,
    rejoin_on_grid,
    rejoined_program,
    resume_from_rest,
    resumed_program,
)
from pvtflow.planner.onpath_stop import OnPathStop, stopped_motion
from pvtflow.planner.path import PlanError
from pvtflow.planner.program_motion import program_motion
from pvtflow.planner.trajectory import Trajectory
from pvtflow.service.api import ApiError, CellState, ErrorCode
from pvtflow.service.config import CellConfig
from pvtflow.service.motion.board import CellBoard
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.motion.runs import Motion

log = logging.getLogger("pvtflow.motion")
_T = TypeVar("_T")


class _RunsToItsEnd(Exception):  # noqa: N818 (not an error: the motion's own end is its stop)
    """The motion's own end is where a braking from t0 would take it, as fast: it runs to its end."""


_CHANGE_ERRORS = (SpliceRefusedError, ChangeError, PlanError, BuildError, ValueError)
# the scales an override falls back to, in turn, where the records of a faster one do not validate (at the
# plan's own 0x60C5 the records' rounding may need room the knot placement's integer repair would find)
FALLBACK_SCALES = (0.97, 0.95, 0.9, 0.85, 0.8, 0.7)


def planned_jerk(metadata: dict[str, Any]) -> NDArray[np.float64] | None:
    """The jerk limit the motion was planned with (joint units/s^3, inf: none for that joint), None: none."""
    jerk = metadata.get("max_jerk")
    if jerk is None:
        return None
    out = np.array([np.inf if j is None else float(j) for j in jerk], dtype=float)
    return out if np.any(np.isfinite(out)) else None


def _scales(scale: float) -> list[float]:
    return [scale, *(s for s in FALLBACK_SCALES if s < scale)]


@dataclass
class MotionPath:
    """A motion's path and timing as the drives run it (program time)."""

    motion_id: str
    planned: Trajectory  # the program as it was started, at s' = 1
    running: Trajectory  # as it runs now (after overrides, a braking)
    program: PvtProgram  # the records as they run now, in the group's axis order
    scale: float = 1.0
    stop: OnPathStop | None = None  # the braking, once stopped or paused on the path
    original: PvtProgram | None = None  # the records as the feeders held them at the first change


@dataclass
class Paused:
    """A motion paused on its path: what ``resume`` continues."""

    motion: Motion
    path: MotionPath
    remaining: float  # the share of the motion's path (program time) still to go


@dataclass(eq=False)
class PathChanges:
    """Changes of the running motion along its path, and the paused motion."""

    cell: CellConfig
    drives: CellDrives
    board: CellBoard
    limits: JointLimits
    paths: dict[str, MotionPath] = field(default_factory=dict)
    paused: Paused | None = None

    # --- the motion's path -------------------------------------------------------------------------
    def path_of(self, motion: Motion, group: AxisGroup) -> MotionPath:
        """The motion's path (made at its first change: a few ms)."""
        path = self.paths.get(motion.motion_id)
        if path is None:
            program = PvtProgram(self.cell.name, group.programs, dict(motion.program.metadata))
            timing = program_motion(program)
            path = MotionPath(motion.motion_id, timing, timing, program)
            self.paths = {motion.motion_id: path}  # the running motion's only
        return path

    def scale_of(self, motion: Motion | None) -> float | None:
        path = self.paths.get(motion.motion_id) if motion is not None else None
        return None if motion is None or motion.done.is_set() else (round(path.scale, 4) if path is not None else 1.0)

    # --- stop and pause on the path -----------------------------------------------------------------
    def brake(self, group: AxisGroup, motion: Motion, reason: str) -> tuple[dict[str, Any] | None, str | None]:
        """Brake the running motion on its path (called with the drives' lock held): (the braking's times,
        None), or (None, why not: the caller stops the quick way)."""
        try:
            path = self.path_of(motion, group)
        except _CHANGE_ERRORS as exc:
            return None, f"the motion's path: {exc}"
        grid_ms = record_grid_ms(group.programs, self.cell.bus.sync_period_ms)
        jerk = planned_jerk(path.program.metadata)
        made: dict[str, Any] = {}

        def make(at: SpliceAt) -> list[Any]:
            begin = change_start_ms(at.t0_ms, at.join_ms, at.programs)
            program = PvtProgram(self.cell.name, at.programs, dict(path.program.metadata))
            for jerk_share in JERK_SHARES if jerk is not None else (None,):
                try:
                    if jerk is None:
                        stop = brake_on_grid(path.running, begin / 1000.0, self.limits, grid_ms / 1000.0)
                    else:  # a motion planned with a jerk limit brakes within it too
                        stop = brake_with_jerk_on_grid(
                            path.running, begin / 1000.0, self.limits, jerk, grid_ms / 1000.0, jerk_share
                        )
                except PlanError:
                    if begin < 0.5 * path.running.duration * 1000.0:
                        raise
                    raise _RunsToItsEnd from None  # at rest on the path's end already, or nearly
                if stop.s_end >= float(path.running.gridpoints[-1]) - 1e-9:
                    raise _RunsToItsEnd  # the path ends before a braking would: its own end is the fastest stop
                whole = stopped_motion(path.running, stop)
                end_ms = stop.t_end * 1000.0
                new, rows = changed_program(program, at.first, at.join_ms, begin, whole, end_ms, self.limits)
                if jerk is None or (ratio := records_jerk_ratio(new, jerk, begin)) <= WINDOW_JERK_RATIO:
                    break
            else:
                raise ChangeError(f"the braking's records reach {ratio:.2f} x the planned jerk limit (window jerk)")
            made.update(stop=stop, whole=whole, program=new, original=program)
            group.ends_as((Result.STOPPED, reason))  # the stop's outcome as the quick one's: the reason
            return rows

        try:
            at = group.splice(make)
        except _RunsToItsEnd:  # nothing replaced: the motion ends as planned, on its path
            group.ends_as((Result.STOPPED, reason))
            end = float(path.program.duration_ms)
            return {
                "requested_ms": None,
                "begun_ms": None,
                "ended_ms": end,
                "begun_sync": None,
                "ended_sync": None,
            }, None
        except _CHANGE_ERRORS as exc:
            group.ends_as(None)
            log.info("path stop of %s made the quick way: %s", motion.motion_id, exc)
            return None, str(exc)
        stop: OnPathStop = made["stop"]
        path.running, path.program, path.stop = made["whole"], made["program"], stop
        if path.original is None:
            path.original = made["original"]  # the records as started: what a resume joins
        begun = stop.t_start * 1000.0
        ended = on_grid(stop.t_end, grid_ms / 1000.0) * 1000.0  # the SYNC from which every axis stands
        return {
            "requested_ms": round(at.now_ms, 3),
            "begun_ms": round(begun, 3),
            "ended_ms": round(ended, 3),
            "begun_sync": at.sync_at(begun),
            "ended_sync": at.sync_at(ended),
        }, None

    def pause_kept(self, motion: Motion) -> Paused | None:
        """The motion stopped on its path by a pause: kept for ``resume`` (None: it ended otherwise)."""
        path = self.paths.get(motion.motion_id)
        result = motion.result
        if path is None or path.stop is None or result is None or result.result is not Result.STOPPED:
            return None
        total = float(path.planned.gridpoints[-1])
        remaining = max(0.0, (total - path.stop.s_end) / total) if total > 0 else 0.0
        self.paused = Paused(motion, path, remaining)
        return self.paused

    def end_pause(self) -> Paused | None:
        """A stop (or a fault) while paused: the paused motion is over."""
        paused, self.paused = self.paused, None
        return paused

    # --- resume ------------------------------------------------------------------------------------
    def resume_program(self) -> tuple[Paused, PvtProgram]:
        """The program that continues the paused motion from where its axes stand, at rest, at its planned
        timing: a ramp up to the planned speed (``BACK_RAMP_SHARES`` of 0x60C5 tried in turn), then the
        motion's own records to its end (``onpath_program.resumed_program``, validated as every program); where
        no ramp joins them, for a motion planned with a jerk limit the re-timing from rest that joins them
        (``_resume_rejoined``), else the rest of the path placed from rest as a plan (``_from_rest``). NOT_ALLOWED
        when nothing is paused."""
        paused = self.paused
        if paused is None or self.board.state != CellState.PAUSED:
            raise ApiError(ErrorCode.NOT_ALLOWED, "nothing is paused on this cell: resume continues a paused motion")
        path = paused.path
        assert path.stop is not None and path.original is not None
        grid_ms = record_grid_ms(path.program.axes, self.cell.bus.sync_period_ms)
        rest = path.stop.t_end  # the braking's rest, near a grid time: the records hold it to the next one
        phase = rest - on_grid(rest, grid_ms / 1000.0)  # an original record's end lands on the resumed grid
        jerk = planned_jerk(path.program.metadata)
        failed: Exception | None = None
        program = None
        joined = True  # the program's own records after the ramp, or (False) the rest placed from rest
        for share, jerk_share in self._ramps(jerk, BACK_RAMP_SHARES if jerk is None else RAMP_SHARES):
            try:
                back = back_to_plan_on_grid(
                    path.planned,
                    path.running,
                    rest,
                    self.limits,
                    grid_ms / 1000.0,
                    share,
                    phase,
                    jerk if jerk_share is not None else None,
                    jerk_share or JERK_SHARES[0],
                )
                within = jerk if jerk_share is not None else None
                candidate = resumed_program(
                    path.program, back, path.original, rest * 1000.0, self.limits, grid_ms, within
                )
                self._hold_jerk(candidate, within, 0.0)
                program = candidate  # only one that holds: a refused one must not be left in ``program``
                break
            except NoRampError as exc:
                failed = exc
                break  # nor at any lower share
            except _CHANGE_ERRORS as exc:
                failed = exc
        if program is None and jerk is not None:  # no S-curve joins: the re-timing from rest that joins the plan
            try:
                program = self._resume_rejoined(path, rest, phase, grid_ms, jerk)
            except _CHANGE_ERRORS as exc:
                failed = exc
        if program is None:  # no ramp joins the planned records: the rest of the path from rest, placed as a plan
            log.info("resume of %s from rest to its end as a plan: %s", paused.motion.motion_id, failed)
            joined = False
            try:
                program = self._from_rest(path, grid_ms, jerk)
            except _CHANGE_ERRORS as exc:
                raise ApiError(
                    ErrorCode.PLAN_FAILED, f"the rest of the paused motion could not be planned: {exc}"
                ) from None
        meta = {**program.metadata, "resumes": paused.motion.motion_id, "resumed_on_planned_records": joined}
        program = PvtProgram(program.cell, program.axes, meta)
        here = [int(a.records[-1, 0]) for a in path.program.axes]
        start = [int(a.records[0, 0]) for a in program.axes]
        if any(abs(h - s) > 1 for h, s in zip(here, start, strict=True)):  # the same path point, rounded alike
            raise ApiError(
                ErrorCode.PLAN_FAILED, f"the resumed motion would start at {start} qc, the axes are at {here}"
            )
        return paused, program

    def _resume_rejoined(
        self, path: MotionPath, rest: float, phase: float, grid_ms: int, jerk: NDArray[np.float64]
    ) -> PvtProgram:
        """A jerk-limited motion's resume as the re-timing of the rest of its path from rest that joins the plan
        delayed by the fewest grid steps (``onpath_program.rejoin_on_grid``, ``REJOIN_JERK_SHARES`` in turn), then
        its own records; ChangeError where none holds the window jerk."""
        assert path.original is not None

        def attempt(jerk_share: float) -> PvtProgram:
            back = rejoin_on_grid(
                path.planned, path.running, rest, self.limits, jerk, grid_ms, jerk_share, phase_s=phase
            )
            program = resumed_program(path.program, back, path.original, rest * 1000.0, self.limits, grid_ms, jerk)
            self._hold_jerk(program, jerk, 0.0)
            return program

        return self._rejoin_shares(attempt)

    @staticmethod
    def _rejoin_shares(attempt: Callable[[float], _T]) -> _T:
        """``attempt`` at each of ``REJOIN_JERK_SHARES`` in turn until one holds; none lower than one where no
        re-timing joins the plan (``NoJoinError``); the last failure where none holds."""
        failed: Exception = ChangeError("no jerk share tried")
        floor = 0.0
        for jerk_share in REJOIN_JERK_SHARES:
            if jerk_share <= floor:
                continue
            try:
                return attempt(jerk_share)
            except NoJoinError as exc:
                failed, floor = exc, jerk_share
            except _CHANGE_ERRORS as exc:
                failed = exc
        raise failed

    def _from_rest(self, path: MotionPath, grid_ms: int, jerk: NDArray[np.float64] | None) -> PvtProgram:
        """The rest of a paused motion's path from rest, as fast as its limits allow under its planned speed
        (``resume_from_rest``; planned with a jerk limit: ``jerk_resume_from_rest``, within it), its records
        placed as a plan's (``build_program``: the knot placement's integer repair holds 0x60C5 at full speed,
        and the window jerk where there is a limit). ChangeError where its records pass the jerk limit."""
        assert path.stop is not None
        if jerk is None:
            rest_motion = resume_from_rest(path.planned, path.stop, self.limits)
        else:
            rest_motion, scale = jerk_resume_from_rest(path.planned, path.stop, self.limits, jerk)
            log.info("resume from rest within the jerk limit at %.2f of the planned speed", scale)
        opts = KnotOptions(
            dwell_ms=max(1, grid_ms),
            tolerance_qc=self.cell.planning.position_tolerance_qc,
            max_jerk=path.program.metadata.get("max_jerk") if jerk is not None else None,
        )
        axes = {a.joint: a for a in self.cell.ordered_axes()}  # what knot placement takes (hashable)
        built = build_program(rest_motion, [axes[a.joint] for a in path.program.axes], self.cell.name, opts)
        program = PvtProgram(
            built.program.cell, built.program.axes, {**path.program.metadata, **built.program.metadata}
        )
        self._hold_jerk(program, jerk, 0.0)
        return program

    # --- override ----------------------------------------------------------------------------------
    @staticmethod
    def _ramps(
        jerk: NDArray[np.float64] | None, shares: tuple[float, ...] = RAMP_SHARES
    ) -> list[tuple[float, float | None]]:
        """The ramps up to a speed tried in turn: (share of 0x60C5, share of the jerk limit or None). A motion
        planned with a jerk limit tries S-curves within it only (an acceleration-limited ramp passes it many
        times over)."""
        if jerk is None:
            return [(share, None) for share in shares]
        return [(share, js) for share in shares for js in JERK_SHARES]

    @staticmethod
    def _hold_jerk(program: PvtProgram, jerk: NDArray[np.float64] | None, from_ms: float) -> None:
        """ChangeError where the records' window jerk from ``from_ms`` on passes 1.2 x ``jerk`` (None: no check)."""
        if jerk is not None and (ratio := records_jerk_ratio(program, jerk, from_ms)) > WINDOW_JERK_RATIO:
            raise ChangeError(f"the change's records reach {ratio:.2f} x the planned jerk limit (window jerk)")

    def _back_to_plan(
        self,
        path: MotionPath,
        program: PvtProgram,
        at: SpliceAt,
        begin: float,
        grid_ms: int,
        jerk: NDArray[np.float64] | None,
        in_time: Callable[[], bool] | None = None,
    ) -> tuple[PvtProgram, list[NDArray[np.int64]], Trajectory]:
        """The records that bring the motion back to its planned timing (the original records joined after a
        ramp, ``_ramps`` tried in turn: within ``jerk`` only, or None: limited by acceleration, all of 0x60C5
        first; for ``jerk`` where no S-curve holds it, ``_rejoin``); ChangeError where none validates."""
        assert path.original is not None
        failed: Exception | None = None
        for share, jerk_share in self._ramps(jerk, BACK_RAMP_SHARES if jerk is None else RAMP_SHARES):
            try:
                back = back_to_plan_on_grid(
                    path.planned,
                    path.running,
                    begin / 1000.0,
                    self.limits,
                    grid_ms / 1000.0,
                    share,
                    max_jerk=jerk if jerk_share is not None else None,
                    jerk_share=jerk_share or JERK_SHARES[0],
                )
                within = jerk if jerk_share is not None else None
                new, rows = rejoined_program(
                    program, at.first, at.join_ms, begin, back, path.original, self.limits, max_jerk=within
                )
                self._hold_jerk(new, jerk if jerk_share is not None else None, begin)
            except NoRampError as exc:
                failed = exc
                break  # nor at any lower share
            except _CHANGE_ERRORS as exc:
                failed = exc
                continue
            return new, rows, back.motion
        if jerk is not None:  # no S-curve in path speed holds the limit: a re-timing that joins the plan later
            try:
                return self._rejoin(path, program, at, begin, grid_ms, jerk, in_time)
            except _CHANGE_ERRORS as exc:
                failed = exc
        raise ChangeError(f"back to the planned timing: {failed}")

    def _rejoin(
        self,
        path: MotionPath,
        program: PvtProgram,
        at: SpliceAt,
        begin: float,
        grid_ms: int,
        jerk: NDArray[np.float64],
        in_time: Callable[[], bool] | None,
    ) -> tuple[PvtProgram, list[NDArray[np.int64]], Trajectory]:
        """The records that bring a jerk-limited motion back to its planned timing by a re-timing of the rest of its
        path that joins the plan later (``onpath_program.rejoin_on_grid``, ``REJOIN_JERK_SHARES`` of the limit tried
        in turn), then the original records; ChangeError where none holds the window jerk, or where ``in_time`` says
        the drives would need the records before they are made (its linear programs are the longest computation of
        a change: on the wall clock the drives run on meanwhile)."""
        assert path.original is not None

        def attempt(jerk_share: float) -> tuple[PvtProgram, list[NDArray[np.int64]], Trajectory]:
            back = rejoin_on_grid(
                path.planned, path.running, begin / 1000.0, self.limits, jerk, grid_ms, jerk_share, in_time
            )
            new, rows = rejoined_program(
                program, at.first, at.join_ms, begin, back, path.original, self.limits, max_jerk=jerk
            )
            self._hold_jerk(new, jerk, begin)
            return new, rows, back.motion

        return self._rejoin_shares(attempt)

    def override(self, group: AxisGroup, motion: Motion, scale: float) -> dict[str, Any]:
        """Re-time the rest of the running motion to ``scale`` of its planned speed (drives' lock held);
        NOT_ALLOWED with nothing changed where it cannot be made in time or within the drives' limits."""
        try:
            path = self.path_of(motion, group)
        except _CHANGE_ERRORS as exc:
            raise ApiError(ErrorCode.NOT_ALLOWED, f"override: the motion's path: {exc}") from None
        if scale >= 1.0 and path.scale == 1.0 and path.stop is None:  # on the planned timing already
            now = float((group.elapsed_syncs() or 0) * self.cell.bus.sync_period_ms)
            return {
                "motion_id": motion.motion_id,
                "scale": 1.0,
                "limited": None,
                "requested_ms": now,
                "from_ms": now,
                "duration_ms": int(path.program.duration_ms),
            }
        grid_ms = record_grid_ms(group.programs, self.cell.bus.sync_period_ms)
        period = float(self.cell.bus.sync_period_ms)
        jerk = planned_jerk(path.program.metadata)
        wall = not group.bus.sync.clock.lockstep
        made: dict[str, Any] = {}

        def make(at: SpliceAt) -> list[Any]:
            begin = change_start_ms(at.t0_ms, at.join_ms, at.programs)
            program = PvtProgram(self.cell.name, at.programs, dict(path.program.metadata))
            need_ms = min(at.join_ms) - 2.0 * period  # an axis's new records are due a SYNC before its held ones end

            asked = [time.monotonic(), 0.0]  # when in_time was last asked, the longest step between two asks

            def in_time() -> bool:  # the drives' clock (on the wall clock it runs on while the change is made)
                now = time.monotonic()
                asked[1], asked[0] = max(asked[1], now - asked[0]), now
                # on the wall clock the next step (a linear program) may take as long as the longest so far, and
                # the records must still come before the held ones end: a step begun in time and ended too late
                # would leave the drives without records while the change is refused (lockstep: their clock
                # stands while the lock is held)
                ahead_ms = 1000.0 * asked[1] if wall else 0.0
                return (group.elapsed_syncs() or 0) * period + ahead_ms < need_ms

            if path.original is None:
                path.original = program  # nothing changed yet: the records as started
            failed: Exception | None = None
            # a motion planned with a jerk limit: the S-curves within it at every scale, and no other (an
            # acceleration-limited ramp passes the limit many times: the motion is better left as it runs)
            tries: list[tuple[float, float | None]] = [(w, None) for w in _scales(scale)]
            if jerk is not None:
                tries = [(w, js) for w in _scales(scale) for js in (JERK_SHARES if w < 1.0 else (0.0,))]
            for wanted, jerk_share in tries:
                try:
                    if wanted >= 1.0:  # the planned timing, late by a whole number of grid steps
                        within = jerk if jerk_share is not None else None  # (0.0: the jerk-limited ramps)
                        new, rows, whole = self._back_to_plan(path, program, at, begin, grid_ms, within, in_time)
                        applied = 1.0
                    else:
                        whole, applied = override_on_grid(
                            path.planned,
                            path.running,
                            begin / 1000.0,
                            wanted,
                            self.limits,
                            grid_ms / 1000.0,
                            jerk if jerk_share is not None else None,
                            jerk_share or JERK_SHARES[0],
                        )
                        end_ms = float(np.round(whole.duration * 1000.0))
                        within = jerk if jerk_share is not None else None
                        new, rows = changed_program(
                            program, at.first, at.join_ms, begin, whole, end_ms, self.limits, max_jerk=within
                        )
                        self._hold_jerk(new, within, begin)
                except (ChangeError, PlanError) as exc:
                    failed = exc
                    if wanted == scale and "why" not in made:
                        made["why"] = str(exc)  # what kept the scale asked for from being made
                    continue
                made.update(whole=whole, program=new, scale=applied, begin=begin, wanted=wanted)
                return rows
            assert failed is not None
            raise failed

        try:
            at = group.splice(make)
        except _CHANGE_ERRORS as exc:
            raise ApiError(
                ErrorCode.NOT_ALLOWED, f"override {scale:g} could not be made: {exc}; nothing changed"
            ) from None
        path.running, path.program, path.scale = made["whole"], made["program"], made["scale"]
        limited = None
        if made["wanted"] < scale:  # the scale asked for could not be made: why, and what runs instead
            limited = f"{scale:g} not reached ({made.get('why')}): runs at {path.scale:.4g}"
            log.info("override of %s: %s", motion.motion_id, limited)
        return {
            "motion_id": motion.motion_id,
            "scale": round(path.scale, 4),
            "limited": limited,
            "requested_ms": round(at.now_ms, 3),
            "from_ms": made["begin"],
            "from_sync": at.sync_at(made["begin"]),
            "duration_ms": int(path.program.duration_ms),
        }
