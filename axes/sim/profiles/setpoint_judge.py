"""How a drive without a ramp of its own judges the setpoints it is given, in a motion or a stop.

The bufferless servodrive and the Parker below a 2.5 ms cycle move each period by the step from the
last setpoint to the new one (0x60C2 / 0x1006): the velocity of a period is that step over the
period (the Parker computes its velocity feed-forward that way, seed: "from the delta of position
reference in the cycle time"), and the change of that velocity from one period to the next is what
its position loop must produce in one period. Neither drive ramps by itself, so nothing softens a
setpoint stream that stops too abruptly: a stream frozen at speed (no new setpoint, or the same one
again: the step falls to 0 in one period) or a jump asks more than the drive can. The simulated drive
judges every SYNC of the stream, in a motion and in a stop alike, by the limits the master wrote:
the velocity change against 0x60C5 (the velocity, against 0x607F, where the demand runs), with the one allowance a
program's linear reconstruction has for whole-count setpoints (``linear_step_acceleration``, the
validator's), so a validated program and the master's stop ramp (``axes.drive.stop_ramp``) pass and a
stream whose step changes faster faults the drive (EMCY 0x8400, as 0x607F does).

The judge's arithmetic is compiled (numba, ``axes.drive.interpolation``): the first compiled call in a
process loads numba's CPU target, 0.5-1.2 s on the development host. A stream loads it when it is
made (with its drive, before the drive answers any SYNC), so that a drive never spends that time
inside its first SYNC of a motion holding its lock: measured, the bufferless drive of gantry3-mixed
then answered every SYNC 0.6 s late (bench/RESULTS.md, "the buffered EPOS2 on the wall clock").
"""

from __future__ import annotations

from dataclasses import dataclass

from pvtflow.axes.drive.interpolation import exceeds, linear_step_acceleration


@dataclass
class SetpointStream:
    """The last setpoint a drive took and the velocity of its step (qc, qc/ms); None: no stream yet."""

    last: float | None = None
    velocity: float = 0.0

    def __post_init__(self) -> None:
        linear_step_acceleration(0.0, 0.0, 1.0)  # compiled now, not in a SYNC (module docstring)

    def reset(self) -> None:
        self.last = None
        self.velocity = 0.0

    def take(self, target: float | None, start: float, period_ms: float) -> tuple[float, float]:
        """The setpoint of this SYNC (None: no new one, the last is held), from ``start`` (where the
        drive stands) for the first of a stream: (velocity qc/ms, acceleration qc/ms^2 as judged)."""
        previous = start if self.last is None else self.last
        point = previous if target is None else float(target)
        velocity = (point - previous) / period_ms
        acceleration = float(linear_step_acceleration(self.velocity, velocity, period_ms))
        self.last, self.velocity = point, velocity
        return velocity, acceleration


def too_fast(acceleration_qc_ms2: float, rpm_s_per_qc_ms2: float, max_acceleration_rpm_s: int) -> bool:
    """The velocity change of a period above 0x60C5 (with the shared round-off allowance)."""
    return bool(exceeds(acceleration_qc_ms2 * rpm_s_per_qc_ms2, max_acceleration_rpm_s))
