"""A mesh's vertex, face, normal and uv arrays checked: lists from a scene file (each row checked
as any other numbers) or numpy arrays (from Python or a .npz file, checked at once)."""

from __future__ import annotations

from typing import Any

import numpy as np

from clray.errors import plural
from clray.scene import limits as L
from clray.scene.obj import ObjMesh
from clray.scene.values import Values, show
from clray.vectors import unit


def mesh_arrays(v: Values, source: dict, prefix: str) -> ObjMesh:
    """Vertices, faces and the optional per-vertex normals (made unit) and uvs of `source`,
    numpy arrays or lists; errors name the array as `prefix` + its name."""
    vertices = vertex_values(v, source["vertices"], f"{prefix}vertices", None, 3)
    faces = face_indices(v, source["faces"], f"{prefix}faces", len(vertices))
    normals, uvs, colors = (None if n not in source else vertex_values(
        v, source[n], f"{prefix}{n}", len(vertices), size) for n, size in (("normals", 3),
                                                                           ("uvs", 2),
                                                                           ("colors", 3)))
    if colors is not None and not np.all((colors >= 0) & (colors <= 1)):
        raise v.error(f"{prefix}colors", "must be linear values in [0, 1]")
    if normals is not None:
        zero = ~np.any(normals != 0, axis=1)
        if zero.any():
            raise v.error(f"{prefix}normals[{int(np.flatnonzero(zero)[0])}]",
                          "must be a nonzero vector")
        normals = unit(normals)
    return ObjMesh(vertices, faces, normals, uvs, colors=colors)


def vertex_values(v: Values, value: Any, key: str, n_vertices: int | None, size: int
                  ) -> np.ndarray:
    """Per-vertex positions, normals or (u, v): a row of `size` numbers for each vertex,
    from a list of lists (scene files: each row checked as any other numbers) or an array
    (Python: checked at once). n_vertices None: the vertices themselves."""
    if isinstance(value, np.ndarray):
        value = v.shaped_array(value, key, (None, size))
    elif not isinstance(value, list):
        raise v.error(key, f"expected a list of {size}-number rows, got {show(value)}")
    # The count first: an array from Python may be of any size, and is read and copied below.
    count = len(value)
    if n_vertices is None and count > L.MAX_MESH_VERTICES:
        raise v.error(key, f"{plural(count, 'vertex', 'vertices')} is over the limit of "
                      f"{L.MAX_MESH_VERTICES} for a mesh")
    if n_vertices is not None and count != n_vertices:
        raise v.error(key, f"expected one row per vertex ({n_vertices}), got {count}")
    if isinstance(value, np.ndarray):
        return v.array(value, key, (None, size)).astype(np.float64)
    return np.array([v.numbers(row, f"{key}[{i}]", size) for i, row in enumerate(value)],
                    dtype=np.float64).reshape(-1, size)


def face_indices(v: Values, value: Any, key: str, n_vertices: int) -> np.ndarray:
    """(F, 3) 0-based vertex indices, each naming one of `n_vertices` vertices."""
    if isinstance(value, np.ndarray):
        faces = v.array(value, key, (None, 3), integer=True)
    else:
        if not isinstance(value, list):
            raise v.error(key, f"expected a list of faces, got {show(value)}")
        for i, face in enumerate(value):
            if (
                not isinstance(face, list)
                or len(face) != 3
                or not all(isinstance(j, int) and not isinstance(j, bool) for j in face)
            ):
                raise v.error(f"{key}[{i}]", f"expected 3 vertex indices, got {show(face)}")
        faces = np.array(value, dtype=object).reshape(-1, 3)
    outside = np.any((faces < 0) | (faces >= n_vertices), axis=1)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        j = next(j for j in faces[i].tolist() if not 0 <= j < n_vertices)
        raise v.error(
            f"{key}[{i}]", f"index {show(j)} out of range (0-based, "
            f"{plural(n_vertices, 'vertex', 'vertices')})"
        )
    return faces.astype(np.int64)
