"""Embree 4's single rays beside clray's single-ray walk: primary rays of the bumpy mesh.

    python benchmarks/embree.py [--json benchmarks/results/embree.json] [--repeat 5]
                                [--size 1280x720] [--subdivisions 7] [--device SPEC]
                                [--packet-spp 16] [--instructions] [--mesh-dir DIR]

Needs the `embree` extra (`pip install -e '.[embree]'`, or `pip install embreex`); without it
the benchmark says so and exits with status 2.

The scene: scripts/make_mesh_scene.py's mesh scene (the 327,680-triangle bumpy icosphere at
seven subdivisions, its camera, size and background) with the mesh alone: no plane and no
lights, written as its own scene file. The rays: one a pixel through the pixel centres, made in
float64 by clray's reference camera (`clray.reference.sampling.camera_rays`, the kernels'
camera), camera-relative as clray packs a scene and rounded to float32. Embree gets the mesh's
vertices in the same frame (float64 minus the eye, rounded to float32, as `pack_scene` does),
so both trace the same float32 rays through the same float32 triangles.

- Embree: embreex's `rtcore_scene.EmbreeScene` with one `mesh_construction.TriangleMesh`;
  `EmbreeScene.run(origins, directions, output=1)` is a Cython loop that calls Embree's
  single-ray `rtcIntersect1` once a ray on the calling thread (embreex 4.4 binds no packet or
  stream call: its `rtcore_scene` module imports `rtcIntersect1` and `rtcOccluded1` only), so
  it runs on one thread. The scene is committed (Embree's BVH build, on TBB's threads) by a
  run on no rays, timed apart (`embree_commit_s`, after `embree_mesh_s`, the mesh's
  construction), and the first full run is an untimed warm-up. Timed by wall clock and by the
  process's CPU time. embreex allocates its output arrays afresh at every run, and the
  memory freed by the run before had gone to clray's arrays between rounds: the kernel's
  mapping of fresh pages (3,000 to 4,600 page faults, up to 52 ms of a 60 to 103 ms 1280x720
  run on an AMD EPYC Zen 3) was timed as Embree's. So each timed run follows an untimed one
  whose freed arrays it reuses, as clray's kernels reuse their buffers; the thread's system
  time and page faults in each timed run are reported (`system_seconds`, `page_faults`).
- clray, on the OpenCL device (PoCL's CPU device by default: one thread a core): the render
  kernel at 1 spp, max depth 0, no lights, built for the single-ray walk
  (`KernelConfig.traversal = "single"`, as `clray render` builds 1-spp renders): each
  work-item makes its camera ray, walks the BVH to the closest hit and shades it by the ambient
  term (`render`). Beside it the `intersect_rays` kernel on the very rays Embree traces, the
  walk's own figure (`intersect`: reads a ray, walks, writes t, the geometric normal and the
  primitive), from which the hits are compared. Both timed by OpenCL profiling events (kernel
  time) and by the process's CPU time from each launch's enqueue to the end of its wait (the
  render's buffers, read-backs and ray counts, outside its launches, are not counted: Embree's
  CPU time holds its loop alone). And both again in a child process held to one core
  (`render_one_core`, `intersect_one_core`: its CPU affinity one CPU, PoCL's threads one), a
  core's own rate beside Embree's one thread; `intersect_one_core` is the walk on Embree's
  very rays, as Embree's loop reads its rays and writes its hits.
- With `--packet-spp N` (default 16, 0: none), the render kernel at N samples a pixel as a
  render builds it on the device (sample packets on CPU devices), for the issue's "sample
  packets against Embree's single rays".

Rates: Mrays/s by the kernel's (or Embree's) wall time; per core, clray's divided by the
device's compute units (CPU threads for PoCL), Embree's per thread as it is; and by CPU time
(`mrays_per_cpu_s`), which holds better than wall time while other work shares the cores. The
sides run in turns (Embree, clray render, the one-core child's render and intersect, clray
intersect, packets) after a warm-up of each,
`--repeat` rounds, so load changes fall on all of them; medians and the spread of the runs are
reported.

Hits: a ray hits where its t is finite (clray) or Embree's geomID is set. `hits` compares
Embree's and `intersect`'s (same rays): rays whose hit masks differ, and the relative t
difference where both hit. `render_hits` compares the render's image (a hit pixel is not the
background) with Embree's mask: the render makes its rays in float32 itself, so a silhouette
pixel may differ. `one_core_hits` compares the one-core child's `intersect` with the device's:
the same rays, so they must agree exactly; the summary says so, or warns.

`--instructions` (needs valgrind and PoCL) also counts the render kernel's instructions a ray
with benchmarks/instructions.py's `primary` variant of the same scene file (one PoCL thread,
the kernel only); the 327k-triangle BVH is built under valgrind too, so this adds a minute or
more. Measures only: nothing is asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import check_outputs  # noqa: E402

if TYPE_CHECKING:
    import pyopencl as cl

    from clray.scene.model import Scene

INSTALL_HINT = ("benchmarks/embree.py needs embreex (Embree 4's Python binding): "
                ".venv/bin/pip install embreex   (or: pip install -e '.[embree]')")
# Embree's geomID of a ray that hit nothing (RTC_INVALID_GEOMETRY_ID) as embreex's int32.
EMBREE_MISS = -1
# Relative t difference within which two hits of one ray agree (float32 intersections of the
# same triangle differ by a few ulps; a neighbouring triangle across an edge by about as much).
T_RTOL = 1e-4
# The clay material of make_mesh_scene.py's scene; shading does not change the walk.
SCENE_TEMPLATE = """\
# benchmarks/embree.py: make_mesh_scene.py's mesh scene, the mesh alone (no plane, no lights).
[render]
width = {width}
height = {height}
spp = 1
max_depth = 0
background = {background}

