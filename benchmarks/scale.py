"""Big models: load, BVH, pack and kernel seconds, host peak memory and device bytes a
triangle of the bumpy icosphere as a binary PLY at several sizes, as `clray render MODEL.ply`
runs them.

    python benchmarks/scale.py [--subdivisions 7,8,9] [--json benchmarks/results/scale.json]
                               [--mesh-dir DIR] [--mitsuba {auto,off}] [--plot docs/scale.png]
                               [--against REF [--rounds 3]]

Each size is written once as a binary little-endian PLY (float x, y, z; uchar/int faces, the
layout scanners and MeshLab write) and rendered in a fresh process as `clray render MODEL.ply`
runs it: the automatic scene of `clray render MODEL` (clray.model_scene), 1280 x 720, 1 spp,
packed as render() packs it for the device (the BVH on the device where it is large). A first
process runs the same file as a warm-up, so that the kernel (whose build options follow the
model: the BVH's stack depth) and, at 20,000 triangles or more, the device BVH build's program
are in pyopencl's and PoCL's caches on disk: the timed process's `bvh_s` and `build_s` hold a
load from those caches, as a second `clray render` of the model does, and no compile; the
warm-up's own are `bvh_first_s` and `build_first_s`. The timed process's peak resident memory
(VmHWM) is its own, as a user's command's is (a warm-up in the same process left its freed
memory resident and raised the peak by it); it is read after load, after pack and after the
render, so each stage's share is in view.

Mitsuba 3's load of the same file (its PLY reader and, where built with it, Embree's BVH: a
`scalar_rgb` scene of one `ply` shape) runs in a process of its own beside clray's where the
`mitsuba` package is installed; otherwise the row says so. Measures only.

--against REF measures the largest size only, the working tree and commit REF in turns (the
machine's load falls on both alike), and writes each one's medians and every run with the load
average before it.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import PEAK_SOURCE, check_outputs, positive_int, positive_ints  # noqa: E402

MIB = 1024.0 * 1024.0

# The children's peak resident bytes (VmHWM: its own, not the parent's mesh writer's).
_PEAK = "import json, sys, time\n" + PEAK_SOURCE

# Runs in the child: one size; prints one JSON line.
_CLRAY = _PEAK + """
from pathlib import Path
from clray.device.context import describe, select_device
from clray.device.launch import render_packed
from clray.model_scene import load_model_scene
from clray.render import RenderSettings, pack_for


path = Path(sys.argv[1])
settings = RenderSettings(width=1280, height=720, spp=1)
device = select_device(None)
out = {"device": describe(device), "rss_before": peak()}
t = time.perf_counter()
scene = load_model_scene(path)
out["load_s"] = time.perf_counter() - t
out["peak_after_load"] = peak()
t = time.perf_counter()
packed = pack_for(scene, settings, device)
out["bvh_s"] = packed.bvh_s
out["pack_s"] = time.perf_counter() - t - packed.bvh_s
out["peak_after_pack"] = peak()
out["device_bytes"] = packed.device_bytes()
out["triangles"] = packed.triangle_count()
del scene  # as clray render hands its scene to render(), which lets it go once packed
_, stats = render_packed(packed, device)
out["build_s"], out["kernel_s"] = stats["build_s"], stats["kernel_s"]
out["peak_after_render"] = peak()
print(json.dumps(out))
"""

_MITSUBA = _PEAK + """
import mitsuba as mi
mi.set_variant("scalar_rgb")
t = time.perf_counter()
scene = mi.load_dict({"type": "scene", "mesh": {"type": "ply", "filename": sys.argv[1]}})
out = {"load_s": time.perf_counter() - t, "mitsuba": mi.__version__,
       "peak": peak()}
