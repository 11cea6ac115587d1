"""Instancing: one 327,680-triangle mesh placed once, and placed 1,000 times, side by side.

    python benchmarks/bench_instances.py [--device SPEC] [--repeat N] [--out FILE.json]

Scenes, all 1280x720, 1 spp, one point light and a ground plane:
- `placed`: the mesh as a plain object (no instance), the close-up camera;
- `one_instance`: the mesh as the one instance of a group, the same camera;
- `thousand_instances`: 1,000 instances on a 40 x 25 grid, each turned and scaled differently
  except the one at the origin, which is the close-up's mesh, seen by the same camera (the
  other instances fill the background);
- `thousand_overview`: the same 1,000 seen from above, filling the view (each mesh covers a few
  hundred pixels with its 327,680 triangles, so rays are incoherent: compare Mrays/s);
- `eight_placed` and `eight_instances`: eight turned copies of the mesh, placed as eight mesh
  objects (2.6 M triangles on the device) and as eight instances of one group, same camera:
  the same image, so their kernel times compare the two-level walk with the flat one.
For each: load time (the OBJ is read once either way), BVH build time, device bytes, kernel
time (OpenCL profiling events) and Mrays/s. Every scene is first loaded, packed twice (the
first pack compiles the device BVH build; `bvh_s` is the second's) and rendered once untimed
(the kernel's build and first launch); then each of `repeat` rounds loads and renders every
scene in turn, so that the machine's load drifting falls on all alike: `load_s` and `kernel_s`
are medians of the rounds.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.common import RESULTS, check_outputs, positive_int  # noqa: E402
from clray.device.context import queue_for, select_device  # noqa: E402
from clray.device.launch import render_packed  # noqa: E402
from clray.device.pack import pack_scene  # noqa: E402
from clray.device.policy import device_plan  # noqa: E402
from clray.knobs import Tuning  # noqa: E402
from clray.scene.load import load_scene  # noqa: E402

GRID = (40, 25)  # instances along x and z, one of them at the origin


def _make_mesh(folder: Path) -> Path:
    spec = importlib.util.spec_from_file_location("make_mesh_scene",
                                                  ROOT / "scripts" / "make_mesh_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    path = folder / "bumpy.obj"
    module.write_obj(path, *module.bumpy_mesh(7))
    return path


def _scene_text(mesh: Path, placements: list[str] | None, camera: str) -> str:
    if placements is None:
        objects = f'\n[[objects]]\ntype = "mesh"\nfile = "{mesh.name}"\nmaterial = "clay"\n'
    else:
        objects = "".join(f'\n[[objects]]\ntype = "instance"\ngroup = "bumpy"\n'
                          f"transform = {p}\n" for p in placements)
    return f"""
[render]
width = 1280
height = 720
spp = 1
max_depth = 0
background = [0.05, 0.05, 0.08]
{camera}
[materials.clay]
color = [0.85, 0.45, 0.25]
ambient = 0.1
diffuse = 0.8
specular = 0.3
shininess = 40

[[lights]]
type = "point"
position = [30, 60, 40]

[groups.bumpy]
objects = [{{ type = "mesh", file = "{mesh.name}", material = "clay" }}]

