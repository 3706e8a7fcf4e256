"""What a validation finds: the findings (each a rule broken, with its severity and a stable rule
code), each axis's worst values, and the report that carries both to the CLI, the service and the
API (as text for a person, as JSON for a tool).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class Severity(StrEnum):
    """What a finding means for the drive: an error makes it refuse or fault, a warning only sets a bit."""

    ERROR = "error"
    WARNING = "warning"


class Rule(StrEnum):
    """The stable rule codes of the findings (the table in the module docstring)."""

    RECORD_RANGE = "record-range"
    TIME_RANGE = "time-range"
    START_RECORD = "start-record"
    END_RECORD = "end-record"
    PERIOD = "period"
    POSITION_LIMIT = "position-limit"
    VELOCITY_LIMIT = "velocity-limit"
    ACCELERATION_LIMIT = "acceleration-limit"
    PROFILE_VELOCITY = "profile-velocity"
    PROFILE_ACCELERATION = "profile-acceleration"


# At most this many findings of one rule per axis are listed in the text report.
_TEXT_FINDINGS_PER_RULE = 8


@dataclass(frozen=True)
class Finding:
    """One broken rule: on which axis, at which record, by how much.

    ``record`` is the index of the record concerned (for a motion check: the record that ends the
    segment where the worst value occurs), or None for a whole-axis finding. ``amount`` is by how
    much the value exceeds the limit, in ``unit``; ``value``/``limit`` are the numbers compared.
    """

    severity: Severity
    rule: Rule
    axis: str
    record: int | None
    message: str
    amount: float = 0.0
    value: float | None = None
    limit: float | None = None
    unit: str = ""
    time_ms: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "severity": self.severity,
            "rule": self.rule,
            "axis": self.axis,
            "record": self.record,
            "message": self.message,
            "amount": self.amount,
            "value": self.value,
            "limit": self.limit,
            "unit": self.unit,
            "time_ms": self.time_ms,
        }

    def format(self) -> str:
        where = f"record {self.record}" if self.record is not None else "axis"
        return f"{self.severity}: {self.axis} {where}: [{self.rule}] {self.message}"


@dataclass(frozen=True)
class AxisSummary:
    """Worst values of one axis's reconstruction, in drive units and as fractions of its limits."""

    axis: str
    profile: str
    records: int
    duration_ms: float
    max_velocity_rpm: float | None = None  # exact, over the whole reconstruction
    max_acceleration_rpm_s: float | None = None
    velocity_ratio: float | None = None  # max |v| / 0x607F
    acceleration_ratio: float | None = None  # max |a| / 0x60C5
    sampled_velocity_ratio: float | None = None  # the same at the drive's 1 kHz samples
    sampled_acceleration_ratio: float | None = None
    min_position_qc: float | None = None
    max_position_qc: float | None = None

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class ValidationReport:
    """Everything found in one program. ``ok`` means no errors (warnings allowed)."""

    cell: str
    errors: tuple[Finding, ...]
    warnings: tuple[Finding, ...]
    axes: tuple[AxisSummary, ...] = field(default_factory=tuple)
    source: str | None = None  # the file it came from, when there is one

    @property
    def ok(self) -> bool:
        return not self.errors

    @property
    def findings(self) -> tuple[Finding, ...]:
        return self.errors + self.warnings

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "ok": self.ok,
            "cell": self.cell,
            "errors": [f.to_json() for f in self.errors],
            "warnings": [f.to_json() for f in self.warnings],
            "axes": [a.to_json() for a in self.axes],
        }
        if self.source is not None:
            out["source"] = self.source
        return out

    def format_text(self) -> str:
        """A report for a person: verdict first, then every finding (grouped per axis and rule)."""
        name = self.source or f"program of cell {self.cell!r}"
        verdict = "VALID" if self.ok else "INVALID"
        lines = [f"{name}: {verdict} ({len(self.errors)} error(s), {len(self.warnings)} warning(s))"]
        for a in self.axes:
            parts = [f"{a.axis} [{a.profile}]: {a.records} records, {a.duration_ms:.0f} ms"]
            if a.velocity_ratio is not None and a.acceleration_ratio is not None:
                parts.append(f"max |v| {a.max_velocity_rpm:.1f} rpm ({100 * a.velocity_ratio:.1f}% of 0x607F)")
                parts.append(
                    f"max |a| {a.max_acceleration_rpm_s:.0f} rpm/s ({100 * a.acceleration_ratio:.1f}% of 0x60C5)"
                )
            lines.append("  " + ", ".join(parts))
        shown: Counter[tuple[str, str]] = Counter()
        hidden: Counter[tuple[str, str]] = Counter()
        for f in self.findings:
            key = (f.axis, f.rule)
            if shown[key] < _TEXT_FINDINGS_PER_RULE:
                shown[key] += 1
                lines.append("  " + f.format())
            else:
                hidden[key] += 1
        for (axis, rule), n in hidden.items():
            lines.append(f"  ... and {n} more [{rule}] finding(s) on {axis}")
        return "\n".join(lines)
