"""The PVT program: what pvtflow hands to the drives, and its JSON form (DESIGN.md section 4).

A program is pure data in drive units. It is read and written as JSON text here; opening files
is the caller's business (the planner does no I/O).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pvtflow.axes.drive import interpolation
from pvtflow.axes.drive.axis import DriveAxis
from pvtflow.axes.drive.config import AxisConfig
from pvtflow.axes.drive.drive_profile import DriveProfile
from pvtflow.axes.drive.interpolation import PiecewiseCubic
from pvtflow.axes.drive.scaling import INT24_MAX, INT24_MIN, INT32_MAX, INT32_MIN, AxisScaling, DriveLimits

FORMAT = "pvtflow.pvt-program"
VERSION = 1

TIME_MAX_MS = 255

# an indented record as json.dumps lays it out (one number per line), to put back on one line
_RECORD_LINE = re.compile(r"\[\s*(-?\d+),\s*(-?\d+),\s*(-?\d+)\s*\]")


class ProgramFormatError(ValueError):
    """The text is not a pvtflow PVT program; ``where`` is a JSON path such as axes[2].records[7]."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}" if where else problem)


@dataclass(frozen=True)
class AxisProgram(DriveAxis):
    """One axis (``DriveAxis``: what its drive will make of records) and its records.

    A fixed-period axis's ``period_ms`` is its records' time (the validator judges every record's).
    """

    records: NDArray[np.int64] = field(kw_only=True)

    def __post_init__(self) -> None:
        object.__setattr__(self, "profile", DriveProfile.parse(self.profile))
        r = self.records
        if self.profile.fixed_period and r.ndim == 2 and r.shape[1] == 3 and len(r):
            object.__setattr__(self, "period_ms", int(r[0, 2]))

    @classmethod
    def of(cls, axis: DriveAxis, records: NDArray[np.int64]) -> AxisProgram:
        """``records`` for ``axis`` (a cell's axis, or a program's)."""
        return cls(**{name: getattr(axis, name) for name in _DRIVE_AXIS_FIELDS}, records=records)

    @property
    def duration_ms(self) -> int:
        return int(self.records[:, 2].sum())

    def reconstruction(self) -> PiecewiseCubic:
        """The motion this axis's drive will execute from these records (qc, ms)."""
        period = float(self.records[0, 2])
        kind = self.profile.reconstruction(period, self.interpolation_submode)
        return interpolation.reconstruct(kind, self.records, period, self.scaling.qc_per_ms_per_velocity_unit)


_DRIVE_AXIS_FIELDS = tuple(f.name for f in fields(DriveAxis))  # what ``AxisProgram.of`` copies


@dataclass(frozen=True)
class PvtProgram:
    cell: str
    axes: tuple[AxisProgram, ...]
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def duration_ms(self) -> int:
        return max((a.duration_ms for a in self.axes), default=0)

    def axis(self, joint: str) -> AxisProgram:
        for a in self.axes:
            if a.joint == joint:
                return a
        raise KeyError(joint)

    # --- JSON --------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": FORMAT, "version": VERSION, "cell": self.cell, "axes": []}
        for a in self.axes:
            entry: dict[str, Any] = {
                "name": a.joint,
                "node_id": a.node_id,
                "profile": a.profile,
                "qc_per_motor_rev": a.scaling.qc_per_motor_rev,
                "motor_rev_per_joint_unit": a.scaling.motor_rev_per_joint_unit,
                "velocity_unit_rpm": a.scaling.velocity_unit_rpm,
                "limits": a.limits.to_json(),
                "records": a.records.tolist(),
            }
            if a.interpolation_submode is not None:
                entry["interpolation_submode"] = a.interpolation_submode
            out["axes"].append(entry)
        if self.metadata:
            out["metadata"] = dict(self.metadata)
        return out

    def dumps(self, indent: int | None = None) -> str:
        if indent is None:
            return json.dumps(self.to_json(), separators=(",", ":"))
        # records one per line: readable and diffable
        text = json.dumps(self.to_json(), indent=indent)
        return _RECORD_LINE.sub(r"[\1, \2, \3]", text)

    @classmethod
    def loads(cls, text: str | bytes, *, check_ranges: bool = True) -> PvtProgram:
        try:
            data = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ProgramFormatError("", f"not JSON: {exc}") from None
        return cls.from_json(data, check_ranges=check_ranges)

    @classmethod
    def from_json(cls, data: Any, *, check_ranges: bool = True) -> PvtProgram:
        """Parse and check the structure (types and ranges of every field); see validate for the rest.

        With ``check_ranges=False`` record values only have to be integers: the offline validator
        reads a program that way so that an out-of-range record is reported as a finding (which
        axis, which record, by how much) instead of refusing the whole file.
        """
        if not isinstance(data, dict):
            raise ProgramFormatError("", "not a PVT program: the top level must be a JSON object")
        if data.get("format") != FORMAT:
            raise ProgramFormatError(
                "format", f"not a PVT program: expected format {FORMAT!r}, got {data.get('format')!r}"
            )
        if data.get("version") != VERSION:
            raise ProgramFormatError(
                "version", f"unsupported version {data.get('version')!r} (this pvtflow reads {VERSION})"
            )
        cell = data.get("cell", "")
        if not isinstance(cell, str):
            raise ProgramFormatError("cell", "must be a string")
        axes_data = data.get("axes")
        if not isinstance(axes_data, list) or not axes_data:
            raise ProgramFormatError("axes", "must be a non-empty list")
        axes = tuple(_axis_from_json(f"axes[{i}]", a, check_ranges) for i, a in enumerate(axes_data))
        _unique(axes, "joint", "name")
        _unique(axes, "node_id")
        metadata = data.get("metadata", {})
        if not isinstance(metadata, dict):
            raise ProgramFormatError("metadata", "must be an object")
        return cls(cell=cell, axes=axes, metadata=metadata)