[camera]
position = {position}
look_at = {look_at}
up = {up}
{fov}

[materials.clay]
color = [0.85, 0.45, 0.25]
ambient = 0.1
diffuse = 0.8

[[objects]]
type = "mesh"
file = "bumpy.obj"
material = "clay"
"""


def _module(name: str, folder: Path = HERE) -> ModuleType:
    # benchmarks/ and scripts/ are not packages: load their modules from their files.
    spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def import_embreex() -> tuple[Any, Any, str] | None:
    """(rtcore_scene, mesh_construction, embreex version), or None where embreex is absent."""
    try:
        import embreex
        from embreex import mesh_construction, rtcore_scene
    except ImportError:
        return None
    return rtcore_scene, mesh_construction, getattr(embreex, "__version__", "unknown")


def compare_hits(t_a: np.ndarray, t_b: np.ndarray, rtol: float = T_RTOL) -> dict:
    """How two tracers' closest hits of the same rays agree: t per ray, inf (or nan) on a miss.
    `mask_mismatches`: rays one hits and the other misses; over the rays both hit, the largest
    and median relative t difference and how many differ by more than `rtol`. `agree`: no mask
    mismatch and no t beyond `rtol`."""
    t_a = np.asarray(t_a, dtype=np.float64).ravel()
    t_b = np.asarray(t_b, dtype=np.float64).ravel()
    if t_a.shape != t_b.shape:
        raise ValueError(f"hit arrays differ in length: {t_a.size} and {t_b.size}")
    hit_a, hit_b = np.isfinite(t_a), np.isfinite(t_b)
    both = hit_a & hit_b
    rel = np.abs(t_a[both] - t_b[both]) / np.maximum(np.abs(t_b[both]), np.finfo(np.float64).tiny)
    mismatches = int(np.count_nonzero(hit_a != hit_b))
    beyond = int(np.count_nonzero(rel > rtol))
    return {
        "rays": int(t_a.size),
        "hits_a": int(np.count_nonzero(hit_a)),
        "hits_b": int(np.count_nonzero(hit_b)),
        "hit_fraction": float(np.count_nonzero(hit_b) / t_b.size) if t_b.size else 0.0,
        "mask_mismatches": mismatches,
        "mask_agreement": float(1.0 - mismatches / t_a.size) if t_a.size else 1.0,
        "both_hit": int(np.count_nonzero(both)),
        "t_rel_diff_max": float(rel.max()) if rel.size else 0.0,
        "t_rel_diff_median": float(np.median(rel)) if rel.size else 0.0,
        "t_rtol": rtol,
        "t_beyond_rtol": beyond,
        "agree": mismatches == 0 and beyond == 0,
    }


def write_scene(out: Path, width: int, height: int, subdivisions: int) -> Path:
    """make_mesh_scene.py's scene in `out` (bumpy.obj, bumpy.toml), and beside it the mesh
    alone at width x height (mesh_only.toml, its camera and background): that file's path."""
    make = _module("make_mesh_scene", ROOT / "scripts")
    make.main(["--out", str(out), "--subdivisions", str(subdivisions)])
    from clray.scene.load import load_scene

    full = load_scene(out / "bumpy.toml")
    cam, background = full.camera, full.render.background
    if cam.type != "perspective" or cam.aperture > 0 or not isinstance(background, tuple):
        raise RuntimeError("make_mesh_scene.py's scene no longer has a pinhole camera and a "
                           "plain background: update benchmarks/embree.py's scene")
    fov = f"vfov = {cam.vfov!r}" if cam.hfov is None else f"hfov = {cam.hfov!r}"
    text = SCENE_TEMPLATE.format(width=width, height=height, background=list(background),
                                 position=list(cam.position), look_at=list(cam.look_at),
                                 up=list(cam.up), fov=fov)
    path = out / "mesh_only.toml"
    path.write_text(text, encoding="ascii")
    return path


