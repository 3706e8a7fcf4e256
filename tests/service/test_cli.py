"""The command line around the service: pvtflow serve (a real process), pvtflow request, pvtflow demo."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from svc_helpers import CONFIGS, free_port

from pvtflow.service.cli import main

ROOT = Path(__file__).resolve().parents[2]


# with the planning process (``--planner-process on``): the default's in-process planner plans in every
# lockstep service test, and ``pvtflow serve`` at its defaults runs in tests/service/test_serve_listen.py
@pytest.mark.parametrize("planner", ["on"])
def test_serve_prints_how_to_talk_to_it_and_request_plans_and_executes(tmp_path, capsys, planner):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    zconfig = tmp_path / "service.json5"
    zconfig.write_text((CONFIGS / "zenoh" / "service.json5").read_text().replace("7447", str(port)))
    channel_cell = tmp_path / "arm6.yaml"  # the demo cell on a CAN channel of its own
    channel_cell.write_text(
        (CONFIGS / "cells" / "arm6.yaml")
        .read_text()
        .replace("channel: pvtflow-arm6", f"channel: cli-{port}")
        .replace("../robots/arm6.urdf", str(CONFIGS / "robots" / "arm6.urdf"))
    )
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pvtflow.service.cli",
            "serve",
            "--config",
            str(channel_cell),
            "--zenoh-config",
            str(zconfig),
            "--journal",
            str(tmp_path / "journal"),
            "--planner-process",
            planner,
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        banner = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            banner.append(line)
            if "Ctrl-C" in line:
                break
        text = "".join(banner)
        assert f"listening on {endpoint}" in text, text + proc.stderr.read()
        assert "pvtflow/arm6/{plan,validate,execute,stop,status,recover,home,pause,resume,override}" in text
        assert "pvtflow/arm6/alive" in text
        # a lockstep simulation plans in the service's process unless told otherwise
        assert ("planner:      in a child process" if planner == "on" else "planner:      in this process") in text
        assert f"pvtflow request status --cell arm6 --connect {endpoint}" in text

        assert main(["request", "status", "--connect", endpoint]) == 0
        status = json.loads(capsys.readouterr().out)
        assert status["state"] == "idle" and status["cell"] == "arm6", status

        assert main(["request", "plan", "--connect", endpoint, "--target", "0.3,-0.2,0.3,-0.2,0.3,-0.2"]) == 0
        plan = json.loads(capsys.readouterr().out)
        assert main(["request", "execute", plan["plan_id"], "--wait", "--connect", endpoint]) == 0
        done = json.loads(capsys.readouterr().out)
        assert done["outcome"]["result"] == "finished"

        waypoints = tmp_path / "wp.json"
        waypoints.write_text(
            json.dumps(
                {
                    "joint_names": [f"joint_{i}" for i in range(6, 0, -1)],
                    "waypoints": [[0.1, 0.2, 0.1, 0.2, 0.1, 0.2], [0.0] * 6],
                }
            )
        )
        request = ["request", "plan", "--connect", endpoint, "--waypoints", str(waypoints), "--start", "current"]
        assert main(request) == 0
        back = json.loads(capsys.readouterr().out)
        assert back["end"] == [0.0] * 6 and back["waypoints"] == 3  # from where the axes are, through both
        assert back["records"]["joint_1"] > 2

        # an error reply: exit 1, the code and message on stderr
        assert main(["request", "execute", "p-0000000000000000", "--connect", endpoint]) == 1
        assert "unknown_plan" in capsys.readouterr().err
        assert main(["request", "status", "--cell", "*", "--connect", endpoint]) == 0
        assert "arm6" in json.loads(capsys.readouterr().out)
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "stopping" in out
    journal = (tmp_path / "journal" / "journal.jsonl").read_text().splitlines()
    assert [json.loads(x)["kind"] for x in journal] == ["motion", "outcome"]


def test_request_without_a_service_and_serve_with_bad_files_fail_clearly(tmp_path, capsys):
    assert main(["request", "status", "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1"]) == 2
    assert "cannot reach the service" in capsys.readouterr().err
    assert main(["serve", "--config", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    assert main(["serve", "--zenoh-config", str(bad)]) == 2
    assert "not a usable zenoh configuration" in capsys.readouterr().err
    assert main(["request", "plan", "--zenoh-config", str(tmp_path / "none.json5")]) == 2
    with socket.socket() as taken:  # the endpoint is in use: a clear refusal, no half-started service
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        zconfig = tmp_path / "taken.json5"
        zconfig.write_text((CONFIGS / "zenoh" / "service.json5").read_text().replace("7447", str(port)))
        cell = tmp_path / "arm6.yaml"
        cell.write_text(
            (CONFIGS / "cells" / "arm6.yaml")
            .read_text()
            .replace("channel: pvtflow-arm6", f"channel: taken-{port}")
            .replace("../robots/arm6.urdf", str(CONFIGS / "robots" / "arm6.urdf"))
        )
        assert (
            main(["serve", "--config", str(cell), "--zenoh-config", str(zconfig), "--journal", str(tmp_path / "j")])
            == 2
        )
        assert f"tcp/127.0.0.1:{port} is in use" in capsys.readouterr().err


def test_demo_plans_and_runs_a_move_through_zenoh_and_writes_a_plot(tmp_path, capsys):
    plot = tmp_path / "demo.png"
    assert main(["demo", "--plot", str(plot), "--journal", str(tmp_path / "j")]) == 0
    out = capsys.readouterr().out
    assert "outcome: finished" in out and "%" in out
    assert "linear move: plan" in out and "outcome finished" in out
    worst_mm = float(out.split("the tool stayed within ")[1].split(" mm")[0])
    assert worst_mm <= 0.1  # the telemetry's positions on the line, by forward kinematics
    assert plot.stat().st_size > 10_000
    assert (tmp_path / "j" / "journal.jsonl").exists()


def test_demo_sequence_runs_the_shipped_pick_and_place_twice_the_second_queued(tmp_path, capsys):
    plot = tmp_path / "seq.png"
    assert main(["demo", "--sequence", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    labels = "0 above pick, 1 pick, 2 retreat from pick, 3 above place, 4 place, 5 retreat from place"
    assert out.count(f"items {labels}; finished") == 2, out
    assert "runs on from it" in out and "0 SYNC periods of standstill" in out
    assert plot.stat().st_size > 10_000
