"""MCAP recordings (service/recording): every channel read back with the mcap library, a file cut by
kill -9 mid-motion read up to its last chunk, ``pvtflow report`` on a recording, the service's
one file per motion named in its journal."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from axes_programs import program
from mcap.reader import make_reader

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.drive.program import PvtProgram
from pvtflow.service.api import ExecuteRequest
from pvtflow.service.cli import main
from pvtflow.service.motion import MotionService
from pvtflow.service.recording import read_recording
from pvtflow.service.recording.writer import CHUNK_WALL_S

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, arm6) -> tuple[Path, PvtProgram]:
    tmp = tmp_path_factory.mktemp("rec")
    prog = program(arm6.ordered_axes(), 400, spacing_ms=10, cell="arm6")
    path = tmp / "program.json"
    path.write_text(prog.dumps())
    out = tmp / "run.mcap"
    assert main(["execute", str(path), "--quiet", "--record", str(out)]) == 0
    return out, prog


def mcap_messages(path: Path) -> dict[str, list[tuple[str, int, dict]]]:
    """Every message by topic, through the mcap library's own reader (schema name, log time, JSON)."""
    by_topic: dict[str, list[tuple[str, int, dict]]] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            json.loads(schema.data)  # every schema is JSON schema
            by_topic.setdefault(channel.topic, []).append((schema.name, message.log_time, json.loads(message.data)))
    return by_topic


def test_every_channel_reads_back_with_the_mcap_reader(recorded, arm6):
    path, prog = recorded
    topics = mcap_messages(path)
    joints = [a.joint for a in arm6.ordered_axes()]
    expected = {"/can", "/sync", "/buffers", "/joint_states", "/tf", "/events"}
    expected |= {f"/axis/{j}/planned" for j in joints} | {f"/axis/{j}/actual" for j in joints}
    assert expected <= set(topics)
    # the plan as the drive executes it: its reconstruction every ms, in counts
    for axis, joint in zip(prog.axes, joints, strict=True):
        planned = topics[f"/axis/{joint}/planned"]
        assert len(planned) == prog.duration_ms + 1
        cubic = axis.reconstruction()
        t = np.array([m[2]["t_ms"] for m in planned])
        assert np.allclose([m[2]["position_qc"] for m in planned], cubic.position(t))
        assert planned[-1][2]["position_qc"] == pytest.approx(axis.records[-1, 0])
        # actual per SYNC: planned minus actual during the run; the simulated drive follows within a count
        actual = [m[2] for m in topics[f"/axis/{joint}/actual"]]
        errors = [s["following_error_qc"] for s in actual if s["following_error_qc"] is not None]
        assert len(errors) >= prog.duration_ms / arm6.bus.sync_period_ms
        assert max(abs(e) for e in errors) <= 2.0
        assert actual[-1]["position_qc"] == axis.records[-1, 0]
        assert actual[-1]["state"] == "OPERATION ENABLED"
    assert {m[0] for m in topics["/events"]} == {"foxglove.Log"}
    assert any(m[2]["name"] == "finished" for m in topics["/events"])
    assert {m[0] for m in topics["/tf"]} == {"foxglove.FrameTransforms"}
    frames = {t["child_frame_id"] for t in topics["/tf"][-1][2]["transforms"]}
    assert {"base_link", "link_1"} <= frames
    # the SYNCs on the bus clock: one /sync message per SYNC frame, intervals of about a period
    syncs = topics["/sync"]
    assert len(syncs) == sum(1 for m in topics["/can"] if m[2]["id"] == 0x80)
    intervals = [m[2]["interval_ms"] for m in syncs[1:]]
    assert np.median(intervals) == pytest.approx(arm6.bus.sync_period_ms, rel=0.2)
    levels = [m[2]["levels"] for m in topics["/buffers"]]
    assert max(max(lv) for lv in levels) > 0
    # every record of every axis went out, as a frame on its RPDO
    assert sum(1 for m in topics["/can"] if m[2]["id"] == 0x200 + prog.axes[0].node_id and not m[2]["rx"]) >= len(
        prog.axes[0].records
    )
    rec = read_recording(path)
    assert rec.complete
    assert rec.attachments["robot.urdf"] == arm6.urdf.read_bytes()
    assert json.loads(rec.metadata["outcome"]["json"])["result"] == "finished"
    assert rec.metadata["pvtflow"]["cell"] == "arm6"


