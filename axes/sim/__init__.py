"""Simulated drives (canopen LocalNodes) for every pvtflow drive profile; ``axes.sim.cell`` builds a cell."""

from pvtflow.axes.sim.drive import SimulatedDrive
from pvtflow.axes.sim.epos2 import Epos2Drive
from pvtflow.axes.sim.ip_linear import IpLinearDrive
from pvtflow.axes.sim.parker import ParkerDrive
from pvtflow.axes.sim.records import FaultRecord, SyncSample
from pvtflow.axes.sim.sync_setpoint import SyncSetpointDrive

__all__ = [
    "Epos2Drive",
    "FaultRecord",
    "IpLinearDrive",
    "ParkerDrive",
    "SimulatedDrive",
    "SyncSample",
    "SyncSetpointDrive",
]
