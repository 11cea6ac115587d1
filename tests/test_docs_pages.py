"""The documentation's shape: README.md is a manual a newcomer reads in ten minutes (at most
README_LINES lines, no chain of earlier figures), no text or comment of the repository calls a
period of the project's history a "stop" (history in docs/ is dated), and
docs/architecture.md names every module of clray/ and every file of kernels/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_LINES = 400

# "stop" as a period of history: "this stop", "a stop before", "earlier stops", "the previous
# stop's packets", "until this stop", "machines and stops". A loop or a ray that stops, the
# exposure's stops and `--rows START:STOP` do not match.
HISTORY_STOP = re.compile(
    r"\b(?:this|that|previous|earlier|later|last|next|former|two|three|several|other)"
    r"\s+stops?\b"
    r"|\b(?:a|the|one|two|three)\s+stops?\s+(?:before|ago|earlier|later)\b"
    r"|\bstops?\s+(?:before|since)\s+(?:this|that|the previous)\b"
    r"|\b(?:machines|days|runs)\s+and\s+stops\b",
    re.IGNORECASE)
# Where history could be written: documentation, and comments and docstrings in code.
TEXT_GLOBS = ("*.md", "docs/**/*.md", "benchmarks/*.md", "clray/**/*.py", "kernels/*.h",
              "kernels/*.cl", "tests/**/*.py", "benchmarks/*.py", "scripts/*", "Makefile")


def history_stops(text: str) -> list[str]:
    """The lines of `text` that use "stop" as a period of the project's history."""
    return [line.strip() for line in text.splitlines() if HISTORY_STOP.search(line)]


def repository_texts() -> list[Path]:
    me = Path(__file__).resolve()
    found = {path for pattern in TEXT_GLOBS for path in ROOT.glob(pattern)
             if path.is_file() and path.resolve() != me}
    return sorted(found)


def test_readme_is_short() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_LINES, f"README.md has {lines} lines, more than {README_LINES}"


def test_readme_has_no_chain_of_earlier_figures() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    chains = [line for line in text.splitlines()
              if re.search(r"\b(?:latest|before)\b.*\(\s*[\d.]+ s?\b.*\bbefore\b", line)]
    assert not chains, "README.md keeps earlier figures:\n" + "\n".join(chains)


@pytest.mark.parametrize("phrase", [
    "0.174 s a stop before", "until this stop they took", "in earlier stops",
    "the previous stop's packets", "the stop before's x2.56", "between machines and stops",
    "(since this stop's lane-wise set-up", "An earlier stop counted",
])
def test_history_stop_is_recognised(phrase: str) -> None:
    assert history_stops(phrase) == [phrase]


@pytest.mark.parametrize("phrase", [
    "a failing baseline stops the run", "the shadow walk stops at the first opaque crossing",
    "--exposure STOPS", "exposure in stops", "stop before the other square roots",
    "`--rows START:STOP`", "an interrupted sequence restarts where it stopped",
])
def test_other_stops_are_not(phrase: str) -> None:
    assert history_stops(phrase) == []


def test_no_text_calls_a_period_of_history_a_stop() -> None:
    found = [f"{path.relative_to(ROOT)}: {line}" for path in repository_texts()
             for line in history_stops(path.read_text(encoding="utf-8", errors="replace"))]
    assert not found, "history written as stops (date it instead):\n" + "\n".join(found)


def test_architecture_names_every_module_and_kernel_file() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    bullets = {m.group(1): m.group(0) for m in
               re.finditer(r"^- `(clray/[a-z]+/)`:.*?(?=^- |^#|\Z)", text, re.M | re.S)}
    missing = []
    for path in sorted((ROOT / "clray").rglob("*.py")):
        relative = path.relative_to(ROOT)
        package = relative.parent.as_posix() + "/"
        if package == "clray/":
            if f"`{path.name}`" not in text and f"`clray/{path.name}`" not in text:
                missing.append(relative.as_posix())
        elif path.name != "__init__.py" and f"`{path.name}`" not in bullets.get(package, ""):
            missing.append(relative.as_posix())
    for path in sorted((ROOT / "kernels").iterdir()):
        if path.suffix in (".h", ".cl", ".py") and f"kernels/{path.name}" not in text:
            missing.append(path.relative_to(ROOT).as_posix())
    assert not missing, f"docs/architecture.md does not name: {', '.join(missing)}"


def test_gpu_targets_counts_are_the_tests() -> None:
    # docs/rendering.md counts the configurations tests/test_gpu_targets.py compiles.
    from test_gpu_targets import CONFIGS, FEATURES, VARIANTS

    text = " ".join((ROOT / "docs" / "rendering.md").read_text(encoding="utf-8").split())
    found = re.search(r"each of the (\d+) feature switches .*? each of the (\d+) other switches"
                      r" .*?: (\d+) configurations, its `CONFIGS`", text)
    assert found, "docs/rendering.md no longer counts tests/test_gpu_targets.py's configurations"
    assert tuple(int(n) for n in found.groups()) == (len(FEATURES), len(VARIANTS), len(CONFIGS))