[[objects]]
type = "plane"
point = [0, -1.1, 0]
normal = [0, 1, 0]
material = "clay"
{objects}"""


def scenes(folder: Path) -> dict[str, Path]:
    mesh = _make_mesh(folder)
    rng = np.random.default_rng(1)
    grid = []
    for i in range(GRID[0]):
        for k in range(GRID[1]):
            x, z = (i - GRID[0] // 2) * 2.5, (k - GRID[1] // 2) * 2.5
            turn = rng.uniform(0, 360, 3).round(1).tolist()
            scale = rng.uniform(0.7, 1.1)
            grid.append("{}" if x == z == 0 else
                        f"{{ rotate = {turn}, scale = {scale:.2f}, translate = [{x}, 0, {z}] }}")
    close = "[camera]\nposition = [0.0, 1.2, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nvfov = 40\n"
    above = "[camera]\nposition = [0.0, 45.0, 55.0]\nlook_at = [0.0, 0.0, 0.0]\nvfov = 45\n"
    texts = {"placed": _scene_text(mesh, None, close),
             "one_instance": _scene_text(mesh, ["{}"], close),
             "thousand_instances": _scene_text(mesh, grid, close),
             "thousand_overview": _scene_text(mesh, grid, above)}
    eight = [f"{{ rotate = [0, {30 * i}, 0], translate = [{(i % 4 - 1.5) * 2.5}, 0, "
             f"{-(i // 4) * 2.5}] }}" for i in range(8)]
    wide = "[camera]\nposition = [0.0, 3.0, 6.0]\nlook_at = [0.0, 0.0, -1.5]\nvfov = 60\n"
    texts["eight_instances"] = _scene_text(mesh, eight, wide)
    texts["eight_placed"] = _scene_text(mesh, None, wide).replace(
        f'\n[[objects]]\ntype = "mesh"\nfile = "{mesh.name}"\nmaterial = "clay"\n',
        "".join(f'\n[[objects]]\ntype = "mesh"\nfile = "{mesh.name}"\nmaterial = "clay"\n'
                f"transform = {p}\n" for p in eight))
    paths = {}
    for name, text in texts.items():
        paths[name] = folder / f"{name}.toml"
        paths[name].write_text(text, encoding="utf-8")
    return paths


def prepare(path: Path, device):
    """The scene at path loaded and packed (twice: the first pack compiles the device BVH
    build), and rendered once untimed (the kernel's build and first launch)."""
    scene = load_scene(path)
    settings = {"width": 1280, "height": 720, "spp": 1, "max_depth": 0, "seed": 0,
                "queue": queue_for(device),
                "bvh_width": device_plan(device, spp=1, tuning=Tuning()).bvh_width}
    pack_scene(scene, **settings)
    packed = pack_scene(scene, **settings)
    render_packed(packed, device)
    return packed


def bench(paths: dict[str, Path], device, repeat: int) -> dict[str, dict]:
    """Each scene's figures: warmed up all, then `repeat` rounds of a load and a render of
    every scene in turn, medians."""
    packed = {name: prepare(path, device) for name, path in paths.items()}
    loads: dict[str, list[float]] = {name: [] for name in paths}
    kernels: dict[str, list[float]] = {name: [] for name in paths}
    rays: dict[str, int] = {}
    for _ in range(repeat):
        for name, path in paths.items():
            start = time.perf_counter()
            load_scene(path)
            loads[name].append(time.perf_counter() - start)
            _, stats = render_packed(packed[name], device)
            kernels[name].append(stats["kernel_s"])
            rays[name] = stats["rays"]["total"]
    results = {}
    for name, one in packed.items():
        kernel_s = statistics.median(kernels[name])
        device_bytes = one.device_bytes()
        results[name] = {
            "instances": len(one.instances), "triangles": one.triangle_count(),
            "load_s": statistics.median(loads[name]), "load_runs_s": loads[name],
            "bvh_s": one.bvh_s, "device_bytes": sum(device_bytes.values()),
            "device_bytes_by_buffer": device_bytes, "kernel_s": kernel_s,
            "kernel_runs_s": kernels[name], "rays": rays[name],
            "mrays_per_s": rays[name] / kernel_s * 1e-6}
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--repeat", type=positive_int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_instances.json")
    args = parser.parse_args(argv)
    check_outputs(parser, out=args.out)
    device = select_device(args.device)
    with tempfile.TemporaryDirectory(prefix="clray-instances-") as tmp:
        results = bench(scenes(Path(tmp)), device, args.repeat)
    ratios = {f"{a}/{b}": {key: results[a][key] / results[b][key] for key in (
        "load_s", "bvh_s", "device_bytes", "kernel_s", "mrays_per_s")}
        for a, b in (("one_instance", "placed"), ("thousand_instances", "one_instance"),
                     ("thousand_overview", "one_instance"), ("eight_instances", "eight_placed"))}
    report = {"benchmark": "instances", "device": device.name.strip(),
              "platform_version": device.platform.version.strip(), "repeat": args.repeat,
              "scenes": results, "ratios": ratios}
    args.out.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    for name, r in results.items():
        print(f"{name}: {r['instances']} instances, load {r['load_s']:.3f} s, BVH "
              f"{r['bvh_s']:.3f} s, {r['device_bytes'] / 2**20:.1f} MiB, kernel "
              f"{r['kernel_s']:.3f} s, {r['mrays_per_s']:.1f} Mrays/s")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
