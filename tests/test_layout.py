"""The host/device contract checked on the device: the numpy dtypes of clray/device/layout.py
against sizeof/offsetof, every constant kernels/clray_types.h defines against its host twin, and
the scene buffers of the kernels' parameter lists (kernels/scene.h) against layout.SCENE_BUFFERS."""

from __future__ import annotations

import re

import numpy as np
import pyopencl as cl
import pytest

from clray.device import layout
from clray.device.program import KernelConfig, kernel_source


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


def _defined_constants() -> list[str]:
    """Every object-like #define of clray_types.h but its include guard."""
    header = kernel_source("clray_types.h")
    names = re.findall(r"^#define ([A-Z][A-Z0-9_]*)[ \t]+\S", header, flags=re.MULTILINE)
    return [name for name in names if name != "CLRAY_TYPES_H"]


def test_every_header_constant_has_a_host_twin() -> None:
    names = _defined_constants()
    # The known ones, so that a broken scan cannot pass by finding none.
    assert {"PRIM_BOX", "PRIM_CONE", "PRIM_INDEX_MASK", "LIGHT_SPOT", "TEXTURE_CHECKER",
            "PACKET_WIDTH", "LEAVE_INSTANCE"} <= set(names)
    assert [name for name in names if not hasattr(layout, name)] == []


def test_header_constants_match_layout_on_the_device(cl_ctx: cl.Context) -> None:
    names = _defined_constants()
    lines = [f"out[{i}] = (long)({name});" for i, name in enumerate(names)]
    source = (kernel_source("clray_types.h") + "\n__kernel void probe(__global long* out) {\n"
              + "\n".join(lines) + "\n}\n")
    program = cl.Program(cl_ctx, source).build(options=["-DBVH_WIDTH=8"])
    queue = cl.CommandQueue(cl_ctx)
    out = np.zeros(len(names), dtype=np.int64)
    buf = cl.Buffer(cl_ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    program.probe(queue, (1,), None, buf)
    cl.enqueue_copy(queue, out, buf)
    device = dict(zip(names, out.tolist(), strict=True))
    host = {name: getattr(layout, name) for name in names}
    assert device == host


def _scene_parameters(kernel: cl.Kernel, first: int) -> list[tuple[str, str]]:
    """(name, type) of the kernel's parameters from `first`, as many as there are buffers."""
    info = cl.kernel_arg_info
    return [(kernel.get_arg_info(i, info.NAME), kernel.get_arg_info(i, info.TYPE_NAME))
            for i in range(first, first + len(layout.SCENE_BUFFERS))]


_HOST_BUFFERS = [(b.name, f"{b.element}*") for b in layout.SCENE_BUFFERS]


def test_scene_buffer_macro_is_the_host_list(cl_ctx: cl.Context) -> None:
    source = kernel_source("scene.h") + "\n__kernel void probe(SCENE_BUFFER_PARAMS) {}\n"
    program = cl.Program(cl_ctx, source).build(options=["-DBVH_WIDTH=8", "-cl-kernel-arg-info"])
    kernel = program.probe
    assert kernel.num_args == len(layout.SCENE_BUFFERS)
    assert _scene_parameters(kernel, 0) == _HOST_BUFFERS


def test_kernels_take_the_scene_buffers_where_the_host_sets_them(cl_ctx: cl.Context) -> None:
    # render: the buffers first; intersect_rays: after the rays' origins and directions
    # (clray.device.launch sets the arguments in this order).
    program = cl.Program(cl_ctx, kernel_source()).build(
        options=[*KernelConfig(intersect_rays=True).options(), "-cl-kernel-arg-info"])
    assert _scene_parameters(cl.Kernel(program, "render"), 0) == _HOST_BUFFERS
    assert _scene_parameters(cl.Kernel(program, "intersect_rays"), 2) == _HOST_BUFFERS


def test_packed_scene_fields_are_the_scene_buffers() -> None:
    from clray.device.pack import PackedScene

    fields = list(PackedScene.__dataclass_fields__)
    assert fields[:len(layout.SCENE_BUFFERS)] == [b.name for b in layout.SCENE_BUFFERS]


def test_light_kinds_are_labels_one_a_light_class() -> None:
    from clray.lights import LIGHTS
    from clray.scene import model as M

    names = [name for name in _defined_constants() if name.startswith("LIGHT_")]
    # Every label of the header is one kind's of the registry, under the kind's name.
    assert sorted(names) == sorted(light.code_name for light in LIGHTS)
    assert len({light.code for light in LIGHTS}) == len(LIGHTS)
    assert {light.model for light in LIGHTS} == {*M.Light.__args__, M.TriangleLight, M.MeshLight}
    # The kernels name the kinds they mean: no comparison orders them.
    kernels = "".join(kernel_source(name) for name in ("lights.h", "direct.h", "shading.h"))
    assert re.findall(r"kind\s*[<>]|LIGHT_[A-Z]+\s*[<>]|[<>]=?\s*LIGHT_", kernels) == []


def test_the_kernels_sample_the_area_lights_of_the_registry() -> None:
    from clray.lights import LIGHTS

    body = re.search(r"bool is_area_light\(int kind\) \{(.*?)\}", kernel_source("lights.h"),
                     flags=re.DOTALL)
    assert body is not None
    assert sorted(re.findall(r"LIGHT_[A-Z]+", body.group(1))) == sorted(
        light.code_name for light in LIGHTS if light.area)
    # A kind's own switch is a build switch of the kernels.
    switches = {light.switch for light in LIGHTS if light.switch}
    assert switches and switches <= set(KernelConfig.__dataclass_fields__)
