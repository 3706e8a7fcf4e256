"""The motion service is composed, not inherited: collaborators own their state and nobody writes it for them.

``MotionService`` is a facade over objects that each own their state and lock (the drives, the cell's
state board, the activity, the plans, the runs). Read from the code: no class of service/motion derives
from another project class, and no code writes a collaborator's attribute through it
(``self.board.state = ...``): it asks the collaborator (``self.board.set(...)``).
"""

from __future__ import annotations

import ast
from pathlib import Path

MOTION = Path(__file__).resolve().parents[2] / "service" / "motion"
ALLOWED_BASES = {"StrEnum", "Enum", "Exception", "Protocol"}


def _modules() -> dict[str, ast.Module]:
    return {p.name: ast.parse(p.read_text(encoding="utf-8")) for p in sorted(MOTION.glob("*.py"))}


def test_no_class_of_the_motion_service_inherits_from_another_of_the_project() -> None:
    derived = [
        f"{name}: {cls.name}({', '.join(ast.unparse(b) for b in cls.bases)})"
        for name, tree in _modules().items()
        for cls in ast.walk(tree)
        if isinstance(cls, ast.ClassDef) and {ast.unparse(b) for b in cls.bases} - ALLOWED_BASES
    ]
    assert derived == []


def test_no_code_writes_a_collaborators_state_through_it() -> None:
    def reaches_through(target: ast.expr) -> bool:
        return (
            isinstance(target, ast.Attribute)
            and isinstance(target.value, ast.Attribute)
            and isinstance(target.value.value, ast.Name)
            and target.value.value.id == "self"
        )

    writes = [
        f"{name}:{node.lineno}: {ast.unparse(t)}"
        for name, tree in _modules().items()
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign)
        for t in (node.targets if isinstance(node, ast.Assign) else [node.target])
        for t in (t.elts if isinstance(t, ast.Tuple) else [t])
        if reaches_through(t)
    ]
    assert writes == []