def primary_rays(scene: Scene, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(origins, directions), float32 (N, 3), camera-relative: one ray a pixel through its
    centre, row by row from the top, as clray's camera makes them (in float64, then rounded)."""
    from clray.reference.sampling import camera_rays

    origins, directions, _ = camera_rays(scene, width, height, 1, scene.render.seed)
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    return ((origins - eye).astype(np.float32), np.ascontiguousarray(directions,
                                                                      dtype=np.float32))


def camera_relative_triangles(scene: Scene) -> np.ndarray:
    """(F, 3, 3) float32: the scene's meshes' triangles, camera-relative as pack_scene stores
    their vertices (float64 minus the eye, then rounded)."""
    from clray.scene import model as M

    eye = np.asarray(scene.camera.position, dtype=np.float64)
    meshes = [obj for obj in scene.objects if isinstance(obj, M.Mesh)]
    vertices = [(mesh.vertices - eye).astype(np.float32)[mesh.faces] for mesh in meshes]
    return np.ascontiguousarray(np.concatenate(vertices))


class EmbreeSide:
    """Embree 4 through embreex: one scene of one triangle mesh, rays by rtcIntersect1.
    `mesh_s`: the mesh's construction (its vertices into Embree's buffers); `commit_s`: the
    scene's commit, Embree's BVH build (embreex commits at a scene's first run: here a run on
    no rays, so no trace is timed with it)."""

    def __init__(self, embree: tuple[Any, Any, str], triangles: np.ndarray,
                 origins: np.ndarray, directions: np.ndarray) -> None:
        rtcore_scene, mesh_construction, _ = embree
        self.scene = rtcore_scene.EmbreeScene()
        start = time.perf_counter()
        self.mesh = mesh_construction.TriangleMesh(self.scene, triangles)
        self.mesh_s = time.perf_counter() - start
        no_rays = np.zeros((0, 3), dtype=np.float32)
        start = time.perf_counter()
        self.scene.run(no_rays, no_rays.copy(), output=1)
        self.commit_s = time.perf_counter() - start
        if not self.scene.is_committed:
            raise RuntimeError("embreex did not commit the scene at a run on no rays")
        self.origins, self.directions = origins, directions

    def run(self) -> dict:
        # On the one CPU the one-core render's child has (OneCoreSide), as that child is: this
        # thread only (Linux pins the calling thread), given back its CPUs after.
        # An untimed run first: its freed output arrays are the timed run's, so no page fault
        # of fresh memory is timed as Embree's tracing (the module's docstring).
        cpus = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {min(cpus)})
        try:
            self.scene.run(self.origins, self.directions, output=1)
            before = resource.getrusage(resource.RUSAGE_THREAD)
            wall, cpu = time.perf_counter(), time.process_time()
            out = self.scene.run(self.origins, self.directions, output=1)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            after = resource.getrusage(resource.RUSAGE_THREAD)
        finally:
            os.sched_setaffinity(0, cpus)
        t = np.where(out["geomID"] != EMBREE_MISS, out["tfar"], np.float32(np.inf))
        return {"wall_s": wall, "cpu_s": cpu, "system_s": after.ru_stime - before.ru_stime,
                "page_faults": after.ru_minflt - before.ru_minflt, "t": t}


