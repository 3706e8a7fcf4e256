"""One piece of a simulated drive's interpolation, as the drive's own formulas make it."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pvtflow.axes.drive.interpolation import hermite_coefficients


@dataclass
class Segment:
    """One piece of the drive's interpolation: p(tau) = c0 + c1 tau + c2 tau^2 + c3 tau^3, tau in [0, T]."""

    start: float  # ms on the motion clock
    duration: float
    c0: float
    c1: float
    c2: float
    c3: float
    p1: float  # exact end point and velocity (no rounding drift from chaining)
    v1: float

    @classmethod
    def cubic(cls, start: float, p0: float, v0: float, p1: float, v1: float, duration: float) -> Segment:
        c0, c1, c2, c3 = (float(c) for c in hermite_coefficients(p0, v0, p1, v1, duration))
        return cls(start, duration, c0, c1, c2, c3, p1, v1)

    @classmethod
    def linear(cls, start: float, p0: float, p1: float, duration: float) -> Segment:
        v = (p1 - p0) / duration
        return cls(start, duration, p0, v, 0.0, 0.0, p1, v)

    @classmethod
    def braking(cls, start: float, p0: float, v0: float, deceleration: float) -> Segment:
        """A ramp to rest at up to ``deceleration`` that ends on a whole count: a drive's position
        demand at standstill is a whole number of increments (what 0x6062 shows), so the ramp takes
        the deceleration that stops exactly on the first count at or past its natural stop."""
        natural = p0 + v0 * abs(v0) / (2.0 * deceleration)
        p1 = float(math.ceil(natural) if v0 > 0 else math.floor(natural))
        duration = 2.0 * abs(p1 - p0) / abs(v0)
        a = -v0 / duration
        return cls(start, duration, p0, v0, 0.5 * a, 0.0, p1, 0.0)

    @property
    def end(self) -> float:
        return self.start + self.duration

    def at(self, t: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) at motion time t (clamped to the segment)."""
        tau = min(max(t - self.start, 0.0), self.duration)
        if tau >= self.duration:
            return self.p1, self.v1, 2.0 * self.c2 + 6.0 * self.c3 * self.duration
        p = self.c0 + tau * (self.c1 + tau * (self.c2 + tau * self.c3))
        v = self.c1 + tau * (2.0 * self.c2 + 3.0 * tau * self.c3)
        return p, v, 2.0 * self.c2 + 6.0 * self.c3 * tau
