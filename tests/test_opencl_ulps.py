"""MATH_ULPS_OFF (kernels/real.h), the switch behind `--opencl-ulps`: each transcendental builtin
it wraps returns the device's own result moved by exactly OpenCL's error bound for it, in the
asked direction, for float and double; dot(), length(), normalize() and mix() fuse the products
as a device may; and a render built with it differs from one without.

The kernels here are built with the options every build for the device gets
(device_build_options): on a GPU that offers it, float division and square root correctly
rounded, as the CPU drivers round them, so that the fused forms' oracles hold there too."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from conftest import forced_ulps

from clray.device.context import context_for, has_fp64, queue_for
from clray.device.program import (
    CORRECTLY_ROUNDED,
    device_build_options,
    kernel_source,
    math_ulps_off,
    ulps_off_option,
)
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


def _device_options(device: cl.Device) -> list[str]:
    """The options every build for `device` gets, less math_ulps_off's switch (--opencl-ulps
    sets it for the run; the tests here set it themselves, or leave it out)."""
    switch = ulps_off_option(1).partition("=")[0]
    return [o for o in device_build_options(device) if o.partition("=")[0] != switch]


def _rounds_divide_sqrt(device: cl.Device, dtype: type) -> bool:
    """Whether the kernels here divide and take square roots correctly rounded on `device`:
    in double always (OpenCL's bound is 0 ulp), in float on the CPU drivers and where the
    build asks for it (CORRECTLY_ROUNDED, on a GPU that offers it)."""
    return (dtype == np.float64 or not device.type & cl.device_type.GPU
            or CORRECTLY_ROUNDED in _device_options(device))


def _run(device: cl.Device, dtype: type, kernel: str, inputs: tuple[np.ndarray, ...],
         columns: int, off: int) -> np.ndarray:
    """`kernel`'s one kernel over `inputs` (one row a work-item), built with the device's
    options, T the dtype's type and T3 its 3-vector, and MATH_ULPS_OFF=off where off: its
    `columns` outputs a row."""
    type_name = "double" if dtype == np.float64 else "float"
    options = [*_device_options(device), f"-DT={type_name}", f"-DT3={type_name}3"]
    options += [ulps_off_option(off)] if off else []
    program = cl.Program(context_for(device), kernel_source("real.h") + kernel).build(options)
    queue = queue_for(device)
    mf = cl.mem_flags
    bufs = [cl.Buffer(queue.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
            for x in inputs]
    out = np.empty((len(inputs[0]), columns), dtype=dtype)
    out_buf = cl.Buffer(queue.context, mf.WRITE_ONLY, out.nbytes)
    program.all_kernels()[0](queue, (len(inputs[0]),), None, *bufs, out_buf)
    cl.enqueue_copy(queue, out, out_buf)
    return out


def _builtins(device: cl.Device, dtype: type, x: np.ndarray, off: int) -> np.ndarray:
    return _run(device, dtype, KERNEL, (x,), len(BOUNDS), off)


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


GEOMETRY_KERNEL = """
__kernel void geometry(__global const T* a, __global const T* b, __global T* out) {
    int i = get_global_id(0);
    T3 u = vload3(i, a), v = vload3(i, b);
    __global T* o = out + 8 * i;
    o[0] = dot(u, v);
    o[1] = length(u);
    vstore3(normalize(u), 0, o + 2);
    vstore3(mix(u, v, (T)0.3), 0, o + 5);
}
"""


def _geometry(device: cl.Device, dtype: type, a: np.ndarray, b: np.ndarray,
              off: int) -> np.ndarray:
    return _run(device, dtype, GEOMETRY_KERNEL, (a, b), 8, off)


def _rounded(exact: Fraction, dtype: type) -> float:
    """`exact` rounded once to dtype, to nearest, ties to even."""
    near = dtype(float(exact))
    candidates = [near, np.nextafter(near, dtype(np.inf)), np.nextafter(near, dtype(-np.inf))]
    bits = np.uint64 if dtype == np.float64 else np.uint32
    return min(candidates, key=lambda c: (abs(Fraction(float(c)) - exact),
                                          int(np.array(c).view(bits)) & 1))


def _within_ulps(got: np.ndarray, want: np.ndarray, ulps: float) -> None:
    spacing = np.spacing(np.abs(want).astype(want.dtype))
    assert np.all(np.abs(got.astype(np.float64) - want) <= ulps * spacing), (got, want)


def _fused(terms: list[tuple[np.ndarray, np.ndarray]], dtype: type) -> np.ndarray:
    """An fma chain's value: the first product rounded to dtype, then each further product
    added exactly to the running sum and the sum rounded once."""
    (u, v), rest = terms[0], terms[1:]
    acc = (u * v).astype(dtype)
    for u, v in rest:
        acc = np.array([_rounded(Fraction(float(x)) * Fraction(float(y)) + Fraction(float(z)),
                                 dtype) for x, y, z in zip(u, v, acc, strict=True)], dtype=dtype)
    return acc


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float", "double"])
@pytest.mark.parametrize("off", [1, -1])
def test_geometric_builtins_and_mix_fuse_their_products(cl_device, dtype, off) -> None:
    # The oracle of the fused chain (_fused): fma rounds once, so each step is the exact
    # product plus the running sum, rounded to dtype.
    if dtype == np.float64 and not has_fp64(cl_device):
        pytest.skip("the device has no cl_khr_fp64")
    rng = np.random.default_rng(3)
    a = rng.uniform(-3, 3, (64, 3)).astype(dtype)
    b = rng.uniform(-3, 3, (64, 3)).astype(dtype)
    moved = _geometry(cl_device, dtype, a, b, off)
    order = (0, 1, 2) if off > 0 else (2, 1, 0)

    def fused_dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return _fused([(u[:, k], v[:, k]) for k in order], dtype)

    dd = fused_dot(a, a)
    np.testing.assert_array_equal(moved[:, 0], fused_dot(a, b))
    if _rounds_divide_sqrt(cl_device, dtype):
        np.testing.assert_array_equal(moved[:, 1], np.sqrt(dd))
        np.testing.assert_array_equal(moved[:, 2:5], a / np.sqrt(dd)[:, None])
    else:  # OpenCL's bounds: a square root 3 ulp off, a division 2.5
        _within_ulps(moved[:, 1], np.sqrt(dd), 3)
        _within_ulps(moved[:, 2:5], a / moved[:, 1:2], 2.5)
    span = (b - a).astype(dtype)
    mixed = [_fused([(a[:, k], np.ones(len(a), dtype)), (span[:, k],
                                                          np.full(len(a), 0.3, dtype))], dtype)
             for k in range(3)]
    np.testing.assert_array_equal(moved[:, 5:], np.stack(mixed, axis=1))
    # The inputs tell a fused chain from one that rounds every product: somewhere they part.
    unfused = ((a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) + a[:, 2] * b[:, 2]).astype(dtype)
    assert np.any(unfused != moved[:, 0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float", "double"])
def test_the_cpus_own_dot_is_not_the_fused_one(cl_device, dtype) -> None:
    # The CPU drivers' dot() rounds every product, so a dot() that the switch left as it was
    # differs from both fused orders somewhere. OpenCL lets a device's own dot() fuse (a GPU's
    # may, in either order): there the fused forms are checked against their oracle alone.
    if not cl_device.type & cl.device_type.CPU:
        pytest.skip("a device's own dot() may fuse its products: only the CPU drivers' is "
                    "known not to")
    if dtype == np.float64 and not has_fp64(cl_device):
        pytest.skip("the device has no cl_khr_fp64")
    rng = np.random.default_rng(3)
    a = rng.uniform(-3, 3, (64, 3)).astype(dtype)
    b = rng.uniform(-3, 3, (64, 3)).astype(dtype)
    own = _geometry(cl_device, dtype, a, b, 0)
    for off in (1, -1):
        assert np.any(own[:, 0] != _geometry(cl_device, dtype, a, b, off)[:, 0])


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
