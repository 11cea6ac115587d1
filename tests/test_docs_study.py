"""The summary tables of README.md (## Accuracy) and docs/accuracy.md give what the committed
study, docs/study/results.json, gives (clray.study.summary, the table of report.md's Summary):
each variant's kernel time relative to the float default, and the scenes it fails with their
pixels off by over 2/255. The tables are written by hand, a row for several variants where
they are alike ("a / b / c" with their times "1.02 / 1.05 / 1.09"); "the three" (or "the same
three") stands for the scenes the float default fails, whose counts it leaves out; any text
after a count in brackets is an explanation."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from test_docs_limits import table_rows

from clray.study import DEFAULT, summary

ROOT = Path(__file__).resolve().parent.parent
# The page and the heading its table follows.
PAGES = {"README.md": "## Accuracy", "docs/accuracy.md": None}
# A failing scene and its pixels: "glass (1264)", "curved_acne_grazing (48 acne pixels)".
SCENE_COUNT = re.compile(r"([\w.-]+) \((\d+)")


def doc_rows(page: str) -> dict[str, tuple[str, str]]:
    """Variant -> (time, fails cell) of the page's summary table, its grouped rows split."""
    found: dict[str, tuple[str, str]] = {}
    for variants, times, fails in table_rows(
        ROOT / page, "| variant | time | fails |", PAGES[page]
    ):
        names = variants.replace("`", "").removesuffix(" (the reference)").split(" / ")
        times_ = times.split(" / ")
        assert len(names) == len(times_), f"{page}: {variants}: a time a variant"
        for name, time in zip(names, times_, strict=True):
            assert name not in found, f"{page}: {name} has two rows"
            found[name] = (time, fails)
    return found


def doc_fails(cell: str, default_fails: set[str]) -> tuple[set[str], dict[str, int]]:
    """The scenes a fails cell names, and the counts it gives."""
    if cell == "-":
        return set(), {}
    counts = {scene: int(n) for scene, n in SCENE_COUNT.findall(cell)}
    the_three = cell.startswith(("the three", "the same three"))
    return set(counts) | (default_fails if the_three else set()), counts


@pytest.fixture(scope="module")
def computed() -> dict[str, dict]:
    records = json.loads((ROOT / "docs/study/results.json").read_text(encoding="utf-8"))
    return {row["variant"]: row for row in summary(records["records"])}


@pytest.mark.parametrize("page", list(PAGES))
def test_summary_table_gives_what_the_study_gives(page: str, computed: dict[str, dict]) -> None:
    rows = doc_rows(page)
    assert set(rows) == set(computed), f"{page}: the table's variants are not the study's"
    default_fails = set(computed[DEFAULT.name]["fails"])
    for name, (time, cell) in rows.items():
        row = computed[name]
        assert time == f"{row['time']:.2f}", f"{page}: {name}'s time"
        scenes, counts = doc_fails(cell, default_fails)
        assert scenes == set(row["fails"]), f"{page}: {name} fails other scenes"
        assert counts == {scene: row["fails"][scene][0] for scene in counts}, (
            f"{page}: {name}'s pixels"
        )


def test_the_three_are_the_defaults_failures() -> None:
    assert doc_fails("the same three", {"a", "b"}) == ({"a", "b"}, {})
    assert doc_fails("the three, c (12: acne), d (3) and e (40)", {"a"}) == (
        {"a", "c", "d", "e"},
        {"c": 12, "d": 3, "e": 40},
    )
    assert doc_fails("a (1264), b (142)", set()) == ({"a", "b"}, {"a": 1264, "b": 142})
