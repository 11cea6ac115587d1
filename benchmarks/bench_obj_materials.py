"""Load time of a large OBJ with and without materials, device bytes per triangle and kernel
time: the cost of `usemtl`/`mtllib` (issue: a 1M-triangle OBJ with 100 materials must load in
at most 1.5x the time of the same OBJ without).

A grid of quads (two triangles each) is written three ways: no materials; 100 materials in
100 `usemtl` runs; the same 100 materials in 2000 runs (exporters write one per object or
group). Loads are interleaved over --repeat rounds after a warm-up; medians are reported.
Then the grid without materials and with 100 runs, each packed as `clray render` packs it for
the default device (320x240, one directional light): device bytes a triangle, of which the
triangle_materials buffer (a material word a triangle slot; one word for the whole mesh where
every triangle has the same material), and kernel time, a median of --repeat renders of each
in turns after a warm-up render of each (the kernel's build and PoCL's first-launch compile).

    python benchmarks/bench_obj_materials.py [--out benchmarks/results/obj_materials.json]
                                             [--side 708] [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import RESULTS, check_outputs, positive_int
from clray.device.context import describe, select_device
from clray.device.launch import render_packed
from clray.render import RenderSettings, pack_for
from clray.scene.load import scene_from_dict

N_MATERIALS = 100


def write_grid(folder: Path, side: int, runs: int) -> Path:
    """side x side quads as `f` lines of v/vt/vn-free triangles; `runs` usemtl statements
    (0: no materials at all) cycling through N_MATERIALS materials."""
    x, z = np.meshgrid(np.arange(side + 1, dtype=np.float64), np.arange(side + 1))
    y = 0.1 * np.sin(x * 0.05) * np.cos(z * 0.07)
    verts = "".join(f"v {a:.4f} {b:.4f} {c:.4f}\n" for a, b, c in
                    zip(x.ravel() / side, y.ravel(), z.ravel() / side, strict=True))
    i, j = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    a = (i * (side + 1) + j + 1).ravel()
    tri = np.concatenate([np.stack([a, a + 1, a + side + 2], 1),
                          np.stack([a, a + side + 2, a + side + 1], 1)])
    face_lines = [f"f {p} {q} {r}\n" for p, q, r in tri.tolist()]
    name = f"grid_{runs}.obj"
    parts = [verts]
    if runs == 0:
        parts += face_lines
    else:
        parts.insert(0, "mtllib grid.mtl\n")
        bounds = np.linspace(0, len(face_lines), runs + 1).astype(int)
        for k in range(runs):
            parts.append(f"usemtl m{k % N_MATERIALS}\n")
            parts += face_lines[bounds[k]:bounds[k + 1]]
    (folder / name).write_text("".join(parts))
    (folder / "grid.mtl").write_text("".join(
        f"newmtl m{k}\nKd {k / N_MATERIALS:.3f} 0.5 0.5\nKs 0.2 0.2 0.2\nNs 30\nillum 2\n"
        for k in range(N_MATERIALS)))
    return folder / name


def load(path: Path) -> tuple[float, object]:
    data = {"camera": {"position": [0.5, 1.5, -1.0], "look_at": [0.5, 0.0, 0.5]},
            "lights": [{"type": "directional", "direction": [0.3, -1, 0.2]}],
            "render": {"width": 320, "height": 240},
            "objects": [{"type": "mesh", "file": path.name}]}
    start = time.perf_counter()
    scene = scene_from_dict(data, path.with_name("scene.toml"))
    return time.perf_counter() - start, scene


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=positive_int, default=708, help="quads per side "
                        "(2 side^2 triangles; 708 gives 1.0M)")
    parser.add_argument("--repeat", type=positive_int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS / "obj_materials.json")
    args = parser.parse_args(argv)
    check_outputs(parser, out=args.out)
    with tempfile.TemporaryDirectory() as tmp:
        files = {"none": write_grid(Path(tmp), args.side, 0),
                 "100_runs": write_grid(Path(tmp), args.side, 100),
                 "2000_runs": write_grid(Path(tmp), args.side, 2000)}
        times: dict[str, list[float]] = {k: [] for k in files}
        for path in files.values():  # warm-up
            load(path)
        for _ in range(args.repeat):
            for name, path in files.items():
                times[name].append(load(path)[0])
        result: dict = {
            "machine": {"cpu": platform.processor() or platform.machine(),
                        "python": platform.python_version()},
            "triangles": 2 * args.side**2, "materials": N_MATERIALS,
            "load_s": {k: median(v) for k, v in times.items()},
            "load_ratio": {k: median(v) / median(times["none"]) for k, v in times.items()},
        }
        device = select_device(None)
        result["device_name"] = describe(device)
        result["device"] = {}
        packed = {}
        for name in ("none", "100_runs"):
            packed[name] = pack_for(load(files[name])[1], RenderSettings(width=320, height=240),
                                    device)
            n_tri = packed[name].triangle_count()
            sizes = packed[name].device_bytes()
            result["device"][name] = {
                "bytes_per_triangle": sum(sizes.values()) / n_tri,
                # Where a mesh has no vertex attributes the device keeps no Triangle records
                # (their bytes are 0): a triangle's material is a word of its own here.
                "triangle_materials_bytes_per_triangle": sizes["triangle_materials"] / n_tri,
            }
        kernel: dict[str, list[float]] = {name: [] for name in packed}
        for one in packed.values():  # warm-up: the kernel's build and first launch
            render_packed(one, device)
        for _ in range(args.repeat):
            for name, one in packed.items():  # in turns: the load's drift falls on both
                kernel[name].append(render_packed(one, device)[1]["kernel_s"])
        for name, runs in kernel.items():
            result["device"][name].update(kernel_s=median(runs), kernel_runs_s=runs)
    args.out.write_text(json.dumps(result, indent=2, default=str) + "\n")
    print(json.dumps(result, indent=2, default=str))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
