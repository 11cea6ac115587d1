"""The names the documentation gives are the code's: every `kernels/FILE` it names exists, a
kernel function it places in a file (`NAME`, `kernels/FILE` or `NAME` in `kernels/FILE`) is
there, every dotted `clray.a.b` name exists, and a `clray.a.b(...)` call the pages show works
after a plain `import clray` unless the page shows the import. Dated history (a heading with a
date or "history" and what is under it, a `- YYYY-MM-DD:` bullet) describes the past and may
name what has moved since."""

from __future__ import annotations

import importlib
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md"),
                *(ROOT / "benchmarks").glob("*.md")])
# The pages whose `clray.a.b` are Python names (benchmarks/README.md's are result keys).
PYTHON_PAGES = [page for page in PAGES if page.parent.name != "benchmarks"]

_DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
_HEADING = re.compile(r"^(#+) (.*)")
_KERNEL_FILE = re.compile(r"\bkernels/([a-z_0-9]+\.(?:h|cl))\b")
_PLACED = re.compile(r"`(\w+)(?:\(\))?`(?:,| in)\s+`kernels/(\w+\.(?:h|cl))`")
_DOTTED = re.compile(r"(?<![\w./-])clray(?:\.[A-Za-z_]\w*)+")
_CALL = re.compile(r"(?<![\w./-])(clray(?:\.[A-Za-z_]\w*)+)\(")


def present_text(text: str) -> str:
    """`text` without its dated history: headings that carry a date or "history" with what is
    under them, and bullets that open with a date (up to the next bullet or heading)."""
    kept, history_level, in_bullet = [], None, False
    for line in text.splitlines():
        heading = _HEADING.match(line)
        if heading:
            level = len(heading.group(1))
            in_bullet = False
            if history_level is not None and level <= history_level:
                history_level = None
            if history_level is None and (_DATE.search(heading.group(2))
                                          or "history" in heading.group(2).lower()):
                history_level = level
        elif re.match(r"^\s*- ", line):
            in_bullet = re.match(r"^\s*- 20\d\d-\d\d-\d\d\b", line) is not None
        elif not line.strip():
            in_bullet = False
        if history_level is None and not in_bullet:
            kept.append(line)
    return "\n".join(kept)


def present(path: Path) -> str:
    # Lines joined, so that a name and its file on two lines are found together.
    return " ".join(present_text(path.read_text(encoding="utf-8")).split())


def test_history_is_left_out() -> None:
    text = ("# Page\nnow `a`\n## Design history\n- 2026-12-04: `b`\n### Step (2026-12-02)\n"
            "`c`\n## Today\n`d`\n- 2026-12-05: `e`\n  more of it\n- `f`\n\n"
            "### Tried (2026-12-03)\n`g`")
    assert re.findall(r"`(\w)`", present_text(text)) == ["a", "d", "f"]


def test_kernel_files_named_exist() -> None:
    missing = [f"{page.relative_to(ROOT)}: kernels/{name}" for page in PAGES
               for name in sorted(set(_KERNEL_FILE.findall(present(page))))
               if not (ROOT / "kernels" / name).is_file()]
    assert not missing, "pages name kernel files that do not exist:\n" + "\n".join(missing)


def test_kernel_functions_are_where_pages_place_them() -> None:
    wrong = []
    for page in PAGES:
        for name, file in _PLACED.findall(present(page)):
            path = ROOT / "kernels" / file
            if not path.is_file() or not re.search(rf"\b{name}\b", path.read_text("utf-8")):
                wrong.append(f"{page.relative_to(ROOT)}: `{name}` in kernels/{file}")
    assert not wrong, "pages place kernel names in files that lack them:\n" + "\n".join(wrong)


def _resolves(name: str) -> bool:
    """Whether a dotted name is a module of clray or an attribute of one."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for part in parts[cut:]:
            if not hasattr(obj, part):
                return False
            obj = getattr(obj, part)
        return True
    return False


def test_dotted_names_exist() -> None:
    missing = [f"{page.relative_to(ROOT)}: {name}" for page in PYTHON_PAGES
               for name in sorted(set(_DOTTED.findall(present(page)))) if not _resolves(name)]
    assert not missing, "pages name what clray does not have:\n" + "\n".join(missing)


def _imported(text: str) -> set[str]:
    """The clray modules a page imports in its examples."""
    found = set(re.findall(r"\bimport (clray(?:\.\w+)+)", text))
    found |= set(re.findall(r"\bfrom (clray(?:\.\w+)+) import\b", text))
    return found


def test_calls_work_after_import_clray() -> None:
    calls = {}
    for page in PYTHON_PAGES:
        text = present(page)
        imported = _imported(text)
        for name in sorted(set(_CALL.findall(text))):
            if not any(name == m or name.startswith(m + ".") for m in imported):
                calls.setdefault(name, []).append(page.relative_to(ROOT).as_posix())
    # A fresh interpreter: this one has imported much of clray already.
    script = ("import json, sys, clray\nbad = []\nfor name in json.loads(sys.argv[1]):\n"
              "    obj = clray\n    for part in name.split('.')[1:]:\n"
              "        if not hasattr(obj, part):\n            bad.append(name)\n"
              "            break\n        obj = getattr(obj, part)\nprint(json.dumps(bad))\n")
    done = subprocess.run([sys.executable, "-c", script, json.dumps(sorted(calls))], cwd=ROOT,
                          capture_output=True, text=True, check=True, timeout=120)
    bad = json.loads(done.stdout.strip().splitlines()[-1])
    assert not bad, "calls that fail after `import clray` (show the import):\n" + "\n".join(
        f"{', '.join(calls[name])}: {name}(...)" for name in bad)


@pytest.mark.parametrize("name", ["clray.render", "clray.device.policy.vector_width",
                                  "clray.tuning.Tuning"])
def test_dotted_name_resolves(name: str) -> None:
    assert _resolves(name)


def test_moved_name_does_not() -> None:
    assert not _resolves("clray.device.program.vector_width")
