"""Stop on the path, pause and resume, and the live speed override, on every shipped gantry profile (issue 37).

The service is driven directly (MotionService, no zenoh), in lockstep, on simulated drives that judge every
record as they judge any program. What is checked is what the drives were given and did: the records every
axis ran (the group's programs after the change), reconstructed as each drive reconstructs them, against the
path of the program as it was started; the drives' faults; where they stand at the end.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from svc_helpers import wait_until
from test_stop_then_move import assert_nothing_left, cell_file, move_again, plan, tour

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.program import PvtProgram, split_long_records
from pvtflow.axes.sim.profiles.epos2 import Epos2Drive
from pvtflow.planner.knots.window_jerk import WINDOW_MS, window_jerk_profile
from pvtflow.service.api import (
    ApiError,
    parse_execute,
    parse_home,
    parse_override,
    parse_pause,
    parse_plan,
    parse_resume,
    parse_status,
    parse_stop,
)
from pvtflow.service.config import CONFIG_DIR, load_cell_config
from pvtflow.service.motion import MotionService

# the gantry's profiles: EPOS2 buffered PVT, CiA 402 linear IP, bufferless setpoint, Parker, and a mixed cell
CELLS = ("gantry3", "gantry3-ip-linear", "gantry3-sync-setpoint", "gantry3-parker", "gantry3-mixed")
PATH_TOLERANCE_M = 1e-4  # 0.1 mm: the gantry's joints are its tool's x, y, z


@pytest.fixture(params=CELLS)
def service(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[MotionService]:
    svc = MotionService(cell_file(request.param), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP).open()
    try:
        if svc.cell.requires_homing:
            assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        yield svc
    finally:
        svc.close()


def start(svc: MotionService, at_fraction: float) -> PvtProgram:
    """A straight move across most of every joint's range, run until ``at_fraction`` of its duration; the
    program as it was started, in the group's axis order."""
    svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [0.85]))}))
    group = svc.group
    assert group is not None
    program = PvtProgram(svc.cell.name, group.programs)
    period = svc.cell.bus.sync_period_ms
    at_ms = at_fraction * program.duration_ms
    assert wait_until(lambda: (group.elapsed_syncs() or 0) * period >= at_ms, timeout=30.0)
    assert svc.running
    return program


def joints(program: PvtProgram, t_ms: np.ndarray) -> np.ndarray:
    """Every axis's position as its drive reconstructs the records, in joint units, (len(t), axes)."""
    return np.column_stack([a.scaling.qc_to_position(a.reconstruction().position(t_ms)) for a in program.axes])


def distance_to_path(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Each point's distance to the polyline ``line`` (exact, segment by segment)."""
    a, ab = line[:-1], np.diff(line, axis=0)
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30)
    out = np.empty(len(points))
    for k, p in enumerate(points):
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / length2, 0.0, 1.0)
        out[k] = np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1))
    return out


def ran(svc: MotionService) -> PvtProgram:
    group = svc.group
    assert group is not None
    return PvtProgram(svc.cell.name, group.programs)


def assert_on_path(before: PvtProgram, after: PvtProgram, from_ms: float) -> None:
    """The records the axes ran keep the joints on the path of the program as started (0.1 mm)."""
    path = joints(before, np.arange(0.0, before.duration_ms + 0.05, 0.05))
    t = np.arange(max(0.0, from_ms - 50.0), after.duration_ms + 1.0)
    worst = float(distance_to_path(joints(after, t), path).max())
    assert worst <= PATH_TOLERANCE_M, f"{worst * 1000:.4f} mm off the path"


