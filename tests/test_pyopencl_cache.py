"""pyopencl's caches under $XDG_CACHE_HOME where they cannot be used: the invoker cache that a
process's first kernel object makes (pytools/) is one error line, and the binary cache of the
builds (pyopencl/), which pyopencl does without, one warning line, never a traceback. Each in a
process of its own: a process makes the invoker cache once."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pyopencl as cl
from pyopencl.characterize import has_src_build_cache

ROOT = Path(__file__).resolve().parent.parent
SPHERES = ROOT / "scenes" / "spheres.toml"


def _render(cache: Path, out: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    env.pop("PYOPENCL_NO_CACHE", None)
    return subprocess.run([sys.executable, "-m", "clray", "render", str(SPHERES), "-W", "32",
                           "-H", "24", "-o", str(out)], capture_output=True, text=True,
                          env=env, timeout=300)


def test_an_invoker_cache_folder_in_the_way_is_one_error_line(cl_device: cl.Device,
                                                               tmp_path: Path) -> None:
    (tmp_path / "pytools").touch()
    done = _render(tmp_path, tmp_path / "out.png")
    assert done.returncode == 1
    assert done.stderr == (f"clray: error: cannot use pyopencl's cache folder "
                           f"{tmp_path / 'pytools'}: File exists: move what is in the way, or "
                           "set PYOPENCL_NO_CACHE=1 to run without pyopencl's caches\n")


def test_a_binary_cache_that_fails_is_one_warning_line(cl_device: cl.Device,
                                                       tmp_path: Path) -> None:
    (tmp_path / "pyopencl").touch()
    done = _render(tmp_path, tmp_path / "out.png")
    assert done.returncode == 0, done.stderr
    warned = [line for line in done.stderr.splitlines() if line.startswith("clray: warning:")]
    if has_src_build_cache(cl_device):  # PoCL: pyopencl leaves caching to the driver
        assert warned == []
    else:
        assert len(warned) == 1 and "Traceback" not in done.stderr
        assert warned[0].startswith("clray: warning: pyopencl's binary cache failed, built "
                                    "without it (NotADirectoryError: ")
