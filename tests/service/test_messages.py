"""What the commands say while they work: the first plan's compile announced, the simulated drives'
homing mode in pvtflow sim's banner, no carriage-return frames into a pipe, the buffer figures explained."""

from __future__ import annotations

import io
import json
import uuid
from pathlib import Path

import pytest

import pvtflow.service.plan_cmd
from pvtflow.axes.sim.cell import SimulatedCell
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, load_cell_config
from pvtflow.service.demo_cmd import _Follower
from pvtflow.service.sim_cmd import banner


def waypoints(tmp_path: Path) -> Path:
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": [[0.0] * 6, [0.2, -0.1, 0.2, -0.1, 0.2, -0.1]]}))
    return wp


def test_a_plan_that_takes_long_says_it_is_compiling(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["plan", "--waypoints", str(waypoints(tmp_path)), "-o", str(tmp_path / "a.json")]) == 0
    assert "compiles" not in capsys.readouterr().err  # kernels loaded: no notice
    monkeypatch.setattr(pvtflow.service.plan_cmd, "SLOW_PLAN_NOTICE_S", 0.0)  # every plan is "slow" now
    assert main(["plan", "--waypoints", str(waypoints(tmp_path)), "-o", str(tmp_path / "b.json")]) == 0
    err = capsys.readouterr().err
    assert "still planning (on a new machine the first plan compiles the planner's loops first" in err, err


@pytest.mark.parametrize(("cell", "homes"), [("gantry3", "nodes 11, 12, 13"), ("gantry3-ip-linear", None)])
def test_the_sim_banner_says_which_drives_home_in_mode_6(cell: str, homes: str | None) -> None:
    config = load_cell_config(CONFIG_DIR / "cells" / f"{cell}.yaml")
    sim = SimulatedCell(config, interface="virtual", channel=f"banner-{uuid.uuid4().hex[:8]}")
    sim.start()
    try:
        text = banner(sim)
    finally:
        sim.stop()
    assert "interpolated position mode (7)" in text
    assert "mode (7) only" not in text
    if homes:
        assert f"home in homing mode (6): {homes}" in text, text
    else:
        assert "homing mode" not in text, text


@pytest.mark.wall
def test_progress_into_a_pipe_is_plain_lines() -> None:
    out = io.StringIO()  # not a terminal
    follower = _Follower(stream=out)
    follower.follow("m-1")
    for i in range(101):
        follower.on_telemetry(
            "arm6", {"motion_id": "m-1", "progress": i / 100, "elapsed_ms": 10 * i, "buffer_levels": [8, None]}
        )
    follower.end_line()
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert len(lines) == 11 and lines[-1].strip().startswith("100.0%"), lines


def test_the_execute_summary_says_what_the_buffer_figures_are(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    program = tmp_path / "p.json"
    assert main(["plan", "--waypoints", str(waypoints(tmp_path)), "-o", str(program)]) == 0
    assert main(["execute", str(program), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "records queued in the drive's buffer during the run" in out, out
