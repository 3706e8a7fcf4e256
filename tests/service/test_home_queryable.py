"""Homing through the service: ``home`` on zenoh, ``not_homed`` refusals before homing and after a
drive reboots, status ``homed`` per axis, the journal's homing lines; a cell without homing says so."""

from __future__ import annotations

import pytest
from svc_helpers import check_reply, nothing_moved, wait_until

GANTRY_START = [0.05, 0.05, -0.05]
GANTRY_END = [0.10, 0.08, -0.08]


@pytest.mark.wall
def test_a_gantry_homes_before_it_moves_and_again_after_a_reboot(gantry3, serve) -> None:
    s = serve(gantry3)
    events = s.follow()
    status = s.request("status")
    check_reply("status", status.data)
    assert status.data["requires_homing"] is True and status.data["homed"] is False
    assert [a["homed"] for a in status.data["axes"]] == [False, False, False]

    # before homing: a plan from the current position and an execute are refused, nothing moves
    here = s.request("plan", {"target": GANTRY_END})
    assert here.data["error"]["code"] == "not_homed", here.data
    assert set(here.data["error"]["details"]["joints"]) == {"x", "y", "z"}
    plan = s.request("plan", {"waypoints": [GANTRY_START, GANTRY_END], "start": "first"})
    assert plan.ok, plan.data
    refused = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert refused.data["error"]["code"] == "not_homed", refused.data
    nothing_moved(s)

    # home: every axis, in the cell's order (z, then x and y together)
    home = s.request("home", {"wait": True}, timeout=60)
    assert home.ok, home.data
    check_reply("home", home.data)
    outcome = home.data["outcome"]
    assert outcome["result"] == "homed" and home.data["stages"] == [["z"], ["x", "y"]]
    for axis in outcome["axes"]:
        drive = s.sim.drive(axis["joint"])
        assert axis["homed"] and axis["position_qc"] == drive.actual == round(drive.machine_position)
    status = s.request("status")
    assert status.data["homed"] is True and all(a["homed"] for a in status.data["axes"])
    assert status.data["state"] == "idle"
    entry = s.service.journal.recent_homings(1)[0]
    assert entry.homing_id == home.data["homing_id"] and entry.outcome["result"] == "homed"
    assert wait_until(lambda: events.events("homing_ended"), timeout=5)

    # homed: the cell moves from where it stands
    move = s.request("plan", {"target": GANTRY_START})
    assert move.ok, move.data
    done = s.request("execute", {"plan_id": move.data["plan_id"], "wait": True}, timeout=60)
    assert done.ok and done.data["outcome"]["result"] == "finished", done.data

    # a drive reboots (NMT reset node): its axis is not homed any more, execute is refused again
    boots = s.service.bus.watch.boot_count(11)
    s.service.bus.nmt(11, 0x81)
    assert wait_until(lambda: s.service.bus.watch.boot_count(11) > boots, timeout=5)
    back = s.request("plan", {"waypoints": [GANTRY_START, GANTRY_END], "start": "first"})
    refused = s.request("execute", {"plan_id": back.data["plan_id"]})
    assert refused.data["error"]["code"] == "not_homed" and refused.data["error"]["details"]["joints"] == ["x"]
    status = s.request("status")
    assert [a["homed"] for a in status.data["axes"]] == [False, True, True]
    # the reboot is a fault to acknowledge; then x alone homes again and the cell moves
    assert s.request("recover").ok
    again = s.request("home", {"joints": ["x"], "wait": True}, timeout=60)
    assert again.ok and again.data["outcome"]["result"] == "homed" and again.data["stages"] == [["x"]]
    assert s.request("status").data["homed"] is True


def test_home_refuses_what_the_cell_does_not_have(gantry3, arm6, serve) -> None:
    g = serve(gantry3)
    reply = g.request("home", {"joints": ["w"]})
    assert reply.data["error"]["code"] == "unknown_joint" and "unknown axis 'w'" in reply.data["error"]["message"]
    bad = g.request("home", {"joints": "x"})
    assert bad.data["error"]["code"] == "invalid_request"
    assert all(d.homing.runs == [] for d in g.sim)
    a = serve(arm6)  # absolute encoders: nothing to home, nothing required
    reply = a.request("home", {})
    assert reply.data["error"]["code"] == "not_allowed", reply.data
    status = a.request("status")
    assert status.data["requires_homing"] is False and status.data["homed"] is True