def assert_at_rest_together(program: PvtProgram, ended_ms: float, period_ms: float) -> None:
    """Every axis at rest from the end of the braking on, which is a SYNC (the same one for all)."""
    ended_ms = (
        round(ended_ms / period_ms) * period_ms
        if abs(ended_ms / period_ms - round(ended_ms / period_ms)) < 1e-3
        else ended_ms
    )
    assert ended_ms % period_ms == 0, ended_ms
    for a in program.axes:
        rec = a.reconstruction()
        t = np.arange(ended_ms, max(ended_ms, rec.end_time) + 1.0)
        assert np.abs(rec.velocity(t)).max() < 1e-9, a.joint
        assert np.ptp(rec.position(t)) < 1e-9, a.joint
    last = np.arange(ended_ms - 2.0 * period_ms, ended_ms, 0.25)  # the braking's last SYNC periods
    moving = [a for a in program.axes if np.abs(a.reconstruction().velocity(last)).max() > 0]
    assert moving, "nothing moved in the braking's last periods: it ended earlier than it says"


def no_faults(svc: MotionService) -> None:
    assert all(not d.faults for d in svc.sim), {d.node_id: d.faults for d in svc.sim}
    assert svc.sim.internal_errors == []


def test_stop_stays_on_the_path_and_rests_on_one_sync(service: MotionService) -> None:
    before = start(service, 0.4)
    reply = service.stop(parse_stop({}))
    assert reply["mode"] == "path" and reply["fallback"] is None, reply["fallback"]
    assert reply["outcome"]["result"] == "stopped"
    braking = reply["braking"]
    lookahead = service.cell.bus.max_lookahead_ms
    assert braking["begun_ms"] - braking["requested_ms"] <= lookahead + 2 * service.cell.bus.sync_period_ms + 255
    after = ran(service)
    assert_on_path(before, after, braking["begun_ms"])
    assert_at_rest_together(after, braking["ended_ms"], service.cell.bus.sync_period_ms)
    assert braking["ended_ms"] < before.duration_ms
    drives = sorted(service.sim, key=lambda d: d.node_id)
    for d, a in zip(drives, sorted(after.axes, key=lambda a: a.node_id), strict=True):
        assert abs(d.demand - int(a.records[-1, 0])) <= 1, (d.node_id, d.demand, a.records[-1])
        if isinstance(d, Epos2Drive):  # the program ran to its end record: nothing left in the FIFO
            assert d.level == 0 and not d.ip_active, d.node_id
    no_faults(service)
    assert service.state == "idle"
    move_again(service)  # a new motion from where the axes stand runs to its end


# the quick stop on every profile and clock: tests/service/test_stop_then_move.py; here that the mode keeps it
@pytest.mark.parametrize("service", ["gantry3-mixed"], indirect=True)
def test_quick_stop_is_the_old_stop(service: MotionService) -> None:
    start(service, 0.4)
    reply = service.stop(parse_stop({"mode": "quick"}))
    assert reply["mode"] == "quick" and reply["braking"] is None
    assert reply["outcome"]["result"] == "stopped"
    assert_nothing_left(service)
    no_faults(service)


def test_pause_then_resume_reaches_the_original_end(service: MotionService) -> None:
    before = start(service, 0.35)
    paused = service.pause(parse_pause({}))
    assert paused["paused"], (paused["fallback"], paused["outcome"])
    assert service.state == "paused"
    status = service.status(parse_status({}))
    assert status["paused"]["motion_id"] == paused["motion_id"]
    assert 0.1 < status["paused"]["remaining"] < 0.9 and status["paused"]["remaining"] == paused["remaining"]
    assert_on_path(before, ran(service), paused["braking"]["begun_ms"])
    with pytest.raises(ApiError) as refused:  # nothing else starts while paused
        service.execute(parse_execute({"plan_id": plan(service, tour(service.cell, [0.5]))}))
    assert refused.value.code == "busy"
    out = service.resume(parse_resume({"wait": True}))
    assert out["resumed"] == paused["motion_id"] and out["outcome"]["result"] == "finished", out["outcome"]
    after = ran(service)
    assert [int(a.records[-1, 0]) for a in after.axes] == [int(a.records[-1, 0]) for a in before.axes]
    # at the planned timing: after the ramp up from rest, every axis runs the program's own records to its end
    half = max(1, int(service.cell.bus.max_lookahead_ms / 2))
    for a, b in zip(after.axes, before.axes, strict=True):
        fed = split_long_records(b, half)  # the program's records as its feeder held them
        n = 0
        while n < min(len(fed), len(a.records)) and (a.records[-1 - n] == fed[-1 - n]).all():
            n += 1
        own_ms = float(np.sum(a.records[len(a.records) - n :, 2]))
        ramp_ms = out["duration_ms"] - own_ms
        assert n >= 3 and ramp_ms <= 300.0, (a.joint, n, ramp_ms)
    assert_on_path(before, after, 0.0)
    no_faults(service)
    assert service.state == "idle"
    entry = service.journal_entry(paused["motion_id"])
    assert entry is not None and entry.outcome is not None and entry.outcome.get("paused") is True
    assert service.journal_entry(out["motion_id"]) is not None


