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
        "pvtflow.axes.master.group.feeder, pvtflow.axes.drive.program, "
        "pvtflow.axes.master.profiles, pvtflow.axes.sim, pvtflow.axes.sim.cell"
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


# --- the rooms of axes/ (issue 36): facts <- master, facts <- sim, and no circle ---------------------------------

AXES = ROOT / "axes"
MAX_FLAT_MODULES = 10  # modules side by side in one folder, beside its __init__.py


def module_name(path: Path) -> str:
    """pvtflow.axes.master.bus.sync for axes/master/bus/sync.py, pvtflow.axes.sim.wire for its __init__.py."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(("pvtflow", *(parts[:-1] if parts[-1] == "__init__" else parts)))


def axes_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(AXES.rglob("*.py"))}


def axes_imports(path: Path, known: set[str]) -> set[str]:
    """The axes modules a module imports, wherever the statement is (under TYPE_CHECKING, in a
    function): ``from pkg import module`` counts as an import of that module, ``from pkg import name``
    as one of the package."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base]) if base else ".".join(up)
            for alias in node.names:
                found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base)
    return {m for m in found if m in known}


def axes_graph() -> dict[str, set[str]]:
    modules = axes_modules()
    return {name: axes_imports(path, set(modules)) - {name} for name, path in modules.items()}


def in_room(module: str, room: str) -> bool:
    return module == room or module.startswith(room + ".")


@pytest.mark.parametrize(
    ("room", "forbidden"),
    [
        ("pvtflow.axes.master", ("pvtflow.axes.sim",)),
        ("pvtflow.axes.sim", ("pvtflow.axes.master",)),
        ("pvtflow.axes.drive", ("pvtflow.axes.master", "pvtflow.axes.sim")),
        ("pvtflow.axes.canbus", ("pvtflow.axes.master", "pvtflow.axes.sim")),
        ("pvtflow.axes.front_door", ("pvtflow.axes.master", "pvtflow.axes.sim")),
    ],
)
def test_the_master_and_the_simulator_meet_only_on_the_wire(room: str, forbidden: tuple[str, ...]) -> None:
    """The drive's and the bus's facts serve both; the master and the simulator never import each other."""
    offenders = {
        module: sorted(m for m in imports if any(in_room(m, f) for f in forbidden))
        for module, imports in axes_graph().items()
        if in_room(module, room)
    }
    assert {m: found for m, found in offenders.items() if found} == {}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_circles_finds_a_circle_through_a_package() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(graph) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_among_the_axes_modules() -> None:
    """Every import counts, under TYPE_CHECKING or in a function too: a part that needs its owner
    is handed what it needs (the network, a report callable) instead."""
    graph = axes_graph()
    # the front door imports every room by design; a module importing it would be a circle of its own
    assert circles(graph) == []


def test_no_axes_folder_holds_more_than_ten_modules() -> None:
    crowded = {
        str(folder.relative_to(ROOT)): count
        for folder in [AXES, *sorted(p for p in AXES.rglob("*") if p.is_dir() and p.name != "__pycache__")]
        if (count := len([p for p in folder.glob("*.py") if p.name != "__init__.py"])) > MAX_FLAT_MODULES
    }
    assert crowded == {}
