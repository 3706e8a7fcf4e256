"""The bus budget of a cell (axes/master/budget.py) and the record allowance the feeders keep to."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import can
import pytest
import yaml
from axes_programs import program

from pvtflow.axes.canbus.frame_time import frame_bits, worst_frame_bits
from pvtflow.axes.drive.config import AxisConfig, BusConfig, Wiring
from pvtflow.axes.master.budget import LOAD_LIMIT, bus_budget
from pvtflow.service.config import CONFIG_DIR, ConfigError, load_cell_config

CELLS = sorted((CONFIG_DIR / "cells").glob("*.yaml"))


def test_the_budget_of_an_epos2_cell_adds_up_frame_by_frame(arm6):
    """Two EPOS2 axes at 2 ms on 500 kbit/s, computed here from the frames themselves: per period on
    average, in the worst period and in the worst window of 10 periods."""
    bus = BusConfig(bitrate=500_000, sync_period_ms=2.0, heartbeat_ms=50, master_heartbeat_ms=100, records_per_sync=3)
    axes = tuple(dataclasses.replace(a, node_id=n) for a, n in zip(arm6.axes[:2], (1, 2), strict=True))
    budget = bus_budget(Wiring(bus, axes))
    sync, stamp = frame_bits(0x80), worst_frame_bits(4)
    control, event, status = worst_frame_bits(2), worst_frame_bits(4), worst_frame_bits(6)
    beats = 2 * 2.0 / 50 + 2.0 / 100  # heartbeats per period: two drives and the master
    reserve = worst_frame_bits(8) + 2 * worst_frame_bits(8)  # an EMCY, an SDO request and its answer
    records = 3 * worst_frame_bits(8)
    steady = sync + stamp + 2 * (event + status) + records  # in every period
    expected = steady + 2 * 0.3 * control + beats * worst_frame_bits(1) + reserve / 10
    assert budget.total_bits == pytest.approx(expected)
    # a window: 3 controlwords per axis (start, halt, end), every heartbeat, one EMCY and one SDO exchange
    window = 10 * steady + 2 * 3 * control + math.ceil(10 * beats) * worst_frame_bits(1) + reserve
    assert budget.window_bits == pytest.approx(window)
    assert budget.window_fraction == pytest.approx(window / 10_000.0)
    # the worst period: a controlword on every axis and a heartbeat, no SDO or EMCY claimed
    assert budget.peak_bits == pytest.approx(steady + 2 * control + worst_frame_bits(1))
    assert budget.capacity_bits == 1000.0
    assert budget.records_per_sync == 3 and budget.buffered_axes == 2


def test_sdo_and_emcy_room_is_reserved_once_per_window_not_per_period(arm6):
    """At 1 ms an SDO exchange and an EMCY in every period would take 40 % of a 1 Mbit/s bus."""
    bus = dataclasses.replace(arm6.bus, sync_period_ms=1.0, records_per_sync=6, tx_queue_frames=64)
    budget = bus_budget(Wiring(bus, arm6.axes))
    reserved = [i for i in budget.items if "reserved" in i.name]
    assert sum(i.window_bits for i in reserved) == worst_frame_bits(8) * 3
    assert sum(i.peak_bits for i in reserved) == 0


def test_the_derived_allowance_is_the_room_under_the_limit(arm6):
    bus = dataclasses.replace(arm6.bus, sync_period_ms=5.0, records_per_sync=None)
    budget = bus_budget(Wiring(bus, arm6.axes))
    others = [i for i in budget.items if not i.name.startswith("records")]
    window_room = (LOAD_LIMIT * 10 * 5000 - sum(i.window_bits for i in others)) / (10 * worst_frame_bits(8))
    period_room = (5000 - sum(i.peak_bits for i in others)) / worst_frame_bits(8)
    room = math.floor(min(window_room, period_room))
    queue_room = bus.tx_queue_frames - 2  # the SYNC and the time stamp go out with the records
    assert budget.records_per_sync == min(room, queue_room)
    assert budget.window_fraction <= LOAD_LIMIT and budget.peak_fraction <= 1 and budget.problem() is None
    longer = dataclasses.replace(bus, tx_queue_frames=64)
    assert bus_budget(Wiring(longer, arm6.axes)).records_per_sync == room  # then the bus is what limits


def test_records_beyond_the_transmit_queue_are_refused(tmp_path: Path):
    """What the master sends right after one SYNC must fit its transmit queue (SocketCAN: ENOBUFS)."""
    file = _write(tmp_path, "arm6.yaml", {"records_per_sync": 9})  # + SYNC + time stamp = 11 > 10
    with pytest.raises(ConfigError, match=r"the master sends 11 frames right after a SYNC .*tx_queue_frames 10"):
        load_cell_config(file)
    cell = load_cell_config(_write(tmp_path, "arm6.yaml", {"records_per_sync": 9, "tx_queue_frames": 16}))
    assert bus_budget(cell).records_per_sync == 9


@pytest.mark.parametrize("path", CELLS, ids=lambda p: p.stem)
def test_every_shipped_cell_is_within_its_budget(path: Path):
    budget = bus_budget(load_cell_config(path))
    assert budget.window_fraction <= LOAD_LIMIT and budget.peak_fraction <= 1.0
    assert budget.buffered_axes == 0 or budget.records_per_sync >= budget.buffered_axes


def _write(tmp_path: Path, source: str, bus: dict[str, object]) -> Path:
    data = yaml.safe_load((CONFIG_DIR / "cells" / source).read_text())
    data["robot"]["urdf"] = str((CONFIG_DIR / "cells" / data["robot"]["urdf"]).resolve())
    data["bus"].update(bus)
    file = tmp_path / "cell.yaml"
    file.write_text(yaml.safe_dump(data))
    return file


def test_a_linear_ip_gantry_at_1_ms_on_250_kbit_is_refused_with_the_figure(tmp_path: Path):
    file = _write(tmp_path, "gantry3-ip-linear.yaml", {"sync_period_ms": 1.0, "bitrate": 250_000})
    with pytest.raises(ConfigError) as err:
        load_cell_config(file)
    message = str(err.value)
    assert message.startswith(f"{file}: bus: ")
    budget = bus_budget(dataclasses.replace(load_cell_config(CONFIG_DIR / "cells" / "gantry3-ip-linear.yaml")))
    assert budget.problem() is None  # the shipped file fits: only the bus changed
    assert "% of the bus" in message and "bus.sync_period_ms" in message and "bus.bitrate" in message


def test_a_linear_ip_gantry_fits_at_the_seeds_1_ms_with_status_every_second_sync(tmp_path: Path):
    """At 1 ms three setpoints and three status TPDOs in every period take 80 % of a window: refused,
    naming the status rate; with the status TPDOs on every second SYNC the cell fits."""
    every = _write(tmp_path, "gantry3-ip-linear.yaml", {"sync_period_ms": 1.0})
    with pytest.raises(ConfigError, match=r"takes 80% of the bus in a window of 10 SYNC periods.*status_every_syncs"):
        load_cell_config(every)
    halved = {"sync_period_ms": 1.0, "status_every_syncs": 2}
    cell = load_cell_config(_write(tmp_path, "gantry3-ip-linear.yaml", halved))
    budget = bus_budget(cell)
    assert budget.problem() is None and budget.window_fraction <= LOAD_LIMIT < budget.peak_fraction <= 1.0
    status = [i for i in budget.items if "TPDO1 status" in i.name]
    assert [(i.frames, i.peak_frames, i.window_frames) for i in status] == [(0.5, 1, 5)] * 3


def test_a_period_over_the_bus_is_refused_even_when_the_window_fits(tmp_path: Path):
    """Parker mode 202 at 1 ms, status every 4th SYNC: 67 % of a window, but a period in which every
    synchronous PDO and a controlword per axis fall carries more than the bus does."""
    file = _write(tmp_path, "gantry3-parker.yaml", {"sync_period_ms": 1.0, "status_every_syncs": 4})
    with pytest.raises(ConfigError, match=r"one SYNC period can carry 109% of the bus \(1091 bits of 1000"):
        load_cell_config(file)


def test_status_rates_are_read_and_checked_in_the_cell_file(tmp_path: Path):
    cell = load_cell_config(
        _write(tmp_path, "arm6.yaml", {"status_every_syncs": 3, "status_inhibit_ms": 10, "status_event_timer_ms": 100})
    )
    assert (cell.bus.status_every_syncs, cell.bus.status_inhibit_ms, cell.bus.status_event_timer_ms) == (3, 10, 100)
    event = next(i for i in bus_budget(cell).items if i.name == "node 1 TPDO1 status")
    assert (event.frames, event.window_frames) == (0.5, 5)  # one per 10 ms inhibit time at 5 ms SYNC
    for bad, match in (({"status_every_syncs": 241}, "241 is outside"), ({"status_inhibit_ms": 7000}, "6553.5")):
        with pytest.raises(ConfigError, match=f"bus.status_.*{match}"):
            load_cell_config(_write(tmp_path, "arm6.yaml", bad))


def test_records_per_sync_over_the_limit_is_refused_and_names_the_knob(tmp_path: Path):
    file = _write(tmp_path, "arm6.yaml", {"records_per_sync": 30, "tx_queue_frames": 64})
    with pytest.raises(ConfigError, match=r"bus: the cell's traffic takes \d+% of the bus .*bus.records_per_sync"):
        load_cell_config(file)


def test_an_epos2_cell_without_room_for_records_is_refused(tmp_path: Path):
    file = _write(tmp_path, "arm6.yaml", {"sync_period_ms": 1.0})
    with pytest.raises(ConfigError, match="no room for one record per EPOS2 axis per SYNC period"):
        load_cell_config(file)


def test_records_per_sync_is_read_from_the_cell_file(tmp_path: Path):
    cell = load_cell_config(_write(tmp_path, "arm6.yaml", {"records_per_sync": 6}))
    assert cell.bus.records_per_sync == 6 and bus_budget(cell).records_per_sync == 6


class RecordCounter:
    """Records (EPOS2 RPDO1) per SYNC period, from the frames in the order the master saw them."""

    def __init__(self, record_cobs: set[int]) -> None:
        self.record_cobs = record_cobs
        self.per_period: list[int] = [0]  # [0]: before the first SYNC

    def sent(self, msg: can.Message) -> None:
        if msg.is_rx:
            return
        if msg.arbitration_id == 0x80:
            self.per_period.append(0)
        elif msg.arbitration_id in self.record_cobs:
            self.per_period[-1] += 1


def test_the_feeders_never_send_more_records_in_a_period_than_the_allowance(make_rig, arm6):
    """A lockstep run of the shipped arm6 cell, twice (the first start, then a ready start with its
    check SYNC): no SYNC period carries more records than the cell's allowance, the preload of a
    ready start spreads over SYNCs before the start SYNC, and no FIFO runs dry."""
    rig = make_rig(arm6)
    allowance = rig.group.allowance.per_sync
    assert allowance == bus_budget(arm6).records_per_sync
    counter = RecordCounter({0x200 + a.node_id for a in arm6.axes})
    rig.bus.recorder.taps.append(counter.sent)
    axes: tuple[AxisConfig, ...] = arm6.ordered_axes()
    rig.group.configure()
    rig.group.refresh()
    starts = [int(lk.position or 0) for lk in rig.group.links]
    there = program(axes, 600, starts=starts, spacing_ms=5)  # 6 records per period needed, 9 allowed
    back = program(axes, 600, starts=[int(a.records[-1, 0]) for a in there.axes], spacing_ms=5, sign=-1)
    for checked, prog in ((False, there), (True, back)):
        counter.per_period = [0]
        result = rig.group.run(prog, timeout_s=60)
        assert result.ok, result.message
        # the first start (checked by SDO) has no SYNC running before it: its preload goes out whole
        # before the first SYNC; from the first SYNC on every period keeps to the allowance
        assert max(counter.per_period[1:]) <= allowance, counter.per_period[:20]
        before_start = counter.per_period[1 : len(counter.per_period) - 1 - (rig.bus.sync.count - result.start_sync)]
        if checked:  # the check SYNC and as many more as the preload needed, each within the allowance
            assert counter.per_period[0] == 0
            assert sum(before_start) > allowance and len(before_start) >= 2
        else:
            assert before_start == [] and counter.per_period[0] > allowance
        assert all(a.feed.underflows == 0 and (a.feed.min_level or 0) >= 2 for a in result.axes)
        assert sum(counter.per_period) == sum(a.feed.sent for a in result.axes)
