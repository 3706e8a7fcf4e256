"""End to end over real zenoh sessions on loopback: plan, execute, follow, stop, busy, journal, restart."""

from __future__ import annotations

import json

import numpy as np
import pytest
from svc_helpers import SHORT_TARGET, check_reply, long_tour, wait_until

from pvtflow.axes.drive.cia402 import Statusword


@pytest.mark.wall
def test_plan_and_execute_six_axes_following_state_and_telemetry_to_the_end(arm6, serve):
    s = serve(arm6)
    col = s.follow()
    status = s.request("status")
    assert status.ok, status.data
    check_reply("status", status.data)
    assert status.data["state"] == "idle" and len(status.data["axes"]) == 6

    plan = s.request("plan", {"waypoints": [*long_tour(arm6)[:2], SHORT_TARGET], "include_program": True})
    assert plan.ok, plan.data
    check_reply("plan", plan.data)
    p = plan.data
    assert p["cell"] == "arm6" and p["validation"]["ok"]
    assert p["start"] == [0.0] * 6  # start=current: from where the drives are
    np.testing.assert_allclose(p["end"], SHORT_TARGET)
    program = p["program"]
    ends = {a["name"]: a["records"][-1][0] for a in program["axes"]}

    ex = s.request("execute", {"plan_id": p["plan_id"], "label": "e2e"})
    assert ex.ok, ex.data
    check_reply("execute", ex.data)
    motion_id = ex.data["motion_id"]
    assert ex.data["state"] == "running" and ex.data["duration_ms"] == round(p["duration_s"] * 1000)

    assert wait_until(lambda: col.events("motion_ended", motion_id), timeout=30), col.get("events")
    ended = col.events("motion_ended", motion_id)[0]
    assert ended["outcome"]["result"] == "finished", ended

    # what the drives did: every axis at its program's end record, no fault, all started on one SYNC
    for drive in s.sim:
        assert drive.faults == []
        joint = arm6.ordered_axes()[[a.node_id for a in arm6.ordered_axes()].index(drive.node_id)].joint
        assert drive.actual == ends[joint]
    assert len({d.ip_active_sync for d in s.sim}) == 1

    # telemetry followed the motion to its end; the last sample of the motion is at the program's end
    assert wait_until(
        lambda: any(t["motion_id"] == motion_id and t["progress"] and t["progress"] > 0.9 for t in col.get("telemetry"))
    )
    tel = [t for t in col.get("telemetry") if t["motion_id"] == motion_id]
    assert len(tel) >= 5
    for t in tel:
        check_reply("telemetry", t)
    times = [t["elapsed_ms"] for t in tel]
    assert times == sorted(times)
    np.testing.assert_allclose(tel[-1]["positions"], SHORT_TARGET, atol=2e-3)
    # state: moving, then idle again; every event of the motion follows its schema
    states = [x["state"] for x in col.get("state")]
    assert "moving" in states and states[-1] == "idle"
    for x in col.get("state"):
        check_reply("state", x)
    for e in col.get("events"):
        check_reply("events", e)
    assert {"started", "finished", "motion_ended"} <= {e["kind"] for e in col.get("events")}

    # status reports what the drives say, and the journal's motion with its outcome
    after = s.request("status", {"recent": 5})
    assert after.ok
    check_reply("status", after.data)
    for axis in after.data["axes"]:
        assert axis["state"] == "OPERATION ENABLED" and not axis["fault"]
        assert axis["position_qc"] == s.sim.drive(axis["node_id"]).actual
    assert after.data["recent"][0]["motion_id"] == motion_id
    assert after.data["recent"][0]["outcome"]["result"] == "finished"
    assert after.data["recent"][0]["label"] == "e2e"


