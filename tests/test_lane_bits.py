"""lane_bits4 and lane_bits8 (kernels/real.h), which turn a comparison's lanes into bits at every
node and leaf a ray visits: x86's movmsk where the compiler offers it (X86_LANE_BITS), the OR
of halves elsewhere (-DPORTABLE_REDUCTIONS forces it). Both give bit k for lane k, for every
combination of lanes and for masks made by comparing floats, NaN among them."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from clray.device.context import context_for, queue_for
from clray.device.program import device_build_options, kernel_source

PROBE = r"""
__kernel void bits4(__global const int* m, __global int* out) {
    int i = get_global_id(0);
    out[i] = lane_bits4(vload4(i, m));
}

__kernel void bits8(__global const int* m, __global int* out) {
    int i = get_global_id(0);
    out[i] = lane_bits8(vload8(i, m));
}

// Masks as the walk makes them: a float comparison, ANDed with another.
__kernel void compared8(__global const float* a, __global const float* b,
                        __global int* out) {
    int i = get_global_id(0);
    float8 x = vload8(i, a), y = vload8(i, b);
    out[i] = lane_bits8((x <= y) & (y >= (float8)(0)));
}

__kernel void which(__global int* out) { out[0] = X86_LANE_BITS; }
"""


def build(device: cl.Device, portable: bool) -> cl.Program:
    options = [*device_build_options(device), *(["-DPORTABLE_REDUCTIONS"] if portable else [])]
    return cl.Program(context_for(device), kernel_source("real.h") + PROBE).build(options=options)


def call(device: cl.Device, kernel: cl.Kernel, count: int, *inputs: np.ndarray) -> np.ndarray:
    ctx, mf = context_for(device), cl.mem_flags
    given = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in inputs]
    out = np.zeros(count, np.int32)
    taken = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    kernel(queue_for(device), (count,), None, *given, taken)
    cl.enqueue_copy(queue_for(device), out, taken)
    return out


def all_masks(lanes: int) -> np.ndarray:
    return -np.array(list(itertools.product([0, 1], repeat=lanes)), dtype=np.int32)


def expected_bits(masks: np.ndarray) -> np.ndarray:
    return ((masks != 0) * (1 << np.arange(masks.shape[1]))).sum(axis=1).astype(np.int32)


@pytest.mark.parametrize("portable", [False, True])
def test_every_lane_combination(cl_device: cl.Device, portable: bool) -> None:
    program = build(cl_device, portable)
    for lanes, kernel in ((4, program.bits4), (8, program.bits8)):
        masks = all_masks(lanes)
        got = call(cl_device, kernel, len(masks), masks.ravel())
        np.testing.assert_array_equal(got, expected_bits(masks))


@pytest.mark.parametrize("portable", [False, True])
def test_masks_of_float_comparisons(cl_device: cl.Device, portable: bool) -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(512, 8)).astype(np.float32)
    b = rng.normal(size=(512, 8)).astype(np.float32)
    a[rng.random(a.shape) < 0.1] = np.nan
    b[rng.random(b.shape) < 0.1] = np.nan
    got = call(cl_device, build(cl_device, portable).compared8, 512, a.ravel(), b.ravel())
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(got, expected_bits((a <= b) & (b >= 0)))


def test_pocl_on_an_avx_machine_takes_movmsk(cl_device: cl.Device) -> None:
    # The fast form is the one the CPU renders take: a guard that stopped matching would
    # leave every walk on the OR of halves, the same images, slower, and no test would say so.
    cpu_flags = Path("/proc/cpuinfo").read_text(encoding="utf-8") if Path(
        "/proc/cpuinfo").exists() else ""
    if not cl_device.platform.name.startswith("Portable Computing Language") or \
            " avx " not in cpu_flags:
        pytest.skip("movmsk is expected on PoCL's CPU device of an x86 machine with AVX")
    assert call(cl_device, build(cl_device, False).which, 1)[0] == 1
    assert call(cl_device, build(cl_device, True).which, 1)[0] == 0