# the service's rule, whatever the profiles: one cell with three (the pause itself: every cell, above)
@pytest.mark.parametrize("service", ["gantry3-mixed"], indirect=True)
def test_stop_while_paused_ends_it(service: MotionService) -> None:
    start(service, 0.3)
    assert service.pause(parse_pause({}))["paused"]
    reply = service.stop(parse_stop({}))
    assert reply["ended_pause"] and service.state == "idle"
    with pytest.raises(ApiError) as refused:
        service.resume(parse_resume({}))
    assert refused.value.code == "not_allowed"


def test_override_slows_the_rest_of_the_motion(service: MotionService) -> None:
    before = start(service, 0.3)
    reply = service.override(parse_override({"scale": 0.3}))
    assert reply["scale"] == pytest.approx(0.3, abs=0.01)
    lookahead = service.cell.bus.max_lookahead_ms
    assert reply["from_ms"] - reply["requested_ms"] <= lookahead + 2 * service.cell.bus.sync_period_ms + 255
    assert service.status(parse_status({}))["override"] == reply["scale"]
    motion = service.motion
    assert motion is not None and motion.done.wait(60.0)
    assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
    after = ran(service)
    assert after.duration_ms > before.duration_ms
    assert_on_path(before, after, reply["from_ms"])
    assert [int(a.records[-1, 0]) for a in after.axes] == [int(a.records[-1, 0]) for a in before.axes]
    no_faults(service)


@pytest.mark.parametrize("cell", ["gantry3"])
def test_bad_requests_change_nothing(cell: str, tmp_path: Path) -> None:
    with MotionService(cell_file(cell), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP) as svc:
        for call in (
            lambda: svc.override(parse_override({"scale": 0.5})),
            lambda: svc.pause(parse_pause({})),
            lambda: svc.resume(parse_resume({})),
        ):
            with pytest.raises(ApiError) as refused:
                call()
            assert refused.value.code == "not_allowed"
        for bad in ({"scale": 1.5}, {"scale": 0.0}, {"scale": "fast"}, {}):
            with pytest.raises(ApiError) as refused:
                parse_override(bad)
            assert refused.value.code == "invalid_request"
        with pytest.raises(ApiError):
            parse_stop({"mode": "gentle"})
        assert svc.state == "idle"