print(json.dumps(out))
"""


def _mesh_module():
    spec = importlib.util.spec_from_file_location(
        "make_mesh_scene", HERE.parent / "scripts" / "make_mesh_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_ply(path: Path, subdivisions: int) -> int:
    """The bumpy icosphere of scripts/make_mesh_scene.py as a binary PLY (positions and
    faces only); returns its triangle count."""
    mesh = _mesh_module()
    vertices, faces, _ = mesh.bumpy_mesh(subdivisions, mesh.SCENE_CENTER, mesh.SCENE_RADIUS)
    face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, faces
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    with path.open("wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertices.astype("<f4").tobytes())
        f.write(face.tobytes())
    return len(faces)


def _child(code: str, *args: str, source: Path = ROOT) -> dict:
    """Runs `code` in a fresh process importing clray from `source` (a checkout's root): its
    cwd, which `python -c` puts first on the path."""
    env = {**os.environ, "PYTHONPATH": str(source)} if source != ROOT else None
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          cwd=source, env=env)
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1][:300] if done.stderr else
                f"exit {done.returncode}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _has_mitsuba() -> bool:
    return importlib.util.find_spec("mitsuba") is not None


def unknown_ref(ref: str) -> bool:
    """Whether git does not resolve `ref` to a commit here."""
    return subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
                          cwd=ROOT, capture_output=True).returncode != 0


def measure(path: Path, mitsuba: bool, source: Path = ROOT) -> dict:
    warm_up = _child(_CLRAY, str(path), source=source)
    row = warm_up if "error" in warm_up else _child(_CLRAY, str(path), source=source)
    if "error" not in row:
        row["bvh_first_s"], row["build_first_s"] = warm_up["bvh_s"], warm_up["build_s"]
        triangles = row["triangles"]
        device = sum(row["device_bytes"].values())
        row["device_bytes_total"] = device
        row["device_bytes_per_triangle"] = device / triangles
        row["load_bvh_pack_s"] = row["load_s"] + row["bvh_s"] + row["pack_s"]
        row["host_peak"] = row["peak_after_render"]
        row["host_peak_over_device"] = row["host_peak"] / device
        row["mtriangles_per_s_bvh"] = triangles / row["bvh_s"] / 1e6
    row["file_bytes"] = path.stat().st_size
    row["mitsuba"] = _child(_MITSUBA, str(path)) if mitsuba else "not installed"
    return row


def _summary(s: int, row: dict) -> str:
    if "error" in row:
        return f"{s} subdivisions: {row['error']}"
    mitsuba = row["mitsuba"]
    if isinstance(mitsuba, dict):
        mitsuba = (f"{mitsuba['load_s']:.2f} s, peak {mitsuba['peak'] / MIB:.0f} MiB"
                   if "load_s" in mitsuba else mitsuba["error"])
    return (f"{s} subdivisions, {row['triangles']:,} triangles: load {row['load_s']:.2f} s, "
            f"bvh {row['bvh_s']:.2f} s, pack {row['pack_s']:.2f} s (together "
            f"{row['load_bvh_pack_s']:.2f} s), warm-up's build {row['build_first_s']:.2f} s "
            f"and bvh {row['bvh_first_s']:.2f} s, kernel "
            f"{row['kernel_s']:.2f} s; host peak {row['host_peak'] / MIB:.0f} MiB "
            f"({row['host_peak_over_device']:.2f}x device), device "
            f"{row['device_bytes_total'] / MIB:.1f} MiB = "
            f"{row['device_bytes_per_triangle']:.1f} B a triangle; Mitsuba 3: {mitsuba}")


def against(ref: str, path: Path, rounds: int) -> dict:
    """The working tree and commit `ref` (exported whole by git archive) measured in turns,
    `rounds` times each, with the load average before each run: the stages' medians and
    the runs."""
    keys = ("load_s", "bvh_s", "pack_s", "load_bvh_pack_s", "mtriangles_per_s_bvh",
            "host_peak")
    runs: dict[str, list[dict]] = {ref: [], "worktree": []}
    with tempfile.TemporaryDirectory() as tmp_name:
        export = Path(tmp_name)
        archive = subprocess.run(["git", "archive", ref], cwd=ROOT, capture_output=True,
                                 check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(export)], input=archive, check=True)
        # The checkout maps kernels/ to clray.kernels (pyproject.toml); an export imported
        # from its folder needs them there, or the installed checkout's kernels are found.
        shutil.copytree(export / "kernels", export / "clray" / "kernels")
        for _ in range(rounds):
            for name, source in ((ref, export), ("worktree", ROOT)):
                load = os.getloadavg()[0]
                row = measure(path, False, source)
                runs[name].append({"load_average": load, **{k: row.get(k) for k in keys},
                                   **({"error": row["error"]} if "error" in row else {})})
                print(name, json.dumps(runs[name][-1]), flush=True)
    medians = {name: {k: float(np.median([r[k] for r in rs if k in r and r[k] is not None]))
                      for k in keys if any(r.get(k) is not None for r in rs)}
               for name, rs in runs.items()}
    return {"ref": ref, "medians": medians, "runs": runs}


def plot(rows: dict[str, dict], out: Path) -> None:
    """Seconds by stage and host peak / device memory against triangles (the `plot` extra)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows.values() if "error" not in r]
    tris = np.array([r["triangles"] for r in done]) / 1e6
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(10, 4))
    for key in ("load_s", "bvh_s", "pack_s", "kernel_s"):
        ax_t.plot(tris, [r[key] for r in done], "o-", label=key[:-2])
    mitsuba = [(t, r["mitsuba"]["load_s"]) for t, r in zip(tris, done, strict=True)
               if isinstance(r["mitsuba"], dict) and "load_s" in r["mitsuba"]]
    if mitsuba:
        ax_t.plot(*zip(*mitsuba, strict=True), "k--", label="Mitsuba 3 load")
    ax_t.set(xlabel="million triangles", ylabel="seconds", title="time by stage")
    ax_t.legend()
    ax_m.plot(tris, [r["host_peak"] / MIB for r in done], "o-", label="host peak (VmHWM)")
    ax_m.plot(tris, [r["device_bytes_total"] / MIB for r in done], "o-", label="device buffers")
    ax_m.set(xlabel="million triangles", ylabel="MiB", title="memory")
    ax_m.legend()
    fig.suptitle(f"clray render MODEL.ply, bumpy icosphere ({done[0]['device']}; "
                 f"{os.cpu_count()} CPUs, shared)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=positive_ints, default=[7, 8, 9],
                        help="comma-separated sizes (10: 21 M triangles, about 8 GB of host "
                        "memory today)")
    parser.add_argument("--json", type=Path, default=HERE / "results" / "scale.json")
    parser.add_argument("--mesh-dir", type=Path, help="keep the PLY files here (default: a "
                        "temporary folder)")
    parser.add_argument("--mitsuba", choices=("auto", "off"), default="auto")
    parser.add_argument("--plot", type=Path, help="write the figure here (needs matplotlib)")
    parser.add_argument("--against", metavar="REF", help="measure the largest size only, in "
                        "turns with commit REF, for --rounds rounds (no Mitsuba)")
    parser.add_argument("--rounds", type=positive_int, default=3)
    args = parser.parse_args(argv)
    if args.against and unknown_ref(args.against):
        parser.error(f"--against {args.against}: not a commit in {ROOT}")
    check_outputs(parser, json=args.json, plot=None if args.against else args.plot)
    mitsuba = args.mitsuba == "auto" and _has_mitsuba()
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        folder = args.mesh_dir or Path(tmp_name)
        folder.mkdir(parents=True, exist_ok=True)
        sizes = args.subdivisions
        for s in [max(sizes)] if args.against else sizes:
            path = folder / f"bumpy{s}.ply"
            if not path.exists():
                write_ply(path, s)
            if args.against:
                rows[str(s)] = against(args.against, path, args.rounds)
                print(json.dumps(rows[str(s)]["medians"]), flush=True)
                continue
            rows[str(s)] = measure(path, mitsuba)
            print(_summary(s, rows[str(s)]), flush=True)
    args.json.write_text(json.dumps({"python": platform.python_version(),
                                     "numpy": np.__version__, "sizes": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")
    if args.plot and not args.against:
        plot(rows, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