class ClraySide:
    """clray's render kernel (single-ray walk, 1 spp, depth 0, no lights), its intersect_rays
    kernel on given rays (none: the render alone), and optionally the render at packet_spp
    samples a pixel."""

    def __init__(self, scene: Scene, device: cl.Device, origins: np.ndarray | None,
                 directions: np.ndarray | None, packet_spp: int) -> None:
        from clray.device.context import queue_for
        from clray.device.pack import pack_scene
        from clray.device.policy import device_plan
        from clray.knobs import Tuning

        r = scene.render
        self.device = device
        # As `clray render --traversal single` packs a 1-spp render (and as a plain 1-spp
        # render does: one sample a pixel makes no sample packet).
        single = device_plan(device, spp=1, traversal="single", tuning=Tuning())
        settings = {"width": r.width, "height": r.height, "max_depth": 0, "seed": r.seed,
                    "bvh_width": single.bvh_width, "queue": queue_for(device)}
        self.packed = pack_scene(scene, spp=1, **settings, **single.switches)
        if self.packed.config.traversal != "single" or self.packed.config.max_depth != 0:
            raise RuntimeError(f"expected the single-ray walk at depth 0, got "
                               f"{self.packed.config.traversal} at {self.packed.config.max_depth}")
        self.bvh_s = self.packed.bvh_s
        self.background = np.asarray(r.background, dtype=np.float32)
        self.packets = None
        if packet_spp:
            switches = device_plan(device, spp=packet_spp, tuning=Tuning()).switches
            self.packets = pack_scene(scene, spp=packet_spp, **settings, **switches)
        if origins is not None:
            self._intersect_setup(origins, directions)

    def _intersect_setup(self, origins: np.ndarray, directions: np.ndarray) -> None:
        # intersect_rays (clray.device.launch) builds its buffers on every call; here they are
        # made once, so a run times the kernel alone. The same kernel and arguments.
        import pyopencl as cl

        from clray.device.buffers import read_only_buffer
        from clray.device.context import queue_for
        from clray.device.launch import _scene_buffers
        from clray.device.program import build_program

        program, _ = build_program(self.device,
                                   dataclasses.replace(self.packed.config, intersect_rays=True))
        self.queue = queue_for(self.device)
        ctx = self.queue.context
        self.n = len(origins)
        o4 = np.zeros((self.n, 4), dtype=np.float32)
        d4 = np.zeros((self.n, 4), dtype=np.float32)
        o4[:, :3], d4[:, :3] = origins, directions
        self.hits_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, self.n * 16)
        self.refs_buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, self.n * 4)
        # Held here: a kernel's arguments do not keep their buffers alive.
        self.buffers = [read_only_buffer(ctx, o4), read_only_buffer(ctx, d4),
                        *_scene_buffers(ctx, self.packed), self.hits_buf, self.refs_buf]
        self.kernel = cl.Kernel(program, "intersect_rays")
        self.kernel.set_args(*self.buffers)

    def render(self, packets: bool = False) -> dict:
        from clray.device import launch

        # CPU time of the launches alone, as intersect() and Embree's loop are timed:
        # render_packed's buffers, read-backs and ray counts are outside them. render_packed
        # launches through its module's `cl`; for this call it is a stand-in that times each
        # launch from its enqueue to the end of its wait (the call's own wait then returns at
        # once).
        timed = _TimedLaunches(launch.cl)
        launch.cl = timed
        try:
            image, stats = launch.render_packed(self.packets if packets else self.packed,
                                                self.device)
        finally:
            launch.cl = timed.module
        out = {"kernel_s": stats["kernel_s"], "cpu_s": timed.cpu_s,
               "rays": stats["rays"]["total"]}
        if not packets:
            # A pixel the walk hit is shaded (ambient term of the clay), not the background.
            out["hit"] = np.any(image.reshape(-1, 3) != self.background, axis=1)
        return out

    def intersect(self) -> dict:
        import pyopencl as cl

        cpu = time.process_time()
        event = cl.enqueue_nd_range_kernel(self.queue, self.kernel, (self.n,), None)
        event.wait()
        cpu = time.process_time() - cpu
        hits = np.empty((self.n, 4), dtype=np.float32)
        cl.enqueue_copy(self.queue, hits, self.hits_buf)
        self.queue.finish()
        return {"kernel_s": (event.profile.end - event.profile.start) * 1e-9, "cpu_s": cpu,
                "t": hits[:, 3]}


