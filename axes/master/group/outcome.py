"""What a run of an axis group reports: how it ended (``Result``, ``RunResult``, ruckig style: one
enum, the details in the result object), its progress, its events and the status of every axis."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum, StrEnum

from pvtflow.axes.drive.cia402 import PowerState
from pvtflow.axes.master.bus.faults import FaultKind
from pvtflow.axes.master.group.feeder import FeedStats


class Result(Enum):
    """How a run or a homing ended (ruckig style: one enum, details in the result object). Both end
    the same ways when a drive or the bus fails; ``FINISHED`` and ``REJECTED`` are a run's own ends,
    ``HOMED``, ``HOMING_ERROR`` and ``TIMEOUT`` a homing's (axes.master.homing)."""

    FINISHED = "finished"  # every axis reached its end record
    HOMED = "homed"  # every axis asked for is homed
    STOPPED = "stopped"  # stop() was called: all axes halted
    DRIVE_FAULT = "drive_fault"  # a drive reported a fault (statusword, buffer error bits)
    EMCY = "emcy"  # a drive sent an emergency
    HEARTBEAT_LOST = "heartbeat_lost"  # a drive's heartbeat stopped, or it left OPERATIONAL
    LOST_SYNC = "lost_sync"  # a drive stopped answering SYNC
    BUS_ERROR = "bus_error"  # the master could not keep SYNC (a gap, a dead SYNC thread, a frame not sent, bus-off)
    REJECTED = "rejected"  # the program does not fit the cell (nothing moved)
    CONFIGURATION_ERROR = "configuration_error"  # a drive refused its configuration, enable or homing settings
    HOMING_ERROR = "homing_error"  # a drive reported a homing error (statusword bit 13)
    TIMEOUT = "timeout"  # a homing stage was not done within its timeout

    @property
    def ok(self) -> bool:
        return self in (Result.FINISHED, Result.HOMED)

    @property
    def is_fault(self) -> bool:
        """A drive failed or would not take its settings: the cell stays faulted until someone
        recovers it (a stop, a refusal, a homing error or timeout leave it usable)."""
        return self in _FAULTS


_FAULTS = frozenset(
    {Result.DRIVE_FAULT, Result.EMCY, Result.HEARTBEAT_LOST, Result.LOST_SYNC, Result.CONFIGURATION_ERROR}
)


@dataclass
class RunResult:
    result: Result
    message: str
    joint: str | None = None  # the axis that caused the end (None: all / none)
    node_id: int | None = None
    start_sync: int | None = None  # absolute SYNC number of the start SYNC (program t = 0)
    end_sync: int | None = None  # last SYNC answered
    fault_sync: int | None = None  # the last SYNC sent when the event was seen (its period)
    halt_sync: int | None = None  # the SYNC that carried the halt
    halt_latency_s: float | None = None  # wall time from the event to the halt frames
    sync_period_ms: float = 1.0
    axes: list[AxisReport] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.result.ok

    @property
    def start_skew_syncs(self) -> int | None:
        """Spread of the SYNCs at which the axes entered ip mode active (0: all on the same SYNC)."""
        starts = [a.start_sync for a in self.axes if a.start_sync is not None]
        return max(starts) - min(starts) if starts else None

    @property
    def halt_latency_syncs(self) -> int | None:
        """SYNC periods from the SYNC after which the fault was seen to the SYNC that halted."""
        if self.fault_sync is None or self.halt_sync is None:
            return None
        return self.halt_sync - self.fault_sync

    def to_json(self) -> dict[str, object]:
        return {
            "result": self.result.value,
            "message": self.message,
            "joint": self.joint,
            "node_id": self.node_id,
            "start_sync": self.start_sync,
            "end_sync": self.end_sync,
            "halt_latency_syncs": self.halt_latency_syncs,
            "start_skew_syncs": self.start_skew_syncs,
            "axes": [
                {
                    "joint": a.joint,
                    "node_id": a.node_id,
                    "state": a.state,
                    "statusword": a.statusword,
                    "position_qc": a.position,
                    "position": a.joint_position,
                    "target_position_qc": a.target_position,
                    "records_sent": a.feed.sent,
                    "underflows": a.feed.underflows,
                    "overflows": a.feed.overflows,
                    "min_level": a.feed.min_level,
                    "max_level": a.feed.max_level,
                }
                for a in self.axes
            ],
        }


