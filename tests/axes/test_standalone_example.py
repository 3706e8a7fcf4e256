"""docs/pvt-program.md's example runs as written: a program file on the simulated drives, with the
axes layer alone (checked in a fresh interpreter: nothing of the planner or the service is loaded)."""

from __future__ import annotations

import re
import subprocess
import sys
import uuid
from pathlib import Path

from axes_programs import program

from pvtflow.service.config import CONFIG_DIR, load_cell_config

DOC = Path(__file__).resolve().parents[2] / "docs" / "pvt-program.md"


def example_code() -> str:
    text = DOC.read_text()
    section = text[text.index("## Running a program without the planner") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_documented_example_runs_a_program_file(tmp_path: Path) -> None:
    cell = load_cell_config(CONFIG_DIR / "cells" / "arm6.yaml")
    file = tmp_path / "program.json"
    file.write_text(program(cell.ordered_axes(), 300).dumps())
    code = example_code().replace('"my-cell"', repr(f"doc-{uuid.uuid4().hex[:8]}"))
    code = f"PROGRAM_FILE = {str(file)!r}\n{code}\nimport sys\n"
    code += "print('LOADED', sorted({m.split('.')[0] for m in sys.modules} & set(sys.argv[1:])))\n"
    out = subprocess.run(
        [sys.executable, "-c", code, "planner", "service", "pinocchio", "toppra", "zenoh"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines()[0].startswith("finished "), out.stdout
    assert out.stdout.splitlines()[-1] == "LOADED []"
