"""The motion journal: every accepted motion (its program, then its outcome), append-only, on disk.

One JSON object per line in ``<directory>/journal.jsonl``. A motion is written (and fsync'ed) before
its first record goes to a drive, so what ran is never lost: after a crash the journal still has the
program, and a motion without an outcome line is reported as ``interrupted``. Lines are never
rewritten; a torn last line (power loss mid-write) is skipped on reading.

Line kinds: ``{"kind": "motion", "motion_id", "time", "plan_id", "label", "cell", "program", ...}``
and ``{"kind": "outcome", "motion_id", "time", "outcome": {...RunResult JSON}}``; every homing (it
moves the axes too) as ``{"kind": "homing", "homing_id", "time", "cell", "stages"}`` before it starts
and ``{"kind": "homing_outcome", "homing_id", "time", "outcome": {...HomingOutcome JSON}}`` after.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pvtflow.service.api.wire import RunState

JOURNAL_FILE = "journal.jsonl"


def default_directory(cell: str) -> Path:
    """``$XDG_STATE_HOME/pvtflow/<cell>`` (``~/.local/state/pvtflow/<cell>`` by default)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "pvtflow" / cell


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds")


@dataclass
class MotionEntry:
    """One motion as the journal knows it."""

    motion_id: str
    accepted_at: float
    plan_id: str | None
    label: str | None
    duration_ms: int
    program: dict[str, Any] = field(repr=False)
    outcome: dict[str, Any] | None = None
    ended_at: float | None = None
    recording: str | None = None  # the motion's MCAP file (pvtflow serve --record DIR)
    queued_after: str | None = None  # queued (execute with queue): the motion it runs on from

    def summary(self, running: bool = False) -> dict[str, Any]:
        return {
            "motion_id": self.motion_id,
            "plan_id": self.plan_id,
            "label": self.label,
            "state": RunState.of(self.outcome is not None, running),
            "accepted_at": _iso(self.accepted_at),
            "ended_at": _iso(self.ended_at) if self.ended_at is not None else None,
            "duration_ms": self.duration_ms,
            "outcome": self.outcome,
            "recording": self.recording,
            "queued_after": self.queued_after,
        }


@dataclass
class HomingEntry:
    """One homing as the journal knows it."""

    homing_id: str
    accepted_at: float
    stages: list[list[str]]
    outcome: dict[str, Any] | None = None
    ended_at: float | None = None
    recording: str | None = None  # the homing's MCAP file (pvtflow serve --record DIR)

    def summary(self, running: bool = False) -> dict[str, Any]:
        return {
            "homing_id": self.homing_id,
            "state": RunState.of(self.outcome is not None, running),
            "stages": self.stages,
            "accepted_at": _iso(self.accepted_at),
            "ended_at": _iso(self.ended_at) if self.ended_at is not None else None,
            "outcome": self.outcome,
        }


class JournalError(OSError):
    """The journal cannot be opened or written (the motion is then refused: nothing unrecorded runs)."""


