"""Simulated Parker SLVDN in interpolated position mode, operative mode 202 (seed parker-slvdn-ip-mode-202).

Pr31 (0x201F) = 202 selects the mode; interpolation runs whenever operation is enabled in it (the
seed names no controlword bit for it; bit 8 halt still brakes). Operative mode 202 is CiA 402's
interpolated position mode, so a CiA 402 master selects it through 0x6060 as well: 0x6060 = 7 sets
Pr31 = 202, 0 (CiA 402's "no mode") changes nothing, any other value is refused (0x06090030), and
0x6061 shows the mode in force: 7 while Pr31 = 202, else 0. The cycle is 0x1006 (us):

* below 2500 us the position reference is taken directly on the SYNC that validates it (no delay);
* from 2500 us on, 0x60C0 selects the interpolation, on the program timeline of
  ``axes.drive.interpolation``: 0 linear (one cycle of delay, ``linear``), -1 cubic through position
  and velocity 0x60C1:03 in rpm (one cycle, ``cubic_pv``), -2 cubic through positions only (two
  cycles, ``cubic_p``: the velocity at a point is the central difference of its neighbours, so the
  segment to point k starts when point k+1 is validated; a SYNC without a new point ends the
  stream: the last segment arrives at rest).

A missing cycle (0x1006 = 0) or an unknown submode faults the drive (EMCY 0x6320) when the mode
starts.

Wall clock, an early SYNC: from 2500 us the seed times each point from its own SYNC, "activated as
trajectory setpoint at the end of the cycle time started with the sync signal that validated the
target position": the cycle (0x1006 on the drive's clock) starts at that SYNC, early or not, from
where the demand is. Below 2500 us "the position loop trajectory setpoint is immediately upgraded
with the last received position setpoint as soon as the sync signal is received": each SYNC of a
burst takes its setpoint at once, and the velocity judged against 0x607F is the one the seed's
drive computes, "from the delta of position reference in the cycle time" (the delta over 0x1006,
not over the time since the previous SYNC).
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.interpolation import Interpolation
from pvtflow.axes.sim.cia402.power_states import OPERATION_ENABLED
from pvtflow.axes.sim.cia402.segment import Segment
from pvtflow.axes.sim.node.device import NO_MODE, PARKER_MODES
from pvtflow.axes.sim.node.dictionary import ABORT_VALUE_RANGE
from pvtflow.axes.sim.profiles.fixed_period import FixedPeriodDrive

DIRECT = "direct"
SUBMODES = DriveProfile.PARKER_SLVDN.spec.submodes  # 0x60C0 -> how the drive joins its setpoints


class ParkerDrive(FixedPeriodDrive):
    PROFILE = DriveProfile.PARKER_SLVDN
    EDS = "parker_slvdn.eds"
    MODES = PARKER_MODES

    def _reset_stream(self) -> None:
        self._points: list[float] | None = None  # submode -2: the last three points of the stream
        self._v_last = 0.0

    # --- mode ---------------------------------------------------------------------------------------
    @property
    def cycle_us(self) -> int:
        return self.read(od.COMMUNICATION_CYCLE_PERIOD)

    @property
    def period_ms(self) -> float:
        return self.cycle_us / 1000.0

    @property
    def interpolation(self) -> str | Interpolation | None:
        """DIRECT below 2500 us, else what the submode 0x60C0 selects (None: a value it does not have)."""
        if self.cycle_us < od.PARKER_CUBIC_THRESHOLD_US:
            return DIRECT
        return SUBMODES.get(self.read(od.INTERPOLATION_SUBMODE))

    @property
    def delay_periods(self) -> int:  # type: ignore[override]
        mode = self.interpolation
        return 0 if mode == DIRECT else 2 if mode is Interpolation.CUBIC_P else 1

    def _ip_mode_selected(self) -> bool:
        return self.read(od.PARKER_OPERATIVE_MODE) == od.PARKER_IP_MODE

    def _check_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.INTERPOLATION_SUBMODE and value not in SUBMODES:
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def _on_mode_bits(self, previous: int, controlword: int) -> None:
        """Mode 202 does not wait for bit 4 (see the module docstring)."""

    def _on_object_write(self, index: int, subindex: int, value: int) -> None:
        if index == od.PARKER_OPERATIVE_MODE:
            if value != od.PARKER_IP_MODE and self.ip_active:
                self._abort_motion()
            self._show_mode()
        super()._on_object_write(index, subindex, value)

    def _on_mode_change(self, old: int, new: int) -> None:
        """0x6060 = 7 is operative mode 202 (see the module docstring)."""
        if new == od.INTERPOLATED_POSITION_MODE:
            self.store(od.PARKER_OPERATIVE_MODE, 0, od.PARKER_IP_MODE)
        self._show_mode()

    def _show_mode(self) -> None:
        """0x6061: the CiA 402 mode of the operative mode in force (Pr31)."""
        mode = od.INTERPOLATED_POSITION_MODE if self._ip_mode_selected() else NO_MODE
        self.store(od.MODES_OF_OPERATION_DISPLAY, 0, mode)

    def _on_sync_validated(self) -> None:
        if (
            self.state == OPERATION_ENABLED
            and not self.ip_active
            and self._ip_mode_selected()
            and not self.power.halted
            and not self.motion.braking
        ):
            self._request_ip()
        super()._on_sync_validated()

    def _activate(self) -> bool:
        if self.cycle_us <= 0:
            self.fault(od.EMCY_PARAMETER_ERROR, "communication cycle period 0x1006 not set")
            return False
        if self.interpolation is None:
            self.fault(od.EMCY_PARAMETER_ERROR, f"interpolation submode 0x60C0 = {self.read(od.INTERPOLATION_SUBMODE)}")
            return False
        return super()._activate()

    # --- setpoints ----------------------------------------------------------------------------------
    def _validated(self, now: float, target: int | None) -> None:
        mode, period = self.interpolation, self.period_ms
        if mode == DIRECT:  # no ramp of its own: every SYNC's setpoint judged (FixedPeriodDrive._judge)
            if target is not None and not self.motion.check_position(float(target)):
                return
            previous = self.demand
            if not self._judge(target) or target is None:
                return
            self._follow(Segment(now, 0.0, float(target), 0.0, 0.0, 0.0, float(target), 0.0))
            self.motion.jump_to(float(target))
            self._check_dynamics((target - previous) / period, 0.0)
        elif mode is Interpolation.LINEAR:
            if target is not None:
                self._ramp(now, target, period)
        elif mode is Interpolation.CUBIC_PV:
            if target is not None:
                p0, v0 = self._start_point()
                rpm = self.read(od.INTERPOLATION_DATA_RECORD, 3)
                v1 = float(self.scaling.rpm_to_qc_per_ms(rpm))
                self._follow(Segment.cubic(now, p0, v0, float(target), v1, period))
        else:
            self._cubic_positions(now, target, period)

    def _cubic_positions(self, now: float, target: int | None, period: float) -> None:
        points = self._points
        if target is not None:
            if points is None:
                points = self._points = [self._start_point()[0]]
                self._v_last = 0.0
            points.append(float(target))
            del points[:-3]
            if len(points) == 3:
                v_next = (points[2] - points[0]) / (2.0 * period)
                self._follow(Segment.cubic(now, points[0], self._v_last, points[1], v_next, period))
                self._v_last = v_next
        elif points is not None:
            if len(points) >= 2:
                self._follow(Segment.cubic(now, points[-2], self._v_last, points[-1], 0.0, period))
            self._points = None
            self._v_last = 0.0
