"""Regressions found in the field (service benchmark): each one a case that once failed."""

from __future__ import annotations

import numpy as np

from pvtflow.axes.drive.program import TIME_MAX_MS
from pvtflow.planner.knots.flat import within_record_time
from pvtflow.planner.plan import PlanInput
from pvtflow.planner.validate import validate_program
from pvtflow.service.cell_planner import plan_cell_program
from pvtflow.service.config import load_cell_config

# an arm6 path whose knot hints once held a segment longer than 255 ms (IndexError in the fit)
LONG_SEGMENT_PATH = [
    [
        -0.4271324913252774,
        -0.4984568355251476,
        -0.12998139921313512,
        0.390456774153501,
        -0.471669171968487,
        -1.255929729272382,
    ],
    [
        -1.096127778992184,
        0.7605800319574498,
        -0.32361421768086174,
        -0.1715813565127906,
        -0.5656877231187067,
        -1.060072838585576,
    ],
    [
        0.7696893707362655,
        -0.5502491344393874,
        -0.9580716639536234,
        -0.5200742263377113,
        -0.773980639901097,
        -0.6038249009192805,
    ],
    [
        0.10035087662181441,
        -0.6707868590974193,
        0.1762470800418363,
        0.2505488406547809,
        -0.05275732079655726,
        -0.674643796023445,
    ],
    [
        0.689777858564492,
        0.6577181931525102,
        -0.4341325066106696,
        -1.3544852680868016,
        0.9244573746242725,
        0.9097624234301733,
    ],
    [
        1.1356770802751714,
        0.2675510902345022,
        -1.1216614813215395,
        -0.0738043852116157,
        -0.8983216921661289,
        -0.9761733817735989,
    ],
    [
        -1.2687341690497296,
        -0.0724079525366792,
        -0.12615046929304796,
        -1.029120344748189,
        0.751887388244085,
        -0.4763158523974389,
    ],
    [
        1.1460590045595815,
        -0.2537903003514621,
        1.165175472869339,
        -1.484636669412306,
        0.11571734325386018,
        1.2362735691968085,
    ],
]


def test_long_gaps_are_split_to_record_times() -> None:
    knots = np.array([0, 10, 700, 701, 1300])
    out = within_record_time(knots)
    assert set(knots) <= set(out.tolist())
    assert np.all(np.diff(out) <= TIME_MAX_MS) and np.all(np.diff(out) >= 1)
    np.testing.assert_array_equal(within_record_time(np.array([0, 255, 510])), [0, 255, 510])


def test_path_with_a_long_hinted_segment_plans_and_validates() -> None:
    plan = plan_cell_program(load_cell_config(None), PlanInput(LONG_SEGMENT_PATH))
    assert plan.code == "ok", plan.message
    assert validate_program(plan.program).ok
    assert all(int(a.records[1:-1, 2].max()) <= TIME_MAX_MS for a in plan.program.axes)
