"""The motion journal: append-only JSON lines, fsync'ed, read back after a restart or a crash."""

from __future__ import annotations

import json
import time

import pytest
from svc_helpers import SHORT_TARGET, nothing_moved

from pvtflow.service.journal import JOURNAL_FILE, Journal, JournalError

PROGRAM = {"format": "pvtflow.pvt-program", "version": 1, "cell": "c", "axes": []}


def test_motions_and_outcomes_survive_a_restart_newest_first(tmp_path):
    j = Journal(tmp_path)
    j.record_motion("m-1", PROGRAM, plan_id="p-1", label="one", duration_ms=10, cell="c")
    j.record_outcome("m-1", {"result": "finished", "message": "ok"})
    j.record_motion("m-2", PROGRAM, plan_id=None, label=None, duration_ms=20, cell="c")
    j.close()
    again = Journal(tmp_path)
    recent = again.recent(10)
    assert [e.motion_id for e in recent] == ["m-2", "m-1"]
    assert recent[1].outcome == {"result": "finished", "message": "ok"}
    # a motion without an outcome line: the service stopped (or crashed) while it ran
    assert recent[0].summary()["state"] == "interrupted"
    assert recent[1].summary()["state"] == "ended"
    assert again.recent(1)[0].motion_id == "m-2" and again.recent(0) == []


def test_homings_survive_a_restart_beside_the_motions(tmp_path):
    j = Journal(tmp_path)
    j.record_homing("h-1", [["z"], ["x", "y"]], cell="c")
    j.record_homing_outcome("h-1", {"result": "homed", "message": "ok"})
    j.record_motion("m-1", PROGRAM, plan_id=None, label=None, duration_ms=10, cell="c")
    j.record_homing("h-2", [["x"]], cell="c")
    j.close()
    again = Journal(tmp_path)
    homings = again.recent_homings(10)
    assert [h.homing_id for h in homings] == ["h-2", "h-1"]
    assert homings[1].summary()["state"] == "ended" and homings[1].outcome == {"result": "homed", "message": "ok"}
    assert homings[0].summary()["state"] == "interrupted" and homings[0].stages == [["x"]]
    assert [e.motion_id for e in again.recent(10)] == ["m-1"]  # homings are not motions
    kinds = [json.loads(line)["kind"] for line in (tmp_path / JOURNAL_FILE).read_text().splitlines()]
    assert kinds == ["homing", "homing_outcome", "motion", "homing"]


def test_the_file_is_only_ever_appended_and_a_torn_last_line_is_skipped(tmp_path):
    j = Journal(tmp_path)
    j.record_motion("m-1", PROGRAM, plan_id=None, label=None, duration_ms=1, cell="c")
    j.close()
    path = tmp_path / JOURNAL_FILE
    before = path.read_bytes()
    with open(path, "ab") as f:
        f.write(b'{"kind": "outcome", "motion_id": "m-1", "ti')  # power lost mid-write
    j = Journal(tmp_path)
    assert j.skipped_lines == 1
    assert j.recent(5)[0].outcome is None
    j.record_outcome("m-1", {"result": "stopped", "message": "late"})
    j.close()
    data = path.read_bytes()
    assert data.startswith(before)
    lines = data.splitlines()
    assert json.loads(lines[0])["program"] == PROGRAM
    assert json.loads(lines[-1])["outcome"]["message"] == "late"  # whole, on its own line
    assert Journal(tmp_path).recent(1)[0].outcome == {"result": "stopped", "message": "late"}


def test_an_unwritable_journal_is_a_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    try:
        Journal(blocker / "journal")
    except OSError as exc:
        assert "journal" in str(exc)
    else:
        raise AssertionError("a journal under a file must not open")


@pytest.mark.wall
def test_a_motion_the_journal_cannot_take_is_refused_with_nothing_sent(arm6, serve):
    """The motion is journaled while the drives answer the start's checks; when that write fails,
    no record has gone out, the execute answers journal_error and the service stays usable."""
    s = serve(arm6)
    plan = s.request("plan", {"target": SHORT_TARGET})
    assert plan.ok, plan.data
    journal = s.service.journal
    written = journal.record_motion

    def full_disk(*args: object, **kwargs: object) -> None:
        time.sleep(0.02)  # after the start's checks have gone out to the drives
        raise JournalError("journal: no space left on device")

    journal.record_motion = full_disk  # type: ignore[method-assign]
    refused = s.request("execute", {"plan_id": plan.data["plan_id"]})
    assert not refused.ok and refused.data["error"]["code"] == "journal_error", refused.data
    assert "nothing was sent" in refused.data["error"]["message"]
    nothing_moved(s)
    journal.record_motion = written  # type: ignore[method-assign]
    ran = s.request("execute", {"plan_id": plan.data["plan_id"], "wait": True}, timeout=60)
    assert ran.ok and ran.data["outcome"]["result"] == "finished", ran.data
    assert [m.motion_id for m in journal.recent(5)] == [ran.data["motion_id"]]