class _TimedLaunches:
    """pyopencl as render_packed sees it, but for enqueue_nd_range_kernel, which waits for the
    launch and adds the process's CPU time from the enqueue to the end of the wait to cpu_s."""

    def __init__(self, module: Any) -> None:
        self.module = module
        self.cpu_s = 0.0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.module, name)

    def enqueue_nd_range_kernel(self, *args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        event = self.module.enqueue_nd_range_kernel(*args, **kwargs)
        event.wait()
        self.cpu_s += time.process_time() - start
        return event


class OneCoreSide:
    """clray's render (ClraySide.render's single-ray 1-spp kernel) and its intersect_rays on
    Embree's rays (ClraySide.intersect), in a child process held to one core: its CPU affinity
    one CPU, and PoCL's worker threads one (POCL_MAX_PTHREAD_COUNT), so that "a core" is a
    core's own rate, as Embree's one thread is, and not the whole device's divided by its
    cores (two threads share the cores' caches and clock: on the 2-core machine the one-core
    render ran 3 to 17 % faster than half the two-core one). The child renders and intersects
    once for each round the parent asks for, and answers both."""

    def __init__(self, scene_file: Path, device_spec: str | None, size: tuple[int, int]) -> None:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--one-core-child",
               str(scene_file), "--size", f"{size[0]}x{size[1]}"]
        cmd += ["--device", device_spec] if device_spec else []
        env = dict(os.environ, POCL_MAX_PTHREAD_COUNT="1")
        self.child = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      text=True, env=env)
        self._answer()  # packed, built and warmed up

    def _answer(self) -> dict:
        line = self.child.stdout.readline()
        if not line:
            raise RuntimeError(f"the one-core render's child ended (exit {self.child.wait()})")
        return json.loads(line)

    def run(self) -> dict:
        self.child.stdin.write("run\n")
        self.child.stdin.flush()
        return self._answer()

    def close(self) -> None:
        self.child.stdin.close()
        self.child.wait()


def one_core_child(scene_file: Path, device_spec: str | None, size: tuple[int, int]) -> None:
    """OneCoreSide's process: the render packed as ClraySide packs it and intersect_rays on
    the parent's rays (primary_rays at `size`, made again here: the same float64 camera, the
    same float32 rays), then one timed render and one timed intersect_rays a line of standard
    input, each line answered with a line of JSON (the first also with intersect_rays' t, for
    the parent's check that both walked the same rays)."""
    from clray.device.context import select_device
    from clray.scene.load import load_scene

    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    scene = load_scene(scene_file)
    origins, directions = primary_rays(scene, *size)
    side = ClraySide(scene, select_device(device_spec), origins, directions, 0)
    side.render()
    side.intersect()
    print(json.dumps({"ready": True}), flush=True)
    for index, _ in enumerate(sys.stdin):
        done, walked = side.render(), side.intersect()
        print(json.dumps({"render": {"kernel_s": done["kernel_s"], "cpu_s": done["cpu_s"],
                                     "rays": done["rays"]},
                          "intersect": {"kernel_s": walked["kernel_s"],
                                        "cpu_s": walked["cpu_s"],
                                        **({} if index else {"t": walked["t"].tolist()})}}),
              flush=True)


