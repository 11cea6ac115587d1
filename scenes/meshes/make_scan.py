"""Writes scan.ply beside this file: a lumpy, scan-like closed mesh (a sphere displaced by a
few smooth random bumps), binary little-endian PLY with per-vertex normals, as 3D scanners
export. Deterministic: the same seed gives the same file.

    python scenes/meshes/make_scan.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROWS, COLUMNS = 64, 128  # latitude rings between the poles, vertices per ring
SEED = 7


def displaced_sphere(rows: int, columns: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), faces (F, 3)): a latitude-longitude sphere with one vertex per pole,
    each point pushed out along its direction by a sum of smooth bumps."""
    theta = np.linspace(0, np.pi, rows + 2)[1:-1]
    phi = np.linspace(0, 2 * np.pi, columns, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    dirs = np.concatenate([[[0, 1, 0]], ring, [[0, -1, 0]]])
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(20, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    heights = rng.uniform(-0.2, 0.4, 20)
    widths = rng.uniform(0.15, 0.45, 20)
    bumps = np.exp(-np.sum((dirs[:, None] - centres[None]) ** 2, -1) / widths**2) @ heights
    vertices = dirs * (1.0 + bumps)[:, None] * [1.0, 0.8, 0.9]
    ring_at = lambda r, c: 1 + r * columns + c % columns  # noqa: E731
    c = np.arange(columns)
    faces = [np.stack([np.zeros(columns, int), ring_at(0, c + 1), ring_at(0, c)], 1)]
    for r in range(rows - 1):
        a, b = ring_at(r, c), ring_at(r, c + 1)
        a2, b2 = ring_at(r + 1, c), ring_at(r + 1, c + 1)
        faces += [np.stack([a, b, b2], 1), np.stack([a, b2, a2], 1)]
    last = len(dirs) - 1
    faces.append(np.stack([ring_at(rows - 1, c), ring_at(rows - 1, c + 1),
                           np.full(columns, last)], 1))
    return vertices, np.concatenate(faces)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted face normals summed at each vertex."""
    corners = vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], cross)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> None:
    vertex = np.zeros(len(vertices), dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny",
                                                                   "nz")])
    for k, axis in enumerate("xyz"):
        vertex[axis], vertex["n" + axis] = vertices[:, k], normals[:, k]
    face = np.zeros(len(faces), dtype=[("count", "u1"), ("index", "<i4", (3,))])
    face["count"], face["index"] = 3, faces
    header = (f"ply\nformat binary_little_endian 1.0\ncomment clray scenes/meshes/make_scan.py, "
              f"seed {SEED}\nelement vertex {len(vertex)}\n"
              + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
              + f"element face {len(face)}\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    path.write_bytes(header.encode() + vertex.tobytes() + face.tobytes())


def main() -> None:
    vertices, faces = displaced_sphere(ROWS, COLUMNS, SEED)
    write_ply(Path(__file__).with_name("scan.ply"), vertices, faces,
              vertex_normals(vertices, faces))


if __name__ == "__main__":
    main()
