"""Feeders against a model FIFO: what they send, when, and the level they keep (no bus)."""

from __future__ import annotations

import numpy as np
import pytest

from pvtflow.axes.drive.config import BufferConfig
from pvtflow.axes.drive.objects import BufferStatus, Record
from pvtflow.axes.master.group.feeder import PRELOAD_MS, TOP_UP_PER_SYNC, BufferFeeder, SetpointFeeder


def records(n: int, dt: int = 2, end: bool = False) -> np.ndarray:
    r = np.array([[10 * k, k, dt] for k in range(n)], dtype=np.int64)
    if end:
        r = np.vstack([r, [[r[-1, 0], 0, 0]]])
    return r


class FifoModel:
    """The EPOS2 FIFO as the app note states it: a record leaves when its segment starts."""

    def __init__(self) -> None:
        self.fifo: list[Record] = []
        self.received: list[Record] = []
        self.max_level = 0
        self.next_start = 0.0

    def send(self, cob: int, data: bytes) -> None:
        assert cob == 0x201
        rec = Record.from_bytes(data)
        self.fifo.append(rec)
        self.received.append(rec)
        self.max_level = max(self.max_level, len(self.fifo))
        assert len(self.fifo) <= 64, "overflow"

    def advance(self, t: float) -> None:
        while self.fifo and self.next_start <= t:
            rec = self.fifo.pop(0)
            if rec.time == 0:
                break
            self.next_start += rec.time


def frame(row: np.ndarray) -> tuple[int, bytes]:
    return 0x201, Record(int(row[0]), int(row[1]), int(row[2])).to_bytes()


@pytest.mark.parametrize(("n", "dt"), [(3, 5), (40, 1), (500, 1), (500, 7)])
def test_buffer_feeder_keeps_the_level_between_the_warnings(n, dt):
    model = FifoModel()
    buf = BufferConfig(underflow_warning=4, overflow_warning=60)
    feeder = BufferFeeder(records(n, dt), frame, model.send, 1.0, buf)
    preloaded = feeder.preload()
    # before the start: the first PRELOAD_MS of motion and two above the underflow warning, no more
    recs = feeder.records
    covered = recs[:preloaded, 2].sum()
    assert preloaded == len(recs) or (preloaded >= buf.underflow_warning + 2 and covered >= PRELOAD_MS)
    assert preloaded <= buf.underflow_warning + 2 or recs[: preloaded - 1, 2].sum() < PRELOAD_MS
    elapsed = 0
    while True:
        model.advance(float(elapsed))
        if model.received and model.received[-1].time == 0 and not model.fifo:
            break
        before = len(model.received)
        feeder.on_sync(elapsed)
        assert len(model.received) - before <= TOP_UP_PER_SYNC or len(model.fifo) <= buf.underflow_warning + 1
        assert len(model.fifo) < buf.overflow_warning  # never at the overflow warning level
        # the level the feeder believes is never below the true one (it never overfills)
        assert feeder.level >= len(model.fifo)
        remaining_ms = sum(r.time for r in model.fifo)
        if not feeder.all_sent:
            assert remaining_ms > 1, "underflow: the drive would run dry"
        elapsed += 1
        assert elapsed < n * dt + 100
    sent = np.array([[r.position, r.velocity, r.time] for r in model.received])
    if n * dt > 200:  # a long program: the FIFO was filled to just below the overflow warning
        assert model.max_level >= buf.overflow_warning - 2  # (the segment running counts as buffered)
    np.testing.assert_array_equal(sent[:-1], records(n, dt))
    assert tuple(sent[-1]) == (records(n, dt)[-1, 0], 0, 0)  # the end record


def test_end_record_is_not_doubled():
    model = FifoModel()
    feeder = BufferFeeder(records(5, end=True), frame, model.send, 1.0, BufferConfig())
    feeder.preload()
    assert [r.time for r in model.received].count(0) == 1


def test_overflow_warning_holds_and_underflow_warning_refills():
    model = FifoModel()
    feeder = BufferFeeder(records(300, 1), frame, model.send, 1.0, BufferConfig(4, 60))
    feeder.preload()
    sent = len(model.received)
    feeder.on_status(int(BufferStatus.OVERFLOW_WARNING | BufferStatus.IP_MODE_ACTIVE))
    model.advance(30.0)
    feeder.on_sync(30)  # 30 records consumed by the clock, but the drive says it is full
    assert len(model.received) == sent
    feeder.on_status(int(BufferStatus.UNDERFLOW_WARNING | BufferStatus.IP_MODE_ACTIVE))
    assert len(model.received) > sent
    assert feeder.stats.overflow_warnings == 1 and feeder.stats.underflow_warnings == 1
    feeder.on_status(int(BufferStatus.UNDERFLOW_ERROR))
    assert feeder.stats.underflows == 1


