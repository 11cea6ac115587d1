"""Dask throughput against the single-process render: a still in tiles and a short animation,
on local clusters of 1 and 2 worker processes; per-task overhead and bytes moved.

    python benchmarks/bench_dask.py [--json benchmarks/results/dask.json] [--rounds 3]
                                    [-W 3840] [-H 2160] [--spp 16] [--frames 12]
                                    [--anim-width 1280] [--anim-height 720] [--anim-spp 4]

Both clusters start first; the still, and then the animation, render once untimed with the
timed settings in this process and on each cluster (PoCL compiles the kernel in each new worker
process, and the kernel's build follows the settings: a 16-spp render builds the sample-packet
walk that a 1-spp one does not). Then each round times the single-process render, 1 worker
and 2 workers in turn, by wall clock on the client, as a user waits for it: on a machine shared
with other work the load drifts, and interleaving spreads the drift over all three. Ratios are
of the rounds' medians.
Measures only: nothing is asserted. See benchmarks/README.md, "bench_dask.py".
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

from distributed import Client

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import check_outputs, positive_int
from clray.device.context import describe, select_device
from clray.distributed import connect, render_sequence, render_still
from clray.render import RenderResult, RenderSettings, render
from clray.scene.load import load_scene
from clray.sequence import load_sequence

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
WORKERS = (1, 2)


def _noop(x: int) -> int:
    return x


def task_round_trip_s(client: Client, n: int = 200) -> float:
    """Wall time per task of n empty tasks submitted at once: the scheduler's share of a tile."""
    client.gather(client.map(_noop, range(20), pure=False))
    start = time.perf_counter()
    client.gather(client.map(_noop, range(n), pure=False))
    return (time.perf_counter() - start) / n


def _rounds(n: int, runs: dict[str, Callable[[], dict]]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {name: [] for name in runs}
    for _ in range(n):
        for name, run in runs.items():
            load = os.getloadavg()[0]
            start = time.perf_counter()
            record = run()
            out[name].append({"wall_s": time.perf_counter() - start, "load_1min": load,
                              **record})
    return out


def _summary(runs: dict[str, list[dict]], work: float, unit: str) -> dict:
    single = statistics.median(r["wall_s"] for r in runs["single_process"])
    out = {}
    for name, records in runs.items():
        wall = statistics.median(r["wall_s"] for r in records)
        workers = int(name.split("_")[1]) if name != "single_process" else 1
        out[name] = {"wall_s_median": wall, f"{unit}_per_s": work / wall,
                     "vs_single_process": single / wall,
                     "per_worker_efficiency": single / wall / workers, "rounds": records}
    return out


def still(args: argparse.Namespace, clients: dict[int, Client]) -> dict:
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    settings = RenderSettings(width=args.width, height=args.height, spp=args.spp)
    samples = args.width * args.height * args.spp
    # Warm-up at the timed settings: a smaller or 1-spp render builds another kernel (the
    # single-ray walk, not the sample packets), leaving the timed one's build to round 1.
    reference = render(scene, settings).image.tobytes()
    for client in clients.values():
        render_still(client, scene, settings)

    def local() -> dict:
        return {"kernel_s": render(scene, settings).stats["kernel_s"]}

    def on(workers: int) -> Callable[[], dict]:
        def run() -> dict:
            result = render_still(clients[workers], scene, settings)
            dask = result.stats["dask"]
            return {
                "kernel_s": result.stats["kernel_s"],  # device time, summed over the tiles
                "tiles": dask["tiles"],
                "tile_rows": dask["tile_rows"],
                "task_s_mean": dask["task_s"] / dask["tiles"],
                "bit_identical": result.image.tobytes() == reference,
                "scene_bytes": dask["scene_bytes"],
                "bytes_sent": dask["bytes_sent"],
                "result_bytes": dask["result_bytes"],
                "task_s": dask["task_s"],
            }
        return run

    runs = _rounds(args.rounds, {"single_process": local,
                                 **{f"workers_{n}": on(n) for n in WORKERS}})
    out = {"size": [args.width, args.height, args.spp], "pixel_samples": samples,
           **_summary(runs, samples * 1e-6, "msamples")}
    for n in WORKERS:
        records = runs[f"workers_{n}"]
        # Worker time not spent in a task, per task: scheduling, transfers, the probe tiles
        # before the rest are sized, and the idle tail of the last tiles.
        out[f"workers_{n}"]["overhead_per_task_s"] = statistics.median(
            (n * r["wall_s"] - r["task_s"]) / r["tiles"] for r in records)
        out[f"workers_{n}"]["empty_task_round_trip_s"] = task_round_trip_s(clients[n])
    return out


def animation(args: argparse.Namespace, clients: dict[int, Client]) -> dict:
    sequence = load_sequence(ROOT / "scenes" / "orbit.toml")
    settings = RenderSettings(width=args.anim_width, height=args.anim_height, spp=args.anim_spp)
    frames = list(range(args.frames))
    render(sequence.scene(0), settings)  # compile this scene's kernel, untimed
    for n, client in clients.items():
        render_sequence(client, sequence, frames[:n], settings, lambda f, r: None)
    reference: dict[int, bytes] = {}

    def local() -> dict:
        for frame in frames:
            reference[frame] = render(sequence.scene(frame), settings).image.tobytes()
        return {}

    def on(workers: int) -> Callable[[], dict]:
        def run() -> dict:
            images: dict[int, bytes] = {}

            def keep(frame: int, result: RenderResult) -> None:
                images[frame] = result.image.tobytes()

            dask = render_sequence(clients[workers], sequence, frames, settings, keep)
            return {"task_s": dask["task_s"], "bytes_sent": dask["bytes_sent"],
                    "result_bytes": dask["result_bytes"], "bit_identical": images == reference}
        return run

    runs = _rounds(args.rounds, {"single_process": local,
                                 **{f"workers_{n}": on(n) for n in WORKERS}})
    out = {"frames": len(frames), "size": [args.anim_width, args.anim_height, args.anim_spp],
           **_summary(runs, len(frames), "frames")}
    for n in WORKERS:
        out[f"workers_{n}"]["overhead_per_task_s"] = statistics.median(
            (n * r["wall_s"] - r["task_s"]) / len(frames) for r in runs[f"workers_{n}"])
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "dask.json")
    parser.add_argument("--rounds", type=positive_int, default=3)
    parser.add_argument("-W", "--width", type=positive_int, default=3840)
    parser.add_argument("-H", "--height", type=positive_int, default=2160)
    parser.add_argument("--spp", type=positive_int, default=16)
    parser.add_argument("--frames", type=positive_int, default=12)
    parser.add_argument("--anim-width", type=positive_int, default=1280)
    parser.add_argument("--anim-height", type=positive_int, default=720)
    parser.add_argument("--anim-spp", type=positive_int, default=4)
    args = parser.parse_args(argv)
    check_outputs(parser, json=args.json)
    with contextlib.ExitStack() as stack:
        clients = {n: stack.enter_context(connect(None, workers=n)) for n in WORKERS}
        record = {
            "device": describe(select_device(None)),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "still": still(args, clients),
            "animation": animation(args, clients),
        }
    args.json.write_text(json.dumps(record, indent=2) + "\n")
    json.dump(record, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
