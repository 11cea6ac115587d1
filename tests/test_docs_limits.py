"""The ranges that README.md's flag table and docs/scene_format.md's [render] table give are
those of the one limits table (clray.scene.limits) that the loader, the command line and
RenderSettings check by: a limit changed in the code must be changed in the docs too."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from clray.scene import limits

ROOT = Path(__file__).resolve().parent.parent

# README flag -> the [render] key whose range it takes.
FLAG_KEYS = {
    "--width": "width",
    "--height": "height",
    "--spp": "spp",
    "--max-depth": "max_depth",
    "--seed": "seed",
    "--min-weight": "min_weight",
    "--exposure": "exposure",
}
_NUMBER = r"-?\d+(?:\.\d+)?(?:\^\d+)?(?: ?- ?1)?"


def number(text: str) -> float:
    """A bound as the docs write it: `16384`, `-32`, `0.5`, `2^32 - 1`, `2^32-1`."""
    text = text.replace(" ", "")
    minus_one = text.endswith("-1") and "^" in text
    if minus_one:
        text = text[:-2]
    base, _, power = text.partition("^")
    value = float(base) ** int(power) if power else float(base)
    return value - 1 if minus_one else value


def code_range(key: str) -> tuple[float, float]:
    ranges = {**limits.RENDER_INTEGERS, **limits.RENDER_NUMBERS}
    low, high = ranges[key]
    return float(low), float(high)


def table_rows(path: Path, header: str, section: str | None = None) -> list[list[str]]:
    """The cells of each row of the first Markdown table whose header row is `header` (after
    the heading `section`, if given)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    first = 0 if section is None else lines.index(section)
    start = lines.index(header, first) + 2  # after the header and the |---| line
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line)[1:-1]])
    return rows


def readme_flag_ranges() -> dict[str, tuple[float, float]]:
    """Flag -> (low, high) of every `A to B` range in README.md's flag table."""
    found: dict[str, tuple[float, float]] = {}
    for flag_cell, meaning in table_rows(ROOT / "README.md", "| flag | meaning |"):
        flags = re.findall(r"--[a-z-]+", flag_cell)
        # "0 (none) to 16": a bound may be followed by a word in brackets.
        match = re.search(rf"({_NUMBER})(?: \([^)]*\))? to ({_NUMBER})\b", meaning)
        if match:
            for flag in flags:
                found[flag] = (number(match.group(1)), number(match.group(2)))
    return found


def readme_flag_choices() -> dict[str, tuple[str, ...]]:
    """Flag -> the choices its metavar lists (`--png-bits 8\\|16`)."""
    rows = table_rows(ROOT / "README.md", "| flag | meaning |")
    choice = re.compile(r"`(--[a-z-]+) (\w+(?:\\\|\w+)+)`")
    return {m.group(1): tuple(m.group(2).split("\\|"))
            for cell, _ in rows if (m := choice.fullmatch(cell))}


def test_number_reads_the_docs_forms() -> None:
    assert number("16384") == 16384
    assert number("-32") == -32
    assert number("2^32 - 1") == 2**32 - 1
    assert number("2^32-1") == 2**32 - 1


@pytest.mark.parametrize("flag", sorted(FLAG_KEYS))
def test_readme_flag_range_is_the_code_range(flag: str) -> None:
    ranges = readme_flag_ranges()
    assert flag in ranges, f"README.md's flag table gives no 'A to B' range for {flag}"
    assert ranges[flag] == code_range(FLAG_KEYS[flag])


def test_readme_flag_choices_are_the_code_choices() -> None:
    choices = readme_flag_choices()
    assert choices["--png-bits"] == tuple(map(str, limits.PNG_BITS))
    assert choices["--precision"] == limits.PRECISIONS


def test_every_readme_range_is_checked() -> None:
    """A range added to the flag table for a flag this test does not know must be added here."""
    assert set(readme_flag_ranges()) == set(FLAG_KEYS)


@pytest.mark.parametrize("key", [*limits.RENDER_INTEGERS, *limits.RENDER_NUMBERS])
def test_scene_format_render_range_is_the_code_range(key: str) -> None:
    rows = {row[0]: row[1] for row in
            table_rows(ROOT / "docs" / "scene_format.md", "| key | type | default | meaning |",
                       "## `[render]`")}
    cell = rows[f"`{key}`"]
    match = (re.search(rf"({_NUMBER})\.\.({_NUMBER})$", cell)
             or re.search(rf"\[({_NUMBER}), ({_NUMBER})\]$", cell))
    assert match, f"docs/scene_format.md gives no range for {key}: {cell!r}"
    assert (number(match.group(1)), number(match.group(2))) == code_range(key)