@pytest.mark.wall
def test_stop_on_the_path_on_the_wall_clock(tmp_path: Path) -> None:
    """On the wall clock the EPOS2s run their records on their own clocks while the braking is made (the
    group's lock held): it is made in time, or the stop is the quick one and says why; either way the
    motion is stopped and nothing faults. A path stop made stays on the path (0.1 mm). So does a jerk-limited
    motion's override, within its jerk limit."""
    cell = cell_file("gantry3")
    cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, heartbeat_timeout_factor=10))
    with MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.WALL) as svc:
        assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        made = 0
        for fraction in (0.3, 0.5):
            before = start(svc, fraction)
            reply = svc.stop(parse_stop({}))
            assert reply["outcome"]["result"] == "stopped", reply["outcome"]
            if reply["mode"] == "path" and reply["braking"]["begun_ms"] is not None:
                made += 1
                assert_on_path(before, ran(svc), reply["braking"]["begun_ms"])
            elif reply["mode"] == "path":  # asked so late (a loaded host) that the motion's own end came first
                assert reply["braking"]["ended_ms"] == before.duration_ms, reply
            else:
                assert reply["fallback"], reply
            no_faults(svc)
            move_again(svc)
        assert made >= 1, "no path stop was made in time on the wall clock"

        # a motion planned with a jerk limit, overridden on the wall clock: 0.5 at 30 %, then 1.0 150 ms on (an
        # S-curve back to the planned records), made in time or refused with nothing changed (a loaded host); the
        # drives judge what ran, the records within the jerk limit from the first change on
        limits = svc.cell.joint_limits()
        max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]
        home = svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [0.15])), "wait": True}))
        assert home["outcome"]["result"] == "finished", home["outcome"]
        req = {"waypoints": tour(svc.cell, [0.85]), "start": "current", "max_jerk": max_jerk}
        svc.execute(parse_execute({"plan_id": svc.plan(parse_plan(req, svc.cell.joint_names, limits))["plan_id"]}))
        before = ran(svc)
        assert wait_until(lambda: _elapsed_ms(svc) >= 0.3 * before.duration_ms, timeout=30.0)
        slow = svc.override(parse_override({"scale": 0.5}))
        assert slow["scale"] == pytest.approx(0.5, abs=0.02)
        assert wait_until(lambda: _elapsed_ms(svc) >= slow["from_ms"] + 150.0, timeout=30.0)
        try:
            back = svc.override(parse_override({"scale": 1.0}))
        except ApiError as refused:
            assert refused.code == "not_allowed" and "nothing changed" in refused.message, refused
        else:
            assert back["scale"] == 1.0 and back["limited"] is None, back
        motion = svc.motion
        assert motion is not None and motion.done.wait(60.0)
        assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
        after = ran(svc)
        assert window_jerk_ratio(after, max_jerk, slow["from_ms"]) <= 1.2
        assert_on_path(before, after, slow["from_ms"])
        no_faults(svc)


def _elapsed_ms(svc: MotionService) -> float:
    group = svc.group
    assert group is not None
    return float((group.elapsed_syncs() or 0) * svc.cell.bus.sync_period_ms)


def test_override_back_to_one_runs_the_planned_records(service: MotionService) -> None:
    """0.5, then 1.0: from where the second change joins them, every axis runs the program's own records
    (later by the time the slower stretch cost), to the program's own end."""
    svc = service
    before = start(svc, 0.2)
    slow = svc.override(parse_override({"scale": 0.5}))
    assert slow["scale"] == pytest.approx(0.5, abs=0.02)
    assert wait_until(lambda: _elapsed_ms(svc) >= slow["from_ms"] + 150.0, timeout=30.0)
    back = svc.override(parse_override({"scale": 1.0}))
    assert back["scale"] == 1.0
    assert svc.status(parse_status({}))["override"] == 1.0
    motion = svc.motion
    assert motion is not None and motion.done.wait(60.0)
    assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
    after = ran(svc)
    assert_planned_records_from(svc, before, after, back["from_ms"] + 200.0)  # the change joins within 200 ms
    assert_on_path(before, after, slow["from_ms"])
    no_faults(svc)


