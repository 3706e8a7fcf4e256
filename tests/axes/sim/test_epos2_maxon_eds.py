"""The simulated EPOS2 on maxon's own EDS (configs/eds/vendor: maxon's published file, unchanged)."""

from __future__ import annotations

import canopen
import numpy as np

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.interpolation import epos2_pvt
from pvtflow.axes.drive.objects import EPOS2_RPDOS, EPOS2_TPDOS, BufferStatus, Record
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits
from pvtflow.axes.sim import Epos2Drive
from pvtflow.axes.sim.drive import MAXON_EPOS2_EDS

from .conftest import Bench, configure_pdos, enable

SCALING = AxisScaling(2000.0, 1.0)


def test_maxon_eds_loads_with_the_epos2_objects() -> None:
    dictionary = canopen.import_od(str(MAXON_EPOS2_EDS), 1)
    record = dictionary[od.EPOS2_INTERPOLATION_DATA_RECORD]
    assert record.data_type == canopen.objectdictionary.UNSIGNED64 and len(record) == 64
    assert record.access_type == "wo" and record.pdo_mappable
    assert not dictionary[od.INTERPOLATION_DATA_CONFIGURATION][2].pdo_mappable


def test_maxon_eds_node_answers_sdo_and_runs_a_program(bench: Bench) -> None:
    limits = DriveLimits(8000, 2_000_000, -100_000, 100_000)
    drive = bench.add(Epos2Drive(3, scaling=SCALING, limits=limits, eds_path=MAXON_EPOS2_EDS))
    assert drive.eds_path == MAXON_EPOS2_EDS
    node = bench.remote(drive)
    assert node.sdo[od.STATUSWORD].raw == 0x0040
    assert node.sdo[od.EPOS2_INTERPOLATION_BUFFER][2].raw == 4
    assert node.sdo[od.EPOS2_INTERPOLATION_BUFFER][3].raw == 60
    assert node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][1].raw == 64
    assert node.sdo[od.MAX_PROFILE_VELOCITY].raw == 8000
    configure_pdos(node, EPOS2_RPDOS, EPOS2_TPDOS)
    node.nmt.state = "OPERATIONAL"
    enable(node)
    node.sdo[od.INTERPOLATION_DATA_CONFIGURATION][6].raw = 1
    records = np.array([[0, 0, 2], [500, 900, 20], [1500, 900, 20], [2000, 0, 20], [2000, 0, 0]])
    p, v, t = records[0]  # the first by SDO (8 bytes: segmented transfer), the rest by the RPDO
    node.sdo[od.EPOS2_INTERPOLATION_DATA_RECORD].raw = Record(int(p), int(v), int(t)).pack()
    for p, v, t in records[1:]:
        bench.send(0x203, Record(int(p), int(v), int(t)).to_bytes())
    assert drive.wait_until(lambda: drive.level == len(records))
    bench.send(0x303, (0x001F).to_bytes(2, "little"))
    start = bench.sync(1)
    bench.sync(70)
    assert drive.ip_active_sync == start and drive.faults == [] and drive.ended_by_time_zero == 1
    rec = epos2_pvt(records, SCALING.qc_per_ms_per_velocity_unit)
    samples = [s for s in drive.history if s.sync >= start]
    t = np.array([s.sync - start for s in samples], dtype=float)
    assert np.max(np.abs(np.array([s.demand for s in samples]) - rec.position(t))) < 1e-6
    assert node.sdo[od.POSITION_ACTUAL_VALUE].raw == 2000
    status = BufferStatus(node.sdo[od.EPOS2_INTERPOLATION_BUFFER][1].raw)
    assert BufferStatus.BUFFER_ENABLED in status and not status & od.BUFFER_ERRORS
