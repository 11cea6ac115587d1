"""clray's glTF reader against pygltflib and trimesh: load time, import time, peak memory and
the message for a truncated file, on a generated .glb (a grid of ~1M vertices, 2M triangles,
positions, normals and indices in one binary chunk).

Each reader runs in its own process (peak RSS is per process), interleaved over --repeat rounds;
medians are reported. pygltflib and trimesh are not clray dependencies: install them to compare.
pygltflib parses the JSON only; the accessors are then read with numpy as clray does.

    python benchmarks/gltf_readers.py --out gltf_readers.json
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.gltf_files import Builder

# (import, read): the import is timed apart, as clray's own import is outside the reader.
READERS = {
    "clray": ("from clray.scene.gltf import read_gltf",
              "m = read_gltf(P.read_bytes(), P, None)\nn = len(m.meshes[0].faces)"),
    "pygltflib": ("import pygltflib, numpy as np",
                  "g = pygltflib.GLTF2().load(str(P))\nblob = g.binary_blob()\n"
                  "def get(i, dt, w):\n"
                  "    a = g.accessors[i]; v = g.bufferViews[a.bufferView]\n"
                  "    o = (v.byteOffset or 0) + (a.byteOffset or 0)\n"
                  "    return np.frombuffer(blob, dt, a.count * w, o).reshape(-1, w)\n"
                  "p = g.meshes[0].primitives[0]\nx = get(p.attributes.POSITION, '<f4', 3)\n"
                  "f = get(p.indices, '<u4', 1).reshape(-1, 3)\nn = len(f)"),
    "trimesh": ("import trimesh",
                "s = trimesh.load(P, process=False, force='scene')\n"
                "n = sum(len(g.faces) for g in s.geometry.values())"),
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


def grid_glb(path: Path, side: int) -> int:
    """A side x side grid of vertices (with normals), two triangles a cell, as a .glb."""
    y, x = np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side), indexing="ij")
    vertices = np.stack([x, y, np.sin(6 * x) * 0.1], -1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(side - 1), np.arange(side - 1), indexing="ij")
    a = (i * side + j).reshape(-1)
    faces = np.concatenate([np.stack([a, a + 1, a + side], -1),
                            np.stack([a + 1, a + side + 1, a + side], -1)]).astype(np.uint32)
    b = Builder()
    mesh = {"POSITION": b.accessor(vertices, "VEC3"),
            "NORMAL": b.accessor(np.tile(np.float32([0, 0, 1]), (len(vertices), 1)), "VEC3")}
    b.doc["meshes"].append({"primitives": [{"attributes": mesh, "indices": b.accessor(
        faces.reshape(-1), "SCALAR")}]})
    b.node(mesh=0)
    path.write_bytes(b.glb())
    return len(faces)


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
        path = Path(tmp) / "grid.glb"
        n_faces = grid_glb(path, args.side)
        truncated = Path(tmp) / "truncated.glb"
        truncated.write_bytes(path.read_bytes()[:path.stat().st_size * 3 // 4])
        runs: dict[str, list[dict]] = {name: [] for name in READERS}
        for _ in range(args.repeat):
            for name in READERS:  # interleaved, so drifting load hits all alike
                runs[name].append(run(name, path))
        result = {
            "machine": {"cpu": platform.processor() or platform.machine(),
                        "python": platform.python_version()},
            "file": {"triangles": n_faces, "bytes": path.stat().st_size},
            "readers": {name: {
                "median_s": median(r["seconds"] for r in rs),
                "median_import_s": median(r["import_s"] for r in rs),
                "median_peak_rss_mib": median(r["peak_rss_mib"] for r in rs),
                "faces": rs[0].get("faces"),
                "truncated_file": run(name, truncated).get("error", "(no error)"),
            } for name, rs in runs.items()},
        }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
