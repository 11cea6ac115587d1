"""Every kernel under Oclgrind, the OpenCL device simulator that reports what CPU drivers
forgive: reads and writes out of bounds, uninitialised values, invalid API calls, data races.
Tiny scenes that between them switch on every kernel feature, in float and double, the
intersection kernel, and the device BVH build; no report allowed, and the same results as the
device under test (docs/rendering.md, Conformance)."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys

import numpy as np
import oclgrind_run as R
import pytest

from clray.device.pack import pack_scene
from clray.device.program import KernelConfig
from clray.scene.load import load_scene

OCLGRIND = shutil.which("oclgrind")
pytestmark = pytest.mark.skipif(
    OCLGRIND is None, reason="oclgrind is not installed (Debian: apt-get install oclgrind)")
# The render and intersection kernels with race detection too; the BVH build without it:
# with --data-races on, Oclgrind 21.10 takes the primitives round_prims wrote into a
# USE_HOST_PTR buffer for uninitialised when root_task reads them (docs/rendering.md), as it
# does in a second build in one process: the float-bounds build runs on its own.
RUNS = {"renders,intersections": ("--check-api", "--uninitialized", "--data-races"),
        "bvh": ("--check-api", "--uninitialized"), "bvh_float": ("--check-api", "--uninitialized")}


@pytest.fixture(scope="module")
def oclgrind_results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, np.ndarray]:
    tmp = tmp_path_factory.mktemp("oclgrind")
    # pyopencl's program cache would hand Oclgrind a binary built before, with other options.
    env = {**os.environ, "PYOPENCL_NO_CACHE": "1"}
    env.pop("CLRAY_DEVICE", None)
    results: dict[str, np.ndarray] = {}
    for parts, flags in RUNS.items():
        out = tmp / f"{parts.replace(',', '_')}.npz"
        run = subprocess.run([OCLGRIND, *flags, sys.executable, R.__file__, str(out),
                              "oclgrind", parts], env=env, capture_output=True, text=True,
                             timeout=600)
        # Oclgrind reports on stderr, each report a block naming its kernel; the driver's own
        # progress lines start with its name.
        reports = "\n".join(line for line in run.stderr.splitlines()
                            if line.strip() and not line.startswith("oclgrind_run:"))
        assert run.returncode == 0 and not reports, (
            f"oclgrind {' '.join(flags)} ({parts}): exit {run.returncode}\n{reports[-6000:]}")
        results.update(np.load(out))
    return results


def test_the_scenes_switch_on_every_feature() -> None:
    on = set()
    for path in sorted(R.SCENES.glob("*.toml")):
        config = pack_scene(load_scene(path), width=R.WIDTH, height=R.HEIGHT, spp=R.SPP,
                            max_depth=4, seed=0).config
        on |= {f.name for f in dataclasses.fields(config) if getattr(config, f.name) is True}
    on |= {name for name, _ in R.VARIANTS} | set(R.RUN_SWITCHES)
    switches = {f.name for f in dataclasses.fields(KernelConfig) if f.type == "bool"}
    assert switches and on >= switches, sorted(switches - on)


def test_kernels_run_clean_under_oclgrind(cl_device, oclgrind_results) -> None:
    here = {**R.renders(None), **R.intersections(None), **R.bvh(None), **R.bvh_float(None)}
    assert set(here) == set(oclgrind_results)
    for name, image in here.items():
        theirs = oclgrind_results[name]
        if name.startswith("bvh/") or name in ("intersect/ref", "intersect/group_ref"):
            np.testing.assert_array_equal(theirs, image, err_msg=name)
        elif name.startswith("intersect/"):
            finite = np.isfinite(image)
            np.testing.assert_array_equal(np.isfinite(theirs), finite, err_msg=name)
            np.testing.assert_allclose(theirs[finite], image[finite], rtol=1e-5, atol=1e-6,
                                       err_msg=name)
        else:
            # Oclgrind builds without optimisation (no contraction into fma): float32 pixels
            # agree to rounding, double to far better.
            tol = 1e-12 if name.endswith("/double") else 1e-4
            np.testing.assert_allclose(theirs, image, rtol=tol, atol=tol, err_msg=name)



@pytest.mark.parametrize("args", [(), ("--spp", "4", "--precision", "double")],
                         ids=["float", "double-4spp"])
def test_a_render_makes_no_invalid_api_call(tmp_path, args) -> None:
    # The whole command as a user runs it, pyopencl's program cache on (in this test's own
    # cache directory): every device query clray or pyopencl makes must be one the device's
    # OpenCL version and extensions define. Any Oclgrind report fails, API errors included.
    env = {**os.environ}
    for name in ("CLRAY_DEVICE", "PYOPENCL_NO_CACHE", "PYOPENCL_CTX"):
        env.pop(name, None)
    out = tmp_path / "tiny.png"
    run = subprocess.run([OCLGRIND, "--check-api", "--uninitialized", sys.executable, "-m",
                          "clray", "render", str(R.SCENES / "spheres.toml"), "-W", "6",
                          "-H", "4", "-o", str(out), *args], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 0 and out.exists(), run.stderr[-4000:]
    assert len(lines) == 1 and lines[0].startswith("clray: wrote"), run.stderr[-4000:]
