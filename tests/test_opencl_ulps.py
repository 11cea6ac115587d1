"""MATH_ULPS_OFF (kernels/real.h), the switch behind `--opencl-ulps`: each builtin it wraps
returns the device's own result moved by exactly OpenCL's error bound for it, in the asked
direction, for float and double, and a render built with it differs from one without."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from conftest import forced_ulps

from clray.device.context import context_for, has_fp64, queue_for
from clray.device.program import kernel_source, math_ulps_off, ulps_off_option
from clray.render import RenderSettings, render
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent

# The builtins and OpenCL's bounds for them (ulps), in the kernel's order.
BOUNDS = {"sin": 4, "cos": 4, "tan": 4, "asin": 4, "atan2": 6, "exp2": 3, "log2": 3}

KERNEL = """
__kernel void builtins(__global const T* x, __global T* out) {
    int i = get_global_id(0);
    T v = x[i];
    __global T* o = out + 7 * i;
    o[0] = sin(v);
    o[1] = cos(v);
    o[2] = tan(v);
    o[3] = asin(v * (T)0.25);
    o[4] = atan2(v, (T)1.5);
    o[5] = exp2(v);
    o[6] = log2(v + (T)4);
}
"""


def _builtins(device: cl.Device, dtype: type, x: np.ndarray, off: int) -> np.ndarray:
    type_name = "double" if dtype == np.float64 else "float"
    options = [f"-DT={type_name}"] + ([ulps_off_option(off)] if off else [])
    program = cl.Program(context_for(device), kernel_source("real.h") + KERNEL).build(options)
    queue = queue_for(device)
    mf = cl.mem_flags
    x_buf = cl.Buffer(queue.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    out = np.empty((len(x), 7), dtype=dtype)
    out_buf = cl.Buffer(queue.context, mf.WRITE_ONLY, out.nbytes)
    program.builtins(queue, (len(x),), None, x_buf, out_buf)
    cl.enqueue_copy(queue, out, out_buf)
    return out


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float", "double"])
@pytest.mark.parametrize("off", [1, -1])
def test_each_builtin_is_off_by_its_whole_bound(cl_device, dtype, off) -> None:
    if dtype == np.float64 and not has_fp64(cl_device):
        pytest.skip("the device has no cl_khr_fp64")
    x = np.array([-3.0, -1.25, -0.5, -1e-3, 0.0, 1e-3, 0.3, 0.5, 1.0, 2.0, 3.0], dtype=dtype)
    own = _builtins(cl_device, dtype, x, 0)
    moved = _builtins(cl_device, dtype, x, off)
    ulp = np.nextafter(np.abs(own), dtype(np.inf)) - np.abs(own)
    bounds = np.array(list(BOUNDS.values()), dtype=dtype)
    expected = own + dtype(off) * bounds * ulp
    assert np.all(np.isfinite(own))
    np.testing.assert_array_equal(moved, expected)
    assert np.all(moved != own)


def test_a_render_built_with_builtins_off_differs(cl_device, request) -> None:
    # The gate of `--opencl-ulps`: the render's build takes the switch (here the panorama's
    # atan2 and asin); were it dropped, the lane would test the device's own builtins again.
    if forced_ulps(request.config):
        pytest.skip("--opencl-ulps builds every render with the switch already")

    scene = load_scene(ROOT / "scenes" / "environment.toml")
    settings = RenderSettings(width=48, height=27, spp=1, stored_tuning=False)
    own = render(scene, settings).image
    with math_ulps_off(1):
        moved = render(scene, settings).image
    # And once it is over, renders are built as before.
    np.testing.assert_array_equal(render(scene, settings).image, own)
    assert not np.array_equal(own, moved)
    assert np.abs(own - moved).max() < 1e-3