@dataclass(frozen=True)
class AxisStatus:
    """What one drive says (the zenoh service publishes this)."""

    joint: str
    node_id: int
    profile: str
    state: PowerState
    statusword: int
    position: int | None
    buffer_status: int
    buffer_flags: tuple[str, ...]
    buffer_level: int | None  # the feeder's estimate (EPOS2), None when idle or bufferless
    last_emcy: tuple[int, str] | None
    nmt_state: int | None
    homed: bool = True  # nothing to home, or homed since its drive last booted


@dataclass(frozen=True, kw_only=True)
class AxisReport(AxisStatus):
    """Per axis, after a run: what its drive says then (``AxisStatus``) and what the run did."""

    target_position: int | None  # qc: the program's last record
    feed: FeedStats
    start_sync: int | None  # absolute SYNC number at which the drive first reported ip mode active
    joint_position: float | None = None  # ``position`` in joint units (rad or m), through the axis scaling


@dataclass(frozen=True)
class GroupStatus:
    running: bool
    sync_count: int
    elapsed_ms: float | None  # program time (None when not running)
    axes: tuple[AxisStatus, ...]
    last_result: Result | None


@dataclass(frozen=True)
class Progress:
    """Telemetry after a SYNC: program time and per-axis position, buffer level, state."""

    sync: int
    elapsed_ms: float
    positions: tuple[int | None, ...]
    levels: tuple[int | None, ...]
    states: tuple[PowerState, ...]
    statuswords: tuple[int, ...] = ()


class EventKind(StrEnum):
    """What an ``Event`` reports: the group's own steps, how a run ended (``Result``'s values) and
    what the bus saw fail (``FaultKind``'s), one closed set."""

    STARTED = "started"
    HALTED = "halted"
    RECOVERED = "recovered"
    FINISHED = Result.FINISHED.value
    STOPPED = Result.STOPPED.value
    DRIVE_FAULT = Result.DRIVE_FAULT.value
    EMCY = Result.EMCY.value
    HEARTBEAT_LOST = Result.HEARTBEAT_LOST.value
    LOST_SYNC = Result.LOST_SYNC.value
    BUS_ERROR = Result.BUS_ERROR.value
    REJECTED = Result.REJECTED.value
    CONFIGURATION_ERROR = Result.CONFIGURATION_ERROR.value
    HEARTBEAT = FaultKind.HEARTBEAT.value
    NMT = FaultKind.NMT.value
    SYNC_GAP = FaultKind.SYNC_GAP.value
    SYNC_STOPPED = FaultKind.SYNC_STOPPED.value
    TX_FAILED = FaultKind.TX_FAILED.value
    BUS_OFF = FaultKind.BUS_OFF.value
    BUS_WARNING = FaultKind.BUS_WARNING.value

    @property
    def is_bus_fault(self) -> bool:
        """A drive or the bus failed (also between runs: the cell is faulted until recovered); a
        warning (error frames, error passive) is no fault."""
        return self.value in {k.value for k in FaultKind if not k.warning}


@dataclass(frozen=True)
class Event:
    """A discrete event for the service's ``events`` publication."""

    kind: EventKind
    message: str
    joint: str | None = None
    node_id: int | None = None


ProgressCallback = Callable[[Progress], None]
EventCallback = Callable[[Event], None]


class GroupError(RuntimeError):
    """A request the group cannot take in its present state (e.g. run while running)."""
