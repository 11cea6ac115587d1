"""BVH build time and quality: the benchmark mesh (327,680 triangles at 7 subdivisions) and a
set of random spheres, built on the host and, where an OpenCL device is found, on the device.

    python benchmarks/bench_bvh.py [--json benchmarks/results/bvh.json] [--subdivisions 7]

Per case and builder: one warm-up build (page faults, lazy imports, kernel compilation), then
--runs timed builds taken in turns with the other builder so that load from elsewhere on the
machine falls on both alike; the median is reported with the SAH cost of the tree. Measures
only; speed goals are checked from the JSON it writes.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clray.accel.bvh import Bvh, build_bvh, max_leaf_count, sah_cost

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from benchmarks.common import check_outputs, positive_int  # noqa: E402


def _mesh_module():
    # scripts/ is not a package: load the generator from its file.
    spec = importlib.util.spec_from_file_location(
        "make_mesh_scene", HERE.parent / "scripts" / "make_mesh_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def mesh_bounds(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces, _ = _mesh_module().bumpy_mesh(subdivisions)
    tri = vertices[faces]
    return tri.min(axis=1), tri.max(axis=1)


def sphere_bounds(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Spheres scattered in a cube, radii exponential: overlapping, varied sizes."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-50, 50, (n, 3))
    radii = rng.exponential(0.5, (n, 1)) + 0.01
    return centres - radii, centres + radii


def _device_queue(n: int):
    """The default device's queue, or None where there is none or it cannot build over n."""
    from clray.device import bvh_builder
    from clray.device.context import queue_for, select_device
    from clray.errors import DeviceError

    try:
        device = select_device()
    except DeviceError:
        return None
    return queue_for(device) if bvh_builder.supports(device, n) else None


def _describe(bvh: Bvh, runs: list[float], n: int, max_leaf_size: int) -> dict:
    count = bvh.nodes["count"]
    leaf_sizes = np.bincount(count[count > 0], minlength=max_leaf_count(max_leaf_size) + 1)
    return {
        "build_s": statistics.median(runs),
        "runs_s": runs,
        "sah_cost": sah_cost(bvh.nodes),
        "nodes": int(bvh.nodes.size),
        "nodes_per_primitive": bvh.nodes.size / n,
        "leaves": int((count > 0).sum()),
        "leaf_size_histogram": leaf_sizes.tolist(),
        "bytes_per_primitive": (bvh.nodes.nbytes + bvh.order.nbytes) / n,
    }


def bench_case(lo: np.ndarray, hi: np.ndarray, builders: dict[str, Callable[[], Bvh]],
               runs: int, max_leaf_size: int) -> dict:
    built = {name: build() for name, build in builders.items()}  # warm-up
    times: dict[str, list[float]] = {name: [] for name in builders}
    for _ in range(runs):
        for name, build in builders.items():
            t0 = time.perf_counter()
            built[name] = build()
            times[name].append(time.perf_counter() - t0)
    result = {name: _describe(built[name], times[name], lo.shape[0], max_leaf_size)
              for name in builders}
    if len(built) == 2:
        a, b = built.values()
        # By value: a min or max over 0.0 and -0.0 may give either.
        result["same_tree"] = all(np.array_equal(a.nodes[f], b.nodes[f])
                                  for f in a.nodes.dtype.names) and bool(
                                      np.array_equal(a.order, b.order))
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "bvh.json")
    parser.add_argument("--subdivisions", type=positive_int, default=7)
    parser.add_argument("--spheres", type=positive_int, default=100_000)
    parser.add_argument("--runs", type=positive_int, default=7)
    parser.add_argument("--max-leaf-size", type=positive_int, default=4)
    parser.add_argument("--host-only", action="store_true", help="skip the device build")
    args = parser.parse_args(argv)
    check_outputs(parser, json=args.json)

    cases = {"mesh": mesh_bounds(args.subdivisions), "spheres": sphere_bounds(args.spheres)}
    largest = max(lo.shape[0] for lo, _ in cases.values())
    queue = None if args.host_only else _device_queue(largest)
    results = {}
    for name, (lo, hi) in cases.items():
        builders = {"host": lambda lo=lo, hi=hi: build_bvh(lo, hi, args.max_leaf_size)}
        if queue is not None:
            from clray.device.bvh_builder import build_bvh_on

            builders["device"] = lambda lo=lo, hi=hi: build_bvh_on(queue, lo, hi,
                                                                   args.max_leaf_size)
        results[name] = {"primitives": lo.shape[0],
                         **bench_case(lo, hi, builders, args.runs, args.max_leaf_size)}

    result = {
        "benchmark": "bvh_build",
        "subdivisions": args.subdivisions,
        "max_leaf_size": args.max_leaf_size,
        "device": None if queue is None else queue.device.name.strip(),
        "cases": results,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
    }
    args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    for name, case in results.items():
        for builder in ("host", "device"):
            if builder in case:
                r = case[builder]
                print(f"{name} ({case['primitives']}) {builder}: {r['build_s']:.3f} s, "
                      f"SAH {r['sah_cost']:.3f}")


if __name__ == "__main__":
    main()
