"""Packaging: the kernels ship inside the package and are read through importlib.resources, with
#line markers that lead back to every source line; the version is the same wherever it shows.

Installing a built wheel outside the checkout and rendering with it is .ci/run's job: it needs a
fresh virtual environment, too slow for every test run.
"""

from __future__ import annotations

import fnmatch
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import tomllib
from importlib.resources import files
from pathlib import Path

import pytest

import clray
from clray.device import program
from clray.device.program import ENTRY_FILE, KERNEL_PACKAGE, kernel_source

ROOT = Path(__file__).resolve().parent.parent
# Written independently of clray.device.program's own pattern, so a test does not share its bugs.
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"')
LINE_MARKER = re.compile(r'^#line (\d+) "([^"]+)"$')


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _kernel_sources() -> dict[str, list[str]]:
    """Every OpenCL source in the kernel package, as lines, by file name."""
    return {entry.name: entry.read_text(encoding="utf-8").splitlines()
            for entry in files(KERNEL_PACKAGE).iterdir()
            if entry.name.endswith((".cl", ".h"))}


def _reached(sources: dict[str, list[str]], name: str, seen: set[str]) -> set[str]:
    """`name` and every file its includes reach."""
    seen.add(name)
    for line in sources[name]:
        match = INCLUDE.match(line)
        if match and match.group(1) not in seen:
            _reached(sources, match.group(1), seen)
    return seen


def test_every_kernel_file_is_package_data() -> None:
    # The tests run against the checkout's kernels/ (an editable install): a file there that the
    # package-data patterns miss would be absent from the wheel, and only installs would fail.
    patterns = _pyproject()["tool"]["setuptools"]["package-data"][KERNEL_PACKAGE]
    shipped = [entry.name for entry in files(KERNEL_PACKAGE).iterdir()
               if entry.name not in ("__init__.py", "__pycache__")]
    assert ENTRY_FILE in shipped
    missed = [name for name in shipped
              if not any(fnmatch.fnmatch(name, pattern) for pattern in patterns)]
    assert not missed, f"kernel files outside package-data {patterns}: {missed}"


def test_every_subpackage_is_in_the_wheel() -> None:
    # The wheel's package list is written out (pyproject.toml): a new folder of the package that
    # it misses imports from the checkout but not from an install.
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    package = ROOT / "clray"
    found = {".".join(init.parent.relative_to(ROOT).parts) for init in package.rglob("__init__.py")}
    assert {"clray", "clray.shapes", "clray.lights"} <= found  # the scan found them
    assert found - listed == set()


def test_every_include_resolves_in_the_package() -> None:
    sources = _kernel_sources()
    for name, lines in sources.items():
        for line in lines:
            match = INCLUDE.match(line)
            assert match is None or match.group(1) in sources, f"{name}: {line.strip()}"
    for name in sources:
        assert kernel_source(name)


def test_line_markers_lead_back_to_every_source_line() -> None:
    """Build logs name the file and line that kernel_source() marked: every line of the inlined
    text must be that line of that file, and every line of every reached file must be there."""
    sources = _kernel_sources()
    emitted: set[tuple[str, int]] = set()
    where: tuple[str, int] | None = None
    for line in kernel_source().splitlines():
        marker = LINE_MARKER.match(line)
        if marker:
            where = (marker.group(2), int(marker.group(1)))
            continue
        assert where is not None, "text before the first #line marker"
        name, lineno = where
        original = sources[name][lineno - 1]
        # An include already inlined elsewhere leaves an empty line in its directive's place.
        assert line == original or (line == "" and INCLUDE.match(original)), (name, lineno)
        emitted.add(where)
        where = (name, lineno + 1)
    expected = {(name, lineno)
                for name in _reached(sources, ENTRY_FILE, set())
                for lineno, line in enumerate(sources[name], start=1)
                if not INCLUDE.match(line)}
    assert expected <= emitted, sorted(expected - emitted)[:5]


def test_kernel_source_is_kept_until_a_file_it_read_changes(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Every render asks for kernel_source(): the expanded text is kept, and expanded again when
    a file that went into it changes on disk, an included one (rng.h, two includes deep) too."""
    folder = tmp_path / "kernels"
    shutil.copytree(str(files(KERNEL_PACKAGE)), folder,
                    ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(program, "files", lambda package: folder)
    first = kernel_source()
    assert "// edited" not in first
    assert kernel_source() is first  # the kept text, not the same text expanded again
    header = folder / "rng.h"
    header.write_text(header.read_text(encoding="utf-8") + "// edited\n", encoding="utf-8")
    edited = kernel_source()
    assert edited.count("// edited") == 1  # inlined once, though two files include it
    assert kernel_source() is edited
    # An edit that keeps the size is seen by its time (set ahead: a coarse clock may not move).
    header.write_text(header.read_text(encoding="utf-8").replace("// edited", "// EDITED"),
                      encoding="utf-8")
    stat = header.stat()
    os.utime(header, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    assert "// EDITED" in kernel_source()


def test_version_is_the_same_everywhere() -> None:
    version = _pyproject()["project"]["version"]
    assert importlib.metadata.version("clray") == version
    assert clray.__version__ == version
    done = subprocess.run([sys.executable, "-m", "clray", "--version"], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"clray {version}"
