"""Every test that depends on the wall clock says so with the ``wall`` marker.

A test depends on the wall clock when it runs SYNC or a drive on the wall clock (``real_time=True``,
``clock=Clock.WALL``, ``lockstep=False``, ``--real-time``, ``clock="wall"``) or lets time pass (a
``time.sleep`` outside a loop: a sleep inside one polls a condition until a deadline and depends on the clock only
for how long it may wait), itself
or through a helper or fixture that does: its outcome can then depend on the host's load, and
``pytest -m wall`` / ``-m "not wall"`` must find it. The marker only labels: the README's test command
runs these tests too.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
WALL_CLOCK_SYNC = re.compile(
    r"real_time\s*=\s*True|lockstep\s*=\s*False|--real-time|clock\s*=\s*[\"']wall[\"']|Clock\.WALL"
)
Function = ast.FunctionDef | ast.AsyncFunctionDef
# what one scan learnt of each function (by id: its trees live as long as the scan), every helper and
# fixture otherwise looked at again for every test file
_SEEN: dict[tuple[str, int], object] = {}


def _functions(tree: ast.Module) -> dict[str, Function]:
    """Module-level functions and methods of module-level classes, by name."""
    found: dict[str, Function] = {}
    for node in tree.body:
        if isinstance(node, Function):
            found[node.name] = node
        elif isinstance(node, ast.ClassDef):
            found.update({f.name: f for f in node.body if isinstance(f, Function) and not f.name.startswith("test_")})
    return found


def _lets_time_pass(f: Function) -> bool:
    """A ``time.sleep`` call that is not inside a loop of ``f``."""
    looped = {id(n) for loop in ast.walk(f) if isinstance(loop, ast.For | ast.While) for n in ast.walk(loop)}
    return any(
        isinstance(n, ast.Call) and ast.unparse(n.func) == "time.sleep" and id(n) not in looped for n in ast.walk(f)
    )


def _on_the_wall_clock(src: str, f: Function) -> bool:
    key = ("wall", id(f))
    if key not in _SEEN:
        lines = _SEEN.setdefault(("lines", id(src)), src.splitlines())  # ast.get_source_segment splits it each call
        segment = "\n".join(lines[f.lineno - 1 : f.end_lineno])  # type: ignore[index]
        _SEEN[key] = bool(WALL_CLOCK_SYNC.search(segment)) or _lets_time_pass(f)
    return bool(_SEEN[key])


def _names(node: ast.AST) -> frozenset[str]:
    """What the node names: calls, attributes, fixture arguments."""
    found: set[str] = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name):
            found.add(sub.id)
        elif isinstance(sub, ast.Attribute):
            found.add(sub.attr)
        elif isinstance(sub, ast.arg):
            found.add(sub.arg)
    return frozenset(found)


def _uses(node: ast.AST, names: set[str]) -> bool:
    """The node names one of ``names`` (a call, an attribute, a fixture argument)."""
    key = ("names", id(node))
    if key not in _SEEN:
        _SEEN[key] = _names(node)
    return not _SEEN[key].isdisjoint(names)  # type: ignore[union-attr]


def _wall_names(trees: list[tuple[str, ast.Module]]) -> set[str]:
    """Helpers and fixtures (not tests) that use the wall clock, directly or through one another."""
    defs = {
        name: (src, f) for src, tree in trees for name, f in _functions(tree).items() if not name.startswith("test_")
    }
    wall = {name for name, (src, f) in defs.items() if _on_the_wall_clock(src, f)}
    while True:
        more = {name for name, (_src, f) in defs.items() if name not in wall and _uses(f, wall)}
        if not more:
            return wall
        wall |= more


def _marked(decorators: list[ast.expr]) -> bool:
    return any("mark.wall" in ast.unparse(d) for d in decorators)


def _module_marked(tree: ast.Module) -> bool:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            return "mark.wall" in ast.unparse(node.value)
    return False


def unmarked_wall_tests() -> list[str]:
    _SEEN.clear()
    parsed = {p: (p.read_text(), ast.parse(p.read_text())) for p in sorted(TESTS.rglob("*.py"))}
    shared = [(src, tree) for p, (src, tree) in parsed.items() if not p.name.startswith("test_")]
    offenders = []
    for path, (src, tree) in parsed.items():
        if not path.name.startswith("test_") or path == Path(__file__).resolve() or _module_marked(tree):
            continue
        wall = _wall_names([*shared, (src, tree)])
        scopes: list[tuple[Function, bool]] = []
        for node in tree.body:
            if isinstance(node, Function):
                scopes.append((node, False))
            elif isinstance(node, ast.ClassDef):
                scopes += [(f, _marked(node.decorator_list)) for f in node.body if isinstance(f, Function)]
        for f, class_marked in scopes:
            if not f.name.startswith("test_") or class_marked or _marked(f.decorator_list):
                continue
            if _on_the_wall_clock(src, f) or _uses(f, wall):
                offenders.append(f"{path.relative_to(TESTS)}::{f.name}")
    return offenders


def test_every_wall_clock_test_carries_the_wall_marker() -> None:
    assert unmarked_wall_tests() == []


def test_the_scan_finds_an_unmarked_wall_clock_test(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The rule itself can fail: a test that sleeps, one that runs a drive on the wall clock through a
    helper, none marked, are found; the marked one and one that polls are not."""
    (tmp_path / "test_made_up.py").write_text(
        "import time\nimport pytest\n\n"
        "def drive():\n    return Drive(clock='wall')\n\n"
        "def test_sleeps():\n    time.sleep(0.1)\n\n"
        "def test_through_a_helper():\n    drive()\n\n"
        "@pytest.mark.wall\ndef test_marked():\n    time.sleep(0.1)\n\n"
        "def test_polls():\n    while not done():\n        time.sleep(0.01)\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "TESTS", tmp_path)
    assert unmarked_wall_tests() == ["test_made_up.py::test_sleeps", "test_made_up.py::test_through_a_helper"]
