"""The master dies or hangs mid-motion: every drive stops by itself (0x1016 consumer, 0x6007).

The master's side is killed in-process on the virtual bus while a program runs: "dead" closes its
CAN connection (no frame in or out, as after SIGKILL), "hung" blocks its receive thread in a SYNC
listener (every thread that supervises the motion waits on it). Nothing tells the drives: they must
notice the master's heartbeat stopping and brake on their own, for every profile. A third node on
the bus (an observer) sees the EMCY 0x8130 each drive sends.
"""

from __future__ import annotations

import configparser
import dataclasses
import threading
import time
from pathlib import Path

import pytest
from axes_programs import check_limits, program
from axes_rig import BusObserver, with_profiles
from canopen.sdo.exceptions import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.group.axis_group import AxisGroup
from pvtflow.axes.master.group.outcome import Result
from pvtflow.axes.sim.drive import MAXON_EPOS2_EDS, SimulatedDrive

PROGRAM_MS = 2000
KILL_AT_MS = 400  # mid-motion: every axis moves then (the quintic is at 20 % of its duration)
MASTER_HEARTBEAT_MS = 50  # x the rig's heartbeat_timeout_factor (10, sharing_the_interpreter): drives wait 500 ms
PROFILES = {
    "epos2_pvt": {"profile": "epos2_pvt"},
    # six fixed-period axes fit a 1 Mbit/s bus from 4 ms on (axes.master.budget; the shipped three-axis cells: 2 ms)
    "cia402_ip_linear": {"profile": "cia402_ip_linear", "period_ms": 4},
    "sync_setpoint": {"profile": "sync_setpoint", "period_ms": 4},
    # 4 ms: interpolated (cubic, position + velocity); below 2.5 ms the direct position loop takes each
    # setpoint at its SYNC, so without SYNC it stands at the last one already
    "parker_slvdn": {"profile": "parker_slvdn", "period_ms": 4, "interpolation_submode": -1},
}


def cell_of(arm6, profile: str):
    period_ms = float(PROFILES[profile].get("period_ms", 1))
    cell = with_profiles(arm6, {a.joint: PROFILES[profile] for a in arm6.axes}, sync_period_ms=period_ms)
    return dataclasses.replace(cell, bus=dataclasses.replace(cell.bus, master_heartbeat_ms=MASTER_HEARTBEAT_MS))


def kill_master(rig, how: str, release: threading.Event) -> None:
    """Run the program and kill the master's side ``KILL_AT_MS`` into the motion."""
    killed = threading.Event()
    kill_at_sync = round(KILL_AT_MS / rig.cell.bus.sync_period_ms)

    def listener(n: int) -> None:  # runs in the master's receive thread
        elapsed = rig.group.elapsed_syncs() if rig.group.running else None
        if elapsed is None or elapsed < kill_at_sync or killed.is_set():
            return
        killed.set()
        if how == "hung":
            release.wait()  # the receive thread, and with it SYNC, feeding and the watchdog's halts, hang

    rig.bus.sync.add_listener(listener)
    prog = program(rig.cell.ordered_axes(), PROGRAM_MS, fraction=0.4)
    check_limits(prog)
    assert rig.group.start(prog) is None
    deadline = time.monotonic() + 60.0
    while not killed.wait(0.05) and rig.group.running and time.monotonic() < deadline:
        pass
    assert killed.is_set(), f"the program did not reach the kill point: {rig.group.last_result}"
    if how == "dead":
        network = rig.bus.network
        network.notifier.stop(timeout=1.0)
        network.bus.shutdown()  # no frame in or out any more: the master's threads are as good as gone


