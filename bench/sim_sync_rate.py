"""How fast a simulated cell runs: SYNCs per second a cell of simulated drives processes.

The simulated drives' motion clock advances by the SYNC period per SYNC, so a test runs a motion as
fast as the master sends SYNCs; this measures that rate for a configured cell with every drive in
operation enabled, interpolating (EPOS2: a long program preloaded), and the per-SYNC cost inside one
drive without the bus.

    python3 bench/sim_sync_rate.py [--config configs/cells/arm6.yaml] [--syncs 3000]
"""

from __future__ import annotations

import argparse
import sys
import time
import uuid
from pathlib import Path

import canopen

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.objects import Record
from pvtflow.axes.sim.cell import SimulatedCell
from pvtflow.axes.sim.profiles.epos2 import Epos2Drive
from pvtflow.service.config import load_cell_config


def prepare(drive: Epos2Drive) -> None:
    """Enable and start a slow 60-record program straight through the object dictionary."""
    n = drive.node
    n.sdo[od.MODES_OF_OPERATION].raw = od.INTERPOLATED_POSITION_MODE
    for cw in (0x0006, 0x000F):
        n.sdo[od.CONTROLWORD].raw = cw
    n.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    start = round(drive.demand)
    n.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw = Record(start, 0, 1).pack()
    for k in range(1, 60):
        n.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw = Record(start + 5 * k, 0, 200).pack()
    n.sdo[od.CONTROLWORD].raw = 0x001F


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(Path(__file__).resolve().parent.parent / "configs/cells/arm6.yaml"))
    parser.add_argument("--syncs", type=int, default=3000)
    args = parser.parse_args()
    cell = load_cell_config(args.config)
    channel = f"bench-sim-{uuid.uuid4().hex[:8]}"
    master = canopen.Network()
    master.connect(interface="virtual", channel=channel)
    with SimulatedCell(cell, channel=channel) as sim:
        drives = [d for d in sim if isinstance(d, Epos2Drive)]
        for d in drives:
            prepare(d)
            d.node.nmt.send_command(0x01)  # operational: the TPDOs run too
            d.pdo.reload()
        t0 = time.perf_counter()
        for _ in range(args.syncs):
            master.send_message(0x80, b"")
        assert sim.wait_sync(args.syncs, timeout=120)
        elapsed = time.perf_counter() - t0
        active = sum(d.ip_active for d in drives)
        print(f"command: python3 bench/sim_sync_rate.py --config {args.config} --syncs {args.syncs}")
        print(
            f"cell {cell.name}: {len(sim.drives)} drives ({active} interpolating), {args.syncs} SYNCs "
            f"in {elapsed:.3f} s = {args.syncs / elapsed:.0f} SYNC/s "
            f"({elapsed / args.syncs * 1e6:.0f} us per SYNC for the whole cell)"
        )
        one = drives[0]
        t0 = time.perf_counter()
        for _ in range(args.syncs):
            one.motion.on_sync(0x80, bytearray(), 0.0)
        per = (time.perf_counter() - t0) / args.syncs
        print(f"one EPOS2 drive, SYNC processing without the bus: {per * 1e6:.1f} us per SYNC")
        errors = sim.internal_errors
    master.disconnect()
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
