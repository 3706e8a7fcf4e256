"""``execute`` with ``queue``: a motion accepted while another runs starts where it ends, on the SYNC after
its last record, with no stop in between (issue 38 item 5). The service is driven directly (MotionService,
no zenoh), in lockstep on simulated drives: two EPOS2 cells and a fixed-period one, full-speed plans."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from axes_programs import standstill_syncs
from svc_helpers import wait_until

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.program import AxisProgram, joined
from pvtflow.planner.validate import validate_program
from pvtflow.service.api import ApiError, parse_execute, parse_home, parse_plan, parse_status, parse_stop
from pvtflow.service.motion import MotionService
from pvtflow.service.motion.runs import Motion

CELLS = ("arm6", "gantry3", "gantry3-sync-setpoint")


@pytest.fixture(params=CELLS)
def service(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[MotionService]:
    from test_stop_then_move import cell_file

    svc = MotionService(cell_file(request.param), journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP).open()
    try:
        if svc.cell.requires_homing:
            assert svc.home(parse_home({"wait": True}))["outcome"]["result"] == "homed"
        yield svc
    finally:
        svc.close()


def at(svc: MotionService, fraction: float) -> list[float]:
    lim = svc.cell.joint_limits()
    return [lo + fraction * (hi - lo) for lo, hi in zip(lim.lower, lim.upper, strict=True)]


def plan(svc: MotionService, waypoints: list[list[float]], start: str) -> str:
    req = parse_plan({"waypoints": waypoints, "start": start}, svc.cell.joint_names, svc.cell.joint_limits())
    return str(svc.plan(req)["plan_id"])


def two_plans(svc: MotionService) -> tuple[str, str]:
    """Across most of every joint's range and back part of the way, the second from where the first ends."""
    first = plan(svc, [at(svc, 0.9)], "current")
    then = plan(svc, [at(svc, 0.9), at(svc, 0.4)], "first")
    return first, then


def motion(svc: MotionService, motion_id: str) -> Motion:
    current = svc.motion
    if current is not None and current.motion_id == motion_id:
        return current
    return next(m for m in svc.activity.queued() if m.motion_id == motion_id)


def test_a_queued_motion_runs_on_without_a_stop(service: MotionService) -> None:
    """The queued motion is listed and journaled; it begins on the SYNC after the first one's last record;
    every drive runs both programs' records as one from one start (the joined programs' reconstruction at
    every SYNC: not a SYNC period of standstill beyond theirs), judging every record as it does (no fault)."""
    first_plan, then_plan = two_plans(service)
    first = service.execute(parse_execute({"plan_id": first_plan}))
    queued = service.execute(parse_execute({"plan_id": then_plan, "queue": True}))
    assert queued["state"] == "queued" and queued["queued_after"] == first["motion_id"], queued
    listed = service.status(parse_status({}))["queue"]
    assert [m["motion_id"] for m in listed] == [queued["motion_id"]]
    second = motion(service, queued["motion_id"])
    assert second.done.wait(60.0)
    entry = service.journal.get(queued["motion_id"])
    assert entry is not None and entry.queued_after == first["motion_id"]
    outcomes = {m: service.journal.get(m).outcome["result"] for m in (first["motion_id"], queued["motion_id"])}
    assert outcomes == {first["motion_id"]: "finished", queued["motion_id"]: "finished"}
    assert service.state == "idle" and service.activity.queued() == []

    programs = [service.stored_plan(p).program for p in (first_plan, then_plan)]
    whole = joined(programs)
    assert validate_program(whole).ok  # the planner's validator judges the pair as one program
    period = service.cell.bus.sync_period_ms
    start = first["start_sync"]
    assert second.start_sync == start + int(np.ceil(programs[0].duration_ms / period))
    end = start + int(np.ceil(whole.duration_ms / period))
    t = (np.arange(start, end + 1) - start) * period
    demands = []
    group = service.drives.connected()
    told = {link.node_id: feeder.records for link, feeder in zip(group.links, group.feeders, strict=True)}
    for axis in whole.axes:
        drive = service.sim.drive(axis.node_id)
        assert drive.faults == [] and drive.ip_active_sync == start
        history = {s.sync: s.demand for s in drive.history}
        demand = np.array([history[n] for n in range(start, end + 1)])
        # what the drive was told: an EPOS2's long segments cut on their own cubic (the look-ahead bound,
        # axes.drive.program.split_long_records), to a count of the programs' own reconstruction
        sent = AxisProgram.of(axis, told[axis.node_id])
        np.testing.assert_allclose(demand, sent.reconstruction().position(t), atol=1e-6)
        np.testing.assert_allclose(demand, axis.reconstruction().position(t), atol=1.0)
        demands.append(demand)
    planned = np.array([a.reconstruction().position(t) for a in whole.axes]).T
    assert standstill_syncs(np.array(demands).T) == standstill_syncs(planned)
    assert service.sim.internal_errors == []


