"""clray's PLY reader against plyfile and trimesh: load time, peak memory and the message for a
truncated file, on a generated binary little-endian mesh (a UV sphere, ~1M vertices, normals).

Each reader runs in its own process (its peak, VmHWM, is its own), interleaved over --repeat rounds;
medians are reported (benchmarks/readers.py, shared with the glTF script). plyfile and trimesh
are not clray dependencies: install them to compare.

    python benchmarks/ply_readers.py [--out benchmarks/results/ply_readers.json] [--side 1000]
                                     [--repeat 3]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

# benchmarks/ is not a package: with the repository root on the path it imports as a namespace
# package, as tests/ does.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.readers import compare

# (import, read): the import is timed apart, as clray's own import is outside the reader.
READERS = {
    "clray": ("from clray.scene.ply import read_ply",
              "m = read_ply(open(P, 'rb').read(), P).mesh\nn = len(m.faces)"),
    "plyfile": ("import plyfile, numpy as np",
                "d = plyfile.PlyData.read(P)\nf = np.vstack(d['face']['vertex_indices'])\n"
                "v = d['vertex']\nx = np.stack([v['x'], v['y'], v['z']], 1)\nn = len(f)"),
    "trimesh": ("import trimesh", "m = trimesh.load(P, process=False)\nn = len(m.faces)"),
}


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


def main(argv: list[str] | None = None) -> None:
    compare(__doc__, READERS, "sphere.ply", lambda path, side: {"vertices": sphere_ply(path, side)},
            "ply_readers.json", argv)


if __name__ == "__main__":
    main()
