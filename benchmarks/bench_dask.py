"""Dask throughput against the single-process render: a still in tiles and a short animation,
on local clusters of 1 and 2 worker processes; per-task overhead and bytes moved.

    python benchmarks/bench_dask.py [--json benchmarks/results/dask.json]
                                    [-W 3840] [-H 2160] [--spp 16] [--frames 12]
                                    [--anim-width 1280] [--anim-height 720] [--anim-spp 4]

Every configuration renders once untimed first (PoCL compiles the kernel in each new worker
process), then is timed by wall clock on the client, as a user waits for it. Measures only:
nothing is asserted. See benchmarks/README.md, "bench_dask.py".
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

from distributed import Client

from clray.animation import load_sequence
from clray.device.context import describe, select_device
from clray.distributed import connect, render_sequence, render_still
from clray.render import RenderSettings, render
from clray.scene.load import load_scene

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _noop(x: int) -> int:
    return x


def task_round_trip_s(client: Client, n: int = 200) -> float:
    """Wall time per task of n empty tasks submitted at once: the scheduler's share of a tile."""
    client.gather(client.map(_noop, range(20), pure=False))
    start = time.perf_counter()
    client.gather(client.map(_noop, range(n), pure=False))
    return (time.perf_counter() - start) / n


def still(args: argparse.Namespace) -> dict:
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    settings = RenderSettings(width=args.width, height=args.height, spp=args.spp)
    samples = args.width * args.height * args.spp
    render(scene, RenderSettings(width=64, height=64, spp=1))  # compile, untimed
    start = time.perf_counter()
    local = render(scene, settings)
    local_s = time.perf_counter() - start
    out = {"pixel_samples": samples, "single_process": {
        "wall_s": local_s, "kernel_s": local.stats["kernel_s"],
        "msamples_per_s": samples / local_s * 1e-6}}
    for workers in (1, 2):
        with connect(None, workers=workers) as client:
            render_still(client, scene, RenderSettings(width=64, height=64, spp=1))
            round_trip = task_round_trip_s(client)
            start = time.perf_counter()
            result = render_still(client, scene, settings)
            wall = time.perf_counter() - start
        dask = result.stats["dask"]
        identical = result.image.tobytes() == local.image.tobytes()
        out[f"workers_{workers}"] = {
            "wall_s": wall,
            "msamples_per_s": samples / wall * 1e-6,
            "vs_single_process": local_s / wall,
            "per_worker_efficiency": local_s / wall / workers,
            "tiles": dask["tiles"],
            "tile_rows": dask["tile_rows"],
            "task_s_mean": dask["task_s"] / dask["tiles"],
            # Worker time not spent in a task, per task: scheduling, transfers, the probe
            # round before tiles are sized, and the idle tail of the last tiles.
            "overhead_per_task_s": (workers * wall - dask["task_s"]) / dask["tiles"],
            "empty_task_round_trip_s": round_trip,
            "scene_bytes": dask["scene_bytes"],
            "bytes_sent": dask["bytes_sent"],
            "result_bytes": dask["result_bytes"],
            "bit_identical": identical,
        }
    return out


def animation(args: argparse.Namespace) -> dict:
    sequence = load_sequence(ROOT / "scenes" / "orbit.toml")
    settings = RenderSettings(width=args.anim_width, height=args.anim_height, spp=args.anim_spp)
    frames = list(range(args.frames))
    images: dict[int, bytes] = {}

    def keep(frame: int, result: object) -> None:
        images[frame] = result.image.tobytes()

    render(sequence.scene(0), settings)  # compile this scene's kernel, untimed
    start = time.perf_counter()
    for frame in frames:
        keep(frame, render(sequence.scene(frame), settings))
    local_s = time.perf_counter() - start
    local = dict(images)
    out = {"frames": len(frames), "size": [args.anim_width, args.anim_height, args.anim_spp],
           "single_process": {"wall_s": local_s, "frames_per_s": len(frames) / local_s}}
    for workers in (1, 2):
        with connect(None, workers=workers) as client:
            render_sequence(client, sequence, frames[:workers], settings, lambda f, r: None)
            images.clear()
            start = time.perf_counter()
            dask = render_sequence(client, sequence, frames, settings, keep)
            wall = time.perf_counter() - start
        out[f"workers_{workers}"] = {
            "wall_s": wall,
            "frames_per_s": len(frames) / wall,
            "vs_single_process": local_s / wall,
            "per_worker_efficiency": local_s / wall / workers,
            "overhead_per_task_s": (workers * wall - dask["task_s"]) / len(frames),
            "bytes_sent": dask["bytes_sent"],
            "result_bytes": dask["result_bytes"],
            "bit_identical": images == local,
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "dask.json")
    parser.add_argument("-W", "--width", type=int, default=3840)
    parser.add_argument("-H", "--height", type=int, default=2160)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--anim-width", type=int, default=1280)
    parser.add_argument("--anim-height", type=int, default=720)
    parser.add_argument("--anim-spp", type=int, default=4)
    args = parser.parse_args()
    record = {
        "device": describe(select_device(None)),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "still": still(args),
        "animation": animation(args),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2) + "\n")
    json.dump(record, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