def assert_planned_records_from(
    svc: MotionService, before: PvtProgram, after: PvtProgram, from_ms: float, least: int = 3
) -> None:
    """From the first record ending after ``from_ms`` on, every axis runs ``before``'s own records (as its feeder
    held them), later by what the motion's end is, to its end: at least ``least`` of them."""
    delay = after.duration_ms - before.duration_ms
    assert delay > 0
    half = max(1, int(svc.cell.bus.max_lookahead_ms / 2))
    for a, b in zip(after.axes, before.axes, strict=True):
        fed = split_long_records(b, half)  # the program's records as its feeder holds them
        ends = np.cumsum(a.records[:, 2])
        tail = int(np.searchsorted(ends, from_ms))
        kept = fed[len(fed) - (len(a.records) - tail) :]
        assert len(kept) >= least, a.joint  # the rest of the motion, not just its end
        np.testing.assert_array_equal(a.records[tail:], kept, err_msg=a.joint)
        assert float(np.cumsum(fed[:, 2])[len(fed) - len(kept) - 1]) + delay == float(ends[tail - 1]), a.joint


def ends_as_planned_later(svc: MotionService, before: PvtProgram, after: PvtProgram) -> None:
    """Back on the planned timing: every axis's records end at its planned end plus one delay (the motion's, a whole
    number of SYNC periods), where it was planned to end, at rest (the records it joins are the plan's own; a join
    late in the motion falls in the axes' last segments, which then end on new records)."""
    delay = after.duration_ms - before.duration_ms
    assert delay > 0 and delay % svc.cell.bus.sync_period_ms == 0, delay
    half = max(1, int(svc.cell.bus.max_lookahead_ms / 2))
    for a, b in zip(after.axes, before.axes, strict=True):
        fed = split_long_records(b, half)
        assert float(a.records[:, 2].sum()) == float(fed[:, 2].sum()) + delay, a.joint
        np.testing.assert_array_equal(a.records[-1], fed[-1], err_msg=a.joint)


def test_override_one_on_the_planned_timing_changes_nothing(service: MotionService) -> None:
    svc = service
    before = start(svc, 0.3)
    reply = svc.override(parse_override({"scale": 1.0}))
    assert reply["scale"] == 1.0 and reply["duration_ms"] == before.duration_ms
    motion = svc.motion
    assert motion is not None and motion.done.wait(60.0)
    assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
    after = ran(svc)
    for a, b in zip(after.axes, before.axes, strict=True):
        np.testing.assert_array_equal(a.records, b.records, err_msg=a.joint)
    no_faults(svc)


def window_jerk_ratio(program: PvtProgram, max_jerk: list[float], from_ms: float) -> float:
    """The drives' 10-ms-window jerk (the knot placement's measure) of every axis's records from ``from_ms``
    on, of the jerk limit in the axis's counts, at most."""
    worst = 0.0
    for a, jmax in zip(program.axes, max_jerk, strict=True):
        t, jerk = window_jerk_profile(a.reconstruction())
        allowed = jmax * abs(a.scaling.qc_per_joint_unit) * 1e-9  # joint units/s^3 -> qc/ms^3
        worst = max(worst, float(jerk[t >= from_ms - WINDOW_MS].max()) / allowed)
    return worst


@pytest.mark.parametrize("fraction", [0.3, 0.6])
def test_stop_of_a_jerk_limited_motion_holds_the_jerk_limit(fraction: float, tmp_path: Path) -> None:
    """A motion planned with a jerk limit brakes on its path within it: the drives' window jerk of the
    braking's records within the knot placement's 1.2 x, at 0x60C5 (the validator), on the path, at rest
    together."""
    with MotionService(cell_file("gantry3"), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP) as svc:
        assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        limits = svc.cell.joint_limits()
        max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]
        req = {"waypoints": tour(svc.cell, [0.85]), "start": "current", "max_jerk": max_jerk}
        svc.execute(parse_execute({"plan_id": svc.plan(parse_plan(req, svc.cell.joint_names, limits))["plan_id"]}))
        group = svc.group
        assert group is not None
        before = PvtProgram(svc.cell.name, group.programs)
        assert wait_until(lambda: _elapsed_ms(svc) >= fraction * before.duration_ms, timeout=30.0)
        reply = svc.stop(parse_stop({}))
        assert reply["mode"] == "path" and reply["fallback"] is None, reply["fallback"]
        braking = reply["braking"]
        after = ran(svc)
        assert window_jerk_ratio(after, max_jerk, braking["begun_ms"]) <= 1.2
        assert_on_path(before, after, braking["begun_ms"])
        assert_at_rest_together(after, braking["ended_ms"], svc.cell.bus.sync_period_ms)
        no_faults(svc)


