"""Every option of every ``pvtflow`` sub-command is documented next to its command (docs/commands.md's command
table or a paragraph of docs/), so that an option added to a parser without a word in the docs fails here."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from pvtflow.service.cli import build_parser, subcommand_parsers

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted((ROOT / "docs").glob("*.md"))  # the command table is docs/commands.md
SUBCOMMANDS = subcommand_parsers(build_parser())


def blocks(text: str) -> list[str]:
    """A table row is one block (one command per row); everything else, one paragraph per block."""
    out: list[str] = []
    for paragraph in re.split(r"\n\s*\n", text):
        rows = [line for line in paragraph.splitlines() if line.lstrip().startswith("|")]
        out.extend(rows)
        rest = "\n".join(line for line in paragraph.splitlines() if not line.lstrip().startswith("|"))
        if rest.strip():
            out.append(rest)
    return out


def documented_for(command: str) -> str:
    """The commands.md rows and API.md paragraphs that name ``pvtflow <command>``."""
    here = re.compile(rf"pvtflow {re.escape(command)}\b")
    return "\n".join(b for doc in DOCS for b in blocks(doc.read_text(encoding="utf-8")) if here.search(b))


def options(parser: argparse.ArgumentParser) -> list[list[str]]:
    """The option strings of each visible option (help and hidden aliases left out)."""
    return [
        a.option_strings
        for a in parser._actions
        if a.option_strings and not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS
    ]


@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_every_option_of_the_command_is_documented_next_to_it(command: str) -> None:
    text = documented_for(command)
    assert text, f"pvtflow {command} is named nowhere in docs/"
    missing = [
        names[-1]
        for names in options(SUBCOMMANDS[command])
        if not any(re.search(rf"(?<![\w-]){re.escape(n)}(?![\w-])", text) for n in names)
    ]
    assert not missing, f"pvtflow {command}: not documented next to the command: {', '.join(missing)}"


def test_the_check_sees_an_undocumented_option() -> None:
    """The walk over the parser finds options, and one that no doc names is reported."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--surely-undocumented-option")
    parser.add_argument("--hidden", help=argparse.SUPPRESS)
    assert options(parser) == [["--surely-undocumented-option"]]
    assert "--surely-undocumented-option" not in documented_for("serve")
    assert all(options(p) for p in SUBCOMMANDS.values())
