"""Orchestration: pack the scene, build the kernel, launch bands of rows, read the image back."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyopencl as cl

from clray.device.context import describe, queue_for, select_device
from clray.device.pack import PackedScene, pack_scene
from clray.device.program import build_program, bvh_width_for
from clray.errors import DeviceError
from clray.image_io import Encoding, write_image
from clray.scene.model import Scene

# Work per launch, in pixel-samples: keeps each launch well under a second on a CPU device
# (and under GPU watchdogs) while leaving enough launches for progress reports.
PIXEL_SAMPLES_PER_LAUNCH = 1 << 20


@dataclass(frozen=True)
class RenderSettings:
    width: int | None = None  # overrides; None = the scene file's value
    height: int | None = None
    spp: int | None = None
    max_depth: int | None = None
    seed: int | None = None
    device: str | None = None  # clray.device.context.select_device spec
    precision: str = "float"  # "float" | "double"
    progress: Callable[[int, int], None] | None = field(default=None, compare=False)
    variants: tuple[tuple[str, object], ...] = ()  # extra KernelConfig fields (studies)
    # PNG output (RenderResult.save, docs/rendering.md); None = the scene file's value.
    linear: bool | None = None
    exposure: float | None = None  # stops
    png_bits: int | None = None


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


def _resolve(scene: Scene, settings: RenderSettings) -> dict[str, int]:
    r = scene.render
    return {
        "width": settings.width if settings.width is not None else r.width,
        "height": settings.height if settings.height is not None else r.height,
        "spp": settings.spp if settings.spp is not None else r.spp,
        "max_depth": settings.max_depth if settings.max_depth is not None else r.max_depth,
        "seed": settings.seed if settings.seed is not None else r.seed,
    }


def _encoding(scene: Scene, settings: RenderSettings) -> Encoding:
    r = scene.render
    return Encoding(
        linear=settings.linear if settings.linear is not None else r.linear,
        exposure=settings.exposure if settings.exposure is not None else r.exposure,
        png_bits=settings.png_bits if settings.png_bits is not None else r.png_bits,
    )


def check_device_memory(packed: PackedScene, global_mem: int, max_alloc: int) -> None:
    """Refuse, before any buffer exists, a render whose buffers exceed the device's limits:
    the largest single buffer against CL_DEVICE_MAX_MEM_ALLOC_SIZE and the sum against
    CL_DEVICE_GLOBAL_MEM_SIZE. The image takes three buffers of 16 bytes a pixel (radiance, ray
    counts, test counts), the scene what PackedScene.device_bytes() lists."""
    params = packed.params[0]
    pixels = int(params["width"]) * int(params["height"])
    sizes = {**packed.device_bytes(), "image": 16 * pixels, "ray counts": 16 * pixels}
    if packed.config.count_tests:
        sizes["test counts"] = 16 * pixels
    largest = max(sizes, key=sizes.__getitem__)
    mib = 1 << 20
    if sizes[largest] > max_alloc:
        raise DeviceError(f"the {largest} buffer needs {sizes[largest] / mib:.0f} MiB, over the "
                          f"device's largest allocation ({max_alloc / mib:.0f} MiB): render a "
                          "smaller image or scene")
    total = sum(sizes.values())
    if total > global_mem:
        raise DeviceError(f"the render needs {total / mib:.0f} MiB of device memory, over the "
                          f"device's {global_mem / mib:.0f} MiB: render a smaller image or scene")


def render_packed(packed: PackedScene, device: cl.Device,
                  progress: Callable[[int, int], None] | None = None
                  ) -> tuple[np.ndarray, dict]:
    """Launch the kernel over a packed scene: (image, stats without load/pack times)."""
    check_device_memory(packed, device.global_mem_size, device.max_mem_alloc_size)
    program, build_s = build_program(device, packed.config)
    queue = queue_for(device)
    ctx = queue.context
    params = packed.params[0]
    width, height, spp = int(params["width"]), int(params["height"]), int(params["spp"])
    try:
        buffers = [_buffer(ctx, getattr(packed, name)) for name in (
            "camera", "params", "planes", "spheres", "boxes", "cylinders", "cones",
            "triangles", "triangle_packets", "sphere_packets", "vertices", "normals", "uvs",
            "nodes")]
        buffers.append(np.int32(len(packed.nodes)))
        buffers += [_buffer(ctx, getattr(packed, name)) for name in (
            "prim_refs", "materials", "textures", "texels", "lights")]
        image_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, width * height * 16)
        counts_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, width * height * 16)
        count_tests = packed.config.count_tests
        tests_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY,
                              width * height * 16 if count_tests else 16)
        kernel = cl.Kernel(program, "render")
        rows = max(1, min(height, PIXEL_SAMPLES_PER_LAUNCH // max(1, width * spp)))
        launches = -(-height // rows)
        kernel_s = 0.0
        for launch in range(launches):
            row0 = launch * rows
            band = min(rows, height - row0)
            kernel.set_args(*buffers, image_buf, counts_buf, tests_buf, np.int32(row0))
            event = cl.enqueue_nd_range_kernel(queue, kernel, (width, band), None)
            event.wait()
            kernel_s += (event.profile.end - event.profile.start) * 1e-9
            if progress is not None:
                progress(launch + 1, launches)
        image = np.empty((height, width, 4), dtype=np.float32)
        counts = np.empty((height * width, 4), dtype=np.int32)
        cl.enqueue_copy(queue, image, image_buf)
        cl.enqueue_copy(queue, counts, counts_buf)
        if count_tests:
            tests = np.empty((height * width, 4), dtype=np.int32)
            cl.enqueue_copy(queue, tests, tests_buf)
        queue.finish()
    except cl.Error as err:
        raise DeviceError(f"OpenCL error while rendering on {describe(device)}: {err}") from err
    totals = counts.sum(axis=0, dtype=np.int64)
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
        sums = tests.sum(axis=0, dtype=np.int64)
        stats["tests"] = dict(zip(("closest_boxes", "closest_prims", "shadow_boxes",
                                   "shadow_prims"), map(int, sums), strict=True))
    return image[:, :, :3], stats


def render(scene: Scene, settings: RenderSettings | None = None) -> RenderResult:
    settings = settings or RenderSettings()
    start = time.perf_counter()
    encoding = _encoding(scene, settings)  # first, so that a bad value costs nothing
    device = select_device(settings.device)
    resolved = _resolve(scene, settings)
    packed = pack_scene(scene, precision=settings.precision,
                        bvh_width=bvh_width_for(device, settings.precision),
                        queue=queue_for(device), **resolved, **dict(settings.variants))
    pack_s = time.perf_counter() - start - packed.bvh_s
    image, stats = render_packed(packed, device, settings.progress)
    stats = {
        **resolved,
        "device": describe(device),
        "precision": settings.precision,
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
        "sphere_packets", "vertices", "normals", "uvs", "nodes")]
    args.append(np.int32(len(packed.nodes)))
    args += [_buffer(ctx, packed.prim_refs), _buffer(ctx, packed.materials)]
    hits_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, n * 16)
    refs_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, n * 4)
    cl.Kernel(program, "intersect_rays")(queue, (n,), None, *args, hits_buf, refs_buf)
    hits = np.empty((n, 4), dtype=np.float32)
    refs = np.empty(n, dtype=np.int32)
    cl.enqueue_copy(queue, hits, hits_buf)
    cl.enqueue_copy(queue, refs, refs_buf)
    queue.finish()
    return hits[:, 3], hits[:, :3], refs
