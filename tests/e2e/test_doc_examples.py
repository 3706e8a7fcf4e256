"""Every example in README.md and docs/*.md runs as pasted, so that the docs and the code cannot drift apart.

- Request examples: each one-line JSON object in a ```json block under a ``### <request>`` heading of
  docs/API.md (``...`` marks a template, left out) is sent to a served arm6 cell and must be answered
  with a result.
- Command lines: every ``pvtflow`` line of a ```sh block parses with the command line's own parser; the
  offline ones (``plan``, ``validate``, ``execute`` on a simulated cell) run, in the order of their block,
  in a scratch directory that holds the repository's configs and the files the block's heredocs write
  (``cat > FILE <<'EOF'``), and must exit 0. A block without a language tag is a synopsis, not run.
"""

from __future__ import annotations

import json
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from pvtflow.service.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
OFFLINE = ("plan", "validate", "execute")
_BLOCK = re.compile(r"^( *)```(\w*)\n(.*?)^\1```", re.S | re.M)
_HEREDOC = re.compile(r"^cat > (\S+) <<'(\w+)'\n(.*?)^\2\n", re.S | re.M)


@dataclass(frozen=True)
class Block:
    source: str  # FILE:LINE
    language: str
    text: str
    heading: str  # the first word of the last heading above it


def blocks() -> list[Block]:
    out = []
    for doc in DOCS:
        text = doc.read_text(encoding="utf-8")
        for m in _BLOCK.finditer(text):
            above = text[: m.start()]
            headings = re.findall(r"^#+ (\S+)", above, re.M)
            body = "\n".join(line.removeprefix(m.group(1)) for line in m.group(3).splitlines()) + "\n"
            where = f"{doc.name}:{above.count(chr(10)) + 1}"
            out.append(Block(where, m.group(2), body, headings[-1] if headings else ""))
    return out


def request_examples() -> list[tuple[str, str, dict[str, object]]]:
    """(where, request, payload) of every runnable one-line request example."""
    from pvtflow.service.api import QUERYABLES

    out = []
    for b in blocks():
        if b.language != "json" or b.heading not in QUERYABLES:
            continue
        for line in b.text.splitlines():
            if line.startswith("{") and "..." not in line:
                out.append((b.source, b.heading, json.loads(line)))
    return out


def commands(block: Block) -> list[str]:
    """The block's ``pvtflow`` command lines (comments off)."""
    text = _HEREDOC.sub("", block.text)
    lines = [line.split(" # ")[0].strip() for line in text.splitlines()]
    return [line for line in lines if line.startswith("pvtflow ")]


SH_BLOCKS = [b for b in blocks() if b.language == "sh"]


def test_the_docs_have_examples_of_both_kinds() -> None:
    """The extraction finds what it is meant to (an empty list would make the other tests pass)."""
    ops = {op for _, op, _ in request_examples()}
    assert {"plan"} <= ops, ops
    offline = [c for b in SH_BLOCKS for c in commands(b) if c.split()[1] in OFFLINE]
    assert any(c.startswith("pvtflow plan ") for c in offline), offline
    assert any(c.startswith("pvtflow validate ") for c in offline), offline


def test_every_request_example_is_answered(serve, arm6) -> None:  # type: ignore[no-untyped-def]
    served = serve(arm6)
    for where, op, payload in request_examples():
        reply = served.request(op, payload, timeout=60.0)
        assert reply.ok, f"{where}: {op} {json.dumps(payload)}: {reply.data}"


@pytest.mark.parametrize("block", SH_BLOCKS, ids=[b.source for b in SH_BLOCKS])
def test_every_documented_command_line_parses(block: Block) -> None:
    parser = build_parser()
    for line in commands(block):
        try:
            parser.parse_args(shlex.split(line)[1:])
        except SystemExit as exc:
            pytest.fail(f"{block.source}: `{line}` is refused by the command line's parser (exit {exc.code})")


RUNNABLE = [b for b in SH_BLOCKS if any(c.split()[1] in OFFLINE for c in commands(b))]


@pytest.mark.parametrize("block", RUNNABLE, ids=[b.source for b in RUNNABLE])
def test_every_offline_command_runs_as_pasted(
    block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    for m in _HEREDOC.finditer(block.text):
        (tmp_path / m.group(1)).write_text(m.group(3), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    for line in commands(block):
        argv = shlex.split(line)[1:]
        if argv[0] not in OFFLINE:
            continue
        code = main(argv)
        out = capsys.readouterr()
        assert code == 0, f"{block.source}: `{line}` exited {code}:\n{out.out}\n{out.err}"