class Journal:
    """Append-only JSON-lines journal of one cell's motions."""

    def __init__(self, directory: str | Path, keep_in_memory: int = 200) -> None:
        self.directory = Path(directory)
        self.path = self.directory / JOURNAL_FILE
        self.keep_in_memory = keep_in_memory
        self.skipped_lines = 0
        self._lock = threading.Lock()
        self._entries: OrderedDict[str, MotionEntry] = OrderedDict()
        self._homings: OrderedDict[str, HomingEntry] = OrderedDict()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._load()
            self._file = open(self.path, "ab")  # noqa: SIM115 - held open for the service's life
            if self._file.tell() > 0 and not self._ends_with_newline():
                self._append_raw(b"\n")  # a torn last line stays alone on its line: the next record is whole
        except OSError as exc:
            raise JournalError(f"cannot open the motion journal {self.path}: {exc.strerror or exc}") from None

    def _load(self) -> None:
        if not self.path.exists():
            return
        with open(self.path, "rb") as f:
            for raw in f:
                try:
                    line = json.loads(raw)
                    kind = line["kind"]
                    if kind == "motion":
                        self._remember(
                            MotionEntry(
                                line["motion_id"],
                                float(line["time"]),
                                line.get("plan_id"),
                                line.get("label"),
                                int(line.get("duration_ms", 0)),
                                line.get("program", {}),
                                recording=line.get("recording"),
                                queued_after=line.get("queued_after"),
                            )
                        )
                    elif kind == "outcome":
                        entry = self._entries.get(line["motion_id"])
                        if entry is not None:
                            entry.outcome = line["outcome"]
                            entry.ended_at = float(line["time"])
                    elif kind == "homing":
                        self._remember_homing(
                            HomingEntry(
                                line["homing_id"], float(line["time"]), line["stages"], recording=line.get("recording")
                            )
                        )
                    elif kind == "homing_outcome":
                        homing = self._homings.get(line["homing_id"])
                        if homing is not None:
                            homing.outcome = line["outcome"]
                            homing.ended_at = float(line["time"])
                except (ValueError, KeyError, TypeError):
                    self.skipped_lines += 1  # a torn or foreign line: keep reading

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            return f.read(1) == b"\n"

    def _append_raw(self, data: bytes) -> None:
        self._file.write(data)
        self._file.flush()
        os.fsync(self._file.fileno())

    def _remember(self, entry: MotionEntry) -> None:
        self._entries[entry.motion_id] = entry
        while len(self._entries) > self.keep_in_memory:
            self._entries.popitem(last=False)

    def _remember_homing(self, entry: HomingEntry) -> None:
        self._homings[entry.homing_id] = entry
        while len(self._homings) > self.keep_in_memory:
            self._homings.popitem(last=False)

    def _append(self, line: dict[str, Any]) -> None:
        data = json.dumps(line, separators=(",", ":"), allow_nan=False).encode() + b"\n"
        try:
            self._append_raw(data)
        except (OSError, ValueError) as exc:
            raise JournalError(f"cannot write the motion journal {self.path}: {exc}") from None

    def record_motion(
        self,
        motion_id: str,
        program: dict[str, Any],
        *,
        plan_id: str | None,
        label: str | None,
        duration_ms: int,
        cell: str,
        recording: str | None = None,
        queued_after: str | None = None,
    ) -> MotionEntry:
        """Write (and fsync) an accepted motion; call before anything is sent to a drive (``queued_after``:
        the motion it is queued after, execute with queue)."""
        now = time.time()
        entry = MotionEntry(
            motion_id, now, plan_id, label, duration_ms, program, recording=recording, queued_after=queued_after
        )
        with self._lock:
            self._append(
                {
                    "kind": "motion",
                    "motion_id": motion_id,
                    "time": now,
                    "cell": cell,
                    "plan_id": plan_id,
                    "label": label,
                    "duration_ms": duration_ms,
                    "program": program,
                    **({"recording": recording} if recording is not None else {}),
                    **({"queued_after": queued_after} if queued_after is not None else {}),
                }
            )
            self._remember(entry)
        return entry

    def record_outcome(self, motion_id: str, outcome: dict[str, Any]) -> None:
        now = time.time()
        with self._lock:
            self._append({"kind": "outcome", "motion_id": motion_id, "time": now, "outcome": outcome})
            entry = self._entries.get(motion_id)
            if entry is not None:
                entry.outcome = outcome
                entry.ended_at = now

    def record_homing(
        self, homing_id: str, stages: list[list[str]], *, cell: str, recording: str | None = None
    ) -> HomingEntry:
        """Write (and fsync) an accepted homing; call before any axis moves."""
        now = time.time()
        entry = HomingEntry(homing_id, now, stages, recording=recording)
        line = {"kind": "homing", "homing_id": homing_id, "time": now, "cell": cell, "stages": stages}
        with self._lock:
            self._append({**line, **({"recording": recording} if recording is not None else {})})
            self._remember_homing(entry)
        return entry

    def record_homing_outcome(self, homing_id: str, outcome: dict[str, Any]) -> None:
        now = time.time()
        with self._lock:
            self._append({"kind": "homing_outcome", "homing_id": homing_id, "time": now, "outcome": outcome})
            entry = self._homings.get(homing_id)
            if entry is not None:
                entry.outcome = outcome
                entry.ended_at = now

    def homing(self, homing_id: str) -> HomingEntry | None:
        with self._lock:
            return self._homings.get(homing_id)

    def recent_homings(self, n: int) -> list[HomingEntry]:
        """The ``n`` most recent homings, newest first."""
        with self._lock:
            return list(reversed(self._homings.values()))[:n] if n > 0 else []

    def get(self, motion_id: str) -> MotionEntry | None:
        with self._lock:
            return self._entries.get(motion_id)

    def recent(self, n: int) -> list[MotionEntry]:
        """The ``n`` most recent motions, newest first."""
        with self._lock:
            return list(reversed(self._entries.values()))[:n] if n > 0 else []

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.close()
