"""Images of any size render within the device's limits, in bands of rows; scenes that cannot
fit the device are refused before any buffer is made; the host's memory for packing a mesh
and for the render's buffers stays near the scene's device bytes (docs/scale.md)."""

from __future__ import annotations

import dataclasses
import gc
import importlib
import tracemalloc
import weakref
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from test_intersect import mesh_gen

from clray.accel.bvh import build_bvh
from clray.accel.wide import collapse
from clray.device import bvh_builder
from clray.device.buffers import read_only_buffer
from clray.device.context import queue_for
from clray.device.launch import band_capacity
from clray.device.pack import pack_scene
from clray.device.program import is_oclgrind
from clray.errors import DeviceError
from clray.render import RenderSettings, render
from clray.scene import model as M
from clray.scene.load import load_scene

MIB = 1 << 20
ROOT = Path(__file__).resolve().parent.parent
# `clray.render` the attribute is the function; the module is needed for monkeypatching.
launch_module = importlib.import_module("clray.device.launch")
pack_module = importlib.import_module("clray.device.pack")


def _scene(width: int, height: int) -> M.Scene:
    return M.Scene(None, M.RenderOptions(width, height, 1, 0, (0.0, 0.0, 0.0)),
                   M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), vfov=40.0),
                   (M.Material("m"),), (M.PointLight((2.0, 3.0, 4.0)),),
                   (M.Sphere((0, 0, 0), 1, 0),))


def _packed(width: int, height: int):
    return pack_scene(_scene(width, height), width=width, height=height, spp=1, max_depth=0,
                      seed=0)


def test_band_fits_the_largest_allocation():
    packed = _packed(1024, 1024)  # 16 KiB a row per output buffer
    assert band_capacity(packed, global_mem=64 * MIB, max_alloc=16 * MIB) == 1024
    assert band_capacity(packed, global_mem=64 * MIB, max_alloc=15 * MIB) == 960


def test_band_fits_beside_the_scene_in_global_memory():
    packed = _packed(1024, 1024)
    room = 8 * MIB + sum(packed.device_bytes().values())
    # Two output buffers (radiance, ray counts) of 16 KiB a row share the 8 MiB.
    assert band_capacity(packed, global_mem=room, max_alloc=64 * MIB) == 256


def test_band_capacity_is_bounded_for_huge_images(monkeypatch):
    monkeypatch.setattr(launch_module, "MAX_BAND_BYTES", 1 * MIB)
    packed = _packed(16384, 16384)
    assert band_capacity(packed, global_mem=1 << 40, max_alloc=1 << 40) == 4


def test_scene_over_the_device_is_refused():
    packed = _packed(64, 64)
    scene_bytes = sum(packed.device_bytes().values())
    largest = max(packed.device_bytes().values())
    with pytest.raises(DeviceError, match=r"buffer needs .* over the device's largest"):
        band_capacity(packed, global_mem=1 << 30, max_alloc=largest - 1)
    with pytest.raises(DeviceError, match=r"scene needs .* leave for rendering"):
        band_capacity(packed, global_mem=scene_bytes + 100, max_alloc=1 << 30)


def test_image_in_small_bands_is_identical(cl_device, monkeypatch):
    scene = _scene(96, 40)
    whole = render(scene, RenderSettings(spp=2))
    # Three rows of 96 pixels a band: the bands, not the launches' timing, split the image.
    monkeypatch.setattr(launch_module, "MAX_BAND_BYTES", 3 * 96 * 16)
    banded = render(scene, RenderSettings(spp=2))
    assert banded.stats["launches"] >= 14
    np.testing.assert_array_equal(banded.image, whole.image)
    assert banded.stats["rays"] == whole.stats["rays"]


def test_spare_rows_come_out_of_the_band():
    packed = _packed(1024, 1024)
    assert band_capacity(packed, global_mem=64 * MIB, max_alloc=15 * MIB, spare_rows=7) == 953
    room = 8 * MIB + sum(packed.device_bytes().values())
    assert band_capacity(packed, global_mem=room, max_alloc=64 * MIB, spare_rows=3) == 253