def test_stop_ends_the_running_and_the_queued_motion(service: MotionService) -> None:
    first_plan, then_plan = two_plans(service)
    first = service.execute(parse_execute({"plan_id": first_plan}))
    queued = service.execute(parse_execute({"plan_id": then_plan, "queue": True}))
    second = motion(service, queued["motion_id"])
    reply = service.stop(parse_stop({}))
    assert reply["was_moving"] and reply["motion_id"] == first["motion_id"]
    assert reply["outcome"]["result"] == "stopped" and reply["queued"] == [queued["motion_id"]]
    assert second.done.is_set() and second.outcome is not None and second.outcome["result"] == "stopped"
    assert "ended before it began" in second.outcome["message"]
    assert service.journal.get(queued["motion_id"]).outcome["result"] == "stopped"
    assert service.state == "idle" and service.activity.queued() == []
    for drive in service.sim:
        assert drive.faults == [] and not drive.ip_active


def test_a_queued_motion_that_does_not_start_where_the_running_one_ends_is_refused(service: MotionService) -> None:
    """Refused naming the axis, nothing journaled, nothing queued; the running motion ends as planned."""
    first_plan = plan(service, [at(service, 0.9)], "current")
    elsewhere = plan(service, [at(service, 0.5), at(service, 0.4)], "first")
    first = service.execute(parse_execute({"plan_id": first_plan}))
    with pytest.raises(ApiError, match="must start where that one ends") as refused:
        service.execute(parse_execute({"plan_id": elsewhere, "queue": True}))
    assert refused.value.code == "not_allowed"
    assert [e.motion_id for e in service.journal.recent(10)] == [first["motion_id"]]
    assert service.activity.queued() == []
    running = service.motion
    assert running is not None and running.done.wait(60.0)
    assert running.outcome is not None and running.outcome["result"] == "finished"
    program = service.stored_plan(first_plan).program
    for axis in program.axes:
        drive = service.sim.drive(axis.node_id)
        assert drive.faults == [] and drive.actual == axis.records[-1, 0]


def test_queue_with_nothing_running_starts_the_motion(service: MotionService) -> None:
    out = service.execute(parse_execute({"plan_id": plan(service, [at(service, 0.6)], "current"), "queue": True}))
    assert out["state"] == "running" and out["queued_after"] is None
    assert wait_until(lambda: service.motion is not None and service.motion.done.is_set(), timeout=60.0)
    assert service.motion.outcome["result"] == "finished"


def test_motions_queued_in_a_row_run_in_order(service: MotionService) -> None:
    """A third motion queued after the second (still queued) runs on from it; approach with queue is refused."""
    first_plan, then_plan = two_plans(service)
    last_plan = plan(service, [at(service, 0.4), at(service, 0.7)], "first")
    first = service.execute(parse_execute({"plan_id": first_plan}))
    second = service.execute(parse_execute({"plan_id": then_plan, "queue": True}))
    with pytest.raises(ApiError, match="approach and queue"):
        service.execute(parse_execute({"plan_id": last_plan, "queue": True, "approach": True}))
    third = service.execute(parse_execute({"plan_id": last_plan, "queue": True}))
    assert third["queued_after"] == second["motion_id"]
    assert [m.motion_id for m in service.activity.queued()] == [second["motion_id"], third["motion_id"]]
    assert motion(service, third["motion_id"]).done.wait(90.0)
    ids = [first["motion_id"], second["motion_id"], third["motion_id"]]
    assert [service.journal.get(m).outcome["result"] for m in ids] == ["finished"] * 3
    assert service.motion is not None and service.motion.motion_id == ids[2]
    for drive in service.sim:
        assert drive.faults == [] and drive.ip_active_sync == first["start_sync"]
