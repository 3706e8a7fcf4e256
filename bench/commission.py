"""Commissioning: how long reading a cell's drives takes, and whether every kind of wrong drive is caught.

For arm6 and gantry3 on their simulated drives (the simulated wire, lockstep), per run: the time of
``axes.master.commission.commission`` (every check of every drive, nothing written) and of
``AxisGroup.configure`` (the facts checked first, then the profile's configuration: PDOs mapped and
read back, limit objects written and read back, heartbeat, homing settings), each with the SDO
round trips it took (median over ``--runs``). Then every kind of drive that differs from the cell
(``simulation:``: encoder, polarity, vendor, product, motor speed on an EPOS2; the encoder of a
drive that reports it in 0x608F) is injected into one axis of gantry3 and counted as caught when
the report names its object on that axis and configuration refuses the cell. The same on gantry3
whose EPOS2s are maxon's own EDS (``simulation.eds``) and require maxon's objects
(``commission_requires``): maxon's encoder, sensor polarity and type, velocity notation, identity,
motor speed, a required object the drive lacks (0x607E) and a setting it cannot take (the status
TPDO event timer: no 0x1800:05). arm6 is timed on maxon-EDS drives too.

    python3 bench/commission.py [--runs 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.config import AxisSimulation
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.commission import commission
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.link import DriveError
from pvtflow.axes.sim.cell import SimulatedCell, sharing_the_interpreter
from pvtflow.service.config import CONFIG_DIR, CellConfig, load_cell_config

KINDS: list[tuple[str, str, dict[str, object], dict[str, int], str]] = [
    # name, joint, profile change, simulation change, the object that must name it
    ("encoder (maxon 0x2210:01)", "y", {}, {"qc_per_motor_rev": 2048}, "0x2210:01"),
    ("polarity", "y", {}, {"polarity": 0x80}, "0x607E"),
    ("vendor id", "y", {}, {"vendor_id": 0x1234}, "0x1018:01-02"),
    ("product code", "y", {}, {"product_code": 0x7}, "0x1018:01-02"),
    ("motor maximal speed", "y", {}, {"max_motor_speed_rpm": 1000}, "0x6410:04"),
    (
        "encoder (0x608F)",
        "x",
        {"profile": "parker_slvdn", "homing": None, "period_ms": 3},
        {"qc_per_motor_rev": 1000},
        "0x608F:01-02",
    ),
]


MAXON_EDS = "vendor/maxon-epos2-70-10.eds"
MAXON_REQUIRES = ("0x2210:01", "0x2210:02", "0x2210:04", "0x608B", "0x608C", "0x6410:04")
# name, simulation change of y, the cell's requirements (None: MAXON_REQUIRES), bus change, the object
MAXON_KINDS: list[tuple[str, dict[str, int], tuple[str, ...] | None, dict[str, int], str]] = [
    ("encoder (0x2210:01)", {"qc_per_motor_rev": 2048}, None, {}, "0x2210:01"),
    ("sensor polarity (0x2210:04)", {"sensor_polarity": 1}, None, {}, "0x2210:04"),
    ("sensor type (0x2210:02)", {"sensor_type": 4}, None, {}, "0x2210:02"),
    ("velocity notation (0x608B)", {"velocity_notation_index": -1}, None, {}, "0x608B"),
    ("vendor id", {"vendor_id": 0x1234}, None, {}, "0x1018:01-02"),
    ("product code", {"product_code": 0x7}, None, {}, "0x1018:01-02"),
    ("motor maximal speed", {"max_motor_speed_rpm": 1000}, None, {}, "0x6410:04"),
    ("required, absent (0x607E)", {}, ("0x607E",), {}, "0x607E"),
    ("TPDO event timer, no :05", {}, None, {"status_event_timer_ms": 100}, ":05"),
]


def with_maxon_eds(cell: CellConfig, requires: tuple[str, ...] = MAXON_REQUIRES) -> CellConfig:
    """Every axis's simulated drive built from maxon's EDS, requiring what maxon's objects give."""
    axes = tuple(
        dataclasses.replace(
            a,
            simulation=dataclasses.replace(a.simulation or AxisSimulation(), eds=MAXON_EDS),
            commission_requires=requires,
        )
        for a in cell.axes
    )
    return dataclasses.replace(cell, axes=axes)


