"""A simulated drive's object dictionary as the drive itself reads and writes it.

python-canopen's ``LocalNode`` holds the values and answers SDO; the drive's own code needs the same
values without the write callbacks an SDO write runs: ``read``, ``store``, and ``publish`` for the
status objects every event refreshes (most refreshes change one or two of them, so it stores only
what changed). The stored parameters a drive keeps through an NMT reset (its limit objects, its
encoder, polarity, identity and motor data) are commissioned here; the SDO abort codes with which
the drive refuses a write are named here.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

import canopen
from canopen import objectdictionary

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.config import AxisSimulation
from pvtflow.axes.drive.scaling import AxisScaling, DriveLimits

ABORT_VALUE_RANGE = 0x06090030
ABORT_DEVICE_STATE = 0x08000022
ABORT_GENERAL = 0x08000000
ABORT_PARAMETER_INCOMPATIBLE = 0x06040043  # CiA 301: a 0x1016 entry for a node another entry watches


class DriveDictionary:
    """A drive's object dictionary from the drive's own side, a part of its ``SimulatedDrive`` (which
    owns the node and the lock and gives them): the entry cache, the refresh cache of ``publish`` and
    the commissioned values kept through resets."""

    def __init__(self, node: canopen.LocalNode, lock: threading.RLock) -> None:
        self.node = node
        self._lock = lock
        self._entries: dict[tuple[int, int], tuple[objectdictionary.ODVariable, int]] = {}
        self._published: dict[tuple[int, int], tuple[int, int, bytes]] = {}  # see publish()
        self._commissioned: dict[tuple[int, int], int] = {}  # kept through an NMT reset (stored parameters)

    def _entry(self, index: int, subindex: int) -> tuple[objectdictionary.ODVariable, int]:
        """The OD variable and the sub-index its value is stored under (0 for a plain variable)."""
        key = (index, subindex)
        hit = self._entries.get(key)
        if hit is None:
            entry = self.node.object_dictionary[index]
            plain = isinstance(entry, objectdictionary.ODVariable)
            hit = (entry, 0) if plain else (entry[subindex], subindex)
            self._entries[key] = hit
        return hit

    def has(self, index: int, subindex: int = 0) -> bool:
        try:
            self._entry(index, subindex)
        except KeyError:
            return False
        return True

    def read(self, index: int, subindex: int = 0) -> int:
        """The value of an object as the drive holds it (EDS default if never written)."""
        var, sub = self._entry(index, subindex)
        raw = self.node.data_store.get(index, {}).get(sub)
        return var.decode_raw(raw if raw is not None else self.node.get_data(index, sub))

    def store(self, index: int, subindex: int, value: int) -> None:
        """Set an object's value from the drive's side (no write callbacks)."""
        var, sub = self._entry(index, subindex)
        self.node.data_store.setdefault(index, {})[sub] = var.encode_raw(value)

    def publish(self, index: int, subindex: int, value: int) -> None:
        """``store`` for the status objects every event refreshes: nothing to do when the object
        still holds this value (the same bytes this call stored last; anything that replaced them,
        a write or a reset, makes it store again). Most refreshes change one or two of them."""
        key = (index, subindex)
        held = self._published.get(key)
        if held is not None and held[0] == value and self.node.data_store.get(index, {}).get(held[1]) is held[2]:
            return
        var, sub = self._entry(index, subindex)
        raw = var.encode_raw(value)
        self.node.data_store.setdefault(index, {})[sub] = raw
        self._published[key] = (value, sub, raw)

    def read_or(self, index: int, subindex: int, default: int) -> int:
        return self.read(index, subindex) if self.has(index, subindex) else default

    def commission(self, values: Mapping[tuple[int, int], int]) -> None:
        """Store ``values`` as stored parameters: they come back after every reset (``restore``)."""
        with self._lock:
            self._commissioned.update(values)
            for (index, subindex), value in values.items():
                self.store(index, subindex, value)

    def power_on(self) -> None:
        """Power-on (or a reset node): the EDS defaults, then the commissioned values."""
        self.node.data_store.clear()
        for (index, subindex), value in self._commissioned.items():
            self.store(index, subindex, value)

    def limit_values(self, limits: DriveLimits, scaling: AxisScaling) -> dict[tuple[int, int], int]:
        """The drive's own limit objects (facts about the drive, DESIGN section 3)."""
        values = {
            (od.MAX_PROFILE_VELOCITY, 0): round(limits.max_profile_velocity_rpm / scaling.velocity_unit_rpm),
            (od.MAX_ACCELERATION, 0): round(limits.max_acceleration_rpm_s),
            (od.SOFTWARE_POSITION_LIMIT, 1): limits.min_position_qc,
            (od.SOFTWARE_POSITION_LIMIT, 2): limits.max_position_qc,
        }
        if self.has(od.QUICK_STOP_DECELERATION):  # the quick stop ramp as configuration writes it
            values[(od.QUICK_STOP_DECELERATION, 0)] = round(limits.max_acceleration_rpm_s)
        if limits.profile_velocity_rpm is not None:
            values[(od.PROFILE_VELOCITY, 0)] = round(limits.profile_velocity_rpm / scaling.velocity_unit_rpm)
        if limits.profile_acceleration_rpm_s is not None:
            values[(od.PROFILE_ACCELERATION, 0)] = round(limits.profile_acceleration_rpm_s)
        return values

    def drive_fact_values(self, simulation: AxisSimulation, scaling: AxisScaling) -> dict[tuple[int, int], int]:
        """What the drive is, kept through resets as a drive's stored parameters are: its encoder
        (0x608F, or maxon's pulse number 0x2210:01 in encoder pulses), and where ``simulation`` says
        so its polarity 0x607E, identity 0x1018:01/:02, motor's maximal speed 0x6410:04 and maxon's sensor
        type 0x2210:02, sensor polarity 0x2210:04 and velocity notation 0x608B."""
        qc = round(scaling.qc_per_motor_rev)
        values: dict[tuple[int, int], int] = {}
        if self.has(od.POSITION_ENCODER_RESOLUTION, 1):
            values[(od.POSITION_ENCODER_RESOLUTION, 1)] = qc
            values[(od.POSITION_ENCODER_RESOLUTION, 2)] = 1
        if self.has(od.EPOS2_SENSOR_CONFIGURATION, 1):
            values[(od.EPOS2_SENSOR_CONFIGURATION, 1)] = round(qc / od.EPOS2_QC_PER_PULSE)
        for key, value in (
            ((od.POLARITY, 0), simulation.polarity),
            ((od.IDENTITY, 1), simulation.vendor_id),
            ((od.IDENTITY, 2), simulation.product_code),
            ((od.MOTOR_DATA, od.MOTOR_MAX_SPEED_SUB), simulation.max_motor_speed_rpm),
            ((od.EPOS2_SENSOR_CONFIGURATION, od.EPOS2_SENSOR_TYPE_SUB), simulation.sensor_type),
            ((od.EPOS2_SENSOR_CONFIGURATION, od.EPOS2_SENSOR_POLARITY_SUB), simulation.sensor_polarity),
            ((od.VELOCITY_NOTATION_INDEX, 0), simulation.velocity_notation_index),
        ):
            if value is not None and self.has(*key):
                values[key] = value
        return values
