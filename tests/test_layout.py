"""The numpy dtypes of clray/device/layout.py against sizeof/offsetof measured on the device."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from clray.accel import wide
from clray.device import layout
from clray.device.program import kernel_source


def _structs(bvh_width: int) -> dict[str, np.dtype]:
    return {**layout.STRUCTS, "BvhNode": layout.bvh_node_dtype(bvh_width)}


def _probe_source(bvh_width: int) -> tuple[str, list[tuple[str, str | None]]]:
    entries: list[tuple[str, str | None]] = []
    lines = []
    for struct, dtype in _structs(bvh_width).items():
        entries.append((struct, None))
        lines.append(f"out[{len(entries) - 1}] = (int)sizeof({struct});")
        for name in dtype.names:
            entries.append((struct, name))
            lines.append(f"out[{len(entries) - 1}] = (int)__builtin_offsetof({struct}, {name});")
    source = kernel_source("clray_types.h") + "\n__kernel void probe(__global int* out) {\n"
    return source + "\n".join(lines) + "\n}\n", entries


@pytest.mark.parametrize("bvh_width", layout.BVH_WIDTHS)
def test_struct_layout_matches_device(cl_ctx: cl.Context, bvh_width: int) -> None:
    source, entries = _probe_source(bvh_width)
    program = cl.Program(cl_ctx, source).build(options=[f"-DBVH_WIDTH={bvh_width}"])
    queue = cl.CommandQueue(cl_ctx)
    out = np.zeros(len(entries), dtype=np.int32)
    buf = cl.Buffer(cl_ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    program.probe(queue, (1,), None, buf)
    cl.enqueue_copy(queue, out, buf)
    mismatches = []
    for (struct, field), measured in zip(entries, out, strict=True):
        dtype = _structs(bvh_width)[struct]
        expected = dtype.itemsize if field is None else dtype.fields[field][1]
        if measured != expected:
            mismatches.append(f"{struct}.{field or 'sizeof'}: device {measured}, numpy {expected}")
    assert not mismatches, "; ".join(mismatches)


@pytest.mark.parametrize("bvh_width", layout.BVH_WIDTHS)
def test_structs_are_16_byte_multiples(bvh_width: int) -> None:
    for name, dtype in _structs(bvh_width).items():
        assert dtype.itemsize % 16 == 0, name


def test_header_constants_match_layout() -> None:
    header = kernel_source("clray_types.h")
    constants = {name: getattr(layout, name) for name in (
        "PRIM_SPHERE", "PRIM_TRIANGLE", "PRIM_INSTANCE", "PRIM_TYPE_SHIFT", "LIGHT_DIRECTIONAL",
        "TEXTURE_IMAGE", "TRIANGLE_SMOOTH", "TRIANGLE_UV", "ENTER_INSTANCE", "LEAVE_INSTANCE")}
    constants.update({name: getattr(wide, name) for name in (
        "PACKET_WIDTH", "LEAF_TRIANGLE_SHIFT", "LEAF_SPHERE_SHIFT", "LEAF_FIELD_MASK")})
    for name, value in constants.items():
        defined = [line.split(None, 2)[2] for line in header.splitlines()
                   if line.startswith(f"#define {name} ")]
        assert defined, name
        assert eval(defined[0].split("//")[0]) == value, name
