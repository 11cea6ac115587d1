"""The cold build compiles the single-ray renderer once (issue 42, docs/acceleration.md: The
kernel's body compiled once). PoCL inlines a kernel into its work-item loop and that loop into
two work-group functions, so a renderer inlined into the render kernel was compiled three
times at the first launch; `pixel_radiance` out of line is compiled once. Checked in the
machine code PoCL keeps: a cold build and first launch of the spheres scene in a new process
with an empty kernel cache (benchmarks/cold_build.py's child), then the symbols of the
render kernel's `render.so`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pyopencl as cl
import pytest

ROOT = Path(__file__).resolve().parent.parent


def _symbol_sizes(library: Path) -> dict[str, int]:
    """name -> bytes of each sized symbol, as `nm -S` lists them."""
    out = subprocess.run(["nm", "-S", str(library)], capture_output=True, text=True,
                         check=True).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4:
            sizes[parts[3]] = int(parts[1], 16)
    return sizes


def test_single_ray_renderer_is_compiled_once(cl_device: cl.Device, tmp_path: Path) -> None:
    if cl_device.platform.name.strip() != "Portable Computing Language":
        pytest.skip("the work-group functions and their kept files are PoCL's")
    if shutil.which("nm") is None:
        pytest.skip("needs nm (binutils)")
    env = dict(os.environ, POCL_CACHE_DIR=str(tmp_path),
               POCL_LEAVE_KERNEL_COMPILER_TEMP_FILES="1")
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "cold_build.py"),
                           "--child", str(ROOT / "scenes" / "spheres.toml")],
                          capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    assert "TRAVERSAL=TRAVERSAL_SINGLE" in " ".join(json.loads(done.stdout.splitlines()[-1])
                                                    ["options"])
    libraries = list(tmp_path.glob("*/*/render/*/render.so"))
    assert len(libraries) == 1, libraries
    sizes = _symbol_sizes(libraries[0])
    assert "pixel_radiance" in sizes, "the renderer was inlined into the render kernel"
    kernels = {name: size for name, size in sizes.items()
               if name.startswith("_pocl_kernel_render")}
    assert len(kernels) >= 2, sizes
    # Each of PoCL's functions holds the work-item loop and a call, not a copy of the
    # renderer: 602 to 1,000 bytes against pixel_radiance's 9,069 on PoCL 3.1 (AVX-512).
    for name, size in kernels.items():
        assert size < sizes["pixel_radiance"] / 4, (name, size, sizes["pixel_radiance"])
