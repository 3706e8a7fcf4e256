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


# --- the rooms of axes: the facts, the master, the simulator -------------------------------------
AXES = ROOT / "axes"
FACTS = ("drive", "canbus")  # and the package's front door (axes/__init__.py, axes/front_door.py)
MAX_FLAT_MODULES = 10


def axes_module(path: Path) -> str:
    """pvtflow.axes.master.bus.sync for axes/master/bus/sync.py (a package: its __init__'s name)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return "pvtflow." + ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def axes_imports() -> dict[str, set[str]]:
    """Every axes module and the axes modules it imports, wherever the import statement is (under
    TYPE_CHECKING, in a function); ``from package import module`` imports that module."""
    paths = {axes_module(p): p for p in sorted(AXES.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                submodules = {f"{node.module}.{a.name}" for a in node.names} & paths.keys()
                found.update(submodules or {node.module})
        graph[name] = {m for m in found if m in paths and m != name}
    return graph


def room(module: str) -> str:
    """facts, master or sim."""
    part = module.removeprefix("pvtflow.axes").lstrip(".").split(".")[0]
    return "facts" if part in (*FACTS, "", "front_door") else part


@pytest.mark.parametrize(
    ("importer", "forbidden"), [("facts", {"master", "sim"}), ("master", {"sim"}), ("sim", {"master"})]
)
def test_the_rooms_of_axes_import_only_the_facts(importer: str, forbidden: set[str]) -> None:
    """The master and the simulator meet on the wire, never in an import; the facts need neither."""
    offenders = {
        module: sorted(m for m in imported if room(m) in forbidden)
        for module, imported in axes_imports().items()
        if room(module) == importer and any(room(m) in forbidden for m in imported)
    }
    assert offenders == {}


def test_no_axes_folder_holds_more_than_ten_modules_flat() -> None:
    crowded = {
        str(folder.relative_to(ROOT)): n
        for folder in [AXES, *(p for p in AXES.rglob("*") if p.is_dir() and (p / "__init__.py").is_file())]
        if (n := len([p for p in folder.glob("*.py") if p.name != "__init__.py"])) > MAX_FLAT_MODULES
    }
    assert crowded == {}
