"""clray's glTF reader against pygltflib and trimesh: load time, import time, peak memory and
the message for a truncated file, on a generated .glb (a grid of ~1M vertices, 2M triangles,
positions, normals and indices in one binary chunk).

Each reader runs in its own process (its peak, VmHWM, is its own), interleaved over --repeat rounds;
medians are reported (benchmarks/readers.py, shared with the PLY script). pygltflib and trimesh
are not clray dependencies: install them to compare.
pygltflib parses the JSON only; the accessors are then read with numpy as clray does.

    python benchmarks/gltf_readers.py [--out benchmarks/results/gltf_readers.json] [--side 1000]
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


def main(argv: list[str] | None = None) -> None:
    compare(__doc__, READERS, "grid.glb", lambda path, side: {"triangles": grid_glb(path, side)},
            "gltf_readers.json", argv)


if __name__ == "__main__":
    main()
