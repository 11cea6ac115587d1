"""exponent_of and power_of_two (kernels/real.h), the powers of two that the torus's units and an
instance's rows take from REAL's bits in place of ilogb and ldexp: built alone in float and in
double, exponent_of(x) is frexp's exponent less one for every positive normal x (powers of two,
their neighbours either side, the loader's 1e-30 and 1e30, the range's ends), power_of_two(e)
is ldexp(1, e) over the whole normal range, and x * power_of_two(e) is ldexp(x, e) bit for bit
where the result is normal."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from clray.device.context import context_for, has_fp64, queue_for
from clray.device.program import device_build_options, kernel_source

PROBE = r"""
__kernel void exponents(__global const REAL* x, __global int* out) {
    int i = get_global_id(0);
    out[i] = exponent_of(x[i]);
}

__kernel void powers(__global const REAL* x, __global const int* e, __global REAL* power,
                     __global REAL* scaled) {
    int i = get_global_id(0);
    power[i] = power_of_two(e[i]);
    scaled[i] = x[i] * power_of_two(e[i]);
}
"""

DTYPES = {"float": np.float32, "double": np.float64}


def build(device: cl.Device, precision: str) -> cl.Program:
    if precision == "double" and not has_fp64(device):
        pytest.skip("the device has no cl_khr_fp64")
    options = [*device_build_options(device)]
    if precision == "double":
        options.append("-DUSE_DOUBLE")
    return cl.Program(context_for(device), kernel_source("real.h") + PROBE).build(options=options)


def run(
    device: cl.Device, kernel: cl.Kernel, inputs: list[np.ndarray], outputs: list[np.ndarray]
) -> None:
    ctx, queue, mf = context_for(device), queue_for(device), cl.mem_flags
    given = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in inputs]
    taken = [cl.Buffer(ctx, mf.WRITE_ONLY, a.nbytes) for a in outputs]
    kernel(queue, (len(outputs[0]),), None, *given, *taken)
    for a, buf in zip(outputs, taken, strict=True):
        cl.enqueue_copy(queue, a, buf)


def normal_exponents(dtype: type) -> np.ndarray:
    info = np.finfo(dtype)
    return np.arange(info.minexp, info.maxexp, dtype=np.int32)


@pytest.mark.parametrize("precision", list(DTYPES))
def test_exponent_of_is_frexps_exponent_less_one(cl_device, precision) -> None:
    program = build(cl_device, precision)
    dtype = DTYPES[precision]
    info = np.finfo(dtype)
    powers = np.ldexp(dtype(1), normal_exponents(dtype))
    rng = np.random.default_rng(7)
    x = np.concatenate(
        [
            powers,
            np.nextafter(powers[1:], dtype(0)),  # just below: the exponent below
            np.nextafter(powers, dtype(np.inf)),
            np.array([1e-30, 1e30, 3.0, 0.75, 1.5, info.tiny, info.max], dtype=dtype),
            (
                rng.uniform(1, 2, 2000) * np.exp2(rng.integers(info.minexp, info.maxexp, 2000))
            ).astype(dtype),
        ]
    ).astype(dtype)
    assert np.all(x >= info.tiny) and np.all(np.isfinite(x))
    got = np.empty(len(x), np.int32)
    run(cl_device, program.exponents, [x], [got])
    want = np.frexp(x)[1] - 1
    bad = np.flatnonzero(got != want)
    assert not len(bad), f"{x[bad[:5]]}: {got[bad[:5]]}, not {want[bad[:5]]}"


@pytest.mark.parametrize("precision", list(DTYPES))
def test_power_of_two_is_ldexps_and_its_product_too(cl_device, precision) -> None:
    program = build(cl_device, precision)
    dtype = DTYPES[precision]
    info = np.finfo(dtype)
    every = normal_exponents(dtype)
    rng = np.random.default_rng(11)
    n = 4000
    # Values from 1e-30 to 1e30 and their neighbours of powers of two, each scaled by a random
    # exponent in the normal range; kept where ldexp's result is normal.
    values = np.concatenate(
        [
            np.array([1e-30, 1e30, 1.0], dtype=dtype),
            np.nextafter(np.ldexp(dtype(1), np.arange(-99, 100)), dtype(0)),
            np.nextafter(np.ldexp(dtype(1), np.arange(-99, 100)), dtype(np.inf)),
            (rng.uniform(1, 2, n) * np.exp2(rng.integers(-99, 100, n))).astype(dtype),
        ]
    ).astype(dtype)
    e_random = rng.integers(info.minexp, info.maxexp, len(values)).astype(np.int32)
    x = np.concatenate([np.ones(len(every), dtype), values]).astype(dtype)
    e = np.concatenate([every, e_random]).astype(np.int32)
    with np.errstate(over="ignore", under="ignore"):
        want = np.ldexp(x, e).astype(dtype)
    keep = np.isfinite(want) & (np.abs(want) >= info.tiny)
    keep[: len(every)] = True
    x, e, want = x[keep], e[keep], want[keep]
    power = np.empty(len(x), dtype)
    scaled = np.empty(len(x), dtype)
    run(cl_device, program.powers, [x, e], [power, scaled])
    assert np.array_equal(power, np.ldexp(dtype(1), e).astype(dtype))
    bad = np.flatnonzero(scaled != want)  # every value positive and finite: equal is bit for bit
    assert not len(bad), f"{x[bad[:5]]} * 2^{e[bad[:5]]}: {scaled[bad[:5]]}, not {want[bad[:5]]}"
    assert len(x) > len(every) + n // 2  # most random products are in range
