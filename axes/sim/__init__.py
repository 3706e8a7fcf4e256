"""Simulated drives (canopen LocalNodes) for every pvtflow drive profile; ``axes.sim.cell`` builds a cell."""

from pvtflow.axes.sim.cia402.records import FaultRecord, SyncSample
from pvtflow.axes.sim.drive import SimulatedDrive
from pvtflow.axes.sim.profiles.epos2 import Epos2Drive
from pvtflow.axes.sim.profiles.ip_linear import IpLinearDrive
from pvtflow.axes.sim.profiles.parker import ParkerDrive
from pvtflow.axes.sim.profiles.sync_setpoint import SyncSetpointDrive

__all__ = [
    "Epos2Drive",
    "FaultRecord",
    "IpLinearDrive",
    "ParkerDrive",
    "SimulatedDrive",
    "SyncSample",
    "SyncSetpointDrive",
]