def test_override_just_below_the_planned_speed(service: MotionService) -> None:
    """0.99: as close to it as the limits and the SYNC grid allow (the scale lowered by at most 3 % so that the
    motion ends on the grid), within every limit."""
    before = start(service, 0.3)
    reply = service.override(parse_override({"scale": 0.99}))
    assert 0.96 <= reply["scale"] <= 0.99
    motion = service.motion
    assert motion is not None and motion.done.wait(60.0)
    assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
    after = ran(service)
    assert after.duration_ms > before.duration_ms
    assert_on_path(before, after, reply["from_ms"])
    no_faults(service)


def test_override_and_resume_of_a_jerk_limited_motion_hold_the_jerk_limit(tmp_path: Path) -> None:
    """A motion planned with a jerk limit changes speed within it: override 0.5, back to 1.0 (the program's own
    records again), and a pause + resume at the planned timing, the drives' window jerk of every change's records
    within the knot placement's 1.2 x, on the path, no drive faults."""
    with MotionService(cell_file("gantry3"), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP) as svc:
        assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        limits = svc.cell.joint_limits()
        max_jerk = [float(j) for j in 10.0 * np.asarray(limits.acceleration)]

        def go(fraction: float, to: float = 0.85, waypoints: list[list[float]] | None = None) -> PvtProgram:
            req = {"waypoints": waypoints or tour(svc.cell, [to]), "start": "current", "max_jerk": max_jerk}
            req["budget_ms"] = 10000  # a jerk-limited plan of two waypoints on a loaded host: not what is judged
            plan_id = svc.plan(parse_plan(req, svc.cell.joint_names, limits))["plan_id"]
            svc.execute(parse_execute({"plan_id": plan_id}))
            before = ran(svc)
            assert wait_until(lambda: _elapsed_ms(svc) >= fraction * before.duration_ms, timeout=30.0)
            return before

        before = go(0.3)
        slow = svc.override(parse_override({"scale": 0.5}))
        assert slow["scale"] == pytest.approx(0.5, abs=0.02)
        assert window_jerk_ratio(ran(svc), max_jerk, slow["from_ms"]) <= 1.2
        assert wait_until(lambda: _elapsed_ms(svc) >= slow["from_ms"] + 150.0, timeout=30.0)
        back = svc.override(parse_override({"scale": 1.0}))
        assert back["scale"] == 1.0
        assert window_jerk_ratio(ran(svc), max_jerk, back["from_ms"]) <= 1.2
        motion = svc.motion
        assert motion is not None and motion.done.wait(60.0) and motion.outcome["result"] == "finished"
        assert_on_path(before, ran(svc), slow["from_ms"])
        home = svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [0.15])), "wait": True}))
        assert home["outcome"]["result"] == "finished"

        # late in the motion (the change meets the plan's own deceleration, where no S-curve in path speed holds
        # the limit): back to the planned timing by a re-timing that joins the plan's records later, within it
        before = go(0.45)
        slow = svc.override(parse_override({"scale": 0.5}))
        assert wait_until(lambda: _elapsed_ms(svc) >= slow["from_ms"] + 150.0, timeout=30.0)
        back = svc.override(parse_override({"scale": 1.0}))
        assert back["scale"] == 1.0 and back["limited"] is None, back
        assert window_jerk_ratio(ran(svc), max_jerk, back["from_ms"]) <= 1.2
        motion = svc.motion
        assert motion is not None and motion.done.wait(60.0) and motion.outcome["result"] == "finished"
        after = ran(svc)  # joined in the plan's own deceleration: the fewest grid steps later, its last records
        # its last segments at least (how many depends on the moment the 1.0 came: in lockstep the test thread
        # polls the drives' clock, and on a loaded host it came 30 ms before the plan's end, joined in its last one)
        ends_as_planned_later(svc, before, after)
        assert_on_path(before, ran(svc), slow["from_ms"])

        # the same on a path off one line in joint space (two waypoints, the joints' shares of their ranges differ):
        # the path speed re-timed to join the plan (the joints' limits along the curve), not a share of its speed
        lo, hi = np.asarray(limits.lower), np.asarray(limits.upper)
        bent = [list(lo + np.asarray(f) * (hi - lo)) for f in ((0.5, 0.8, 0.3), (0.85, 0.3, 0.8))]
        for fraction, change in ((0.5, "override"), (0.6, "pause")):
            before = go(fraction, waypoints=bent)  # from where the last motion ended
            if change == "override":
                slow = svc.override(parse_override({"scale": 0.5}))
                assert wait_until(lambda: _elapsed_ms(svc) >= slow["from_ms"] + 150.0, timeout=30.0)  # noqa: B023
                back = svc.override(parse_override({"scale": 1.0}))
                assert back["scale"] == 1.0 and back["limited"] is None, back
                motion = svc.motion
                assert motion is not None and motion.done.wait(60.0) and motion.outcome["result"] == "finished"
                after, since = ran(svc), back["from_ms"]
                assert after.duration_ms == back["duration_ms"]
                ends_as_planned_later(svc, before, after)
            else:  # paused near the plan's deceleration: resumed from rest joining the plan's records
                assert svc.pause(parse_pause({}))["paused"]
                out = svc.resume(parse_resume({"wait": True}))
                assert out["outcome"]["result"] == "finished", out["outcome"]
                assert svc.motion is not None and svc.motion.program.metadata["resumed_on_planned_records"]
                after, since = ran(svc), 0.0
                assert [int(a.records[-1, 0]) for a in after.axes] == [int(a.records[-1, 0]) for a in before.axes]
            assert window_jerk_ratio(after, max_jerk, since) <= 1.2, change
            assert_on_path(before, after, since)
            no_faults(svc)

        # paused early (the ramp joins the planned records) and late (at rest near the plan's deceleration: from
        # rest to the end as a plan, within the jerk limit; before, the acceleration-limited ramp at 8.7 x it)
        for fraction, to in ((0.4, 0.15), (0.5, 0.85)):
            before = go(fraction, to)
            paused = svc.pause(parse_pause({}))
            assert paused["paused"], paused["fallback"]
            out = svc.resume(parse_resume({"wait": True}))
            assert out["outcome"]["result"] == "finished", out["outcome"]
            after = ran(svc)
            assert window_jerk_ratio(after, max_jerk, 0.0) <= 1.2, fraction
            assert_on_path(before, after, 0.0)
            assert [int(a.records[-1, 0]) for a in after.axes] == [int(a.records[-1, 0]) for a in before.axes]
            no_faults(svc)