def spread(values: list[float]) -> dict:
    """Median, smallest and largest of runs, and every run."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "runs": values}


def rates(rays: int, seconds: list[float], cpu_seconds: list[float], workers: int) -> dict:
    """Mrays/s of each run by wall (or kernel) time, per worker, and by CPU time."""
    per_s = [rays / s * 1e-6 for s in seconds]
    return {"rays": rays, "seconds": spread(seconds), "cpu_seconds": spread(cpu_seconds),
            "mrays_per_s": spread(per_s),
            "mrays_per_s_per_worker": spread([v / workers for v in per_s]),
            "mrays_per_cpu_s": spread([rays / s * 1e-6 for s in cpu_seconds])}


def count_instructions(scene_file: Path) -> dict:
    """benchmarks/instructions.py's count of the render kernel's `primary` variant (depth 0,
    no lights: the single-ray walk of the camera rays and their ambient shading)."""
    instructions = _module("instructions")
    own_size = (0, 0)  # the scene file's, which write_scene made the benchmark's
    instructions._render(scene_file, "primary", own_size, valgrind=False)  # fills the cache
    counted = instructions._render(scene_file, "primary", own_size, valgrind=True)
    rays = counted["rays"]["primary"]
    return {"instructions": counted["instructions"], "rays": rays,
            "instructions_per_ray": counted["instructions"] / rays}


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "embree.json")
    parser.add_argument("--repeat", type=int, default=5, help="timed rounds after a warm-up")
    parser.add_argument("--size", default="1280x720", metavar="WxH")
    parser.add_argument("--subdivisions", type=int, default=7,
                        help="of the icosphere (7: 327,680 triangles)")
    parser.add_argument("--device", default=None, help="OpenCL device spec, as clray render's")
    parser.add_argument("--packet-spp", type=int, default=16,
                        help="also time the render at this many samples a pixel as a render "
                             "builds it (sample packets on CPU devices); 0: not")
    parser.add_argument("--instructions", action="store_true",
                        help="count the render kernel's instructions a ray under valgrind")
    parser.add_argument("--mesh-dir", type=Path, default=None,
                        help="where to write the scene (default: a temporary folder)")
    parser.add_argument("--one-core-child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    width, _, height = args.size.partition("x")
    if not (width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        parser.error(f"--size is WxH, got {args.size!r}")
    args.width, args.height = int(width), int(height)
    if args.one_core_child is not None:
        return args
    if args.repeat < 1 or args.packet_spp < 0 or args.subdivisions < 0:
        parser.error("--repeat must be >= 1, --packet-spp and --subdivisions >= 0")
    if args.instructions and shutil.which("valgrind") is None:
        parser.error("--instructions needs valgrind (Debian: apt-get install valgrind)")
    check_outputs(parser, json=args.json)
    return args


def timed_rounds(args: argparse.Namespace, embree_side: EmbreeSide, clray_side: ClraySide,
                 one_core: OneCoreSide) -> dict[str, list[dict]]:
    """Each side's runs, interleaved round by round after a warm-up of each."""
    # PoCL compiles the work-group functions at the first launch.
    clray_side.render()
    clray_side.intersect()
    if args.packet_spp:
        clray_side.render(packets=True)
    embree_side.run()
    runs: dict[str, list[dict]] = {"embree": [], "render": [], "render_one_core": [],
                                   "intersect": [], "intersect_one_core": [], "packets": []}
    for round_index in range(args.repeat):
        runs["embree"].append(embree_side.run())
        runs["render"].append(clray_side.render())
        alone = one_core.run()
        runs["render_one_core"].append(alone["render"])
        runs["intersect_one_core"].append(alone["intersect"])
        runs["intersect"].append(clray_side.intersect())
        if args.packet_spp:
            runs["packets"].append(clray_side.render(packets=True))
        print(f"round {round_index + 1}/{args.repeat}: embree "
              f"{runs['embree'][-1]['wall_s']:.4f} s, clray render "
              f"{runs['render'][-1]['kernel_s']:.4f} s, intersect "
              f"{runs['intersect'][-1]['kernel_s']:.4f} s, on one core: render "
              f"{runs['render_one_core'][-1]['kernel_s']:.4f} s, intersect "
              f"{runs['intersect_one_core'][-1]['kernel_s']:.4f} s", file=sys.stderr)
    return runs


