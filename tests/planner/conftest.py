"""Fixtures of the planner tests."""

from __future__ import annotations

import pytest
from hand_programs import GOOD_RECORDS, axis, program

from pvtflow.axes.drive.program import PvtProgram


@pytest.fixture
def good_program() -> PvtProgram:
    return program(
        axis(GOOD_RECORDS), axis([[500, 0, 1], [400, -60, 40], [300, 0, 40], [300, 0, 0]], name="joint_2", node_id=2)
    )
