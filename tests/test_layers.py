"""Layers point one way (service -> planner -> axes), and the axes layer runs without the planner.

Each import check runs in a fresh interpreter: the test process itself has everything loaded.
"""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# What an integrator who brings their own trajectories must not have to install or load. (numba
# itself imports scipy and yaml when they are installed: those are numba's, not the axes'.)
PLANNING_STACK = ("pinocchio", "toppra", "casadi", "zenoh", "matplotlib", "planner", "service")


def layer(module: str) -> str:
    """The layer a module belongs to (pvtflow.axes.master.bus.cell_bus: axes), or its top-level package (numpy)."""
    return module.removeprefix("pvtflow.").split(".")[0]


def imported_packages(path: Path) -> set[str]:
    """Top-level packages a module imports, wherever the import statement is."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(layer(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(layer(node.module))
    return found


@pytest.mark.parametrize(("layer", "above"), [("axes", {"planner", "service"}), ("planner", {"service"})])
def test_no_layer_imports_a_layer_above_it(layer: str, above: set[str]) -> None:
    offenders = {
        str(p.relative_to(ROOT)): sorted(imported_packages(p) & above)
        for p in sorted((ROOT / layer).rglob("*.py"))
        if imported_packages(p) & above
    }
    assert offenders == {}


def loaded_after(code: str) -> list[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_axes_layer_loads_without_the_planning_stack() -> None:
    modules = loaded_after(
        "import pvtflow.axes, pvtflow.axes.master.group.axis_group, pvtflow.axes.master.bus.cell_bus, "
        "pvtflow.axes.master.group.feeder, pvtflow.axes.drive.program, pvtflow.axes.master.profiles, "
        "pvtflow.axes.sim, pvtflow.axes.sim.cell"
    )
    top = {layer(m) for m in modules}
    assert sorted(top & set(PLANNING_STACK)) == []
    assert {"canopen", "can", "numpy"} <= top


def test_validating_a_program_needs_no_robot_model(tmp_path: Path) -> None:
    from hand_programs import GOOD_RECORDS, axis, program

    file = tmp_path / "p.json"
    file.write_text(program(axis(GOOD_RECORDS)).dumps())
    modules = loaded_after(
        "from pvtflow.service.cli import main\n"
        "import contextlib, io\n"
        f"with contextlib.redirect_stdout(io.StringIO()):\n    main(['validate', {str(file)!r}])"
    )
    top = {layer(m) for m in modules}
    assert sorted(top & {"pinocchio", "toppra", "casadi", "zenoh", "matplotlib"}) == []


@pytest.mark.parametrize("package", ["axes", "planner", "service"])
def test_each_package_front_door_names_what_it_exports(package: str) -> None:
    """``from pvtflow.axes import AxisGroup`` and the like: every name in ``__all__`` resolves."""
    module = importlib.import_module(f"pvtflow.{package}")
    assert module.__all__, f"{package} has no public surface"
    for name in module.__all__:
        assert getattr(module, name) is not None, name
