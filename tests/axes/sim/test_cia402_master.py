"""Conformance of the simulated drives to a CiA 402 master nobody here wrote: python-canopen's own
``BaseNode402``, driven as its documentation says (NMT, ``setup_402_state_machine``, ``op_mode``,
``state``), on every drive's own EDS and on maxon's EPOS2 70/10 EDS. Beside it, the objects such a
master reads: Supported Drive Modes (0x6502), Modes of Operation (0x6060, refusing what the drive
does not support), Modes of Operation Display (0x6061) and every object an EDS declares readable."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import canopen
import pytest
from canopen import objectdictionary
from canopen.profiles.p402 import BaseNode402, OperationMode
from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.sim import Epos2Drive, IpLinearDrive, ParkerDrive, SimulatedDrive, SyncSetpointDrive
from pvtflow.axes.sim.drive import MAXON_EPOS2_EDS
from pvtflow.axes.sim.node.device import EPOS2_MODES, SUPPORTED_DRIVE_MODES

from .conftest import Bench

ABORT_VALUE_RANGE = 0x06090030
ABORT_NO_DATA = 0x08000024  # CiA 301 "no data available": what an empty domain answers

# every simulated drive on its own EDS, and the EPOS2 on maxon's
DRIVES: list[tuple[str, type[SimulatedDrive], Path | None]] = [
    ("epos2", Epos2Drive, None),
    ("cia402_ip_linear", IpLinearDrive, None),
    ("sync_setpoint", SyncSetpointDrive, None),
    ("parker_slvdn", ParkerDrive, None),
    ("epos2-maxon-eds", Epos2Drive, MAXON_EPOS2_EDS),
]
CASES = [pytest.param(cls, eds, id=name) for name, cls, eds in DRIVES]


def base_node(bench: Bench, drive: SimulatedDrive) -> BaseNode402:
    """A BaseNode402 on the drive's EDS, set up as python-canopen's profile docs say: the PDO
    configuration read in PRE-OPERATIONAL, then the node started (PDOs run only when OPERATIONAL)."""
    node = BaseNode402(drive.node_id, str(drive.eds_path))
    bench.master.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()
    node.nmt.state = "OPERATIONAL"
    assert drive.wait_until(lambda: drive.operational, 2.0)
    return node


@pytest.mark.parametrize(("cls", "eds"), CASES)
def test_base_node_402_enables_the_drive_in_interpolated_position_mode(
    bench: Bench, cls: type[SimulatedDrive], eds: Path | None
) -> None:
    drive = bench.add(cls(5, eds_path=eds))
    node = base_node(bench, drive)
    # the mode first, then the power states (maxon's sequence, app note 3.7): on maxon's default
    # PDOs the mode travels in RPDO2 beside a controlword, which must not undo an enabled state
    node.op_mode = "INTERPOLATED POSITION"  # BaseNode402 logs and swallows its errors: check after
    assert node.op_mode == "INTERPOLATED POSITION"
    for state in ("SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"):
        node.state = state
        assert node.state == state
        assert drive.state == state
    assert drive.read(od.MODES_OF_OPERATION_DISPLAY) == od.INTERPOLATED_POSITION_MODE
    assert drive.faults == []
    if eds is not None:  # maxon's EDS maps the statusword to TPDO1: BaseNode402 followed it by PDO
        assert 0x6041 in node.tpdo_values and 0x6040 in node.rpdo_pointers


@pytest.mark.parametrize(("cls", "eds"), CASES)
def test_modes_of_operation_refuses_a_mode_the_drive_does_not_support(
    bench: Bench, cls: type[SimulatedDrive], eds: Path | None
) -> None:
    drive = bench.add(cls(6, eds_path=eds))
    node = base_node(bench, drive)
    supported = node.sdo[SUPPORTED_DRIVE_MODES].raw
    assert supported == drive.MODES.supported
    assert supported & OperationMode.SUPPORTED["INTERPOLATED POSITION"]
    shown = node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw
    torque = OperationMode.PROFILED_TORQUE  # supported by none of the four
    assert not supported & OperationMode.SUPPORTED["PROFILED TORQUE"]
    with pytest.raises(SdoAbortedError) as refused:
        node.sdo[od.MODES_OF_OPERATION].raw = torque
    assert refused.value.code == ABORT_VALUE_RANGE
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == shown
    with pytest.raises(TypeError):  # BaseNode402 reads 0x6502 first, then refuses itself
        node.op_mode = "PROFILED TORQUE"
    with pytest.raises(SdoAbortedError) as refused:
        node.sdo[od.MODES_OF_OPERATION].raw = 42
    assert refused.value.code == ABORT_VALUE_RANGE
    node.sdo[od.MODES_OF_OPERATION].raw = od.INTERPOLATED_POSITION_MODE
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == od.INTERPOLATED_POSITION_MODE


def test_epos2_accepts_its_other_modes_and_shows_the_mode_in_force(bench: Bench) -> None:
    """Profile position is the EPOS2's power-on mode on maxon's EDS; the simulation moves in mode 7
    only, but accepts every mode of the real drive and reports it (axes/sim/node/device.py)."""
    drive = bench.add(Epos2Drive(7, eds_path=MAXON_EPOS2_EDS))
    node = bench.remote(drive)
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == OperationMode.PROFILED_POSITION
    for mode in EPOS2_MODES.codes:
        node.sdo[od.MODES_OF_OPERATION].raw = mode
        assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == mode
    for mode in (OperationMode.CYCLIC_SYNCHRONOUS_POSITION, OperationMode.CYCLIC_SYNCHRONOUS_VELOCITY, -4):
        with pytest.raises(SdoAbortedError):
            node.sdo[od.MODES_OF_OPERATION].raw = mode
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == EPOS2_MODES.codes[-1]


def readable_variables(dictionary: canopen.ObjectDictionary) -> list[objectdictionary.ODVariable]:
    out: list[objectdictionary.ODVariable] = []
    for entry in dictionary.values():
        variables = [entry] if isinstance(entry, objectdictionary.ODVariable) else list(entry.values())
        out.extend(v for v in variables if v.readable)
    return out


@pytest.mark.parametrize(("cls", "eds"), CASES)
def test_every_object_the_eds_declares_readable_answers(
    bench: Bench, cls: type[SimulatedDrive], eds: Path | None
) -> None:
    drive = bench.add(cls(8, eds_path=eds))
    node = bench.remote(drive)
    silent: list[str] = []
    empty: list[int] = []
    for var in readable_variables(node.object_dictionary):
        try:
            node.sdo.upload(var.index, var.subindex)
        except SdoAbortedError as exc:
            if exc.code == ABORT_NO_DATA and var.data_type == objectdictionary.DOMAIN:
                empty.append(var.index)
            else:
                silent.append(f"0x{var.index:04X}:{var.subindex:02X} {var.name}: {exc}")
    assert silent == []
    assert empty == ([0x201B] if eds is not None else [])  # maxon's data recorder buffer, nothing recorded


def test_epos2_on_maxon_eds_reports_maxon_identity_and_cubic_pvt(bench: Bench) -> None:
    drive = bench.add(Epos2Drive(9, eds_path=MAXON_EPOS2_EDS))
    node = bench.remote(drive)
    assert node.sdo[0x1000].raw == 0x00020192
    assert node.sdo[0x1008].raw == "EPOS2 70/10"
    assert [node.sdo[0x1018][k].raw for k in (1, 2, 3)] == [0xFB, 0x64200000, 0x21220000]
    assert node.sdo[0x2003][1].raw == 0x2122 and node.sdo[0x2003][2].raw == 0x6420  # the EDS's comments
    assert node.sdo[od.INTERPOLATION_SUBMODE].raw == -1
    assert node.sdo[SUPPORTED_DRIVE_MODES].raw == 0x00370065
    node.nmt.send_command(0x81)  # reset node: the drive's own values come back with the defaults
    assert drive.wait_until(lambda: drive.nmt_state == "PRE-OPERATIONAL")
    assert node.sdo[SUPPORTED_DRIVE_MODES].raw == 0x00370065 and node.sdo[0x1018][1].raw == 0xFB


@pytest.mark.parametrize("cls", [Epos2Drive, IpLinearDrive, SyncSetpointDrive, ParkerDrive])
def test_own_eds_states_the_drives_supported_modes(cls: type[SimulatedDrive]) -> None:
    dictionary = canopen.import_od(str(Path(__file__).resolve().parents[3] / "configs" / "eds" / cls.EDS), 1)
    assert dictionary[SUPPORTED_DRIVE_MODES].default == cls.MODES.supported
    assert dictionary[SUPPORTED_DRIVE_MODES].access_type == "ro"


def test_parker_mode_202_is_interpolated_position_either_way(bench: Bench) -> None:
    """0x6060 = 7 selects Pr31 = 202; Pr31 = 202 (pvtflow's master) shows as 7 in 0x6061."""
    drive = bench.add(ParkerDrive(10))
    node = bench.remote(drive)
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == 0
    node.sdo[od.MODES_OF_OPERATION].raw = od.INTERPOLATED_POSITION_MODE
    assert node.sdo[od.PARKER_OPERATIVE_MODE].raw == od.PARKER_IP_MODE
    node.sdo[od.MODES_OF_OPERATION].raw = 0  # "no mode": no change
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == od.INTERPOLATED_POSITION_MODE
    node.sdo[od.PARKER_OPERATIVE_MODE].raw = 0
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == 0
    node.sdo[od.PARKER_OPERATIVE_MODE].raw = od.PARKER_IP_MODE
    assert node.sdo[od.MODES_OF_OPERATION_DISPLAY].raw == od.INTERPOLATED_POSITION_MODE


# Not on maxon's EDS: its TPDO1 carries the statusword on change (transmission type 255), and
# BaseNode402, having seen two of them, takes it for periodic (python-canopen estimates
# ``PdoMap.period`` from receptions) and waits for the next one, which a statusword that does not
# change never sends: the same with a real EPOS2 on that EDS. The project's master homes the EPOS2
# (tests/axes/test_homing.py).
HOMING_DRIVES = [
    pytest.param(cls, eds, id=name)
    for name, cls, eds in DRIVES
    if eds is None and OperationMode.HOMING in cls.MODES.codes
]


@pytest.mark.parametrize(("cls", "eds"), HOMING_DRIVES)
def test_base_node_402_homes_the_drive(bench: Bench, cls: type[SimulatedDrive], eds: Path | None) -> None:
    """BaseNode402.homing() (mode 6, controlword bit 4, statusword homing attained) on every drive
    whose 0x6502 has homing: method 35 (here is home) sets the position to the home offset 0x607C
    (maxon: to the home position 0x2081)."""
    drive = bench.add(cls(5, eds_path=eds))
    node = base_node(bench, drive)
    node.sdo[od.HOMING_METHOD].raw = od.HomingMethod.CURRENT_POSITION
    home_position = od.EPOS2_HOME_POSITION if cls is Epos2Drive else od.HOME_OFFSET  # maxon's and CiA's definitions
    node.sdo[home_position].raw = 1234
    done: list[bool] = []
    homing = threading.Thread(target=lambda: done.append(node.homing(timeout=10)), daemon=True)
    homing.start()
    while homing.is_alive():  # the drive's motion clock runs on SYNC, as on a real bus
        bench.sync(1, wait=False)
        time.sleep(0.002)
    assert done == [True]
    assert node.op_mode == "HOMING" and node.is_homed()
    assert node.sdo[od.POSITION_ACTUAL_VALUE].raw == 1234
    assert drive.faults == []
