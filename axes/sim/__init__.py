"""Simulated drives (canopen LocalNodes) for every pvtflow drive profile; ``axes.sim.cell`` builds a cell."""

from axes.sim.drive import SimulatedDrive
from axes.sim.epos2 import Epos2Drive
from axes.sim.ip_linear import IpLinearDrive
from axes.sim.parker import ParkerDrive
from axes.sim.records import FaultRecord, SyncSample
from axes.sim.sync_setpoint import SyncSetpointDrive

__all__ = [
    "Epos2Drive",
    "FaultRecord",
    "IpLinearDrive",
    "ParkerDrive",
    "SimulatedDrive",
    "SyncSample",
    "SyncSetpointDrive",
]
