"""The CLI's simulated drives are new in each process (docs/commands.md says so next to pvtflow execute): the
same program runs twice from the command line, while a service, one set of drives for its life,
refuses the second run (start_mismatch)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pvtflow.service.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_each_execute_starts_fresh_drives_and_the_service_keeps_its_own(  # type: ignore[no-untyped-def]
    serve, arm6, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    readme = " ".join((ROOT / "docs" / "commands.md").read_text(encoding="utf-8").split())
    assert "A simulated cell's drives are new in each `pvtflow execute`" in readme
    wp = tmp_path / "wp.json"
    wp.write_text(json.dumps({"waypoints": [[0.0] * 6, [0.2, -0.1, 0.2, -0.1, 0.2, -0.1]]}))
    program = tmp_path / "p.json"
    assert main(["plan", "--waypoints", str(wp), "-o", str(program)]) == 0
    assert main(["execute", str(program), "--quiet"]) == 0
    assert main(["execute", str(program), "--quiet"]) == 0  # new drives at 0 again
    capsys.readouterr()
    served = serve(arm6)
    body = {"program": json.loads(program.read_text()), "wait": True}
    assert served.request("execute", body, timeout=60).ok
    again = served.request("execute", body, timeout=60)
    assert again.error_code == "start_mismatch", again.data
