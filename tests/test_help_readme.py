"""The README's command table and the CLI's --help agree: every option a command's --help lists appears in that
command's synopsis in the README (its first code span), and the live view's address is the same in both."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from furuta_rt.cli import build_parser

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def _commands() -> list[tuple[str, argparse.ArgumentParser]]:
    out = []

    def walk(name: str, parser: argparse.ArgumentParser) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        for a in subs:
            for child, sp in a.choices.items():
                walk(f"{name} {child}".strip(), sp)
        if name and not subs:
            out.append((name, parser))

    walk("", build_parser())
    return out


def _synopsis(command: str) -> str:
    rows = [line for line in README.splitlines() if line.startswith(f"| `furuta-rt {command}")]
    assert rows, f"the README's command table has no row for furuta-rt {command}"
    return rows[0][: rows[0].index("` |")]


@pytest.mark.parametrize(("command", "parser"), _commands(), ids=[c for c, _ in _commands()])
def test_every_option_in_help_is_in_the_readme_synopsis(command: str, parser: argparse.ArgumentParser) -> None:
    synopsis = _synopsis(command)
    missing = []
    for action in parser._actions:
        options = [o for o in action.option_strings if o not in ("-h", "--help")]
        if options and action.help != argparse.SUPPRESS and not any(
                re.search(re.escape(o) + r"(?![\w-])", synopsis) for o in options):
            missing.append(max(options, key=len))
    assert not missing, f"furuta-rt {command}: --help lists {missing}, the README's synopsis does not"


def test_the_live_view_address_is_the_same_in_help_and_readme() -> None:
    run = dict(_commands())["run"]
    help_text = " ".join(run.format_help().split())
    assert "ws://127.0.0.1:PORT" in help_text and "ws://127.0.0.1:8765" in README and "ws://localhost" not in README
