"""A regular install works from anywhere: the wheel built from this clone, installed into a fresh virtualenv, runs
from a directory outside the clone with only what the wheel and its dependencies brought.

The virtualenv has no system site-packages: there the editable install's import finder (``pip install -e``, a
``.pth`` file) would hand out this clone's modules for any the wheel lacks, and the test would pass without the wheel
carrying them. Its dependencies are this interpreter's, on the virtualenv's path as a plain directory (a path line in
a ``.pth`` file: that directory's own ``.pth`` files, the editable finder among them, are not run), and pip installs
the wheel alone: a few seconds, no registry. ``PVTFLOW_INSTALL_FROM_REGISTRY=1`` installs the dependencies from the
package index instead, as a user's ``pip install`` does (half a minute to two here, as the registry answers): for a CI
step of its own, ``pytest -m install``. The first plan compiles the planner's loops, as on any new machine (15 to 60
s, with the machine's load). ``-m "not install"`` leaves the test out.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT_S = 900  # a slow registry, or the first plan's compilation on a loaded machine
NOT_SHIPPED = (
    "tests",
    "bench",
    "docs",
    ".git",
    "build",
    "dist",
    "*.egg-info",
    "__pycache__",
    ".*_cache",
    ".hypothesis",
)

OURS = frozenset({"pvtflow", "axes", "planner", "service"})  # top-level names pvtflow has installed
pytestmark = pytest.mark.install


def run(args: list[str | Path], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S, check=False
    )
    assert done.returncode == 0, f"{' '.join(map(str, args))}: exit {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done


def dependency_paths(cwd: Path, env: dict[str, str]) -> list[str]:
    """This interpreter's import path as a fresh process has it (the folders its ``.pth`` files add too, such as
    Pinocchio's cmeel prefix), less the clone: the folders, not the editable install's finder (a hook, no folder)."""
    out = run([sys.executable, "-c", "import json, sys; print(json.dumps(sys.path))"], cwd, env).stdout
    folders = [Path(p) for p in json.loads(out) if p and Path(p).is_dir()]
    return [str(p) for p in folders if p != ROOT and ROOT not in p.parents]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """The bin folder of a fresh virtualenv with pvtflow's wheel installed, and the environment to run it in."""
    tmp = tmp_path_factory.mktemp("install")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    source = tmp / "source"  # a copy: building in the clone would leave build/ there, and a stale build/ ships
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*NOT_SHIPPED))
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", tmp / "dist", source], tmp, env)
    (wheel,) = (tmp / "dist").glob("pvtflow-*.whl")
    run([sys.executable, "-m", "venv", tmp / "venv"], tmp, env)
    bin_dir = tmp / "venv" / "bin"
    if os.environ.get("PVTFLOW_INSTALL_FROM_REGISTRY"):
        run([bin_dir / "python", "-m", "pip", "install", "-q", wheel], tmp, env)
        return bin_dir, env
    (own,) = (tmp / "venv" / "lib").glob("python*/site-packages")
    (own / "dependencies.pth").write_text("".join(f"{p}\n" for p in dependency_paths(tmp, env)))
    run([bin_dir / "python", "-m", "pip", "install", "-q", "--no-deps", wheel], tmp, env)
    return bin_dir, env


def test_the_wheel_plans_and_validates_from_outside_the_clone(
    installed: tuple[Path, dict[str, str]], tmp_path: Path
) -> None:
    bin_dir, env = installed
    pvtflow = bin_dir / "pvtflow"
    (tmp_path / "arm.json").write_text(
        json.dumps({"waypoints": [[0, 0, 0, 0, 0, 0], [0.5, -0.3, 0.4, 0.2, 0.3, -0.5]]})
    )

    # the defaults: the shipped arm6 cell, its robot and its EDS files, all from the wheel
    run([pvtflow, "plan", "--waypoints", "arm.json", "-o", "arm-program.json"], tmp_path, env)
    checked = run([pvtflow, "validate", "arm-program.json", "--config", "arm6", "--json"], tmp_path, env)
    report = json.loads(checked.stdout)
    assert (report["ok"], report["fits"]) == (True, {"cell": "arm6", "ok": True, "problems": []})

    # where pvtflow's modules and data came from: the wheel in the virtualenv, never the clone
    probe = (
        "import json, sys\nfrom pvtflow.service.cli import main\nfrom pvtflow.axes.sim.drive import EDS_DIR\n"
        "ours = [m for n, m in list(sys.modules.items()) if n.split('.')[0] in OURS]\n"
        "print(json.dumps([str(EDS_DIR), *(m.__file__ or '' for m in ours)]))"
    ).replace("OURS", repr(OURS))
    files = json.loads(run([bin_dir / "python", "-c", probe], tmp_path, env).stdout)
    assert len(files) > 20
    assert [f for f in files if not f.startswith(str(bin_dir.parent))] == []

    # a cell file given by path, its URDF beside it
    cell = tmp_path / "my-cell"
    cell.mkdir()
    shutil.copy(ROOT / "configs" / "robots" / "gantry3.urdf", cell)
    text = (ROOT / "configs" / "cells" / "gantry3.yaml").read_text()
    (cell / "cell.yaml").write_text(text.replace("urdf: ../robots/gantry3.urdf", "urdf: gantry3.urdf"))
    assert "urdf: gantry3.urdf" in (cell / "cell.yaml").read_text()
    (tmp_path / "gantry.json").write_text(json.dumps({"waypoints": [[0.1, 0.1, -0.05], [0.9, 0.6, -0.2]]}))
    run([pvtflow, "plan", "--config", "my-cell/cell.yaml", "--waypoints", "gantry.json", "-o", "g.json"], tmp_path, env)
    fits = run([pvtflow, "validate", "g.json", "--config", "my-cell/cell.yaml"], tmp_path, env)
    assert "g.json: fits cell gantry3" in fits.stdout
