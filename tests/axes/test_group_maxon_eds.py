"""The master configures and runs a simulated node whose dictionary is maxon's own EPOS2 70/10 EDS."""

from __future__ import annotations

from axes_programs import check_limits, program

from pvtflow.axes.drive import objects as od
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.sim.drive import MAXON_EPOS2_EDS as MAXON_EDS  # configs/eds/vendor: maxon's file, unchanged


def test_master_configures_a_node_with_the_maxon_eds(arm6, make_rig):
    assert MAXON_EDS.is_file()
    rig = make_rig(arm6, eds_paths={1: MAXON_EDS, 4: MAXON_EDS})
    prog = program(arm6.ordered_axes(), 400, spacing_ms=4)
    check_limits(prog)
    result = rig.group.run(prog, timeout_s=30)
    assert result.result is Result.FINISHED, result.message
    assert result.start_skew_syncs == 0
    for node_id in (1, 4):
        drive = rig.sim.drive(node_id)
        assert drive.eds_path == MAXON_EDS
        axis = next(a for a in prog.axes if a.node_id == node_id)
        assert drive.actual == axis.records[-1, 0]
        # what the master wrote is in maxon's dictionary: mode, limits, warning levels, PDO mapping
        config = arm6.axis_for_joint(axis.joint)
        assert drive.read(od.MODES_OF_OPERATION) == od.INTERPOLATED_POSITION_MODE
        assert drive.read(od.MAX_PROFILE_VELOCITY) == round(config.limits.max_profile_velocity_rpm)
        assert drive.read(od.SOFTWARE_POSITION_LIMIT, 2) == config.limits.max_position_qc
        assert drive.read(od.EPOS2_INTERPOLATION_BUFFER, 3) == config.buffer.overflow_warning
        assert drive.read(0x1600, 1) == (od.EPOS2_INTERPOLATION_DATA_RECORD << 16) | 64
        assert drive.read(0x1A00, 0) == 2 and drive.read(0x1801, 2) == od.SYNCHRONOUS
        assert drive.read(od.PRODUCER_HEARTBEAT_TIME) == arm6.bus.heartbeat_ms
