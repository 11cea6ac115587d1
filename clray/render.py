"""Orchestration: pack the scene, build the kernel, launch bands of rows, read the image back."""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyopencl as cl

from clray.device.context import describe, queue_for, select_device
from clray.device.pack import PackedScene, pack_scene
from clray.device.program import build_program, bvh_width_for
from clray.errors import DeviceError, SettingsError
from clray.image_io import Encoding, write_image
from clray.scene import limits as L
from clray.scene.check import check_scene
from clray.scene.load import load_scene
from clray.scene.model import Scene
from clray.tuning.knobs import DEFAULT_TUNING, Tuning
from clray.tuning.store import chosen_tuning

# Launches are sized by the time they take, not by their work, so that progress advances
# several times a second on any device and no launch nears a GPU watchdog, while a small render
# still takes a few launches: the first covers first_launch_pixel_samples, each later one the
# rows that the previous launch's rate does in launch_seconds, at most launch_growth times the
# previous band (one fast band of sky says little about the rows below it) and at most
# max_launch_pixel_samples: knobs of clray.tuning. Pixels are independent, so the image does not
# depend on the bands.


@dataclass(frozen=True)
class RenderSettings:
    """Overrides of the scene's [render] values (None keeps the scene's), checked on creation
    by the scene file's rules: a bad value raises SettingsError (a ValueError)."""

    width: int | None = None
    height: int | None = None
    spp: int | None = None
    max_depth: int | None = None
    seed: int | None = None
    min_weight: float | None = None
    device: str | None = None  # clray.device.context.select_device spec
    precision: str = "float"  # "float" | "double"
    # progress(done, total) in pixel-samples (pixels x spp): called with done = 0 before the
    # first launch, then after each launch, rising to done = total; several times a second.
    progress: Callable[[int, int], None] | None = field(default=None, compare=False)
    variants: tuple[tuple[str, object], ...] = ()  # extra KernelConfig fields (studies)
    # PNG output (RenderResult.save, docs/rendering.md); None = the scene file's value.
    linear: bool | None = None
    exposure: float | None = None  # stops
    png_bits: int | None = None
    # Performance knobs (clray.tuning): None takes the device's tuning file, written by `clray
    # tune`, where stored_tuning and one exists, else the knob table's defaults.
    tuning: Tuning | None = None
    stored_tuning: bool = True

    def __post_init__(self) -> None:
        # The scene file's [render] rules (clray.scene.limits), in the same words.
        checks = [(name, lambda v, r=rule: L.integer_problem(v, *r))
                  for name, rule in L.RENDER_INTEGERS.items()]
        checks += [(name, lambda v, r=rule: L.number_problem(v, *r))
                   for name, rule in L.RENDER_NUMBERS.items()]
        checks += [(name, lambda v, r=rule: L.choice_problem(v, r))
                   for name, rule in L.RENDER_CHOICES.items()]
        checks += [("linear", lambda v: None if isinstance(v, bool) else "expected True or False"),
                   ("precision", lambda v: L.choice_problem(v, L.PRECISIONS)),
                   ("device", lambda v: None if isinstance(v, str) else "expected a string"),
                   ("tuning", lambda v: None if isinstance(v, Tuning)
                    else "expected a clray.tuning.Tuning"),
                   ("stored_tuning",
                    lambda v: None if isinstance(v, bool) else "expected True or False")]
        for name, problem_of in checks:
            value = getattr(self, name)
            problem = None if value is None else problem_of(value)
            if problem:
                raise SettingsError(f"RenderSettings.{name}: {problem}, got {value!r}")
        if self.progress is not None and not callable(self.progress):
            raise SettingsError(f"RenderSettings.progress: expected a callable, "
                                f"got {self.progress!r}")


@dataclass(frozen=True)
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32, linear, may hold non-finite values
    stats: dict
    encoding: Encoding = field(default_factory=Encoding)  # how save() writes a PNG

    def save(self, path: str | Path) -> None:
        """Write the image, the suffix picking the format (.png, .pfm, .exr)."""
        write_image(path, self.image, self.encoding)


