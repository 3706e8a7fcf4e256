"""The PVT program's JSON form (DESIGN.md section 4) and the EPOS2 record packing of its records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pvtflow.axes.drive.objects import Record
from pvtflow.axes.drive.program import FORMAT, ProgramFormatError, PvtProgram

DESIGN_EXAMPLE = {
    "format": "pvtflow.pvt-program",
    "version": 1,
    "cell": "demo",
    "axes": [
        {
            "name": "joint_1",
            "node_id": 1,
            "profile": "epos2_pvt",
            "qc_per_motor_rev": 2048,
            "motor_rev_per_joint_unit": 15.915494,
            "velocity_unit_rpm": 1.0,
            "limits": {
                "max_profile_velocity_rpm": 8000,
                "max_acceleration_rpm_s": 40000,
                "min_position_qc": -2000000,
                "max_position_qc": 2000000,
            },
            "records": [[0, 0, 1], [1520, 412, 37], [5230, 1177, 52], [9000, 0, 40], [9000, 0, 0]],
        }
    ],
}


def test_design_example_round_trips() -> None:
    p = PvtProgram.from_json(DESIGN_EXAMPLE)
    assert p.cell == "demo" and p.axis("joint_1").records.dtype == np.int64
    assert p.duration_ms == 1 + 37 + 52 + 40
    again = PvtProgram.loads(p.dumps())
    assert again.to_json() == p.to_json()
    assert json.loads(p.dumps(indent=1))["format"] == FORMAT


@pytest.mark.parametrize(
    ("mutate", "where"),
    [
        (lambda d: d.update(format="something-else"), "format"),
        (lambda d: d.update(version=2), "version"),
        (lambda d: d.update(axes=[]), "axes"),
        (lambda d: d["axes"][0].pop("records"), "axes[0].records"),
        (lambda d: d["axes"][0].update(profile="epos4"), "axes[0].profile"),
        (lambda d: d["axes"][0].update(node_id=128), "axes[0].node_id"),
        (lambda d: d["axes"][0]["records"].__setitem__(2, [1, 2]), "axes[0].records[2]"),
        (lambda d: d["axes"][0]["records"].__setitem__(2, [1.5, 2, 3]), "axes[0].records[2] position"),
        (lambda d: d["axes"][0]["limits"].update(min_position_qc=5, max_position_qc=5), "axes[0].limits"),
        (lambda d: d["axes"].append(dict(d["axes"][0])), "axes[1].name"),
    ],
)
def test_format_errors_name_the_place(mutate, where: str) -> None:
    data = json.loads(json.dumps(DESIGN_EXAMPLE))
    mutate(data)
    with pytest.raises(ProgramFormatError) as err:
        PvtProgram.from_json(data)
    assert err.value.where == where


def test_not_json_and_not_a_program() -> None:
    with pytest.raises(ProgramFormatError, match="not JSON"):
        PvtProgram.loads("{nope")
    with pytest.raises(ProgramFormatError, match="not a PVT program"):
        PvtProgram.loads("[1, 2, 3]")
    with pytest.raises(ProgramFormatError, match="not a PVT program"):
        PvtProgram.loads('{"waypoints": [[0, 0]]}')


@pytest.mark.parametrize(
    ("position", "velocity", "time"),
    [(0, 0, 0), (1520, 412, 37), (-5230, -1177, 255), (2**31 - 1, 2**23 - 1, 1), (-(2**31), -(2**23), 200)],
)
def test_record_packing_round_trip(position: int, velocity: int, time: int) -> None:
    rec = Record(position, velocity, time)
    value = rec.pack()
    assert value >> 56 == time
    assert value & 0xFFFFFFFF == position & 0xFFFFFFFF
    assert (value >> 32) & 0xFFFFFF == velocity & 0xFFFFFF
    assert Record.unpack(value) == rec
    assert Record.from_bytes(rec.to_bytes()) == rec
    assert rec.to_bytes() == value.to_bytes(8, "little")


def test_record_packing_by_hand() -> None:
    # time 37 = 0x25, velocity -2 = 0xFFFFFE (s24), position -1 = 0xFFFFFFFF (s32)
    assert Record(-1, -2, 37).pack() == 0x25FFFFFE_FFFFFFFF
    assert Record(1520, 412, 37).to_bytes() == bytes([0xF0, 0x05, 0, 0, 0x9C, 0x01, 0, 0x25])


@pytest.mark.parametrize(
    ("position", "velocity", "time", "what"), [(2**31, 0, 1, "int32"), (0, 2**23, 1, "int24"), (0, 0, 256, "0..255")]
)
def test_record_packing_refuses_out_of_range(position: int, velocity: int, time: int, what: str) -> None:
    with pytest.raises(ValueError, match=what):
        Record(position, velocity, time).pack()


def test_every_record_of_a_program_packs() -> None:
    p = PvtProgram.from_json(DESIGN_EXAMPLE)
    for a in p.axes:
        for r in a.records:
            assert Record.unpack(Record(*map(int, r)).pack()) == Record(*map(int, r))
