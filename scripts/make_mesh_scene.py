"""Generate the benchmark mesh scene: a bumpy icosphere on a ground plane, one point light.

    python scripts/make_mesh_scene.py --out DIR [--subdivisions 7]

writes DIR/bumpy.obj (positions, vertex normals, faces `a//a b//b c//c`) and DIR/bumpy.toml.
Seven subdivisions give 327,680 triangles. The bumps come from a fixed sum of sinusoids of the
unit-sphere position, not a random generator, so every run and machine writes the same mesh.

Tests, benchmarks and scripts/gpu_check.py use `icosphere` and `bumpy_mesh` from this file by path
(scripts/ is not a package).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

# Bump height as a fraction of the radius.
BUMP_AMPLITUDE = 0.05
# Where the scene puts the sphere: its lowest point stays just above the ground plane y = 0.
SCENE_CENTER = (0.0, 1.0, 0.0)
SCENE_RADIUS = 1.0


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (V, 3) float64 vertices on the sphere and (20 * 4**s, 3) int64 faces,
    wound counter-clockwise seen from outside."""
    if subdivisions < 0:
        raise ValueError(f"subdivisions must be >= 0, got {subdivisions}")
    t = (1.0 + 5.0**0.5) / 2.0
    vertices = np.array([
        [-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
        [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
        [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1],
    ], dtype=np.float64)
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    faces = np.array([
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ], dtype=np.int64)
    for _ in range(subdivisions):
        vertices, faces = _subdivide(vertices, faces)
    return vertices, faces


def _subdivide(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into four at its edge midpoints, projected back onto the sphere."""
    nv = vertices.shape[0]
    a, b, c = faces.T
    # Edges ab, bc, ca of every face; each interior edge appears twice (once per neighbour), so
    # midpoints are shared through np.unique on the (min, max) vertex pair.
    e0 = np.concatenate([a, b, c])
    e1 = np.concatenate([b, c, a])
    key = np.minimum(e0, e1) * nv + np.maximum(e0, e1)
    unique_key, edge_of = np.unique(key, return_inverse=True)
    lo, hi = np.divmod(unique_key, nv)
    mid = vertices[lo] + vertices[hi]
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    ab, bc, ca = (nv + edge_of).reshape(3, -1)
    new_faces = np.concatenate([
        np.stack([a, ab, ca], axis=1),
        np.stack([b, bc, ab], axis=1),
        np.stack([c, ca, bc], axis=1),
        np.stack([ab, bc, ca], axis=1),
    ])
    return np.concatenate([vertices, mid]), new_faces


def bump(p: np.ndarray) -> np.ndarray:
    """Deterministic noise in [-1, 1] of unit-sphere positions (N, 3): a few incommensurate
    sinusoids, so bumps neither repeat visibly nor line up with the icosahedron's symmetry."""
    x, y, z = p.T
    s = (np.sin(5.0 * x + 1.3) * np.sin(4.0 * y + 0.7) * np.sin(6.0 * z + 2.1)
         + 0.5 * np.sin(11.0 * x - 7.0 * y + 3.0 * z)
         + 0.25 * np.sin(-9.0 * x + 17.0 * y + 13.0 * z + 0.5))
    return s / 1.75


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals, the area-weighted mean of the adjacent faces' normals."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    # The cross product's length is twice the face area: the weighting comes for free.
    face_n = np.cross(v1 - v0, v2 - v0)
    n = np.stack([np.bincount(faces.ravel(), weights=np.repeat(face_n[:, d], 3),
                              minlength=vertices.shape[0]) for d in range(3)], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def bumpy_mesh(subdivisions: int, center: tuple[float, float, float] = (0.0, 0.0, 0.0),
               radius: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The benchmark mesh: (vertices, faces, unit area-weighted vertex normals), float64."""
    unit, faces = icosphere(subdivisions)
    r = radius * (1.0 + BUMP_AMPLITUDE * bump(unit))
    vertices = unit * r[:, None] + np.asarray(center, dtype=np.float64)
    return vertices, faces, vertex_normals(vertices, faces)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> None:
    with path.open("w", encoding="ascii") as f:
        f.write(f"# bumpy icosphere: {len(vertices)} vertices, {len(faces)} triangles\n")
        np.savetxt(f, vertices, fmt="v %.9g %.9g %.9g")
        np.savetxt(f, normals, fmt="vn %.7g %.7g %.7g")
        one = faces + 1  # OBJ indices start at 1
        np.savetxt(f, np.repeat(one, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")


SCENE_TOML = """\
# Benchmark mesh scene, written by scripts/make_mesh_scene.py ({triangles} triangles).
[render]
width = 1280
height = 720
spp = 1
max_depth = 0
background = [0.05, 0.05, 0.08]
ambient = [1.0, 1.0, 1.0]

[camera]
position = [0.0, 2.2, 5.0]
look_at = [0.0, 0.8, 0.0]
up = [0, 1, 0]
vfov = 40

[materials.ground]
color = [0.8, 0.8, 0.8]
ambient = 0.1
texture = {{ type = "checker", size = 0.5, color2 = [0.3, 0.3, 0.3] }}

[materials.clay]
color = [0.85, 0.45, 0.25]
ambient = 0.1
diffuse = 0.8
specular = 0.3
shininess = 40

[[lights]]
type = "point"
position = [-4.0, 6.0, 5.0]
color = [1.0, 1.0, 1.0]

[[objects]]
type = "plane"
point = [0, 0, 0]
normal = [0, 1, 0]
material = "ground"

[[objects]]
type = "mesh"
file = "bumpy.obj"
material = "clay"
"""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="directory to write into")
    parser.add_argument("--subdivisions", type=int, default=7)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    vertices, faces, normals = bumpy_mesh(args.subdivisions, SCENE_CENTER, SCENE_RADIUS)
    write_obj(args.out / "bumpy.obj", vertices, faces, normals)
    (args.out / "bumpy.toml").write_text(SCENE_TOML.format(triangles=len(faces)),
                                         encoding="ascii")


if __name__ == "__main__":
    main()
