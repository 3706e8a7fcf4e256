"""A fixed-period drive's cycle locked to the SYNCs it hears (wall clock only).

A drive in interpolated position mode "synchronized to the SYNC object" (seed
cia402-ip-linear-single-setpoint, "Synchronization to the SYNC object": "the controller is
synchronized to the SYNC object ... carried out as soon as the controller is switched to NMT
Operational") runs its control cycle phase-locked to SYNC: each cycle starts on the locked period,
and the jitter of the SYNC frame's arrival does not move it. ``SyncLock`` is that phase-locked loop:

* **The window.** A SYNC within ``window_us`` of the instant the locked period predicts is that
  cycle's SYNC: its cycle starts at the predicted instant, not at the arrival, so the segment it
  starts runs on the locked period and the demand is what it would be with a perfect SYNC. The
  window is the jitter the bus itself gives SYNC whatever the master does: SYNC (COB-ID 0x080)
  wins arbitration against every frame but NMT, yet a frame already on the wire is never
  interrupted, so a SYNC due while one is being sent waits for it; the longest classic frame is
  8 data bytes with every stuff bit, ``axes.canbus.frame_time.worst_frame_bits(8)`` = 135 bit times
  (interframe space included), 135 us at 1 Mbit/s. None of the seeds names a wider tolerance,
  so jitter the master adds beyond the wire's is not absorbed.
* **Outside the window, or a missing SYNC** (which shows as the next SYNC a whole period late): the
  drive's reaction stays what axes/sim/profiles/fixed_period.py documents for a late or an early SYNC: the
  cycle starts at the arrival and the lock restarts from it.
* **Following SYNC.** The master's clock and the drive's quartz differ (crystals: about +-100 ppm
  each), so the loop follows the SYNCs inside the window with a proportional-integral correction
  of the drive's motion clock rate (``MotionClock.slew``), bounded to ``MAX_SLEW`` (0.1 %, five
  times the worst crystal pair): the demand, a function of motion time, is untouched by it; the
  axis's speed over real time differs from it by the rate, at most 0.1 %.
"""

from __future__ import annotations

from dataclasses import dataclass

from pvtflow.axes.canbus.frame_time import worst_frame_bits

SYNC_WAIT_BITS = worst_frame_bits(8)  # the longest frame a SYNC can find on the wire (module docstring)
MAX_SLEW = 1e-3  # the loop's bound on the motion clock rate's departure from 1
KP = 1.0 / 128.0  # phase: 1/128 of a period's error corrected per period (about 128 periods to settle)
KI = KP * KP / 4.0  # frequency: the loop is critically damped (poles at about 1 - KP / 2)


def sync_window_us(bitrate: int) -> float:
    """The window around the locked instant inside which a SYNC is on time (module docstring)."""
    if bitrate <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate!r}")
    return SYNC_WAIT_BITS * 1e6 / bitrate


@dataclass
class SyncLock:
    """The phase-locked cycle of one drive: where its last cycle started and how fast its clock runs."""

    window_us: float
    cycle_us: float | None = None  # the last cycle's start on the motion clock (None: not locked)
    frequency: float = 0.0  # the integral part of the rate correction (a fraction, + = slower)
    on_time: int = 0  # SYNCs inside the window (their cycles started on the locked period)
    late: int = 0  # SYNCs after the window (a missing SYNC among them): the cycle started at the arrival
    early: int = 0  # SYNCs before the window: the cycle started at the arrival

    def reset(self) -> None:
        self.cycle_us = None
        self.frequency = 0.0

    def expected(self, period_us: float) -> float | None:
        """The motion time the next SYNC is due at (None: not locked)."""
        return None if self.cycle_us is None else self.cycle_us + period_us

    def place(self, latched_us: float, period_us: float) -> tuple[float, float | None]:
        """The start of the cycle a SYNC latched at ``latched_us`` begins, and the motion clock's new
        rate (None: leave it)."""
        expected = self.expected(period_us)
        if expected is None or period_us <= 0.0 or abs(latched_us - expected) > self.window_us:
            if expected is not None:
                if latched_us > expected:
                    self.late += 1
                else:
                    self.early += 1
            self.cycle_us = float(latched_us)
            return self.cycle_us, None
        self.on_time += 1
        error = (latched_us - expected) / period_us  # + : the SYNC came later than the drive's clock said
        self.frequency = _bounded(self.frequency + KI * error)
        self.cycle_us = expected
        return expected, 1.0 - _bounded(self.frequency + KP * error)

    def holds_at(self, now_us: float, period_us: float) -> float | None:
        """While the SYNC due next may still come inside its window (it is due and ``now_us`` is not past
        the window), the motion time the drive samples up to: the due instant, so that the samples after
        it are those of the segment the SYNC starts there (None: sample up to now)."""
        expected = self.expected(period_us)
        if expected is None or not expected < now_us <= expected + self.window_us:
            return None
        return expected


def _bounded(x: float) -> float:
    return min(max(x, -MAX_SLEW), MAX_SLEW)
