"""Launching the kernels on a packed scene: its buffers on the device, bands of rows sized by
their time, the image and ray counts read back."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import pyopencl as cl

from clray.device.buffers import read_only_buffer
from clray.device.context import describe, device_type, queue_for
from clray.device.pack import PackedScene
from clray.device.program import build_program, cache_folder_errors
from clray.errors import DeviceError
from clray.host_memory import small_pages
from clray.knobs import DEFAULT_TUNING, GROUP_SIDES, TRAVERSAL_SCHEMES, Tuning

# Launches are sized by the time they take, not by their work, so that progress advances
# several times a second on any device and no launch nears a GPU watchdog, while a small render
# still takes a few launches: the first covers first_launch_pixel_samples, each later one the
# rows that the previous launch's rate does in launch_seconds, at most launch_growth times the
# previous band (one fast band of sky says little about the rows below it) and at most
# max_launch_pixel_samples: knobs of clray.tuning. Pixels are independent, so the image does not
# depend on the bands.


def _scene_buffers(ctx: cl.Context, packed: PackedScene) -> list[cl.Buffer]:
    """The scene's buffers on the device, in the kernels' parameter order (SCENE_BUFFERS)."""
    return [read_only_buffer(ctx, array) for array in packed.buffers().values()]


def next_band_rows(row_samples: int, last_rows: int, last_s: float, rows_left: int,
                   tuning: Tuning = DEFAULT_TUNING) -> int:
    """Rows of the next launch, given the pixel-samples in one row and the rows and device time
    of the previous launch (last_rows = 0 before the first), under `tuning`'s band knobs. At
    least one row, at most rows_left."""
    if last_rows == 0:
        rows = tuning.first_launch_pixel_samples // row_samples
    else:
        by_time = last_rows * tuning.launch_seconds / last_s if last_s > 0 else math.inf
        rows = min(by_time, tuning.launch_growth * last_rows,
                   tuning.max_launch_pixel_samples // row_samples)
    return int(max(1, min(rows_left, rows)))


# The output buffers (test counts 16 bytes a pixel, radiance 12, ray counts 8) hold one band of
# rows, at most this many bytes each: any image the format allows renders on any device, in
# bands, and a CPU device does not double the image in its memory.
MAX_BAND_BYTES = 256 << 20


def band_capacity(packed: PackedScene, global_mem: int, max_alloc: int,
                  outputs: int | None = None, spare_rows: int = 0) -> int:
    """The most rows one launch may render: its output buffers (`outputs` of 16 bytes a pixel:
    the render kernel's where None, its 12 and 8 bytes taken as 16), with `spare_rows` more
    rows each, within the device's largest allocation and, beside the scene's buffers, within
    its global memory. Refuses (DeviceError) a scene whose own buffers do not fit, before any
    buffer exists."""
    width, height = int(packed.params[0]["width"]), int(packed.params[0]["height"])
    scene = packed.device_bytes()
    mib = 1 << 20
    largest = max(scene, key=scene.__getitem__)
    if scene[largest] > max_alloc:
        raise DeviceError(f"the {largest} buffer needs {scene[largest] / mib:.0f} MiB, over the "
                          f"device's largest allocation ({max_alloc / mib:.0f} MiB): render a "
                          "smaller scene")
    if outputs is None:
        outputs = 3 if packed.config.count_tests else 2
    row_bytes = 16 * width
    room = global_mem - sum(scene.values())
    if room < outputs * row_bytes * (1 + spare_rows):
        raise DeviceError(f"the scene needs {sum(scene.values()) / mib:.0f} MiB of device "
                          f"memory, more than the device's {global_mem / mib:.0f} MiB leave for "
                          "rendering: render a smaller scene")
    return max(1, min(height, min(max_alloc, MAX_BAND_BYTES) // row_bytes - spare_rows,
                      room // (outputs * row_bytes) - spare_rows))


def check_argument_bytes(n_buffers: int, n_ints: int, device: cl.Device) -> None:
    """A launch's arguments within the device's CL_DEVICE_MAX_PARAMETER_SIZE (1,024 bytes at
    least; NVIDIA's 4,352): one pointer a buffer and 4 bytes an int. A driver past it fails
    the launch with a bare CL_INVALID_KERNEL_ARGS, or, as pyopencl warns of on NVIDIA, the
    build."""
    need = n_buffers * device.address_bits // 8 + 4 * n_ints
    if need > device.max_parameter_size:
        raise DeviceError(f"the render kernel's {n_buffers} buffers and {n_ints} ints take "
                          f"{need} bytes of arguments, over {describe(device)}'s "
                          f"CL_DEVICE_MAX_PARAMETER_SIZE of {device.max_parameter_size}")


def _group_width(kernel: cl.Kernel, device: cl.Device, tuning: Tuning) -> int:
    """Work-items per work-group, one row segment: the work_group_width knob, within the
    kernel's limit on the device. Never left to the driver: PoCL puts up to 4096 work-items in
    a group and gives them their private memory on one thread's stack, which a deep ray stack
    (MAX_DEPTH + 1 tasks of 80 bytes each, per work-item) overflows: a segfault at depth 28."""
    limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device)
    width = max(1, min(tuning.work_group_width, limit))
    if device_type(device) != "GPU":
        return width
    return gpu_group_width(width, limit, kernel.get_work_group_info(
        cl.kernel_work_group_info.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device))


def gpu_group_width(width: int, limit: int, multiple: int) -> int:
    """A GPU's work-group: whole warps or wavefronts (the kernel's preferred multiple, 32 on
    NVIDIA), so that no SIMT lane of a group's last one idles; the knob's width rounded down
    to a multiple, at least one multiple where the kernel's limit allows it. CPU drivers'
    multiples (128 on Intel's runtime) describe implicit vectorization across work-items,
    which the render kernels turn off, so there the knob's width stands."""
    if multiple <= 1 or multiple > limit:
        return width
    return max(multiple, width // multiple * multiple)


def _group_rows(packed: PackedScene) -> int:
    """The rows of the launch's work-group: group packets' tile is group_side rows high, a row
    segment one."""
    return packed.tuning.group_side if TRAVERSAL_SCHEMES[packed.config.traversal].tiles else 1


def _local_size(kernel: cl.Kernel, device: cl.Device, packed: PackedScene) -> tuple[int, int]:
    """The launch's work-group: a row segment (_group_width), or with group packets the tile of
    group_side x group_side pixels that walk the BVH together, which the device must take
    whole."""
    side = _group_rows(packed)
    if side == 1:
        return _group_width(kernel, device, packed.tuning), 1
    limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device)
    if side * side > limit:
        raise DeviceError(f"{describe(device)} runs at most {limit} work-items a group for this "
                          f"kernel, under group packets' {side} x {side}: render with a "
                          "smaller group_side or another traversal")
    return side, side


def _resource_hint(err: cl.Error, packed: PackedScene, tiles: bool) -> str:
    """What a launch that ran out of the device's resources can lower, of what this render
    could: registers and private memory grow with the ray tree's depth and with the lanes of
    the walks that carry several rays, and a group's share of them with its size (group
    packets' tile, where `tiles`, else work_group_width). work_group_width and group_side have
    no flag: they are tuning knobs."""
    if getattr(err, "code", None) not in (cl.status_code.OUT_OF_RESOURCES,
                                          cl.status_code.INVALID_WORK_GROUP_SIZE):
        return ""
    tuning = packed.tuning
    knob, value = (("group_side", tuning.group_side) if tiles else
                   ("work_group_width", tuning.work_group_width))
    advice = []
    if value > (min(GROUP_SIDES) if tiles else 1):
        advice.append(f"a smaller {knob} (now {value}; a tuning knob: clray.RenderSettings("
                      f"tuning=Tuning({knob}=N)) in Python, or the device's tuning file, "
                      "docs/tuning.md)")
    max_depth = int(packed.params[0]["max_depth"])
    if max_depth > 0:
        advice.append(f"a lower --max-depth (now {max_depth})")
    if packed.config.traversal != "single":
        advice.append("--traversal single")
    hint = "; the kernel needs more registers or private memory than the device has for a group"
    if not advice:
        return hint
    listed = advice[-1] if len(advice) == 1 else f"{', '.join(advice[:-1])}, or {advice[-1]}"
    return f"{hint}: render with {listed}"


class _Launch(NamedTuple):
    """What a launch over a packed scene starts from: the program (and its build time), the
    queue, the image's width and samples a pixel, and the rows asked for, from `first` on."""

    program: cl.Program
    build_s: float
    queue: cl.CommandQueue
    width: int
    spp: int
    first: int
    height: int


def _launch_of(packed: PackedScene, device: cl.Device, rows: tuple[int, int] | None) -> _Launch:
    program, build_s = build_program(device, packed.config)
    params = packed.params[0]
    first, end = rows if rows is not None else (0, int(params["height"]))
    return _Launch(program, build_s, queue_for(device), int(params["width"]),
                   int(params["spp"]), first, end - first)


class _BandOutputs:
    """The render kernel's output buffers for a band of `rows` rows and `spare` more (a
    work-group's rows past the band), and the ray and test counts of the bands read back."""

    def __init__(self, ctx: cl.Context, width: int, rows: int, spare: int,
                 count_tests: bool) -> None:
        band_bytes = width * (rows + spare) * 16
        # A pixel's radiance, three floats: a band's rows are the image's, copied in place.
        self.image = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes // 16 * 12)
        # A pixel's secondary and shadow rays (int2); its spp primary rays are counted here.
        self.counts = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes // 2)
        self.tests = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes if count_tests else 16)
        self.count_tests = count_tests
        self.band_counts = np.empty((rows * width, 2), dtype=np.int32)
        self.band_tests = np.empty((rows * width if count_tests else 0, 4), dtype=np.int32)
        self.rays = np.zeros(3, dtype=np.int64)
        self.test_totals = np.zeros(4, dtype=np.int64)

    def read_band(self, queue: cl.CommandQueue, image_rows: np.ndarray, spp: int) -> None:
        """A launched band's radiance into `image_rows` (the image's rows, in place), and its
        counts into the totals."""
        pixels = image_rows.shape[0] * image_rows.shape[1]
        cl.enqueue_copy(queue, image_rows, self.image)
        cl.enqueue_copy(queue, self.band_counts[:pixels], self.counts)
        self.rays[0] += pixels * spp
        # einsum sums int32 columns into int64 about 3x faster than sum(axis=0, dtype=...).
        self.rays[1:] += np.einsum("ij->j", self.band_counts[:pixels], dtype=np.int64)
        if self.count_tests:
            cl.enqueue_copy(queue, self.band_tests[:pixels], self.tests)
            self.test_totals += np.einsum("ij->j", self.band_tests[:pixels], dtype=np.int64)

    def stats(self, build_s: float, kernel_s: float, launches: int, packed: PackedScene) -> dict:
        """render_packed's stats of the bands read."""
        rays = dict(zip(("primary", "secondary", "shadow"), map(int, self.rays), strict=True))
        rays["total"] = sum(rays.values())
        stats = {
            "build_s": build_s,
            "kernel_s": kernel_s,
            "launches": launches,
            "rays": rays,
            "mrays_per_s": rays["total"] / kernel_s * 1e-6 if kernel_s > 0 else None,
            "device_bytes": packed.device_bytes(),
        }
        if self.count_tests:
            stats["tests"] = dict(zip(("closest_boxes", "closest_prims", "shadow_boxes",
                                       "shadow_prims"), map(int, self.test_totals), strict=True))
        return stats


@small_pages
def render_packed(packed: PackedScene, device: cl.Device,
                  progress: Callable[[int, int], None] | None = None,
                  rows: tuple[int, int] | None = None,
                  on_band: Callable[[int, np.ndarray], None] | None = None
                  ) -> tuple[np.ndarray, dict]:
    """Launch the kernel over a packed scene: (image, stats without load/pack times). With
    `rows` = (start, stop), only those rows of the image (a tile of a distributed render): the
    same values, bit for bit, as those rows of the whole image. on_band(first row, its rows of
    the image) hears each band as it arrives (a notebook's progressive display)."""
    # A band's launch covers whole work-groups: with group packets, the rows past the band
    # (below the image, or the next band's, rendered again there) land in spare rows.
    spare = _group_rows(packed) - 1
    capacity = band_capacity(packed, device.global_mem_size, device.max_mem_alloc_size,
                             spare_rows=spare)
    program, build_s, queue, width, spp, first, height = _launch_of(packed, device, rows)
    try:
        buffers = _scene_buffers(queue.context, packed)
        check_argument_bytes(len(buffers) + 3, 1, device)
        with cache_folder_errors():
            kernel = cl.Kernel(program, "render")
        group_width, group_height = _local_size(kernel, device, packed)
        outputs = _BandOutputs(queue.context, width, capacity, spare, packed.config.count_tests)
        image = np.empty((height, width, 3), dtype=np.float32)
        padded_width = -(-width // group_width) * group_width
        row_samples = width * spp
        if progress is not None:
            progress(0, height * row_samples)
        kernel_s, launches, row0, band, band_s = 0.0, 0, 0, 0, 0.0
        while row0 < height:
            band = min(capacity, next_band_rows(row_samples, band, band_s, height - row0,
                                                packed.tuning))
            kernel.set_args(*buffers, outputs.image, outputs.counts, outputs.tests,
                            np.int32(first + row0))
            padded_band = -(-band // group_height) * group_height
            event = cl.enqueue_nd_range_kernel(queue, kernel, (padded_width, padded_band),
                                               (group_width, group_height))
            event.wait()
            # Device time, not wall time: the first launch's wall time holds one-off costs
            # (PoCL compiles the work-group function then) that say nothing of the rate.
            band_s = (event.profile.end - event.profile.start) * 1e-9
            kernel_s += band_s
            launches += 1
            outputs.read_band(queue, image[row0:row0 + band], spp)
            if on_band is not None:
                on_band(first + row0, image[row0:row0 + band])
            row0 += band
            if progress is not None:
                progress(row0 * row_samples, height * row_samples)
        queue.finish()
    except cl.Error as err:
        raise DeviceError(f"OpenCL error while rendering on {describe(device)}: {err}"
                          f"{_resource_hint(err, packed, _group_rows(packed) > 1)}") from err
    return image, outputs.stats(build_s, kernel_s, launches, packed)


# render_passes' outputs (kernels/render.cl), 16 bytes a pixel each: normal and depth,
# position, albedo, and the nearest sample's (primitive reference, instance, material, 0).
PASS_OUTPUTS = (("geometry", np.float32), ("position", np.float32), ("albedo", np.float32),
                ("indices", np.int32))


@small_pages
def render_passes_packed(packed: PackedScene, device: cl.Device,
                         rows: tuple[int, int] | None = None,
                         progress: Callable[[int, int], None] | None = None
                         ) -> tuple[dict[str, np.ndarray], dict]:
    """Launch render_passes over a scene packed for passes (packed.config.passes): (its outputs
    by PASS_OUTPUTS' names, (H, W, 4) each, stats: passes_kernel_s, the launches' device time,
    and passes_launches), for `rows` = (start, stop) as render_packed. In bands of rows sized
    as render_packed's, by their time and within the device's memory; `progress` hears them in
    pixel-samples as render_packed's does (a pixel's samples are traced for its passes too)."""
    if not packed.config.passes:
        raise ValueError("render_passes_packed needs a scene packed with passes=True")
    capacity = band_capacity(packed, device.global_mem_size, device.max_mem_alloc_size,
                             outputs=len(PASS_OUTPUTS))
    program, _, queue, width, spp, first, height = _launch_of(packed, device, rows)
    ctx = queue.context
    out = {name: np.empty((height, width, 4), dtype=dtype) for name, dtype in PASS_OUTPUTS}
    try:
        buffers = _scene_buffers(ctx, packed)
        check_argument_bytes(len(buffers) + len(PASS_OUTPUTS), 1, device)
        with cache_folder_errors():
            kernel = cl.Kernel(program, "render_passes")
        group_width = _group_width(kernel, device, packed.tuning)
        padded_width = -(-width // group_width) * group_width
        band_buffers = [cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, width * capacity * 16)
                        for _ in PASS_OUTPUTS]
        row_samples = width * spp
        if progress is not None:
            progress(0, height * row_samples)
        row0, band, band_s, kernel_s, launches = 0, 0, 0.0, 0.0, 0
        while row0 < height:
            band = min(capacity, next_band_rows(row_samples, band, band_s, height - row0,
                                                packed.tuning))
            kernel.set_args(*buffers, *band_buffers, np.int32(first + row0))
            event = cl.enqueue_nd_range_kernel(queue, kernel, (padded_width, band),
                                               (group_width, 1))
            event.wait()
            band_s = (event.profile.end - event.profile.start) * 1e-9
            kernel_s += band_s
            launches += 1
            for (name, _), buf in zip(PASS_OUTPUTS, band_buffers, strict=True):
                cl.enqueue_copy(queue, out[name][row0:row0 + band], buf)
            row0 += band
            if progress is not None:
                progress(row0 * row_samples, height * row_samples)
        queue.finish()
    except cl.Error as err:
        raise DeviceError(f"OpenCL error while rendering passes on {describe(device)}: {err}"
                          f"{_resource_hint(err, packed, tiles=False)}") from err
    return out, {"passes_kernel_s": kernel_s, "passes_launches": launches}


def intersect_rays(packed: PackedScene, device: cl.Device, origins: np.ndarray,
                   directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest hits of rays given in the packed (camera-relative) frame: (t, normal, ref),
    t = inf and ref = -1 on a miss. For tests and tools; runs the render kernel's code. With
    sample packets (packed.config.traversal), rays k * lanes .. k * lanes + lanes - 1 walk the
    BVH as one packet; with group packets, each work-group's group_side ** 2 rays."""
    program, _ = build_program(device, replace(packed.config, intersect_rays=True))
    queue = queue_for(device)
    ctx = queue.context
    n = len(origins)
    scheme = TRAVERSAL_SCHEMES[packed.config.traversal]
    lanes = packed.config.packet_lanes if scheme.packs_samples else 1
    # A group packet's rays are a work-group's: the launch covers whole groups.
    group = packed.tuning.group_side ** 2 if scheme.tiles else None
    padding = group or lanes
    # The last packet padded with copies of the last ray.
    padded = -(-max(n, 1) // padding) * padding
    o4 = np.zeros((padded, 4), dtype=np.float32)
    d4 = np.zeros((padded, 4), dtype=np.float32)
    o4[:n, :3] = origins
    d4[:n, :3] = directions
    o4[n:] = o4[n - 1] if n else 0
    d4[n:] = d4[n - 1] if n else 0
    args = [read_only_buffer(ctx, o4), read_only_buffer(ctx, d4), *_scene_buffers(ctx, packed)]
    hits_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, padded * 16)
    refs_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, padded * 4)
    local = (group,) if group else None
    with cache_folder_errors():
        kernel = cl.Kernel(program, "intersect_rays")
    kernel(queue, (padded // lanes,), local, *args, hits_buf, refs_buf)
    hits = np.empty((padded, 4), dtype=np.float32)
    refs = np.empty(padded, dtype=np.int32)
    cl.enqueue_copy(queue, hits, hits_buf)
    cl.enqueue_copy(queue, refs, refs_buf)
    queue.finish()
    return hits[:n, 3], hits[:n, :3], refs[:n]