@pytest.mark.wall
def test_path_stop_pause_resume_and_override_from_the_cyclic_process(tmp_path: Path) -> None:
    """With ``bus.cyclic_process`` (the records sent by a process of its own, the drives in theirs, on the wall
    clock) a change reaches that process's feeders: a path stop stays on the path, pause + resume reaches the
    original end, an override runs to its end, nothing faults. Made in time or refused with the reason (a loaded
    host), never half made: at least one change of each kind is made. A queued motion runs on after the first."""
    source = CONFIG_DIR / "cells" / "gantry3.yaml"
    data = yaml.safe_load(source.read_text())
    for axis in data["axes"]:
        axis.pop("homing", None)
        axis.setdefault("simulation", {})["power_up_qc"] = 0  # not homed: the machine at its encoder's 0
    data.pop("homing_order", None)
    data.pop("requires_homing", None)
    data["bus"].update(cyclic_process=True, sync_period_ms=10, heartbeat_timeout_factor=10)
    if "urdf" in data.get("robot", {}):
        data["robot"]["urdf"] = str((source.parent / data["robot"]["urdf"]).resolve())
    copy = tmp_path / "gantry3.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    cell = load_cell_config(copy)
    with MotionService(cell, journal_dir=tmp_path / "journal", clock=Clock.WALL, drives_process=True) as svc:
        assert svc.drives.bus is not None and svc.drives.bus.sync.cyclic is not None
        lim = svc.cell.joint_limits()
        made = {"stop": 0, "pause": 0, "override": 0}

        def again(svc: MotionService) -> None:  # the drives are in a process of their own: their outcome says
            out = svc.execute(parse_execute({"plan_id": plan(svc, tour(svc.cell, [0.45])), "wait": True}))
            assert out["outcome"]["result"] == "finished", out["outcome"]

        for _ in range(2):
            before = start(svc, 0.3)
            reply = svc.stop(parse_stop({}))
            assert reply["outcome"]["result"] == "stopped", reply["outcome"]
            if reply["mode"] == "path":
                made["stop"] += 1
                assert_on_path(before, ran(svc), reply["braking"]["begun_ms"])
                # the drives ran the braking the cyclic process sent: they stand where it ends, short of the end
                stood = [int(a.records[-1, 0]) for a in ran(svc).axes]
                assert svc.drives.positions_qc(refresh=True) == stood
                assert stood != [int(a.records[-1, 0]) for a in before.axes]
            else:
                assert reply["fallback"], reply
            again(svc)

            before = start(svc, 0.3)
            paused = svc.pause(parse_pause({}))
            if paused["paused"]:
                made["pause"] += 1
                assert svc.drives.positions_qc(refresh=True) == [int(a.records[-1, 0]) for a in ran(svc).axes]
                out = svc.resume(parse_resume({"wait": True}))
                assert out["outcome"]["result"] == "finished", out["outcome"]
                after = ran(svc)
                assert_on_path(before, after, 0.0)
                ends = [int(a.records[-1, 0]) for a in before.axes]
                assert [int(a.records[-1, 0]) for a in after.axes] == ends
                assert svc.drives.positions_qc(refresh=True) == ends
            again(svc)

            before = start(svc, 0.3)
            try:
                over = svc.override(parse_override({"scale": 0.5}))
            except ApiError as refused:
                assert refused.code == "not_allowed", refused
            else:
                made["override"] += 1
                assert over["scale"] == pytest.approx(0.5, abs=0.02)
            motion = svc.motion
            assert motion is not None and motion.done.wait(60.0)
            assert motion.outcome is not None and motion.outcome["result"] == "finished", motion.outcome
            assert_on_path(before, ran(svc), 0.0)
            again(svc)
            if all(made.values()):
                break  # a second round only where a loaded host refused one in the first
        assert all(made.values()), made

        # a queued motion reaches the cyclic process's feeders too: it runs on from the first's end
        first_plan = plan(svc, tour(svc.cell, [0.05, 0.95]))  # long enough to queue on (the end hold: 1 s here)
        req = parse_plan({"waypoints": tour(svc.cell, [0.95, 0.2]), "start": "first"}, svc.cell.joint_names, lim)
        then_plan = str(svc.plan(req)["plan_id"])
        first = svc.execute(parse_execute({"plan_id": first_plan}))
        queued = svc.execute(parse_execute({"plan_id": then_plan, "queue": True}))
        assert queued["state"] == "queued" and queued["queued_after"] == first["motion_id"], queued
        assert wait_until(lambda: svc.state == "idle" and not svc.activity.queued(), timeout=60.0)
        results = {m: svc.journal.get(m).outcome["result"] for m in (first["motion_id"], queued["motion_id"])}
        assert set(results.values()) == {"finished"}, results
        ends = [int(a.records[-1, 0]) for a in svc.stored_plan(then_plan).program.axes]
        assert svc.drives.positions_qc(refresh=True) == ends