@pytest.mark.wall
def test_stop_mid_move_halts_every_axis(arm6, serve):
    s = serve(arm6)
    col = s.follow()
    plan = s.request("plan", {"waypoints": long_tour(arm6)})
    assert plan.ok, plan.data
    assert plan.data["duration_s"] > 1.0
    ex = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert ex.ok, ex.data
    motion_id = ex.data["motion_id"]
    assert wait_until(
        lambda: any(t["motion_id"] == motion_id and t["elapsed_ms"] >= 300 for t in col.get("telemetry")), timeout=20
    )

    moving = s.request("status")
    assert moving.ok and moving.data["state"] == "moving" and moving.data["elapsed_ms"] > 0
    for axis in moving.data["axes"]:  # live, from the drives' TPDOs
        assert axis["statusword"] & int(Statusword.IP_MODE_ACTIVE)
        assert axis["buffer_level"] is not None and axis["buffer_level"] > 0
        assert "buffer_enabled" in axis["buffer_flags"]

    stop = s.request("stop", {"reason": "test stop"})
    assert stop.ok, stop.data
    check_reply("stop", stop.data)
    assert stop.data["was_moving"] and stop.data["motion_id"] == motion_id
    assert stop.data["outcome"]["result"] == "stopped"
    assert stop.data["outcome"]["message"] == "test stop"
    end_ms = plan.data["duration_s"] * 1000
    for drive in s.sim:
        assert drive.faults == []
        assert drive.state == "OPERATION ENABLED"
        assert drive.statusword() & int(Statusword.TARGET_REACHED)  # halted: standing still
        assert not drive.ip_active
        stopped_at = [h.sync for h in drive.history if h.ip_active][-1]
        assert stopped_at < drive.ip_active_sync + end_ms  # it did not run to the end of the program

        # it comes to rest at the halt ramp's end: its demand velocity, sampled every ms on its own clock,
        # reaches 0 (its per-SYNC history need not: the run ends, and SYNC with it, on the SYNC whose
        # status reports every axis standing still, which may be the first SYNC after the ramp's end)
        assert wait_until(lambda drive=drive: drive.velocity == 0.0, timeout=2), drive.velocity
    # every axis halted on the same SYNC: the same last ip-active SYNC
    assert len({[h.sync for h in d.history if h.ip_active][-1] for d in s.sim}) == 1
    assert wait_until(lambda: col.events("motion_ended", motion_id))
    assert s.request("status").data["state"] == "idle"
    # a stop while idle is an answer too, and changes nothing
    again = s.request("stop")
    assert again.ok and again.data["was_moving"] is False


@pytest.mark.wall
def test_second_execute_while_busy_is_refused_and_changes_nothing(arm6, serve):
    s = serve(arm6)
    col = s.follow()
    plan = s.request("plan", {"waypoints": long_tour(arm6)})
    other = s.request("plan", {"target": SHORT_TARGET})
    assert plan.ok and other.ok
    first = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert first.ok, first.data
    busy = s.request("execute", {"plan_id": other.data["plan_id"]})
    assert not busy.ok
    check_reply("error", busy.data)
    assert busy.data["error"]["code"] == "busy"
    assert busy.data["error"]["details"]["motion_id"] == first.data["motion_id"]
    busy_recover = s.request("recover")
    assert busy_recover.data["error"]["code"] == "busy"
    # the first motion runs to its end untouched; the journal has only it
    assert wait_until(lambda: col.events("motion_ended", first.data["motion_id"]), timeout=30)
    assert col.events("motion_ended", first.data["motion_id"])[0]["outcome"]["result"] == "finished"
    assert [e.motion_id for e in s.service.journal.recent(10)] == [first.data["motion_id"]]
    assert len(col.events("started")) == 1


def test_execute_wait_replies_with_the_outcome_and_a_program_can_be_sent_instead_of_a_plan_id(arm6, serve):
    s = serve(arm6)
    plan = s.request("plan", {"target": SHORT_TARGET, "include_program": True})
    assert plan.ok, plan.data
    valid = s.request("validate", {"program": plan.data["program"]})
    assert valid.ok and valid.data["ok"] and valid.data["cell_problems"] == []
    check_reply("validate", valid.data)
    done = s.request("execute", {"program": plan.data["program"], "wait": True})
    assert done.ok, done.data
    assert done.data["state"] == "ended" and done.data["outcome"]["result"] == "finished"
    assert done.data["plan_id"] is None
    # the same program again: the axes are no longer at its start
    again = s.request("execute", {"program": plan.data["program"]})
    assert again.data["error"]["code"] == "start_mismatch", again.data
    assert len(s.service.journal.recent(10)) == 1  # the refused one left no trace
    # back home from where the axes are
    home = s.request("plan", {"target": [0.0] * 6})
    assert home.ok
    np.testing.assert_allclose(home.data["start"], SHORT_TARGET, atol=1e-3)


@pytest.mark.wall
def test_a_fault_mid_move_halts_every_axis_and_the_cell_stays_in_fault(arm6, serve):
    s = serve(arm6)
    col = s.follow()
    plan = s.request("plan", {"waypoints": long_tour(arm6)})
    ex = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert ex.ok
    assert wait_until(lambda: any(t["elapsed_ms"] >= 200 for t in col.get("telemetry") if t["motion_id"]))
    s.sim.drive(4).inject_emcy(0x5113, fault=True)  # a drive fault in the middle of the move
    assert wait_until(lambda: col.events("motion_ended", ex.data["motion_id"]), timeout=20)
    outcome = col.events("motion_ended", ex.data["motion_id"])[0]["outcome"]
    assert outcome["result"] in ("emcy", "drive_fault") and outcome["node_id"] == 4
    for drive in s.sim:
        assert drive.node_id == 4 or (drive.faults == [] and not drive.ip_active)
    st = s.request("status").data
    assert st["state"] == "fault" and "node 4" in st["fault_reason"]
    assert next(a for a in st["axes"] if a["node_id"] == 4)["fault"]
    home = s.request("plan", {"target": [0.0] * 6})
    assert home.ok
    refused = s.request("execute", {"plan_id": home.data["plan_id"]})
    assert refused.data["error"]["code"] == "drive_fault"
    rec = s.request("recover")
    assert rec.ok, rec.data
    assert all(a["state"] == "OPERATION ENABLED" and not a["fault"] for a in rec.data["axes"])
    assert s.request("status").data["state"] == "idle"