def test_disabled_feeder_sends_nothing():
    model = FifoModel()
    feeder = BufferFeeder(records(300, 1), frame, model.send, 1.0, BufferConfig())
    feeder.preload()
    feeder.enabled = False
    sent = len(model.received)
    for k in range(100):
        feeder.on_sync(k)
    assert len(model.received) == sent


@pytest.mark.parametrize("lead", [0, 1, 2])
def test_setpoint_feeder_validates_record_k_at_start_plus_k_plus_1_minus_lead(lead):
    sent: list[tuple[int, int]] = []  # (SYNC that will validate it, position)
    sync = {"next": 0}  # the start SYNC is 0

    def send(cob: int, data: bytes) -> None:
        sent.append((sync["next"], int.from_bytes(data[:4], "little", signed=True)))

    recs = records(20, 4)
    feeder = SetpointFeeder(recs, lambda row: (0x201, int(row[0]).to_bytes(4, "little", signed=True)), send, 4.0, lead)
    feeder.preload()
    for elapsed in range(25):
        sync["next"] = elapsed + 1
        before = len(sent)
        feeder.on_sync(elapsed)  # the drives' answers pace nothing: the setpoint goes out after the SYNC
        assert len(sent) == before
        feeder.after_sync(elapsed)
        if feeder.finished(elapsed, True):
            break
    first = max(0, lead - 1)
    assert [p for _, p in sent] == list(recs[first:, 0])
    for validating, position in sent:
        k = int(position // 10)
        assert validating == k + 1 - lead
    assert feeder.finished(len(recs), True) and not feeder.finished(len(recs) - 1, True)


@pytest.mark.parametrize("lead", [0, 1, 2])
def test_setpoints_after_syncs_that_went_out_without_one_go_on_with_the_next_record_never_a_jump(lead):
    """The interface sends SYNC and its follower was held through three SYNCs (axes.master.bus.sync_follower):
    the drive held through them; the next setpoint is the record after the last one sent, so the
    drive's step is the program's, and one goes out per SYNC until the program's end."""
    recs = records(12)
    sent: list[int] = []
    feeder = SetpointFeeder(
        recs,
        lambda row: (0x201, int(row[0]).to_bytes(4, "little", signed=True)),
        lambda c, d: sent.append(d),
        4.0,
        lead,
    )
    feeder.preload()
    for elapsed in (0, 1, 2, 6, 7, 8):  # SYNCs 3, 4 and 5 carried no setpoint
        feeder.after_sync(elapsed)
    positions = [int.from_bytes(d, "little", signed=True) for d in sent]
    first = max(0, lead - 1)
    assert positions == [10 * k for k in range(first, first + len(positions))]  # every record, in order
    assert len(positions) == (1 if lead >= 1 else 0) + 6  # one per SYNC that was followed, none twice
    elapsed = 8
    while not feeder.all_sent:
        elapsed += 1
        feeder.after_sync(elapsed)
    assert [int.from_bytes(d, "little", signed=True) for d in sent] == list(recs[first:, 0])
    # the drive held three periods: its last record is reached three SYNCs after the program's end
    assert feeder.held_syncs == 3
    assert not feeder.finished(len(recs) + 2, True) and feeder.finished(len(recs) + 3, True)


def test_the_end_record_waits_for_its_hold_and_a_program_can_take_its_place_until_then():
    """A buffered feeder holding its end record (axes.master.run_queue) sends every other record as before;
    the end record goes once the drive's clock is ``hold_end_ms`` from the end. Until then another program's
    records can take its place (the end record then follows them); after it, not."""
    model = FifoModel()
    feeder = BufferFeeder(records(20, 10), frame, model.send, 1.0, BufferConfig(4, 60))
    feeder.hold_end(50.0)
    feeder.preload()
    elapsed = 0
    while feeder.next < len(feeder.records) - 1 or not feeder.end_held:
        elapsed += 1
        feeder.on_sync(elapsed)
        if elapsed > 1000:
            break
    assert feeder.next == 20 and feeder.end_held and elapsed < 200 - 50  # every record but the end one is out
    later = records(5, 10) + np.array([190, 0, 0])
    extension = feeder.extension(later)
    assert extension.ready()
    extension.apply()
    assert len(feeder.records) == 20 + 5 + 1 and feeder.duration_ms == 250
    np.testing.assert_array_equal(feeder.records[-1], [later[-1, 0], 0, 0])
    while not feeder.all_sent:
        elapsed += 1
        feeder.on_sync(elapsed)
    assert elapsed >= 250 - 50  # the end record only once the clock was within the hold of the new end
    assert [r.time for r in model.received][-1] == 0 and sum(r.time == 0 for r in model.received) == 1
    assert not feeder.extension(later).ready()  # the end record is out: nothing can follow any more
