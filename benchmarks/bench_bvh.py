"""BVH build time for the benchmark mesh (327,680 triangles at 7 subdivisions).

    python benchmarks/bench_bvh.py [--json benchmarks/results/bvh.json] [--subdivisions 7]

One warm-up build, then the median of --runs timed builds of clray.accel.bvh.build_bvh over the
triangles' bounds. Measures only; speed goals are checked from the JSON it writes.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from clray.accel.bvh import build_bvh, max_leaf_count

HERE = Path(__file__).resolve().parent


def _mesh_module():
    # benchmarks/ is not a package: load the generator from its file.
    spec = importlib.util.spec_from_file_location("make_mesh_scene", HERE / "make_mesh_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def sah_cost(nodes: np.ndarray) -> float:
    """SAH cost of the tree (node visits + primitive tests, each 1), relative to the root's
    area: a build-quality figure to read next to the build time."""
    e = (nodes["hi"].astype(np.float64) - nodes["lo"]).clip(min=0)
    area = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    count = nodes["count"].astype(np.float64)
    per_node = np.where(count > 0, count, 1.0) * area
    return float(per_node.sum() / area[0])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "bvh.json")
    parser.add_argument("--subdivisions", type=int, default=7)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--max-leaf-size", type=int, default=4)
    args = parser.parse_args(argv)

    vertices, faces, _ = _mesh_module().bumpy_mesh(args.subdivisions)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)

    bvh = build_bvh(lo, hi, args.max_leaf_size)  # warm-up: page faults, lazy imports
    runs = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        bvh = build_bvh(lo, hi, args.max_leaf_size)
        runs.append(time.perf_counter() - t0)

    n = len(faces)
    count = bvh.nodes["count"]
    leaf_sizes = np.bincount(count[count > 0], minlength=max_leaf_count(args.max_leaf_size) + 1)
    result = {
        "benchmark": "bvh_build",
        "triangles": n,
        "subdivisions": args.subdivisions,
        "max_leaf_size": args.max_leaf_size,
        "build_s": statistics.median(runs),
        "runs_s": runs,
        "nodes": int(bvh.nodes.size),
        "nodes_per_triangle": bvh.nodes.size / n,
        "leaves": int((count > 0).sum()),
        "leaf_size_histogram": leaf_sizes.tolist(),
        "bytes_per_triangle": (bvh.nodes.nbytes + bvh.order.nbytes) / n,
        "sah_cost": sah_cost(bvh.nodes),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