@pytest.mark.wall
def test_a_fault_while_idle_needs_recover_before_the_next_motion(arm6, serve):
    s = serve(arm6)
    col = s.follow()
    plan = s.request("plan", {"target": SHORT_TARGET})
    assert plan.ok
    s.sim.drive(2).inject_emcy(0x3210, fault=True)
    assert wait_until(lambda: col.events("emcy"))
    assert wait_until(lambda: s.request("status").data["state"] == "fault")
    refused = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert refused.data["error"]["code"] == "drive_fault", refused.data
    assert all(d.records_received == 0 for d in s.sim)
    rec = s.request("recover")
    assert rec.ok, rec.data
    check_reply("recover", rec.data)
    assert all(a["state"] == "OPERATION ENABLED" for a in rec.data["axes"])
    assert s.request("status").data["state"] == "idle"
    done = s.request("execute", {"plan_id": plan.data["plan_id"], "wait": True})
    assert done.ok and done.data["outcome"]["result"] == "finished", done.data


def test_the_motion_is_on_disk_before_its_first_record_is_sent(arm6, serve, monkeypatch):
    s = serve(arm6)
    journal = s.service.journal.path
    seen_at_start: list[list[dict]] = []
    start = s.service.group.start

    def start_and_look(program, before_records=None):
        def look() -> None:  # where the group is about to send its first record
            if before_records is not None:
                before_records()
            records = sum(d.records_received for d in s.sim)
            seen_at_start.append([json.loads(x) for x in journal.read_bytes().splitlines()])
            assert records == 0

        return start(program, before_records=look)

    monkeypatch.setattr(s.service.group, "start", start_and_look)
    plan = s.request("plan", {"target": SHORT_TARGET})
    done = s.request("execute", {"plan_id": plan.data["plan_id"], "wait": True})
    assert done.ok, done.data
    [lines] = seen_at_start
    assert [x["kind"] for x in lines] == ["motion"] and lines[0]["motion_id"] == done.data["motion_id"]
    assert lines[0]["program"]["axes"][0]["records"]  # the whole program, not a reference to it
    kinds = [json.loads(x)["kind"] for x in journal.read_bytes().splitlines()]
    assert kinds == ["motion", "outcome"]


def test_a_restart_keeps_the_journal(arm6, serve, tmp_path):
    journal = tmp_path / "journal"
    first = serve(arm6, journal_dir=journal)
    plan = first.request("plan", {"target": SHORT_TARGET})
    done = first.request("execute", {"plan_id": plan.data["plan_id"], "wait": True, "label": "before restart"})
    assert done.ok and done.data["outcome"]["result"] == "finished"
    motion_id = done.data["motion_id"]
    first.server.close()
    first.service.close()

    second = serve(arm6, journal_dir=journal)
    st = second.request("status", {"recent": 10})
    assert st.ok
    [entry] = st.data["recent"]
    assert entry["motion_id"] == motion_id and entry["label"] == "before restart"
    assert entry["state"] == "ended" and entry["outcome"]["result"] == "finished"
    # the program that ran is on disk, as sent
    kept = second.service.journal_entry(motion_id)
    assert kept is not None and kept.program["cell"] == "arm6"
    assert [a["records"] for a in kept.program["axes"]] == [
        a["records"] for a in first.service.journal_entry(motion_id).program["axes"]
    ]


def test_a_plan_request_with_a_speed_override_runs_slower_and_a_bad_one_plans_nothing(arm6, serve):
    s = serve(arm6)
    full = s.request("plan", {"target": SHORT_TARGET})
    half = s.request(
        "plan", {"target": SHORT_TARGET, "velocity_scale": 0.5, "acceleration_scale": 0.5, "include_program": True}
    )
    assert full.ok and half.ok, (full.data, half.data)
    assert half.data["duration_s"] > full.data["duration_s"]
    meta = half.data["program"]["metadata"]
    assert meta["velocity_scale"] == 0.5 and meta["acceleration_scale"] == 0.5
    for ax, cfg in zip(half.data["program"]["axes"], arm6.ordered_axes(), strict=True):
        assert ax["limits"]["max_profile_velocity_rpm"] == cfg.limits.max_profile_velocity_rpm
    stored = len(s.service.plans)
    bad = s.request("plan", {"target": SHORT_TARGET, "velocity_scale": 0})
    assert not bad.ok and bad.data["error"]["code"] == "invalid_request"
    assert "$.velocity_scale" in bad.data["error"]["message"]
    assert len(s.service.plans) == stored  # nothing planned
    done = s.request("execute", {"plan_id": half.data["plan_id"], "wait": True}, timeout=60)
    assert done.ok and done.data["outcome"]["result"] == "finished", done.data
