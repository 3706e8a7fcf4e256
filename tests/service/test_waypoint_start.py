"""One rule for where a waypoint file starts: at its first row, in ``pvtflow plan`` and in ``pvtflow
request plan`` alike; the motion from the axes through every row only when asked (--start current)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pvtflow.service.cli import main

ROWS = [[0.1, 0.0, 0.1, 0.0, 0.1, 0.0], [0.2, -0.1, 0.2, -0.1, 0.2, -0.1]]


def reply_of(capsys: pytest.CaptureFixture[str]) -> dict:  # type: ignore[type-arg]
    return json.loads(capsys.readouterr().out)


def test_a_file_starts_at_its_first_row_through_the_service_as_offline(  # type: ignore[no-untyped-def]
    serve, arm6, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": ROWS}))
    served = serve(arm6)
    connect = ["--connect", served.endpoint]
    assert main(["request", "plan", "--waypoints", str(wp), *connect]) == 0
    first = reply_of(capsys)
    assert first["start"] == pytest.approx(ROWS[0], abs=1e-3) and first["waypoints"] == 2, first
    program = tmp_path / "offline.json"
    assert main(["plan", "--waypoints", str(wp), "-o", str(program), "--json"]) == 0
    offline = json.loads(program.read_text())
    capsys.readouterr()
    starts = [a["records"][0][0] for a in offline["axes"]]
    assert served.request("validate", {"plan_id": first["plan_id"]}).ok
    # the same motion: the same start records as the offline program
    stored = served.service.stored_plan(first["plan_id"]).program
    assert [int(a.records[0, 0]) for a in stored.axes] == starts
    # no detour on the machine: the axes are elsewhere, so execute refuses and nothing moves
    assert main(["request", "execute", first["plan_id"], *connect]) == 1
    assert "start_mismatch" in capsys.readouterr().err
    assert all(d.records_received == 0 for d in served.sim)
    # the motion from the axes through every row, when asked
    assert main(["request", "plan", "--waypoints", str(wp), "--start", "current", *connect]) == 0
    current = reply_of(capsys)
    assert current["start"] == pytest.approx([0.0] * 6, abs=1e-6) and current["waypoints"] == 3, current


def test_a_one_row_file_is_a_goal_from_the_axes(serve, arm6, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    wp = tmp_path / "goal.json"
    wp.write_text(json.dumps({"waypoints": ROWS[:1]}))
    served = serve(arm6)
    assert main(["request", "plan", "--waypoints", str(wp), "--connect", served.endpoint]) == 0
    reply = reply_of(capsys)
    assert reply["start"] == pytest.approx([0.0] * 6, abs=1e-6) and reply["end"] == pytest.approx(ROWS[0], abs=1e-3)
