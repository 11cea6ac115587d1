"""A `mesh` object: an OBJ or .npz file, or vertices and faces given inline, placed by its
transform (vertices, normals and winding) while loading."""

from __future__ import annotations

import numpy as np

from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.mesh_data import mesh_arrays
from clray.scene.model import Mesh, unit
from clray.scene.obj import ObjMesh
from clray.scene.parse_transform import parse_transform
from clray.scene.values import Values


def parse_mesh(spec: dict, key: str, material: int, v: Values, assets: Assets) -> Mesh:
    obj = _mesh_source(spec, key, v, assets)
    vertices, faces, normals, uvs = obj.vertices, obj.faces, obj.normals, obj.uvs
    if len(faces) == 0:
        raise v.error(key, "mesh has no faces")
    assets.take_triangles(len(faces), key)
    tkey = f"{key}.transform"
    a, offset = parse_transform(spec.get("transform", {}), tkey, v)
    # Without a transform the vertices are used as read: a 327k-triangle mesh spends a
    # fifth of its load time in the matrix product otherwise.
    identity = "transform" not in spec
    if not identity:
        vertices = vertices.reshape(-1, 3) @ a.T + offset
    if not np.all(np.abs(vertices) <= L.MAX_MAGNITUDE):
        raise v.error(
            tkey, f"moves vertices beyond {L.MAX_MAGNITUDE:g} in magnitude "
            f"(largest {np.max(np.abs(vertices)):.3g})"
        )
    if normals is not None and not identity:
        # Normals follow the inverse transpose of A (n @ A^-1 as rows): they stay
        # perpendicular to the surface under non-uniform scale and shear. Unit normals
        # under a matrix whose singular values are at least MIN_LENGTH stay finite. They
        # arrive unit (the OBJ reader and mesh_arrays normalise them).
        normals = unit(normals @ np.linalg.inv(a))
    if np.linalg.det(a) < 0:
        # A mirroring transform turns the winding inside out; swapping two corners keeps
        # (v1 - v0) x (v2 - v0) pointing outward, which refraction relies on.
        faces = faces[:, [0, 2, 1]]
    return Mesh(
        vertices=np.ascontiguousarray(vertices),
        faces=np.ascontiguousarray(faces, dtype=np.int64),
        material=material,
        normals=normals,
        uvs=uvs,
    )


def _mesh_source(spec: dict, key: str, v: Values, assets: Assets) -> ObjMesh:
    """The mesh as read: from its file, or its inline vertices and faces."""
    inline = "vertices" in spec or "faces" in spec
    if "file" in spec and inline:
        raise v.error(key, "give file or vertices + faces, not both")
    for name in ("normals", "uvs"):
        if name in spec and not inline:
            raise v.error(f"{key}.{name}", "only with vertices + faces (an OBJ file "
                          "gives its own)")
    if "file" in spec:
        return assets.mesh_file(spec["file"], f"{key}.file")
    if not inline:
        raise v.error(key, "a mesh needs file or vertices + faces")
    for name in ("vertices", "faces"):
        if name not in spec:
            raise v.error(f"{key}.{name}", "missing required key")
    return mesh_arrays(v, spec, f"{key}.")
