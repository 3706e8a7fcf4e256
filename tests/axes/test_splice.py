"""The look-ahead bound and the splice's pieces, without a bus (issue 37): an EPOS2 feeder holds records at most
the bound beyond the drive's clock (and never fewer than MIN_HELD), long segments are cut on their own cubic
within the drive's limits, a horizon holds records back, and a replacement keeps what was sent."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.program import AxisProgram, split_long_records
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.master.group.feeder import MIN_HELD, BufferFeeder, SetpointFeeder

SCALING = AxisScaling.prismatic(4096, 0.02)
LIMITS = DriveLimits(3000, 30000, -10_000_000, 10_000_000)


def axis(records: np.ndarray) -> AxisProgram:
    return AxisProgram("x", 1, "epos2_pvt", SCALING, LIMITS, records=np.asarray(records, dtype=np.int64))


def cruise() -> np.ndarray:
    """Accelerate in 100 ms at 0x60C5, cruise 600 ms in one segment at 3000 rpm, brake: the knots a plan makes."""
    v = 3000  # rpm = velocity units
    f = SCALING.qc_per_ms_per_velocity_unit
    d_ramp = round(0.5 * v * f * 100)
    d_cruise = round(v * f * 600)
    return np.array(
        [
            [0, 0, 1],
            [d_ramp, v, 100],
            [d_ramp + d_cruise, v, 600],
            [2 * d_ramp + d_cruise, 0, 100],
            [2 * d_ramp + d_cruise, 0, 0],
        ]
    )


def test_long_segments_are_cut_on_their_cubic_within_the_limits() -> None:
    original = axis(cruise())
    cut = split_long_records(original, 25)
    assert cut[1:-1, 2].max() <= 25 and cut[:, 2].sum() == original.records[:, 2].sum()
    again = axis(cut)
    t = np.arange(0.0, original.duration_ms + 1.0)
    drift = np.abs(again.reconstruction().position(t) - original.reconstruction().position(t)).max()
    assert drift <= 1.0  # a count: the cut points are rounded, the cubic is the same
    rec = again.reconstruction()
    vmax = SCALING.rpm_to_qc_per_ms(LIMITS.max_profile_velocity_rpm)
    amax = SCALING.rpm_s_to_qc_per_ms2(LIMITS.max_acceleration_rpm_s)
    assert rec.max_abs_velocity().max() <= vmax * (1 + 1e-9)
    assert rec.max_abs_acceleration().max() <= amax * (1 + 1e-9)


@pytest.mark.parametrize("lookahead", [20.0, 50.0, 120.0])
def test_the_fifo_holds_at_most_the_lookahead_and_at_least_min_held(lookahead: float) -> None:
    records = split_long_records(axis(cruise()), int(lookahead / 2))
    sent: list[bytes] = []
    feeder = BufferFeeder(
        records, lambda r: (0x201, bytes(8)), lambda c, d: sent.append(d), 1.0, BufferConfig(), lookahead_ms=lookahead
    )
    feeder.preload(whole=True)
    longest = float(records[1:, 2].max())
    for ms in range(1, feeder.duration_ms):
        feeder.on_sync(ms)  # a feeder on its own tops up on every SYNC
        if feeder.all_sent:
            break
        held = float(feeder.end_ms[feeder.next - 1])
        assert held <= ms + max(lookahead + longest, float(feeder.end_ms[feeder.consumed() + MIN_HELD - 1]))
        assert feeder.level >= MIN_HELD - 1  # the segment running and the one after it, at least
    assert feeder.stats.underflows == 0


def test_a_horizon_holds_records_back_and_a_replacement_keeps_what_was_sent() -> None:
    rows = np.array([[k * 10, 0, 2] for k in range(40)], dtype=np.int64)
    sent: list[int] = []
    feeder = SetpointFeeder(
        rows, lambda r: (0x300, bytes(int(r[0]) % 256 for _ in range(1))), lambda c, d: sent.append(d[0]), 2.0, 1
    )
    feeder.preload()
    feeder.horizon_ms = 20.0  # records ending after 20 ms stay back
    for elapsed in range(30):
        feeder.after_sync(elapsed)
    assert feeder.next == 10  # records 0..9 end by 20 ms
    feeder.replace_from(12, np.array([[999, 0, 2]] * 3))
    assert feeder.horizon_ms is None and len(feeder.records) == 15
    assert feeder.records[:12].tolist() == rows[:12].tolist() and feeder.records[12, 0] == 999
    for elapsed in range(30, 40):
        feeder.after_sync(elapsed)
    assert feeder.all_sent
