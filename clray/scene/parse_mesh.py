"""A `mesh` object: an OBJ, PLY or .npz file, or vertices and faces given inline, placed by its
transform (vertices, normals and winding) while loading, with one material or one per face."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from clray.errors import plural
from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.mesh_data import mesh_arrays
from clray.scene.model import Mesh
from clray.scene.obj import ObjMesh
from clray.scene.obj_materials import obj_face_materials
from clray.scene.parse_transform import parse_transform
from clray.scene.values import Values, rows, show
from clray.vectors import unit

if TYPE_CHECKING:
    from clray.scene.parse_materials import MaterialTable


def parse_mesh(spec: dict, key: str, material: int | None, v: Values, assets: Assets,
               materials: MaterialTable) -> Mesh:
    """material: the mesh's material, None where `materials` gives one per face."""
    obj = _mesh_source(spec, key, v, assets)
    face_materials = None
    # A scene `material` (or `materials`) overrides the file's own.
    if obj.face_groups is not None and material is not None and "material" not in spec:
        face_materials = obj_face_materials(obj, spec["file"], f"{key}.file", material, v,
                                            assets, materials)
    if len(obj.faces) == 0:
        raise v.error(key, "mesh has no faces")
    assets.take_triangles(len(obj.faces), key)
    tkey = f"{key}.transform"
    # Without a transform the vertices are used as read: a 327k-triangle mesh spends a
    # fifth of its load time in the matrix product otherwise.
    if "transform" in spec:
        obj = transformed(obj, *parse_transform(spec["transform"], tkey, v), tkey, v)
    else:
        _within_limits(obj.vertices, tkey, v)
    vertices, faces, normals, uvs = obj.vertices, obj.faces, obj.normals, obj.uvs
    if face_materials is None:
        face_materials = _face_materials(spec, key, len(faces), v, materials)
    return Mesh(
        vertices=np.ascontiguousarray(vertices),
        # A PLY file's int32 indices stay int32 (Mesh.faces).
        faces=np.ascontiguousarray(faces, dtype=np.int32 if faces.dtype == np.int32
                                   else np.int64),
        # Per-face materials leave `material` unused; the first face's keeps it valid.
        material=int(face_materials[0]) if material is None else material,
        normals=normals,
        uvs=uvs,
        face_materials=face_materials,
        colors=obj.colors,
    )


def transformed(obj: ObjMesh, a: np.ndarray, offset: np.ndarray, tkey: str, v: Values
                ) -> ObjMesh:
    """`obj` placed by x -> A x + offset: vertices, normals and winding."""
    if np.array_equal(a, np.eye(3)) and not np.any(offset):
        # The identity (a glTF node without a transform) moves nothing: its product would
        # give every coordinate back, at the cost of a pass over millions of vertices. The
        # normals are made unit again, as below.
        _within_limits(obj.vertices, tkey, v)
        normals = None if obj.normals is None else unit(obj.normals)
        return dataclasses.replace(obj, normals=normals)
    vertices = obj.vertices.reshape(-1, 3) @ a.T + offset
    _within_limits(vertices, tkey, v)
    normals, faces = obj.normals, obj.faces
    if normals is not None:
        # Normals follow the inverse transpose of A (n @ A^-1 as rows): they stay
        # perpendicular to the surface under non-uniform scale and shear. Unit normals
        # under a matrix whose singular values are at least MIN_LENGTH stay finite. They
        # arrive unit (the OBJ reader and mesh_arrays normalise them).
        normals = unit(normals @ np.linalg.inv(a))
    if np.linalg.det(a) < 0:
        # A mirroring transform turns the winding inside out; swapping two corners keeps
        # (v1 - v0) x (v2 - v0) pointing outward, which refraction relies on.
        faces = faces[:, [0, 2, 1]]
    return dataclasses.replace(obj, vertices=vertices, normals=normals, faces=faces)


def _within_limits(vertices: np.ndarray, tkey: str, v: Values) -> None:
    # By reductions (a NaN fails both tests), not an array of magnitudes as large as the
    # vertices.
    if not len(vertices) or (vertices.min() >= -L.MAX_MAGNITUDE
                             and vertices.max() <= L.MAX_MAGNITUDE):
        return
    if not np.all(np.abs(vertices) <= L.MAX_MAGNITUDE):
        raise v.error(
            tkey, f"moves vertices beyond {L.MAX_MAGNITUDE:g} in magnitude "
            f"(largest {np.max(np.abs(vertices)):.3g})"
        )


def _face_materials(spec: dict, key: str, n_faces: int, v: Values,
                    materials: MaterialTable) -> np.ndarray | None:
    """A mesh's material per face: `materials` (names or inline tables) picked by
    `material_index`, one per triangle, as for `spheres`."""
    if "material_index" in spec and "materials" not in spec:
        raise v.error(f"{key}.material_index", "only with materials (a list)")
    if "materials" not in spec:
        return None
    names = spec["materials"]
    if not isinstance(names, list) or not names:
        raise v.error(f"{key}.materials", f"expected a list of material names or inline "
                      f"tables, got {show(names)}")
    refs = np.array([materials.ref(x, f"{key}.materials[{j}]") for j, x in enumerate(names)],
                    dtype=np.int64)
    if "material_index" not in spec:
        raise v.error(key, "materials needs material_index (one per triangle)")
    index = v.array(spec["material_index"], f"{key}.material_index", (n_faces,), integer=True)
    outside = (index < 0) | (index >= len(refs))
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise v.error(f"{key}.material_index[{i}]", f"index {index[i]} out of range "
                      f"(0-based, {plural(len(refs), 'material')})")
    return refs[index]


def _mesh_source(spec: dict, key: str, v: Values, assets: Assets) -> ObjMesh:
    """The mesh as read: from its file, or its inline vertices and faces."""
    inline = "vertices" in spec or "faces" in spec
    if "file" in spec and inline:
        raise v.error(key, "give file or vertices + faces, not both")
    for name in ("normals", "uvs", "colors"):
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
    # Before the arrays are converted: parse_mesh counts them again, taking them.
    assets.fits_triangles(rows(spec["faces"]), key)
    return mesh_arrays(v, spec, f"{key}.")
