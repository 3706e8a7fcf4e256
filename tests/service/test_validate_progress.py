"""``pvtflow validate FOLDER``: the progress bar is drawn on a terminal only; piped or redirected, stderr
carries the messages and no carriage returns (a log file or CI output stays clean)."""

from __future__ import annotations

import os
import select
import subprocess
import sys
from pathlib import Path

from test_doc_program import documented

from pvtflow.axes.drive.program import PvtProgram
from pvtflow.service.validate_cmd import Progress

ROOT = Path(__file__).resolve().parents[2]


def folder_of_programs(tmp_path: Path) -> Path:
    """Three valid programs (the documented example) and one file that is not one (its message goes to stderr)."""
    _, program = documented()
    folder = tmp_path / "programs"
    folder.mkdir()
    for i in range(3):
        (folder / f"p{i}.json").write_text(program.dumps(indent=1), encoding="utf-8")
    (folder / "zz_junk.json").write_text("[]", encoding="utf-8")
    assert PvtProgram.loads((folder / "p0.json").read_text())
    return folder


def test_validate_of_a_folder_writes_no_progress_bar_into_a_pipe(tmp_path: Path) -> None:
    folder = folder_of_programs(tmp_path)
    done = subprocess.run(
        [sys.executable, "-m", "pvtflow.service.cli", "validate", str(folder)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr  # the junk file: unreadable
    assert "\r" not in done.stderr and "[###" not in done.stderr, repr(done.stderr)
    assert done.stderr.strip().splitlines() == [
        f"pvtflow validate: {folder / 'zz_junk.json'}: cannot read a PVT program: "
        "not a PVT program: the top level must be a JSON object"
    ]
    assert "4 program(s): 3 valid, 0 with violations, 1 unreadable" in done.stdout


def test_the_progress_bar_is_drawn_on_a_terminal(tmp_path: Path) -> None:
    primary, secondary = os.openpty()
    try:
        with open(secondary, "w", closefd=False) as terminal:
            bar = Progress(3, terminal)
            assert bar.enabled
            bar.update(1, "a.json")
            bar.close()
        drawn = ""
        while not drawn.endswith("\r") or drawn.count("\r") < 2:  # the terminal may hand it over in pieces
            ready, _, _ = select.select([primary], [], [], 5.0)
            assert ready, f"the bar stopped at {drawn!r}"
            drawn += os.read(primary, 4096).decode()
        assert drawn.startswith("\r[##########....................] 1/3 a.json") and drawn.endswith("\r")
    finally:
        os.close(primary)
        os.close(secondary)
    with open(tmp_path / "stderr.txt", "w") as file:
        assert not Progress(3, file).enabled