def wait_standstill(drives: list[SimulatedDrive], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(d.master_loss.losses and d.master_loss.losses[-1].standstill is not None for d in drives):
            return
        time.sleep(0.02)
    pending = [d.node_id for d in drives if not d.master_loss.losses or d.master_loss.losses[-1].standstill is None]
    raise AssertionError(f"drives {pending} still moving {timeout_s} s after the master was lost")


@pytest.mark.wall
@pytest.mark.parametrize("how", ["dead", "hung"])
@pytest.mark.parametrize("profile", list(PROFILES))
def test_every_axis_stops_by_itself_when_the_master_is_lost(arm6, make_rig, profile, how):
    cell = cell_of(arm6, profile)
    rig = make_rig(cell)
    observer = BusObserver(rig.cell.bus.channel, rig.cell.bus.interface)
    release = threading.Event()
    consumer_s = rig.cell.bus.master_consumer_time_ms / 1000.0
    try:
        kill_master(rig, how, release)
        drives = list(rig.sim)
        # hung: the master withholds its heartbeat once its receive thread is silent for the drives'
        # heartbeat window (heartbeat_ms x factor), then the drives wait their consumer time
        window_s = rig.cell.bus.heartbeat_ms * rig.cell.bus.heartbeat_timeout_factor / 1000.0
        wait_standstill(drives, timeout_s=window_s + consumer_s + 10.0)
        for d in drives:
            loss = d.master_loss.losses[-1]
            assert loss.node_id == cell.bus.master_node_id
            assert loss.state == "OPERATION ENABLED" and abs(loss.velocity_rpm) > 1.0, (d.node_id, loss)
            assert loss.silent_s >= consumer_s  # never before its consumer time
            assert loss.option == od.AbortConnectionOption.QUICK_STOP
            if profile == "epos2_pvt":  # maxon: a heartbeat error is a device error
                assert d.state is PowerState.FAULT and d.faults[-1].code == od.EMCY_HEARTBEAT_ERROR
                assert len(d.fifo) == 0 and not d.ip_active  # its FIFO stopped and was emptied
            else:  # CiA 402 quick stop: the ramp, then SWITCH ON DISABLED (0x605A = 2)
                assert d.state is PowerState.SWITCH_ON_DISABLED, d.state
            assert d.velocity == 0.0
        # it stays where it stopped
        demands = {d.node_id: d.demand for d in drives}
        time.sleep(0.1)
        assert {d.node_id: d.demand for d in drives} == demands
        deadline = time.monotonic() + 2.0
        nodes = {d.node_id for d in drives}
        while time.monotonic() < deadline and observer.emcy_nodes(od.EMCY_HEARTBEAT_ERROR) != nodes:
            time.sleep(0.02)
        assert observer.emcy_nodes(od.EMCY_HEARTBEAT_ERROR) == nodes
        assert rig.bus.master_heartbeat.withheld is not None
        assert rig.sim.internal_errors == []
    finally:
        release.set()
        observer.close()


def test_drives_watch_the_master_after_configuration(arm6, make_rig):
    cell = with_profiles(
        arm6,
        {
            "joint_2": PROFILES["cia402_ip_linear"],
            "joint_3": PROFILES["sync_setpoint"],
            "joint_4": {"profile": "parker_slvdn", "period_ms": 1, "interpolation_submode": 0},
        },
        sync_period_ms=1.0,
    )
    rig = make_rig(cell, eds_paths={5: MAXON_EPOS2_EDS})
    for d in rig.sim:  # a deceleration a vendor tool left: a halt would brake on it
        d.store(od.PROFILE_DECELERATION, 0, 7)
    rig.group.configure()
    bus = rig.cell.bus
    entry = (bus.master_node_id << 16) | bus.master_consumer_time_ms
    assert bus.master_consumer_time_ms == round(bus.master_heartbeat_ms * bus.heartbeat_timeout_factor)
    for d in rig.sim:
        assert d.read(od.CONSUMER_HEARTBEAT_TIME, 1) == entry, d.node_id
        assert d.read(od.ABORT_CONNECTION_OPTION_CODE) == od.AbortConnectionOption.QUICK_STOP, d.node_id
        if d.PROFILE == "epos2_pvt":  # its master-loss reaction is its fault reaction: on the quick stop ramp
            assert d.read(od.FAULT_REACTION_OPTION_CODE) == od.FaultReaction.QUICK_STOP, d.node_id
        limits = next(a.limits for a in cell.axes if a.node_id == d.node_id)
        assert d.read(od.QUICK_STOP_DECELERATION) == round(limits.max_acceleration_rpm_s)
        # a drive that brakes by itself on halt does so on 0x60C5; the others get the master's ramp
        halt_ramp = round(limits.max_acceleration_rpm_s) if d.PROFILE in ("epos2_pvt", "cia402_ip_linear") else 7
        assert d.read(od.PROFILE_DECELERATION) == halt_ramp, d.node_id
    # the drives hear the master: their consumer entry is armed by its next heartbeat
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and not all(
        d.master_loss.consumer.active(cell.bus.master_node_id) for d in rig.sim
    ):
        time.sleep(0.01)
    assert [d.node_id for d in rig.sim if not d.master_loss.consumer.active(cell.bus.master_node_id)] == []


def without_object(eds: Path, index: int, out: Path) -> Path:
    """A copy of an EDS without one object (a drive that lacks it)."""
    cp = configparser.RawConfigParser()
    cp.optionxform = str  # type: ignore[assignment,method-assign]
    cp.read(eds)
    name = f"{index:04X}"
    for section in [s for s in cp.sections() if s.upper() == name or s.upper().startswith(name + "SUB")]:
        cp.remove_section(section)
    for listing in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        if not cp.has_section(listing):
            continue
        kept = [v for k, v in cp.items(listing) if k != "SupportedObjects" and int(v, 0) != index]
        cp.remove_section(listing)
        cp.add_section(listing)
        cp.set(listing, "SupportedObjects", str(len(kept)))
        for k, v in enumerate(kept, start=1):
            cp.set(listing, str(k), v)
    with out.open("w") as f:
        cp.write(f, space_around_delimiters=False)
    return out


@pytest.mark.parametrize(
    "index", [od.ABORT_CONNECTION_OPTION_CODE, od.CONSUMER_HEARTBEAT_TIME, od.FAULT_REACTION_OPTION_CODE]
)
def test_a_drive_without_master_supervision_is_refused(arm6, make_rig, tmp_path, index):
    eds = without_object(MAXON_EPOS2_EDS, index, tmp_path / "no-supervision.eds")
    rig = make_rig(arm6, eds_paths={3: eds})
    prog = program(arm6.ordered_axes(), 300, fraction=0.4)
    result = rig.group.run(prog, timeout_s=30)
    assert result.result is Result.CONFIGURATION_ERROR
    assert f"node 3: 0x{index:04X}" in result.message
    assert "0x06020000" in result.message  # the drive's SDO abort code: object does not exist
    assert "goes on moving when the master is lost" in result.message
    assert all(d.velocity == 0.0 and d.state is not PowerState.OPERATION_ENABLED for d in rig.sim)


@pytest.mark.parametrize("profile", ["epos2_pvt", "cia402_ip_linear"])
def test_a_new_master_recovers_the_cell_the_dead_one_left(arm6, make_rig, profile):
    """After the crash, a new master (a restarted service) finds the drives stopped by themselves
    (FAULT, SWITCH ON DISABLED), recovers them and runs from where they stand."""
    rig = make_rig(cell_of(arm6, profile))
    kill_master(rig, "dead", threading.Event())
    drives = list(rig.sim)
    wait_standstill(drives, timeout_s=rig.cell.bus.master_consumer_time_ms / 1000.0 + 10.0)
    bus = CellBus(rig.cell.bus).open()
    group = AxisGroup(bus, rig.cell.ordered_axes())
    try:
        recovered = group.recover()
        assert recovered.result is Result.FINISHED, recovered.message
        assert all(d.state is PowerState.OPERATION_ENABLED for d in drives)
        axes = rig.cell.ordered_axes()
        starts = [rig.sim.drive(a.node_id).actual for a in axes]
        prog = program(axes, 300, starts=starts, fraction=0.2, sign=-1)
        check_limits(prog)
        result = group.run(prog, timeout_s=30)
        assert result.result is Result.FINISHED, result.message
        for axis in prog.axes:
            assert rig.sim.drive(axis.node_id).actual == axis.records[-1, 0]
        # and the drives watch the new master: it is their consumer's node, armed again
        assert all(d.master_loss.consumer.active(rig.cell.bus.master_node_id) for d in drives)
    finally:
        group.close()
        bus.close()


def test_an_earlier_entry_for_the_master_node_is_switched_off(arm6, make_rig):
    """CiA 301: one 0x1016 entry per node; an earlier commissioning's entry for the master's node id
    in :02 would make the drive refuse :01 (abort 0x06040043), so configuration switches it off."""
    rig = make_rig(arm6)
    drive = rig.sim.drive(2)
    earlier = (arm6.bus.master_node_id << 16) | 5000
    drive.store(od.CONSUMER_HEARTBEAT_TIME, 2, earlier)
    entry = (arm6.bus.master_node_id << 16) | rig.cell.bus.master_consumer_time_ms
    with pytest.raises(SdoAbortedError) as refused:  # the drive keeps the rule
        rig.bus.add_node(2).sdo.download(od.CONSUMER_HEARTBEAT_TIME, 1, entry.to_bytes(4, "little"))
    assert refused.value.code == 0x06040043
    rig.group.configure()
    assert drive.read(od.CONSUMER_HEARTBEAT_TIME, 2) == 0
    assert drive.read(od.CONSUMER_HEARTBEAT_TIME, 1) == entry


@pytest.mark.wall
def test_an_orderly_close_is_not_a_lost_master(arm6, make_rig):
    """A master that closes at rest shuts the drives down (READY TO SWITCH ON: nobody commands them)
    and then tells them to stop watching: after the consumer time no EMCY 0x8130, no fault (the next
    master starts without a recover)."""
    rig = make_rig(cell_of(arm6, "epos2_pvt"))
    prog = program(rig.cell.ordered_axes(), 300, fraction=0.2)
    assert rig.group.run(prog, timeout_s=30).ok
    assert rig.group.settle(5.0)
    rig.group.close()
    rig.bus.close()  # the master's heartbeat stops with its bus
    time.sleep(3 * rig.cell.bus.master_consumer_time_ms / 1000.0)
    for drive in rig.sim:
        assert not drive.master_loss.losses, f"node {drive.node_id} took the close for a lost master"
        assert drive.state == PowerState.READY_TO_SWITCH_ON, f"node {drive.node_id}: {drive.state}"
        assert drive.read(od.CONSUMER_HEARTBEAT_TIME, 1) == 0