def test_report_on_a_recording(recorded, tmp_path, capsys):
    path, _ = recorded
    png = tmp_path / "run.png"
    assert main(["report", str(path), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "motion on cell arm6" in out and "complete, result finished" in out
    assert "joint_1: worst following error" in out and "faults: 0" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["report", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["result"] == "finished" and report["complete"] is True
    assert all(abs(a["worst_following_error_qc"]) <= 2.0 for a in report["axes"].values())
    assert report["sync"]["count"] > 0 and report["sync"]["jitter_p99_ms"] >= 0.0


@pytest.mark.parametrize("content", [None, b"not an mcap file at all"])
def test_report_on_no_recording_is_one_line(tmp_path, capsys, content):
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    assert main(["report", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pvtflow report: ")


def test_record_refuses_a_file_that_is_not_mcap_before_anything(tmp_path, capsys):
    assert main(["execute", str(tmp_path / "p.json"), "--record", str(tmp_path / "run.txt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"pvtflow execute: --record {tmp_path / 'run.txt'}: the recording is an MCAP file: name it FILE.mcap"
    ]


@pytest.mark.wall
def test_a_recording_cut_by_kill_9_reads_up_to_its_last_chunk(tmp_path, arm6):
    prog = program(arm6.ordered_axes(), 10000, spacing_ms=10, cell="arm6")
    path = tmp_path / "program.json"
    path.write_text(prog.dumps())
    out = tmp_path / "cut.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen(
        [sys.executable, "-m", "pvtflow.service.cli", "execute", str(path), "--record", str(out)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert child.stdout is not None
        for line in child.stdout:  # progress lines: "t=   1.200 s  SYNC ..." (bus time, lockstep)
            if line.startswith("t=") and float(line[2:].split()[0]) >= 1.2:
                break
        time.sleep(4 * CHUNK_WALL_S)  # the chunks of that second closed, the motion still running
        assert child.poll() is None
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.wait(10)
    rec = read_recording(out)
    assert not rec.complete
    assert {"/can", "/sync", "/axis/joint_1/planned", "/axis/joint_1/actual", "/buffers"} <= rec.topics
    elapsed = max(m.data["elapsed_ms"] or 0.0 for m in rec.topic("/axis/joint_1/actual"))
    assert 1200.0 <= elapsed < prog.duration_ms
    planned = max(m.data["t_ms"] for m in rec.topic("/axis/joint_1/planned"))
    assert elapsed <= planned < prog.duration_ms  # the plan ahead of the run, never behind it
    assert rec.attachments["robot.urdf"] == arm6.urdf.read_bytes()
    assert main(["report", str(out)]) == 0


def test_the_service_records_one_file_per_motion_named_in_its_journal(tmp_path, arm6):
    cell = dataclasses.replace(arm6, bus=dataclasses.replace(arm6.bus, channel=f"rec-{uuid.uuid4().hex[:10]}"))
    prog = program(cell.ordered_axes(), 200, spacing_ms=10, cell="arm6")
    ends = [int(a.records[-1, 0]) for a in prog.axes]
    back = program(cell.ordered_axes(), 200, spacing_ms=10, cell="arm6", starts=ends, sign=-1)
    with MotionService(
        cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, record_dir=tmp_path / "rec"
    ) as svc:
        ids = []
        for p in (prog, back):
            reply = svc.execute(ExecuteRequest(program=p.to_json(), wait=True))
            ids.append(reply["motion_id"])
            time.sleep(1.5)  # the idle bus's clock follows the wall clock: the next file starts at its own motion
        entries = [svc.journal_entry(i) for i in ids]
    for motion_id, entry in zip(ids, entries, strict=True):
        assert entry is not None and entry.recording == str(tmp_path / "rec" / f"{motion_id}.mcap")
        rec = read_recording(entry.recording)
        assert rec.complete and json.loads(rec.metadata["outcome"]["json"])["result"] == "finished"
        assert rec.topic("/axis/joint_1/planned")
        # the robot's description on a topic too, at the motion's bus time: the file spans its motion only
        (description,) = rec.topic("/robot_description")
        assert description.schema == "std_msgs/msg/String" and "<robot" in description.data["data"]
        times = [m.log_time_ns for m in rec.messages]
        assert (max(times) - min(times)) / 1e9 < 1.0  # a 200 ms motion, its start checks and its end


def test_a_fault_is_recorded_and_reported(tmp_path, arm6, capsys):
    cell = dataclasses.replace(arm6, bus=dataclasses.replace(arm6.bus, channel=f"rec-{uuid.uuid4().hex[:10]}"))
    prog = program(cell.ordered_axes(), 2000, spacing_ms=10, cell="arm6")
    with MotionService(
        cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, record_dir=tmp_path / "rec"
    ) as svc:
        reply = svc.execute(ExecuteRequest(program=prog.to_json()))
        deadline = time.monotonic() + 20.0
        while (svc.group.elapsed_syncs() or 0) < 40 and time.monotonic() < deadline:
            time.sleep(0.01)
        svc.sim.drive("joint_3").inject_emcy(0x7320)  # position sensor error: EMCY and fault
        svc.motion.done.wait(20.0)
        entry = svc.journal_entry(reply["motion_id"])
    assert entry is not None and entry.outcome["result"] == "emcy"
    rec = read_recording(entry.recording)
    faults = rec.topic("/faults")
    assert any(f.data["code"] == 0x7320 and f.data["joint"] == "joint_3" for f in faults)
    errors = [m.data for m in rec.topic("/events") if m.data["level"] == 4]
    assert any("0x7320" in e["message"] for e in errors)
    assert any(e["name"].startswith("emcy") for e in errors)
    assert any(f.data["id"] == 0x80 + 3 and f.data["rx"] for f in rec.topic("/can"))  # the EMCY frame itself
    assert main(["report", entry.recording, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["result"] == "emcy"
    assert any(f["code"] == 0x7320 for f in report["faults"])


def test_the_service_records_a_homing_named_in_its_journal(tmp_path):
    from pvtflow.service.api import HomeRequest
    from pvtflow.service.config import CONFIG_DIR, load_cell_config

    gantry = load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml")
    cell = dataclasses.replace(gantry, bus=dataclasses.replace(gantry.bus, channel=f"rec-{uuid.uuid4().hex[:10]}"))
    with MotionService(
        cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, record_dir=tmp_path / "rec"
    ) as svc:
        reply = svc.home(HomeRequest(wait=True))
        entry = svc.journal.homing(reply["homing_id"])
    assert reply["outcome"]["result"] == "homed"
    assert entry is not None and entry.recording == str(tmp_path / "rec" / f"{reply['homing_id']}.mcap")
    rec = read_recording(entry.recording)
    assert rec.complete and rec.metadata["pvtflow"]["kind"] == "homing"
    assert [m.data["name"] for m in rec.topic("/events")].count("homed") == len(cell.homing_stages())
    z = [m.data for m in rec.topic("/axis/z/actual")]
    assert z[-1]["position_qc"] == cell.axis_for_joint("z").homing.offset_qc


def test_following_error_is_taken_at_the_sync_a_status_belongs_to(tmp_path, arm6):
    """Status TPDOs every third SYNC: the position a drive answered stands for the SYNC it answered, so
    the recorded following error is the plan at that SYNC minus that position, not the plan at a later
    SYNC the same old position is still the latest on."""
    every = 3
    bus = dataclasses.replace(arm6.bus, channel=f"rec-{uuid.uuid4().hex[:10]}", status_every_syncs=every)
    cell = dataclasses.replace(arm6, bus=bus)
    prog = program(cell.ordered_axes(), 300, spacing_ms=10, cell="arm6")
    with MotionService(
        cell, journal_dir=tmp_path / "journal", clock=Clock.LOCKSTEP, record_dir=tmp_path / "rec"
    ) as svc:
        reply = svc.execute(ExecuteRequest(program=prog.to_json(), wait=True))
        entry = svc.journal_entry(reply["motion_id"])
    assert reply["outcome"]["result"] == "finished"
    rec = read_recording(entry.recording)
    period = cell.bus.sync_period_ms
    for axis, a in zip(prog.axes, cell.ordered_axes(), strict=True):
        cubic = axis.reconstruction()
        run = [m.data for m in rec.topic(f"/axis/{a.joint}/actual") if m.data["following_error_qc"] is not None]
        assert len(run) >= prog.duration_ms / period
        # one status in three SYNCs: most samples carry a status answered one or two SYNCs before theirs
        ages = [s["sync"] - s["status_sync"] for s in run]
        assert set(ages) == set(range(every)), a.joint
        status_ms = np.array([s["elapsed_ms"] - age * period for s, age in zip(run, ages, strict=True)])
        planned = np.array([s["planned_qc"] for s in run])
        actual = np.array([s["position_qc"] for s in run], dtype=float)
        np.testing.assert_allclose(planned, cubic.position(status_ms), atol=1e-6, err_msg=a.joint)
        np.testing.assert_allclose([s["following_error_qc"] for s in run], planned - actual, atol=1e-6)
        # the simulated drive follows its reconstruction within a count at its own SYNC
        assert np.abs(planned - actual).max() <= 2.0, a.joint
