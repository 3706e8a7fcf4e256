"""A simwire server in a child process, for the tests of the loopback wire (client and server in
two interpreters, as ``pvtflow sim`` and a master run them)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


@contextlib.contextmanager
def wire_in_a_child(clock: str, bitrate: int, sync_period: float) -> Iterator[tuple[str, subprocess.Popen[str]]]:
    """The server's channel string (``cell@127.0.0.1:port``) and its process; closed on exit (a child
    a test stopped with SIGSTOP is continued first)."""
    code = (
        "import sys\n"
        "from pvtflow.axes.sim.wire import serve_wire\n"
        f"s = serve_wire('cell', 0, clock={clock!r}, bitrate={bitrate}, sync_period={sync_period})\n"
        "print(s.address, flush=True)\n"
        "sys.stdin.read()\n"
        "s.close()\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    child = subprocess.Popen(
        [sys.executable, "-c", code], cwd=REPO, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None and child.stdin is not None
        yield child.stdout.readline().strip(), child
    finally:
        os.kill(child.pid, signal.SIGCONT)
        assert child.stdin is not None
        child.stdin.close()
        child.wait(timeout=10)