@pytest.mark.parametrize("count_tests", [False, True])
def test_group_packets_output_buffers_stay_within_the_band_cap(cl_device, monkeypatch,
                                                               count_tests):
    # Group packets' launches cover whole 8 x 8 tiles, whose rows past the band land in spare
    # rows: those come out of the band, so no output buffer is over the cap (on a device, its
    # largest allocation), and the image is the one of a single launch.
    from clray.render import pack_for
    from clray.tuning import Tuning

    width = 96
    scene = _scene(width, 40)
    settings = RenderSettings(spp=2, traversal="group_packet", tuning=Tuning(group_side=8))
    packed = pack_for(scene, settings, cl_device)
    packed = dataclasses.replace(packed, config=dataclasses.replace(packed.config,
                                                                    count_tests=count_tests))
    whole, _ = launch_module.render_packed(packed, cl_device)
    cap = 8 * width * 16  # eight rows of the widest output, 16 bytes a pixel
    monkeypatch.setattr(launch_module, "MAX_BAND_BYTES", cap)
    sizes: list[int] = []
    real_buffer = cl.Buffer

    def recording_buffer(ctx, flags, size=0, hostbuf=None):
        if flags & cl.mem_flags.WRITE_ONLY:
            sizes.append(size)
        return real_buffer(ctx, flags, size, hostbuf)

    monkeypatch.setattr(cl, "Buffer", recording_buffer)
    banded, stats = launch_module.render_packed(packed, cl_device)
    assert len(sizes) == 3 and max(sizes) <= cap, sizes
    assert stats["launches"] >= 40 // 8
    np.testing.assert_array_equal(banded, whole)


def _mesh_scene(subdivisions: int) -> M.Scene:
    vertices, faces, _ = mesh_gen.bumpy_mesh(subdivisions)
    return M.Scene(None, M.RenderOptions(64, 48, 1, 0, (0.0, 0.0, 0.0)),
                   M.Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0)), (M.Material("m"),),
                   (M.PointLight((2.0, 3.0, 4.0)),),
                   (M.Mesh(vertices=vertices, faces=faces, material=0),))


