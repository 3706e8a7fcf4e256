"""The docs say what the code does: the package table lists each package's public names, the docs'
Python imports only those, every "cell's `KEY`" is a key of a shipped cell file, the design the docs
cite is docs/DESIGN.md (in the repository, not beside it), and a plan outlives its execution as
docs/API.md says."""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PACKAGES = ("axes", "planner", "service")


def text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


@pytest.mark.parametrize("package", PACKAGES)
def test_the_development_guide_lists_the_public_names_of_each_package(package: str) -> None:
    row = re.search(rf"^\| `pvtflow.{package}` \| (.*) \|$", text(ROOT / "docs" / "development.md"), re.M)
    assert row, f"docs/development.md: no row for {package}"
    listed = set(re.findall(r"`(\w+)`", re.sub(r"\([^)]*\)", "", row.group(1))))  # (remarks) left out
    public = set(importlib.import_module(f"pvtflow.{package}").__all__)
    extra, missing = sorted(listed - public), sorted(public - listed)
    assert listed == public, f"docs/development.md lists {extra} extra, {missing} missing"


def test_the_docs_python_imports_only_public_names() -> None:
    for doc in DOCS:
        for block in re.findall(r"```python\n(.*?)```", text(doc), re.S):
            for package, names in re.findall(r"^from pvtflow\.(axes|planner|service) import (.+)$", block, re.M):
                public = set(importlib.import_module(f"pvtflow.{package}").__all__)
                missing = {n.strip() for n in names.strip("()").split(",")} - public
                assert not missing, f"{doc.name}: from {package} import {sorted(missing)}: not in {package}.__all__"


def _keys(data: Any, prefix: str = "") -> set[str]:
    out: set[str] = set()
    if isinstance(data, dict):
        for k, v in data.items():
            out.add(prefix + str(k))
            out |= _keys(v, f"{prefix}{k}.")
    elif isinstance(data, list):
        for item in data:
            out |= _keys(item, prefix)
    return out


def test_every_cell_key_the_docs_name_is_a_key_of_a_cell_file() -> None:
    keys: set[str] = set()
    for cell in (ROOT / "configs" / "cells").glob("*.yaml"):
        keys |= _keys(yaml.safe_load(text(cell)))
    named = [(doc.name, k) for doc in DOCS for k in re.findall(r"cell's `([\w.]+)`", text(doc))]
    assert named
    unknown = [(doc, k) for doc, k in named if k not in keys]
    assert not unknown, f"not a key of any shipped cell file: {unknown}"


def test_the_design_the_docs_cite_is_in_the_repository() -> None:
    assert (ROOT / "docs" / "DESIGN.md").is_file()
    sources = [*DOCS, *(p for d in PACKAGES for p in (ROOT / d).rglob("*.py"))]
    outside = [p.relative_to(ROOT) for p in sources if re.search(r"\.\./shared|shared/DESIGN", text(p))]
    assert not outside, f"they point outside the repository: {outside}"
    assert "`docs/DESIGN.md` is the architecture and the contracts" in text(ROOT / "README.md")


def test_an_executed_plan_stays_as_api_md_says(serve, arm6) -> None:  # type: ignore[no-untyped-def]
    assert "executing a plan does not remove it" in text(ROOT / "docs" / "API.md")
    served = serve(arm6)
    plan = served.request("plan", {"target": [0.1] * 6})
    assert served.request("execute", {"plan_id": plan.data["plan_id"], "wait": True}).ok
    assert served.request("validate", {"plan_id": plan.data["plan_id"]}).ok
