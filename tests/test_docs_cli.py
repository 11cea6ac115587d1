"""docs/cli.md describes the command line that clray/cli.py builds: every command has a section
(`## \\`clray NAME\\``), every flag of a command is named in backticks in its section, and every
flag a section's tables name exists. A flag added to the parser fails here until the page
describes it; a flag removed fails until the page forgets it."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from clray.cli import _build_parser

ROOT = Path(__file__).resolve().parent.parent
CLI_DOC = ROOT / "docs" / "cli.md"
TOP = "clray"  # the section of the top-level flags


def commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The top-level parser under TOP and each subcommand's parser under its name."""
    found = {TOP: parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def option_strings(parser: argparse.ArgumentParser, top: bool) -> list[str]:
    """Every option string of a parser: a subcommand's `-h`/`--help` is described once, in the
    top-level section, for every command."""
    return [option for action in parser._actions for option in action.option_strings
            if top or not isinstance(action, argparse._HelpAction)]


def sections(text: str) -> dict[str, str]:
    """`## \\`clray NAME\\`` heading -> the text up to the next `## ` heading."""
    found: dict[str, str] = {}
    for match in re.finditer(r"^## `(clray(?: [a-z]+)?)`\n(.*?)(?=^## |\Z)", text, re.M | re.S):
        name = match.group(1).removeprefix("clray").strip() or TOP
        found[name] = match.group(2)
    return found


def named(option: str, section: str) -> bool:
    """Whether `option` opens a code span of the section: `--spp N`, `-W`, `--linear`."""
    return re.search(rf"`{re.escape(option)}(?=[ `=\]])", section) is not None


def undocumented(parser: argparse.ArgumentParser, text: str) -> list[str]:
    """`COMMAND OPTION` for every option of the parser that the text's sections do not name,
    and `COMMAND` for every command without a section."""
    described = sections(text)
    missing = []
    for name, sub in commands(parser).items():
        if name not in described:
            missing.append(f"clray {name}".strip())
            continue
        missing += [f"{name} {option}" for option in option_strings(sub, name == TOP)
                    if not named(option, described[name])]
        missing += [f"{name} {action.metavar}" for action in sub._actions
                    if not action.option_strings and isinstance(action.metavar, str)
                    and not isinstance(action, argparse._SubParsersAction)
                    and action.metavar not in described[name]]
    return missing


def stale(parser: argparse.ArgumentParser, text: str) -> list[str]:
    """`COMMAND OPTION` for every flag a section's table rows name that the command lacks, and
    every section of a command that does not exist."""
    subs = commands(parser)
    found = []
    for name, section in sections(text).items():
        if name not in subs:
            found.append(f"clray {name}")
            continue
        known = set(option_strings(subs[name], top=True))
        for row in re.findall(r"^\| ([^|]*(?:\\\|[^|]*)*) \|", section, re.M):
            found += [f"{name} {flag}" for flag in re.findall(r"`(--?[A-Za-z][\w-]*)", row)
                      if flag not in known]
    return found


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    return _build_parser()


def test_every_command_and_flag_is_in_docs_cli(parser: argparse.ArgumentParser) -> None:
    missing = undocumented(parser, CLI_DOC.read_text(encoding="utf-8"))
    assert not missing, f"docs/cli.md does not describe: {', '.join(missing)}"


def test_docs_cli_names_no_flag_the_command_lacks(parser: argparse.ArgumentParser) -> None:
    extra = stale(parser, CLI_DOC.read_text(encoding="utf-8"))
    assert not extra, f"docs/cli.md describes what clray does not have: {', '.join(extra)}"


def test_the_check_sees_a_flag_removed_from_the_page(parser: argparse.ArgumentParser) -> None:
    """The check can fail: the page without the `--spp` row of `clray render`, or without a
    command's section, is reported."""
    text = CLI_DOC.read_text(encoding="utf-8")
    render = sections(text)["render"]
    row = next(line for line in render.splitlines() if line.startswith("| `--spp N`"))
    assert undocumented(parser, text.replace(row + "\n", "")) == ["render --spp"]
    without_devices = re.sub(r"^## `clray devices`\n.*?(?=^## )", "", text, flags=re.M | re.S)
    assert undocumented(parser, without_devices) == ["clray devices"]
    assert stale(parser, text + "\n## `clray render`\n\n| `--no-such-flag` | x |\n") == \
        ["render --no-such-flag"]


def test_a_subcommand_without_help_is_still_walked(parser: argparse.ArgumentParser) -> None:
    names = set(commands(parser))
    assert {TOP, "render", "scene", "devices", "study", "tune", "profile"} <= names