def clray_rates(runs: dict[str, list[dict]], rays: int, workers: int,
                clray_side: ClraySide) -> dict:
    """rates() of each clray side: the render's, intersect_rays' on the `rays` Embree
    traces, each on the device and on one core, and the packets' where they ran."""
    def of(name: str, n: int, per: int) -> dict:
        return rates(n, [r["kernel_s"] for r in runs[name]], [r["cpu_s"] for r in runs[name]],
                     per)

    sides = {"render": of("render", runs["render"][-1]["rays"], workers),
             "render_one_core": of("render_one_core", runs["render_one_core"][-1]["rays"], 1),
             "intersect": of("intersect", rays, workers),
             "intersect_one_core": of("intersect_one_core", rays, 1)}
    if runs["packets"]:
        config = clray_side.packets.config
        sides["packets"] = {**of("packets", runs["packets"][-1]["rays"], workers),
                            "spp": int(clray_side.packets.params[0]["spp"]),
                            "traversal": config.traversal, "packet_lanes": config.packet_lanes}
    return sides


def ratios_to_embree(sides: dict, embree_rates: dict) -> dict:
    """Each clray side's rate a core over Embree's a thread: of the medians, round by round,
    and per CPU second."""
    ratios = {}
    for name, side in sides.items():
        per_round = [c / e for c, e in zip(side["mrays_per_s_per_worker"]["runs"],
                                           embree_rates["mrays_per_s"]["runs"], strict=True)]
        ratios[name] = {
            "per_core_vs_embree_per_thread": side["mrays_per_s_per_worker"]["median"]
            / embree_rates["mrays_per_s_per_worker"]["median"],
            "per_round": spread(per_round),
            "per_cpu_s_vs_embree_per_cpu_s": side["mrays_per_cpu_s"]["median"]
            / embree_rates["mrays_per_cpu_s"]["median"],
        }
    return ratios


def print_summary(report: dict, json_path: Path) -> None:
    embree_rates, hits = report["embree"], report["hits"]
    print(f"{report['rays']} rays ({report['width']}x{report['height']}), "
          f"{report['triangles']} triangles, {hits['hit_fraction']:.1%} hit; "
          f"{report['device']}, {report['clray_workers']} compute units; "
          f"embree {report['embreex_version']}")
    print(f"  embree rtcIntersect1, 1 thread: "
          f"{embree_rates['mrays_per_s_per_worker']['median']:.2f} Mrays/s (runs "
          f"{embree_rates['mrays_per_s']['min']:.2f} to {embree_rates['mrays_per_s']['max']:.2f}),"
          f" {embree_rates['mrays_per_cpu_s']['median']:.2f} Mrays per CPU s; system time "
          f"{embree_rates['system_seconds']['min']:.4f} to "
          f"{embree_rates['system_seconds']['max']:.4f} s a run, page faults "
          f"{embree_rates['page_faults']['min']} to {embree_rates['page_faults']['max']}")
    for name, side in report["clray"].items():
        per = side["mrays_per_s_per_worker"]
        print(f"  clray {name}: {side['mrays_per_s']['median']:.2f} Mrays/s, "
              f"{per['median']:.2f} a core (runs {per['min']:.2f} to {per['max']:.2f}), "
              f"{side['mrays_per_cpu_s']['median']:.2f} Mrays per CPU s; per core / embree per "
              f"thread x{report['ratios'][name]['per_core_vs_embree_per_thread']:.2f}")
    print(f"  hits (intersect vs embree): {hits['mask_mismatches']} of {report['rays']} rays "
          f"differ, t within {hits['t_rel_diff_max']:.1e} (relative); render vs embree: "
          f"{report['render_hits']['mask_mismatches']} pixels differ")
    alone = report["one_core_hits"]
    if alone["agree"] and alone["t_rel_diff_max"] == 0:
        print("  one-core intersect: the device's very hits")
    else:
        print(f"  warning: the one-core intersect differs from the device's "
              f"({alone['mask_mismatches']} rays, t within {alone['t_rel_diff_max']:.1e}): its "
              "rate is not of the same rays", file=sys.stderr)
    if report["instructions"]:
        print(f"  render kernel: {report['instructions']['instructions_per_ray']:.0f} "
              "instructions a ray")
    print(f"wrote {json_path}")


