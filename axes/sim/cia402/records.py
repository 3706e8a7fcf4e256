"""What a simulated drive keeps of its run for tests and benches: its faults, a lost master, its SYNC samples."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FaultRecord:
    """One fault the drive went into: when, the EMCY code it sent and which check tripped."""

    sync: int
    time_ms: float
    code: int
    check: str


@dataclass
class MasterLoss:
    """A heartbeat the drive watches (0x1016) stopped: when, and how the drive took it (tests, benches)."""

    node_id: int  # whose heartbeat stopped
    silent_s: float  # since its last heartbeat when the consumer fired
    detected: float  # time.monotonic()
    last_heartbeat: float | None  # time.monotonic() of that node's last heartbeat
    option: int  # 0x6007 in force
    state: str  # the power state the drive was in
    velocity_rpm: float  # the demand velocity then (motor rpm)
    standstill: float | None = None  # time.monotonic() when the demand came to rest (None: still moving)


@dataclass(frozen=True, slots=True)
class SyncSample:
    """The drive's demand and actual position at one SYNC instant (after the SYNC's processing)."""

    sync: int
    time_ms: float
    demand: float
    actual: int
    ip_active: bool
    state: str
    # wall clock: how far (us) the drive's samples had run past this SYNC's arrival when the simulation
    # processed it (the SYNC still acts at its arrival; ``demand`` is then the later sample's)
    behind_us: int = 0