def _buffer(ctx: cl.Context, array: np.ndarray) -> cl.Buffer:
    # OpenCL has no zero-sized buffers: an empty array becomes one zeroed element.
    data = array if array.size else np.zeros(1, dtype=array.dtype)
    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                     hostbuf=np.ascontiguousarray(data))


def _overrides(scene: Scene, settings: RenderSettings, names: tuple[str, ...]) -> dict:
    """Each of `names` from the settings where given, else from the scene's [render]."""
    return {name: getattr(settings, name) if getattr(settings, name) is not None
            else getattr(scene.render, name) for name in names}


def _resolve(scene: Scene, settings: RenderSettings) -> dict[str, int | float]:
    return _overrides(scene, settings, (*L.RENDER_INTEGERS, "min_weight"))


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


def _encoding(scene: Scene, settings: RenderSettings) -> Encoding:
    return Encoding(**_overrides(scene, settings, ("linear", "exposure", "png_bits")))


# The output buffers (radiance, ray counts, test counts: 16 bytes a pixel each) hold one band of
# rows, at most this many bytes each: any image the format allows renders on any device, in
# bands, and a CPU device does not double the image in its memory.
MAX_BAND_BYTES = 256 << 20


def band_capacity(packed: PackedScene, global_mem: int, max_alloc: int) -> int:
    """The most rows one launch may render: its output buffers within the device's largest
    allocation and, beside the scene's buffers, within its global memory. Refuses (DeviceError)
    a scene whose own buffers do not fit, before any buffer exists."""
    width, height = int(packed.params[0]["width"]), int(packed.params[0]["height"])
    scene = packed.device_bytes()
    mib = 1 << 20
    largest = max(scene, key=scene.__getitem__)
    if scene[largest] > max_alloc:
        raise DeviceError(f"the {largest} buffer needs {scene[largest] / mib:.0f} MiB, over the "
                          f"device's largest allocation ({max_alloc / mib:.0f} MiB): render a "
                          "smaller scene")
    outputs = 3 if packed.config.count_tests else 2
    row_bytes = 16 * width
    room = global_mem - sum(scene.values())
    if room < outputs * row_bytes:
        raise DeviceError(f"the scene needs {sum(scene.values()) / mib:.0f} MiB of device "
                          f"memory, more than the device's {global_mem / mib:.0f} MiB leave for "
                          "rendering: render a smaller scene")
    return max(1, min(height, min(max_alloc, MAX_BAND_BYTES) // row_bytes,
                      room // (outputs * row_bytes)))


# Above this depth a transmissive scene without min_weight gets a warning: glass.toml takes
# 0.03 s at depth 16 and did not finish in 5 minutes at depth 32 (80x60 pixels, PoCL).
DEEP_TREE_DEPTH = 20

def _group_width(kernel: cl.Kernel, device: cl.Device, tuning: Tuning) -> int:
    """Work-items per work-group, one row segment: the work_group_width knob, within the
    kernel's limit on the device. Never left to the driver: PoCL puts up to 4096 work-items in
    a group and gives them their private memory on one thread's stack, which a deep ray stack
    (MAX_DEPTH + 1 tasks of 80 bytes each, per work-item) overflows: a segfault at depth 28."""
    limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device)
    return max(1, min(tuning.work_group_width, limit))


def render_packed(packed: PackedScene, device: cl.Device,
                  progress: Callable[[int, int], None] | None = None,
                  rows: tuple[int, int] | None = None) -> tuple[np.ndarray, dict]:
    """Launch the kernel over a packed scene: (image, stats without load/pack times). With
    `rows` = (start, stop), only those rows of the image (a tile of a distributed render): the
    same values, bit for bit, as those rows of the whole image."""
    capacity = band_capacity(packed, device.global_mem_size, device.max_mem_alloc_size)
    program, build_s = build_program(device, packed.config)
    queue = queue_for(device)
    ctx = queue.context
    params = packed.params[0]
    width, spp = int(params["width"]), int(params["spp"])
    first, end = rows if rows is not None else (0, int(params["height"]))
    height = end - first
    try:
        buffers = [_buffer(ctx, getattr(packed, name)) for name in (
            "camera", "params", "planes", "spheres", "boxes", "cylinders", "cones",
            "triangles", "triangle_packets", "sphere_packets", "normals", "uvs",
            "nodes")]
        buffers.append(np.int32(len(packed.nodes)))
        buffers += [_buffer(ctx, getattr(packed, name)) for name in (
            "prim_refs", "materials", "textures", "texels", "lights", "instances")]
        band_bytes = width * capacity * 16
        image_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes)
        counts_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes)
        count_tests = packed.config.count_tests
        tests_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, band_bytes if count_tests else 16)
        image = np.empty((height, width, 3), dtype=np.float32)
        band_image = np.empty((capacity, width, 4), dtype=np.float32)
        band_counts = np.empty((capacity * width, 4), dtype=np.int32)
        totals = np.zeros(4, dtype=np.int64)
        test_totals = np.zeros(4, dtype=np.int64)
        kernel = cl.Kernel(program, "render")
        group_width = _group_width(kernel, device, packed.tuning)
        padded_width = -(-width // group_width) * group_width
        row_samples = width * spp
        if progress is not None:
            progress(0, height * row_samples)
        kernel_s, launches, row0, band, band_s = 0.0, 0, 0, 0, 0.0
        while row0 < height:
            band = min(capacity, next_band_rows(row_samples, band, band_s, height - row0,
                                                packed.tuning))
            kernel.set_args(*buffers, image_buf, counts_buf, tests_buf, np.int32(first + row0))
            event = cl.enqueue_nd_range_kernel(queue, kernel, (padded_width, band),
                                               (group_width, 1))
            event.wait()
            # Device time, not wall time: the first launch's wall time holds one-off costs
            # (PoCL compiles the work-group function then) that say nothing of the rate.
            band_s = (event.profile.end - event.profile.start) * 1e-9
            kernel_s += band_s
            launches += 1
            pixels = band * width
            cl.enqueue_copy(queue, band_image[:band], image_buf)
            cl.enqueue_copy(queue, band_counts[:pixels], counts_buf)
            image[row0:row0 + band] = band_image[:band, :, :3]
            # einsum sums int32 columns into int64 about 3x faster than sum(axis=0, dtype=...).
            totals += np.einsum("ij->j", band_counts[:pixels], dtype=np.int64)
            if count_tests:
                cl.enqueue_copy(queue, band_counts[:pixels], tests_buf)
                test_totals += np.einsum("ij->j", band_counts[:pixels], dtype=np.int64)
            row0 += band
            if progress is not None:
                progress(row0 * row_samples, height * row_samples)
        queue.finish()
    except cl.Error as err:
        raise DeviceError(f"OpenCL error while rendering on {describe(device)}: {err}") from err
    rays = {"primary": int(totals[0]), "secondary": int(totals[1]), "shadow": int(totals[2])}
    rays["total"] = sum(rays.values())
    stats = {
        "build_s": build_s,
        "kernel_s": kernel_s,
        "launches": launches,
        "rays": rays,
        "mrays_per_s": rays["total"] / kernel_s * 1e-6 if kernel_s > 0 else None,
        "device_bytes": packed.device_bytes(),
    }
    if count_tests:
        stats["tests"] = dict(zip(("closest_boxes", "closest_prims", "shadow_boxes",
                                   "shadow_prims"), map(int, test_totals), strict=True))
    return image, stats


def warn_deep_tree(scene: Scene, resolved: dict[str, int | float]) -> None:
    """A warning (before any device work) for a transmissive scene traced deep without
    min_weight, whose ray tree can double at every bounce."""
    if (resolved["max_depth"] > DEEP_TREE_DEPTH and resolved["min_weight"] == 0
            and any(m.transmit > 0 for m in scene.materials)):
        warnings.warn(f"max_depth {resolved['max_depth']} with transmissive materials and "
                      "min_weight 0: inside glass the ray tree can double at every bounce and "
                      "the render take very long; set min_weight (e.g. 0.004) to stop faint rays",
                      stacklevel=3)


def pack_for(scene: Scene, settings: RenderSettings, device: cl.Device) -> PackedScene:
    """The checked `scene` packed for `device` with `settings`: what render() launches, and
    what each worker of a distributed render packs once for all its tiles. The knobs are the
    settings' tuning, else the device's tuning file's (clray.tuning.store.chosen_tuning)."""
    tuning = settings.tuning or chosen_tuning(device, settings.stored_tuning)[0]
    return pack_scene(scene, precision=settings.precision,
                      bvh_width=tuning.bvh_width or bvh_width_for(device, settings.precision),
                      queue=queue_for(device), tuning=tuning, **_resolve(scene, settings),
                      **dict(settings.variants))


def render(scene: Scene | str | os.PathLike, settings: RenderSettings | None = None
           ) -> RenderResult:
    """Render a scene, or the scene file at a path. A scene built in Python is first checked
    by the scene file's rules (clray.scene.check): SceneError names the bad value."""
    settings = settings or RenderSettings()
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else check_scene(scene)
    start = time.perf_counter()
    encoding = _encoding(scene, settings)
    resolved = _resolve(scene, settings)
    warn_deep_tree(scene, resolved)
    device = select_device(settings.device)
    if settings.tuning is None:
        tuning, tuning_source = chosen_tuning(device, settings.stored_tuning)
        settings = replace(settings, tuning=tuning)
    else:
        tuning_source = "given"
    packed = pack_for(scene, settings, device)
    pack_s = time.perf_counter() - start - packed.bvh_s
    image, stats = render_packed(packed, device, settings.progress)
    stats = {
        **resolved,
        "device": describe(device),
        "precision": settings.precision,
        # Which configuration rendered: its source, the knobs changed from the defaults, every
        # knob's value, and the BVH width that "auto" (None) picked.
        "tuning": {"source": tuning_source, "label": packed.tuning.label(),
                   **packed.tuning.values(), "bvh_width": packed.config.bvh_width},
        "bvh_s": packed.bvh_s,
        "pack_s": pack_s,
        **stats,
        "total_s": time.perf_counter() - start,
    }
    return RenderResult(image, stats, encoding)


def intersect_rays(packed: PackedScene, device: cl.Device, origins: np.ndarray,
                   directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest hits of rays given in the packed (camera-relative) frame: (t, normal, ref),
    t = inf and ref = -1 on a miss. For tests and tools; runs the render kernel's code."""
    program, _ = build_program(device, packed.config)
    queue = queue_for(device)
    ctx = queue.context
    n = len(origins)
    o4 = np.zeros((n, 4), dtype=np.float32)
    d4 = np.zeros((n, 4), dtype=np.float32)
    o4[:, :3] = origins
    d4[:, :3] = directions
    args = [_buffer(ctx, o4), _buffer(ctx, d4), _buffer(ctx, packed.planes),
            np.int32(len(packed.planes))]
    args += [_buffer(ctx, getattr(packed, name)) for name in (
        "spheres", "boxes", "cylinders", "cones", "triangles", "triangle_packets",
        "sphere_packets", "normals", "uvs", "nodes")]
    args.append(np.int32(len(packed.nodes)))
    args += [_buffer(ctx, packed.prim_refs), _buffer(ctx, packed.materials),
             _buffer(ctx, packed.instances)]
    hits_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, n * 16)
    refs_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, n * 4)
    cl.Kernel(program, "intersect_rays")(queue, (n,), None, *args, hits_buf, refs_buf)
    hits = np.empty((n, 4), dtype=np.float32)
    refs = np.empty(n, dtype=np.int32)
    cl.enqueue_copy(queue, hits, hits_buf)
    cl.enqueue_copy(queue, refs, refs_buf)
    queue.finish()
    return hits[:, 3], hits[:, :3], refs