def test_a_meshs_bounds_are_the_device_builds_primitives(cl_device, monkeypatch):
    # The pack writes a mesh's float32 bounds (24 B a triangle) into the device build's own
    # primitive records (bvh_builder.float_prims): the build takes them as its first buffer,
    # with no bounds beside it and no copy of them on the device.
    scene = _mesh_scene(5)
    if not bvh_builder.supports(cl_device, 20480, 4):
        pytest.skip("the device does not build BVHs")
    read, given = [], []
    real_read, real_prims_of = bvh_builder.read_only_buffer, bvh_builder._prims_of

    def read_only_buffer(ctx: cl.Context, array: np.ndarray) -> cl.Buffer:
        read.append(array.ndim)
        return real_read(ctx, array)

    def prims_of(lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
        given.append(real_prims_of(lo, hi))
        return given[-1]

    monkeypatch.setattr(bvh_builder, "read_only_buffer", read_only_buffer)
    monkeypatch.setattr(bvh_builder, "_prims_of", prims_of)
    pack_scene(scene, width=64, height=48, spp=1, max_depth=0, seed=0,
               queue=queue_for(cl_device))
    assert len(given) == 1 and given[0] is not None and len(given[0]) == 20480
    assert 2 not in read  # only the task lists (1-D) were read from the host


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_a_meshs_finite_vertices_spare_the_builds_scans_of_its_bounds(cl_device, monkeypatch):
    # Triangle boxes made from finite float32 vertices are finite with lo <= hi, so the build
    # skips its three passes over the bounds (0.14 s at 5.24 M triangles); bounds of other
    # kinds, or a vertex that float32 cannot hold, keep them.
    if not bvh_builder.supports(cl_device, 20480, 4):
        pytest.skip("the device does not build BVHs")
    said, real = [], bvh_builder.checked_bounds

    def checked_bounds(*args: object) -> tuple:
        said.append(args[-1])
        return real(*args)

    monkeypatch.setattr(bvh_builder, "checked_bounds", checked_bounds)
    settings = {"width": 64, "height": 48, "spp": 1, "max_depth": 0, "seed": 0,
                "queue": queue_for(cl_device)}
    scene = _mesh_scene(5)
    pack_scene(scene, **settings)
    pack_scene(dataclasses.replace(scene, objects=(*scene.objects, M.Sphere((0, 0, 0), 1, 0))),
               **settings)
    assert said == [True, False]
    mesh = scene.objects[0]
    vertices = mesh.vertices.copy()
    vertices[7] = (1e39, 0.0, 0.0)  # inf in float32
    with pytest.raises(ValueError, match="finite"):
        pack_scene(dataclasses.replace(scene, objects=(
            dataclasses.replace(mesh, vertices=vertices),)), **settings)
    assert said[2:] == [False]


def test_device_build_frees_other_bounds_before_its_buffers_fill(cl_device, monkeypatch):
    # Bounds that are not the build's records (float64: spheres, boxes; or float32 from
    # elsewhere) are rounded into them by a kernel that reads them in place on a CPU device;
    # once it is done nothing holds them, before the build's primitives and node slots fill.
    rng = np.random.default_rng(3)
    if not bvh_builder.supports(cl_device, 20480, 8):
        pytest.skip("the device does not build BVHs")
    queue = queue_for(cl_device)
    copied, checked = [], []
    real_read, real_split = bvh_builder.read_only_buffer, bvh_builder._split_levels

    def read_only_buffer(ctx: cl.Context, array: np.ndarray) -> cl.Buffer:
        if array.ndim == 2:  # the bounds, not the task lists
            copied.append(weakref.ref(array))
        return real_read(ctx, array)

    def split_levels(*args: object) -> np.ndarray:
        checked.append([ref() is None for ref in copied])
        return real_split(*args)

    monkeypatch.setattr(bvh_builder, "read_only_buffer", read_only_buffer)
    monkeypatch.setattr(bvh_builder, "_split_levels", split_levels)
    for dtype in (np.float64, np.float32):
        centres = rng.uniform(-1.0, 1.0, (20480, 3))
        bounds = [(centres - 0.01).astype(dtype), (centres + 0.01).astype(dtype)]
        bvh_builder.build_bvh_from(queue, bounds, 4)
        assert bounds == []
    assert checked == [[True, True], [True, True, True, True]]


def _device_built_mesh(cl_device: cl.Device) -> tuple[M.Scene, int, dict]:
    """The 81,920-triangle mesh scene, its triangle count and pack_scene's settings for a
    device BVH build, packed once so that the build's program is compiled before measuring."""
    scene = _mesh_scene(6)
    n = len(scene.objects[0].faces)
    if not bvh_builder.supports(cl_device, n, 4):
        pytest.skip("the device does not build BVHs")
    settings = {"width": 64, "height": 48, "spp": 1, "max_depth": 0, "seed": 0,
                "queue": queue_for(cl_device)}
    pack_scene(scene, **settings)
    return scene, n, settings


def test_pack_of_a_mesh_peaks_within_its_device_bytes_beside_the_build(cl_device):
    # The pack's host allocations (numpy's, which tracemalloc sees) at their peak, beside the
    # device BVH build's own buffers (its primitives, node slots and order: the build's, sized
    # by bvh_builder.build_buffer_bytes), stay under the packed scene's device bytes. The pack
    # held the mesh's bounds, int64 references and an owner a triangle through the build and
    # the collapse, and gathered every corner at once: 1.24 times the device bytes there at
    # 81,920 triangles (issue 43).
    scene, n, settings = _device_built_mesh(cl_device)
    tracemalloc.start()
    try:
        packed = pack_scene(scene, **settings)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    build = bvh_builder.build_buffer_bytes(n, 4)
    own = build["prims"] + build["prims_stash"] + build["nodes"] + build["order"]
    assert peak - own <= sum(packed.device_bytes().values())


def test_the_device_build_starts_beside_the_primitives_and_faces_alone(cl_device, monkeypatch):
    # When the device build starts, the pack holds the build's primitive records (32 B a
    # triangle, its bounds written in) and the triangle records (16 B: this mesh's int64 faces
    # are written out), and no more: the camera-relative vertices (16 B a vertex) are let go
    # (a mesh alone's packets take its own vertices), and a mesh's references are a run, not
    # an array (4 B a triangle). Both were held through the build, the pack's highest stage
    # (docs/scale.md).
    scene, n, settings = _device_built_mesh(cl_device)
    held = []
    build = bvh_builder.build

    def spy(*args, **kwargs):
        held.append(tracemalloc.get_traced_memory()[0])
        return build(*args, **kwargs)

    monkeypatch.setattr(bvh_builder, "build", spy)
    tracemalloc.start()
    try:
        pack_scene(scene, **settings)
    finally:
        tracemalloc.stop()
    assert len(held) == 1
    assert held[0] <= n * (32 + 16) + 64 * 1024


def test_triangle_count_counts_the_triangle_slots(cl_device):
    # Packed a chunk at a time: every triangle of the mesh once, and not the sphere beside it.
    scene = _mesh_scene(6)
    n = len(scene.objects[0].faces)
    scene = dataclasses.replace(scene, objects=(*scene.objects, M.Sphere((0, 0, 0), 0.1, 0)))
    packed = pack_scene(scene, width=64, height=48, spp=1, max_depth=0, seed=0,
                        queue=queue_for(cl_device))
    assert packed.triangle_count() == n


@pytest.mark.parametrize("width", [4, 8])
def test_cpu_device_reads_the_wide_nodes_in_place(cl_ctx, width):
    # The collapse aligns its nodes to their own size: in numpy's usual place, 16 bytes into a
    # page, a CPU device copied them (49 MiB while a 5.24 M-triangle mesh rendered).
    device = cl_ctx.devices[0]
    if not device.type & cl.device_type.CPU or is_oclgrind(device):
        pytest.skip("copied where the device is not the host (and on Oclgrind)")
    rng = np.random.default_rng(width)
    centres = rng.uniform(-1.0, 1.0, (3000, 3))
    for n in (3000, 40, 1):  # arrays of every size: numpy places small ones otherwise
        nodes = collapse(build_bvh(centres[:n] - 0.01, centres[:n] + 0.01),
                         np.arange(n, dtype=np.int32), width).nodes
        assert nodes.ctypes.data % nodes.itemsize == 0
        assert read_only_buffer(cl_ctx, nodes).flags & cl.mem_flags.USE_HOST_PTR


def test_cpu_device_reads_a_scene_with_instances_nodes_in_place(cl_ctx):
    # The scene's tree and its groups' trees are joined into nodes aligned as the collapse
    # aligns one tree's: joined by np.concatenate, they were copied for the render.
    device = cl_ctx.devices[0]
    if not device.type & cl.device_type.CPU or is_oclgrind(device):
        pytest.skip("copied where the device is not the host (and on Oclgrind)")
    packed = pack_scene(load_scene(ROOT / "scenes" / "instances.toml"), width=64, height=48,
                        spp=1, max_depth=2, seed=0)
    assert len(packed.instances) > 0
    assert packed.nodes.ctypes.data % packed.nodes.itemsize == 0
    assert read_only_buffer(cl_ctx, packed.nodes).flags & cl.mem_flags.USE_HOST_PTR


def test_cpu_device_reads_scene_buffers_in_place(cl_ctx):
    # A CPU device's memory is the host's: a copy of each scene buffer doubled the scene in
    # host memory while it rendered. Rows placed otherwise across the cache lines than in the
    # device's own allocation are copied (a float4 row 4 bytes off its 16).
    device = cl_ctx.devices[0]
    if not device.type & cl.device_type.CPU or is_oclgrind(device):
        pytest.skip("copied where the device is not the host (and on Oclgrind)")
    array = np.arange(4096, dtype=np.float32).reshape(-1, 4)
    buf = read_only_buffer(cl_ctx, array)
    assert buf.flags & cl.mem_flags.USE_HOST_PTR
    assert np.shares_memory(buf.get_host_array(array.shape, array.dtype), array)
    shifted = array.reshape(-1)[1:-3].reshape(-1, 4)
    assert not read_only_buffer(cl_ctx, shifted).flags & cl.mem_flags.USE_HOST_PTR


def test_render_lets_a_handed_over_scene_go_before_the_render(cl_device, monkeypatch):
    # Given a callable (as clray render hands its scene over), render holds the scene alone
    # and lets it go once packed: a big model's mesh is not held beside the packed scene
    # while the kernel runs. A scene the caller passes in stays the caller's.
    render_module = importlib.import_module("clray.render")
    faces = []
    alive = []
    render_packed = render_module.render_packed

    def spy(*args, **kwargs):
        gc.collect()
        alive.append(faces[-1]() is not None)
        return render_packed(*args, **kwargs)

    def handed_over() -> M.Scene:
        scene = _mesh_scene(2)
        faces.append(weakref.ref(scene.objects[0].faces))
        return scene

    monkeypatch.setattr(render_module, "render_packed", spy)
    settings = RenderSettings(width=32, height=24)
    first = render(handed_over, settings)
    kept = handed_over()
    second = render(kept, settings)
    assert alive == [False, True]
    assert np.array_equal(first.image, second.image)
