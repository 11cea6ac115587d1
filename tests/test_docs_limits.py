"""The ranges that the flag tables (docs/cli.md's for `clray render`, README.md's summary of it)
and docs/scene_format.md's [render] table give are those of the one limits table
(clray.scene.limits) that the loader, the command line and RenderSettings check by: a limit
changed in the code must be changed in the docs too."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from clray.cli import _build_parser
from clray.scene import limits
from clray.scene.include import _KEYS
from clray.scene.load import _TOP_KEYS

ROOT = Path(__file__).resolve().parent.parent

# The flag tables: (file, the heading their table follows).
FLAG_TABLES = {
    "docs/cli.md": "## `clray render`",
    "README.md": "## Command line",
}
# Flag -> the [render] key whose range it takes.
FLAG_KEYS = {
    "--width": "width",
    "--height": "height",
    "--spp": "spp",
    "--max-depth": "max_depth",
    "--seed": "seed",
    "--min-weight": "min_weight",
    "--exposure": "exposure",
}
# Flags whose range only the command line checks (clray/cli.py), not the limits table: the
# range is tried on the parser itself.
PARSER_RANGES = {"--dask-workers", "--dask-timeout"}
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


def flag_rows(doc: str) -> list[list[str]]:
    return table_rows(ROOT / doc, "| flag | meaning |", FLAG_TABLES[doc])


def flag_ranges(doc: str) -> dict[str, tuple[float, float]]:
    """Flag -> (low, high) of every `A to B` range in the doc's flag table."""
    found: dict[str, tuple[float, float]] = {}
    for flag_cell, meaning in flag_rows(doc):
        flags = re.findall(r"--[a-z-]+", flag_cell)
        # "0 (none) to 16": a bound may be followed by a word in brackets.
        match = re.search(rf"({_NUMBER})(?: \([^)]*\))? to ({_NUMBER})\b", meaning)
        if match:
            for flag in flags:
                found[flag] = (number(match.group(1)), number(match.group(2)))
    return found


def flag_choices(doc: str) -> dict[str, tuple[str, ...]]:
    """Flag -> the choices its metavar lists (`--png-bits 8\\|16`)."""
    rows = flag_rows(doc)
    choice = re.compile(r"`(--[a-z-]+) (\w+(?:\\\|\w+)+)`")
    return {m.group(1): tuple(m.group(2).split("\\|"))
            for cell, _ in rows if (m := choice.fullmatch(cell))}


def test_number_reads_the_docs_forms() -> None:
    assert number("16384") == 16384
    assert number("-32") == -32
    assert number("2^32 - 1") == 2**32 - 1
    assert number("2^32-1") == 2**32 - 1


@pytest.mark.parametrize("doc", sorted(FLAG_TABLES))
@pytest.mark.parametrize("flag", sorted(FLAG_KEYS))
def test_flag_range_is_the_code_range(doc: str, flag: str) -> None:
    ranges = flag_ranges(doc)
    assert flag in ranges, f"{doc}'s flag table gives no 'A to B' range for {flag}"
    assert ranges[flag] == code_range(FLAG_KEYS[flag])


@pytest.mark.parametrize("doc", sorted(FLAG_TABLES))
def test_flag_choices_are_the_code_choices(doc: str) -> None:
    choices = flag_choices(doc)
    assert choices["--png-bits"] == tuple(map(str, limits.PNG_BITS))
    assert choices["--precision"] == limits.PRECISIONS


def accepts(flag: str, value: float) -> bool:
    """Whether `clray render` takes `flag value` (a local cluster's flags with --dask)."""
    text = str(int(value)) if value == int(value) else str(value)
    try:
        _build_parser().parse_args(["render", "scene.toml", "--dask", flag, text])
    except SystemExit:
        return False
    return True


@pytest.mark.parametrize("flag", sorted(PARSER_RANGES))
def test_cli_only_range_is_the_parser_range(flag: str) -> None:
    low, high = flag_ranges("docs/cli.md")[flag]
    step = 1 if low == int(low) and high == int(high) else low / 2
    assert accepts(flag, low) and accepts(flag, high)
    assert not accepts(flag, low - step) and not accepts(flag, high + step)


@pytest.mark.parametrize("doc", sorted(FLAG_TABLES))
def test_every_flag_range_is_checked(doc: str) -> None:
    """A range added to a flag table for a flag this test does not know must be added here."""
    assert set(flag_ranges(doc)) - PARSER_RANGES == set(FLAG_KEYS)


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


SCENE_FORMAT = ROOT / "docs" / "scene_format.md"
# Rows of docs/scene_format.md's Limits table -> the count clray.scene.limits checks.
LIMIT_COUNTS = {
    "entries in `objects`": limits.MAX_OBJECTS,
    "entries in `lights`": limits.MAX_LIGHTS,
    "nesting of `include`": limits.MAX_INCLUDE_DEPTH,
    "tracks in `[animation]`": limits.MAX_TRACKS,
    "keyframes in all tracks together": limits.MAX_KEYFRAMES,
}


@pytest.mark.parametrize("what", sorted(LIMIT_COUNTS))
def test_limits_table_count_is_the_code_limit(what: str) -> None:
    rows = {row[0]: row[1] for row in
            table_rows(SCENE_FORMAT, "| what | limit | why |", "## Limits")}
    assert what in rows, f"docs/scene_format.md's Limits table has no row {what!r}"
    count = re.match(r"[\d,]+", rows[what])
    assert count and int(count.group().replace(",", "")) == LIMIT_COUNTS[what]


def test_top_level_table_is_the_loaders_keys() -> None:
    rows = table_rows(SCENE_FORMAT, "| key | type | default | meaning |", "# Scene format")
    assert [row[0] for row in rows] == [f"`{key}`" for key in _TOP_KEYS]


def test_an_included_files_tables_are_the_includes_keys() -> None:
    text = " ".join(SCENE_FORMAT.read_text(encoding="utf-8").split())
    found = re.search(r"has the same tables as a scene but `animation` \(([^)]*)\)", text)
    assert found, "docs/scene_format.md's Includes section no longer lists an included file's"
    assert set(re.findall(r"`(\w+)`", found.group(1))) == set(_KEYS) - {"animation"}