def on_own_channel(cell: CellConfig) -> CellConfig:
    return dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, channel=f"bench-{uuid.uuid4().hex[:8]}"))


def open_cell(cell: CellConfig) -> tuple[SimulatedCell, CellBus, AxisGroup]:
    cell = sharing_the_interpreter(cell)  # the drives run in this interpreter
    sim = SimulatedCell(cell).start()
    bus = CellBus(cell.bus, clock=Clock.LOCKSTEP).open()
    return sim, bus, AxisGroup(bus, cell.ordered_axes())


def close_cell(sim: SimulatedCell, bus: CellBus, group: AxisGroup) -> None:
    group.close()
    bus.close()
    sim.stop()


def sdo_count(group: AxisGroup) -> int:
    return sum(link.sdo_transfers for link in group.links)


def time_cell(cell: CellConfig, runs: int) -> tuple[float, int, float, int]:
    """Median (commission ms, its SDO transfers, configure ms, its SDO transfers) over fresh drives."""
    c_ms, c_n, k_ms, k_n = [], [], [], []
    for _ in range(runs):
        sim, bus, group = open_cell(on_own_channel(cell))
        try:
            t0 = time.perf_counter()
            report = commission(group.links, group.profiles)
            c_ms.append((time.perf_counter() - t0) * 1000)
            c_n.append(report.sdo_transfers)
            assert report.ok, [str(c) for a in report.axes for c in a.mismatches]
            before = sdo_count(group)
            t0 = time.perf_counter()
            group.configure()
            k_ms.append((time.perf_counter() - t0) * 1000)
            k_n.append(sdo_count(group) - before)
        finally:
            close_cell(sim, bus, group)
    return statistics.median(c_ms), int(statistics.median(c_n)), statistics.median(k_ms), int(statistics.median(k_n))


def caught(cell: CellConfig, joint: str, profile: dict[str, object], drive: dict[str, int], where: str) -> bool:
    axes = []
    for a in cell.axes:
        if a.joint == joint:
            a = dataclasses.replace(a, **profile)  # type: ignore[arg-type]
            a = dataclasses.replace(a, simulation=dataclasses.replace(a.simulation or AxisSimulation(), **drive))
        axes.append(a)
    wrong = on_own_channel(dataclasses.replace(cell, axes=tuple(axes)))
    sim, bus, group = open_cell(wrong)
    try:
        report = commission(group.links, group.profiles)
        named = any(a.joint == joint and any(where in c.object for c in a.mismatches) for a in report.axes)
        try:
            group.configure()
            refused = False
        except DriveError as exc:
            refused = where in str(exc)
        return named and refused
    finally:
        close_cell(sim, bus, group)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    print(
        f"{'cell':18} {'axes':>4} {'commission':>11} {'SDO':>5} {'configure':>10} {'SDO':>5}   (median of {args.runs})"
    )
    for name, maxon in (("arm6", False), ("arm6", True), ("gantry3", False)):
        cell = load_cell_config(CONFIG_DIR / "cells" / f"{name}.yaml")
        c_ms, c_n, k_ms, k_n = time_cell(with_maxon_eds(cell) if maxon else cell, args.runs)
        label = name + (" (maxon EDS)" if maxon else "")
        print(f"{label:18} {len(cell.axes):>4} {c_ms:>8.1f} ms {c_n:>5} {k_ms:>7.1f} ms {k_n:>5}")
    gantry3 = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
    hits = 0
    for name, joint, profile, drive, where in KINDS:
        ok = caught(gantry3, joint, profile, drive, where)
        hits += ok
        print(f"  injected {name:28} on {joint}: {'caught' if ok else 'MISSED'} ({where})")
    print(f"mismatch kinds caught: {hits}/{len(KINDS)}")
    hits = 0
    for name, drive, requires, bus, where in MAXON_KINDS:
        cell = with_maxon_eds(gantry3, MAXON_REQUIRES if requires is None else requires)
        cell = dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, **bus))
        ok = caught(cell, "y", {}, drive, where)
        hits += ok
        print(f"  injected {name:28} on y, maxon EDS: {'caught' if ok else 'MISSED'} ({where})")
    print(f"mismatch kinds caught on maxon-EDS EPOS2s: {hits}/{len(MAXON_KINDS)}")
    print("command: python3 bench/commission.py" + (f" --runs {args.runs}" if args.runs != 5 else ""))


if __name__ == "__main__":
    main()
