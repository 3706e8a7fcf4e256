"""Motion time for fewer records (planner.speed_band) through the planning pipeline: none by default,
and where a plan is flattened (the cell file asks, or its bus cannot feed the time-optimal records)
the plan says why and what it cost, in the program's metadata and in ``pvtflow plan``'s summary."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.planner.plan import PlanInput
from pvtflow.service.cell_planner import CELL_FILE_REASON, FEED_BANDS, CellPlanner
from pvtflow.service.cli import main
from pvtflow.service.config import CONFIG_DIR, load_cell_config

GANTRY_FILE = CONFIG_DIR / "cells" / "gantry3.yaml"
GANTRY = load_cell_config(GANTRY_FILE)


def gantry_waypoints(seed: int = 1) -> np.ndarray:
    lim = GANTRY.joint_limits()
    rng = np.random.default_rng(seed)
    return lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * rng.random((8, lim.dof)))


def test_the_shipped_cells_plan_time_optimal_motions() -> None:
    """No shipped cell gives motion time away: its plan is TOPP-RA's own, and its bus feeds it."""
    for name in ("arm6", "gantry3", "gantry3-mixed"):
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        assert cell.planning.speed_band == 0.0
        planner = CellPlanner(cell)
        lim = planner.limits
        w = lim.lower + (lim.upper - lim.lower) * (0.1 + 0.8 * np.random.default_rng(5).random((8, lim.dof)))
        result = planner.plan(PlanInput(w))
        assert result.ok and result.program is not None
        assert result.speed_band is None and "speed_band" not in result.program.metadata
        assert planner.feed.shortfall(result.program) is None


def test_a_band_the_cell_file_asks_for_is_said_with_its_cost(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = yaml.safe_load(GANTRY_FILE.read_text())
    data["robot"]["urdf"] = str(CONFIG_DIR / "robots" / "gantry3.urdf")
    data["planning"]["speed_band"] = 0.05
    file = tmp_path / "cell.yaml"
    file.write_text(yaml.safe_dump(data))
    w = gantry_waypoints()
    optimal = CellPlanner(GANTRY).plan(PlanInput(w))
    banded = CellPlanner(load_cell_config(file)).plan(PlanInput(w))
    assert optimal.ok and banded.ok and optimal.plan is not None and banded.plan is not None
    assert banded.speed_band is not None and banded.program is not None
    assert banded.speed_band["band"] == 0.05 and banded.speed_band["reason"] == CELL_FILE_REASON
    cost = 100.0 * (banded.plan.trajectory.duration / optimal.plan.trajectory.duration - 1.0)
    assert 0.0 < banded.speed_band["cost_pct"] == pytest.approx(cost, abs=1e-3)
    assert banded.program.metadata["speed_band"] == banded.speed_band
    assert sum(len(a.records) for a in banded.program.axes) < sum(len(a.records) for a in optimal.program.axes)
    # pvtflow plan's summary and the program it writes say the same
    wp, out = tmp_path / "wp.json", tmp_path / "program.json"
    wp.write_text(json.dumps({"joint_names": list(GANTRY.joint_names), "waypoints": w.tolist()}))
    assert main(["plan", "--config", str(file), "--waypoints", str(wp), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["speed_band"] == banded.speed_band
    assert PvtProgram.loads(out.read_text()).metadata["speed_band"] == banded.speed_band


def test_a_bus_that_cannot_feed_the_optimal_records_gets_the_narrowest_band_that_it_can() -> None:
    """gantry3 at a 40 ms SYNC period with 3 records per SYNC: one record per axis per 40 ms is too few
    for the time-optimal plan's records; the plan is flattened within the narrowest band the bus
    feeds, and says so (the shortfall) and what it cost."""
    slow_bus = dataclasses.replace(GANTRY.bus, sync_period_ms=40.0, records_per_sync=3)
    planner = CellPlanner(dataclasses.replace(GANTRY, bus=slow_bus))
    optimal = CellPlanner(GANTRY).plan(PlanInput(gantry_waypoints()))
    assert optimal.program is not None and planner.feed.shortfall(optimal.program) is not None
    result = planner.plan(PlanInput(gantry_waypoints()))
    assert result.ok and result.program is not None and result.speed_band is not None
    assert planner.feed.shortfall(result.program) is None
    band = result.speed_band
    assert band["band"] > 0.0 and "the bus cannot feed" in band["reason"] and "40 ms SYNC period" in band["reason"]
    assert 0.0 < band["cost_pct"] <= 100.0 * (1.0 / (1.0 - band["band"]) - 1.0)
    assert result.program.metadata["speed_band"] == band
    # the narrowest: every band tried before it (none: the optimal plan above) runs a FIFO dry
    for narrower in FEED_BANDS[: FEED_BANDS.index(band["band"])]:
        tried = planner.plan(PlanInput(gantry_waypoints(), speed_band=narrower))
        assert tried.program is not None and planner.feed.shortfall(tried.program) is not None