def _unique(axes: Sequence[AxisProgram], attr: str, key: str | None = None) -> None:
    key = key or attr  # the file's name of the field
    seen: dict[Any, int] = {}
    for i, a in enumerate(axes):
        value = getattr(a, attr)
        if value in seen:
            raise ProgramFormatError(f"axes[{i}].{key}", f"duplicate {key} {value!r} (also axes[{seen[value]}])")
        seen[value] = i


def _number(where: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ProgramFormatError(where, f"must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ProgramFormatError(where, f"must be positive, got {value!r}")
    return float(value)


def _integer(where: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProgramFormatError(where, f"must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise ProgramFormatError(where, f"{value} is outside [{lo}, {hi}]")
    return value


def _axis_from_json(where: str, a: Any, check_ranges: bool = True) -> AxisProgram:
    if not isinstance(a, dict):
        raise ProgramFormatError(where, "must be an object")
    for key in ("name", "node_id", "profile", "qc_per_motor_rev", "motor_rev_per_joint_unit", "limits", "records"):
        if key not in a:
            raise ProgramFormatError(f"{where}.{key}", "missing")
    name = a["name"]
    if not isinstance(name, str) or not name:
        raise ProgramFormatError(f"{where}.name", "must be a non-empty string")
    node_id = _integer(f"{where}.node_id", a["node_id"], 1, 127)
    try:
        profile = DriveProfile.parse(a["profile"])
    except ValueError as exc:
        raise ProgramFormatError(f"{where}.profile", str(exc)) from None
    qc_per_rev = _number(f"{where}.qc_per_motor_rev", a["qc_per_motor_rev"], positive=True)
    rev_per_unit = _number(f"{where}.motor_rev_per_joint_unit", a["motor_rev_per_joint_unit"])
    if rev_per_unit == 0:
        raise ProgramFormatError(f"{where}.motor_rev_per_joint_unit", "must not be zero")
    vel_unit = _number(f"{where}.velocity_unit_rpm", a.get("velocity_unit_rpm", 1.0), positive=True)
    scaling = AxisScaling(qc_per_rev, rev_per_unit, vel_unit)

    lim = a["limits"]
    lw = f"{where}.limits"
    if not isinstance(lim, dict):
        raise ProgramFormatError(lw, "must be an object")
    for key in ("max_profile_velocity_rpm", "max_acceleration_rpm_s", "min_position_qc", "max_position_qc"):
        if key not in lim:
            raise ProgramFormatError(f"{lw}.{key}", "missing")
    optional = {
        k: _number(f"{lw}.{k}", lim[k], positive=True)
        for k in ("profile_velocity_rpm", "profile_acceleration_rpm_s")
        if lim.get(k) is not None
    }
    lo = _integer(f"{lw}.min_position_qc", lim["min_position_qc"], INT32_MIN, INT32_MAX)
    hi = _integer(f"{lw}.max_position_qc", lim["max_position_qc"], INT32_MIN, INT32_MAX)
    if lo >= hi:
        raise ProgramFormatError(lw, f"min_position_qc {lo} must be below max_position_qc {hi}")
    limits = DriveLimits(
        max_profile_velocity_rpm=_number(
            f"{lw}.max_profile_velocity_rpm", lim["max_profile_velocity_rpm"], positive=True
        ),
        max_acceleration_rpm_s=_number(f"{lw}.max_acceleration_rpm_s", lim["max_acceleration_rpm_s"], positive=True),
        min_position_qc=lo,
        max_position_qc=hi,
        **optional,
    )

    submode = a.get("interpolation_submode")
    if submode is not None:
        if not profile.has_submodes:
            raise ProgramFormatError(f"{where}.interpolation_submode", f"the {profile} profile has no submodes")
        _integer(f"{where}.interpolation_submode", submode, min(profile.spec.submodes), max(profile.spec.submodes))

    records = a["records"]
    rw = f"{where}.records"
    if not isinstance(records, list) or len(records) < 2:
        raise ProgramFormatError(rw, "must be a list of at least 2 records [position_qc, velocity, time_ms]")
    out = np.empty((len(records), 3), dtype=np.int64)
    # without range checks a value only has to fit the int64 array (the validator reports ranges)
    wide = (-(2**62), 2**62)
    strict = ((INT32_MIN, INT32_MAX), (INT24_MIN, INT24_MAX), (0, TIME_MAX_MS))
    ranges = strict if check_ranges else (wide,) * 3
    for k, rec in enumerate(records):
        if not isinstance(rec, list) or len(rec) != 3:
            raise ProgramFormatError(f"{rw}[{k}]", f"must be [position_qc, velocity, time_ms], got {rec!r}")
        for j, what in enumerate(("position", "velocity", "time")):
            out[k, j] = _integer(f"{rw}[{k}] {what}", rec[j], *ranges[j])
    return AxisProgram(name, node_id, profile, scaling, limits, None, submode, records=out)


def joined(programs: Sequence[PvtProgram], metadata: Mapping[str, Any] | None = None) -> PvtProgram:
    """The programs one after the other on one time line, as one program: each one's first record
    follows the last record of the one before (they meet at rest where it ends), and a time-0 end record
    (the EPOS2's: interpolation ends there) goes out only after the last. ``metadata``: the joined
    program's (None: the first's)."""
    first = programs[0]
    axes = []
    for i, axis in enumerate(first.axes):
        parts = [p.axes[i].records for p in programs]
        parts[:-1] = [r[:-1] if r[-1, 2] == 0 else r for r in parts[:-1]]
        axes.append(AxisProgram.of(axis, np.concatenate(parts)))
    return PvtProgram(first.cell, tuple(axes), dict(first.metadata if metadata is None else metadata))


def axes_of(program: PvtProgram) -> tuple[AxisConfig, ...]:
    """The axis settings a program was made for (node, profile, scaling, limits, period): what a
    user of the axes layer without a cell file gives the bus and the group."""
    return tuple(AxisConfig(**{f.name: getattr(a, f.name) for f in fields(DriveAxis)}) for a in program.axes)


def _shown(value: float | int | None) -> str:
    return "unset" if value is None else f"{value:g}"


def program_mismatch(program: PvtProgram, axes: Sequence[AxisConfig], cell_name: str) -> list[str]:
    """Why ``program`` was not made for the cell whose axes are ``axes`` (empty: it was): the one
    check of a program against a cell, for the group's start, ``pvtflow execute`` and the service."""
    problems: list[str] = []
    by_node = {a.node_id: a for a in program.axes}
    for axis in axes:
        a = by_node.pop(axis.node_id, None)
        if a is None:
            problems.append(f"the program has no axis for node {axis.node_id} ({axis.joint})")
            continue
        where = f"axis {a.joint} (node {a.node_id})"
        if a.joint != axis.joint:
            problems.append(f"{where}: node {axis.node_id} is joint {axis.joint} in cell {cell_name}")
        if a.profile != axis.profile:
            problems.append(f"{where}: profile {a.profile}, the cell's drive runs {axis.profile}")
            continue
        if a.profile.submode(a.interpolation_submode) != a.profile.submode(axis.interpolation_submode):
            problems.append(
                f"{where}: interpolation submode {a.interpolation_submode}, "
                f"the cell's drive uses {axis.interpolation_submode}"
            )
        planned, cell_has = a.limits.to_json(), axis.limits.to_json()
        for name in sorted(planned.keys() | cell_has.keys()):  # one line per differing limit object
            if planned.get(name) != cell_has.get(name):
                problems.append(
                    f"{where}: limits.{name} {_shown(planned.get(name))} in the program, "
                    f"{_shown(cell_has.get(name))} in cell {cell_name}"
                )
        for name in ("qc_per_motor_rev", "motor_rev_per_joint_unit", "velocity_unit_rpm"):
            mine, theirs = getattr(a.scaling, name), getattr(axis.scaling, name)
            if not math.isclose(mine, theirs, rel_tol=1e-6):
                problems.append(f"{where}: {name} {mine:g}, the cell has {theirs:g}")
        if axis.period_ms is not None and not (a.records[:, 2] == axis.period_ms).all():
            problems.append(f"{where}: every record time must be the axis period {axis.period_ms} ms")
        lo, hi = axis.limits.min_position_qc, axis.limits.max_position_qc
        if a.records[:, 0].min() < lo or a.records[:, 0].max() > hi:
            problems.append(f"{where}: a record position is outside 0x607D [{lo}, {hi}] qc")
    for a in by_node.values():
        problems.append(f"axis {a.joint}: node {a.node_id} is not in cell {cell_name}")
    return problems


def split_long_records(program: AxisProgram, max_ms: int) -> NDArray[np.int64]:
    """An EPOS2 axis's records with every segment longer than ``max_ms`` cut into equal whole-ms parts on
    its own cubic (positions and velocities rounded), so that the FIFO can be held within the look-ahead
    bound (a held record is what a change cannot take back; a time-optimal program cruises in segments of
    hundreds of ms). A segment whose parts' reconstruction would leave 0x607F or 0x60C5 (the rounding) is
    kept whole. The motion is the program's to a count: the program itself is unchanged."""
    r = np.asarray(program.records, dtype=np.int64)
    if len(r) < 2 or int(r[1:, 2].max()) <= max_ms:
        return r
    sc, lim = program.scaling, program.limits
    f = sc.qc_per_ms_per_velocity_unit
    amax = float(sc.rpm_s_to_qc_per_ms2(lim.max_acceleration_rpm_s))
    vmax = float(sc.rpm_to_qc_per_ms(lim.max_profile_velocity_rpm))
    out = [r[0]]
    for k in range(1, len(r)):
        T = int(r[k, 2])
        if max_ms >= T:
            out.append(r[k])
            continue
        c0, c1, c2, c3 = interpolation.hermite(
            float(r[k - 1, 0]), float(r[k - 1, 1]) * f, float(r[k, 0]), float(r[k, 1]) * f, T
        )
        n = math.ceil(T / max_ms)
        cuts = [round(T * i / n) for i in range(1, n)]
        parts, prev_p, prev_v, prev_t = [], int(r[k - 1, 0]), int(r[k - 1, 1]), 0
        for t in [*cuts, T]:
            if t == T:
                p, v = int(r[k, 0]), int(r[k, 1])
            else:
                p = round(c0 + t * (c1 + t * (c2 + t * c3)))
                v = round((c1 + t * (2.0 * c2 + 3.0 * c3 * t)) / f)
            d = t - prev_t
            _, b, cc, dd = interpolation.hermite(float(prev_p), prev_v * f, float(p), v * f, float(d))
            peak_a = interpolation.cubic_peak_acceleration(cc, dd, d)
            peak_v = interpolation.cubic_peak_speed(b, cc, dd, d)
            if interpolation.exceeds(peak_a, amax) or interpolation.exceeds(peak_v, vmax):
                parts = [r[k]]
                break
            parts.append(np.array([p, v, d], dtype=np.int64))
            prev_p, prev_v, prev_t = p, v, t
        out.extend(parts)
    return np.asarray(out, dtype=np.int64)