def main(argv: list[str] | None = None) -> None:
    args = parse_arguments(argv)
    if args.one_core_child is not None:
        one_core_child(args.one_core_child, args.device, (args.width, args.height))
        return
    embree = import_embreex()
    if embree is None:
        print(INSTALL_HINT, file=sys.stderr)
        sys.exit(2)

    from clray.device.context import select_device
    from clray.scene.load import load_scene

    with tempfile.TemporaryDirectory(prefix="clray-embree-") as tmp:
        out = args.mesh_dir or Path(tmp) / "mesh"
        scene_file = write_scene(out, args.width, args.height, args.subdivisions)
        scene = load_scene(scene_file)
        device = select_device(args.device)
        workers = device.max_compute_units
        origins, directions = primary_rays(scene, args.width, args.height)
        triangles = camera_relative_triangles(scene)

        embree_side = EmbreeSide(embree, triangles, origins, directions)
        clray_side = ClraySide(scene, device, origins, directions, args.packet_spp)
        one_core = OneCoreSide(scene_file, args.device, (args.width, args.height))
        runs = timed_rounds(args, embree_side, clray_side, one_core)
        one_core.close()
        counted = count_instructions(scene_file) if args.instructions else None

    n = len(origins)
    embree_rates = {**rates(n, [r["wall_s"] for r in runs["embree"]],
                            [r["cpu_s"] for r in runs["embree"]], 1),
                    "system_seconds": spread([r["system_s"] for r in runs["embree"]]),
                    "page_faults": spread([r["page_faults"] for r in runs["embree"]])}
    sides = clray_rates(runs, n, workers, clray_side)
    embree_t = runs["embree"][-1]["t"]
    report = {
        "benchmark": "embree",
        "repeat": args.repeat,
        "width": args.width,
        "height": args.height,
        "scene": "make_mesh_scene.py's mesh alone (no plane, no lights), 1 ray a pixel",
        "subdivisions": args.subdivisions,
        "triangles": len(triangles),
        "rays": n,
        **_module("bench").environment(device),
        "clray_workers": workers,
        "bvh_width": clray_side.packed.config.bvh_width,
        "traversal": clray_side.packed.config.traversal,
        "clray_bvh_s": clray_side.bvh_s,
        "embreex_version": embree[2],
        # embreex's version numbers follow the Embree release its wheels bundle.
        "embree_version": (re.match(r"\d+\.\d+\.\d+", embree[2]) or [None])[0],
        "embree_threads": 1,
        "embree_call": "rtcIntersect1 (embreex EmbreeScene.run, a Cython loop over rays)",
        "embree_mesh_s": embree_side.mesh_s,
        "embree_commit_s": embree_side.commit_s,
        "embree": embree_rates,
        "clray": sides,
        "ratios": ratios_to_embree(sides, embree_rates),
        "hits": compare_hits(runs["intersect"][-1]["t"], embree_t),
        # The one-core child's intersect_rays against the device's: the same rays, the same t.
        "one_core_hits": compare_hits(np.asarray(runs["intersect_one_core"][0]["t"],
                                                 dtype=np.float32), runs["intersect"][-1]["t"]),
        "render_hits": compare_hits(np.where(runs["render"][-1]["hit"], 1.0, np.inf),
                                    np.where(np.isfinite(embree_t), 1.0, np.inf)),
        "instructions": counted,
    }
    args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print_summary(report, args.json)

if __name__ == "__main__":
    main()
