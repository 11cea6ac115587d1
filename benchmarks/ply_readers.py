"""clray's PLY reader against plyfile and trimesh: load time, peak memory and the message for a
truncated file, on a generated binary little-endian mesh (a UV sphere, ~1M vertices, normals).

Each reader runs in its own process (peak RSS is per process), interleaved over --repeat rounds;
medians are reported. plyfile and trimesh are not clray dependencies: install them to compare.

    python benchmarks/ply_readers.py --out ply_readers.json
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median

import numpy as np

# (import, read): the import is timed apart, as clray's own import is outside the reader.
READERS = {
    "clray": ("from clray.scene.ply import read_ply",
              "m = read_ply(open(P, 'rb').read(), P).mesh\nn = len(m.faces)"),
    "plyfile": ("import plyfile, numpy as np",
                "d = plyfile.PlyData.read(P)\nf = np.vstack(d['face']['vertex_indices'])\n"
                "v = d['vertex']\nx = np.stack([v['x'], v['y'], v['z']], 1)\nn = len(f)"),
    "trimesh": ("import trimesh", "m = trimesh.load(P, process=False)\nn = len(m.faces)"),
}
_RUN = """
import json, resource, sys, time
from pathlib import Path
P = Path(sys.argv[1])
t = time.perf_counter()
{head}
out = {{"import_s": time.perf_counter() - t}}
t = time.perf_counter()
try:
{body}
    out.update(seconds=time.perf_counter() - t, faces=n)
except Exception as exc:
    out["error"] = (type(exc).__name__ + ": " + str(exc))[:300]
out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def sphere_ply(path: Path, n_side: int) -> int:
    """A UV sphere of n_side x n_side vertices with normals, binary little endian."""
    theta, phi = np.meshgrid(np.linspace(0.01, np.pi - 0.01, n_side),
                             np.linspace(0, 2 * np.pi, n_side, endpoint=False), indexing="ij")
    normals = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta),
                        np.sin(theta) * np.sin(phi)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_side - 1), np.arange(n_side), indexing="ij")
    a, b = i * n_side + j, i * n_side + (j + 1) % n_side
    c, d = a + n_side, b + n_side
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([b, c, d], -1).reshape(-1, 3)])
    vertex = np.zeros(len(normals), dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for k, name in enumerate("xyz"):
        vertex[name] = normals[:, k]
        vertex["n" + name] = normals[:, k]
    face = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, faces
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertex)}\n"
              + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
              + f"element face {len(face)}\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    path.write_bytes(header.encode() + vertex.tobytes() + face.tobytes())
    return len(vertex)


def run(reader: str, path: Path) -> dict:
    head, read = READERS[reader]
    body = "\n".join("    " + line for line in read.splitlines())
    done = subprocess.run([sys.executable, "-c", _RUN.format(head=head, body=body), str(path)],
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=int, default=1000, help="vertices per side (V = side^2)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sphere.ply"
        n_vertices = sphere_ply(path, args.side)
        truncated = Path(tmp) / "truncated.ply"
        truncated.write_bytes(path.read_bytes()[:path.stat().st_size * 3 // 4])
        runs: dict[str, list[dict]] = {name: [] for name in READERS}
        for _ in range(args.repeat):
            for name in READERS:  # interleaved, so drifting load hits all alike
                runs[name].append(run(name, path))
        result = {
            "machine": {"cpu": platform.processor() or platform.machine(),
                        "python": platform.python_version()},
            "file": {"vertices": n_vertices, "bytes": path.stat().st_size},
            "readers": {name: {
                "median_s": median(r["seconds"] for r in rs),
                "median_import_s": median(r["import_s"] for r in rs),
                "median_peak_rss_mib": median(r["peak_rss_mib"] for r in rs),
                "faces": rs[0]["faces"],
                "truncated_file": run(name, truncated).get("error", "(no error)"),
            } for name, rs in runs.items()},
        }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
