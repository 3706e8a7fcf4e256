"""``pvtflow serve --port P`` / ``--listen ENDPOINT`` listen where they say, and a second service on a port
in use is refused in one line with the way out, before anything starts (loopback only)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from svc_helpers import free_port

from pvtflow.service.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("how", ["--port", "--listen"])
def test_a_taken_port_is_one_clear_line_and_nothing_starts(
    how: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        value = str(port) if how == "--port" else f"tcp/127.0.0.1:{port}"
        journal = tmp_path / "journal"
        assert main(["serve", how, value, "--journal", str(journal)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"tcp/127.0.0.1:{port} is in use" in err[0] and "--port P or --listen ENDPOINT" in err[0], err
    assert "(" not in err[0].split("in use")[0] and "os error" not in err[0]
    assert not journal.exists()  # nothing started


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--port", "70000"], "--port must be a TCP port 1..65535, got 70000"),
        (["--listen", "127.0.0.1:7447"], "--listen: '127.0.0.1:7447' is not a zenoh endpoint"),
    ],
)
def test_a_bad_listen_option_is_refused(args: list[str], words: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_serve_listens_on_the_port_given_and_a_second_one_is_told_it_is_taken(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "pvtflow.service.cli", "serve", "--port", str(port)]
    first = subprocess.Popen(
        [*cmd, "--journal", str(tmp_path / "a")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    try:
        assert first.stdout is not None
        deadline, banner = time.monotonic() + 120, ""
        while time.monotonic() < deadline and "talk to it" not in banner:
            line = first.stdout.readline()
            if not line:
                break
            banner += line
        assert f"listening on tcp/127.0.0.1:{port}" in banner, banner
        second = subprocess.run(
            [*cmd, "--journal", str(tmp_path / "b")], capture_output=True, text=True, env=env, timeout=120
        )
        assert second.returncode == 2
        assert second.stderr.strip() == (
            f"pvtflow serve: tcp/127.0.0.1:{port} is in use (another pvtflow serve? `pvtflow request status "
            f"--cell '*' --connect tcp/127.0.0.1:{port}` says which cell): give this one another with --port P "
            "or --listen ENDPOINT"
        ), second.stderr
        reply = subprocess.run(
            [*cmd[:3], "request", "status", "--connect", f"tcp/127.0.0.1:{port}"],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
        )
        assert reply.returncode == 0, reply.stderr
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(timeout=60)
