"""A `mesh` object whose file is glTF (.gltf, .glb): the model's meshes placed by its nodes and
the object's transform, with the file's materials mapped onto clray's.

A glTF mesh placed by one node is transformed into one world-space mesh with the others; one
placed by several nodes becomes a group (the mesh in its own frame, on the device once) and an
instance per node, unless it emits light (only a scene's own meshes light it,
clray.scene.emitters) or the object is inside a group (groups do not nest): those are
transformed copies. docs/scene_format.md (glTF files) has the material rule.
"""

from __future__ import annotations

import dataclasses
import io
from collections import Counter
from typing import TYPE_CHECKING

import numpy as np

from clray.errors import SceneError
from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.gltf import GltfMaterial, GltfModel, flat_corners
from clray.scene.model import Group, Instance, Material, Mesh, SceneObject, Texture
from clray.scene.obj import ObjMesh
from clray.scene.parse_mesh import transformed
from clray.scene.parse_transform import parse_transform
from clray.scene.texture import TextureError
from clray.scene.transform import placed_magnitude
from clray.scene.values import Values, file_name

if TYPE_CHECKING:
    from clray.scene.parse_materials import MaterialTable

# Roughness below this is taken as this: a mirror-smooth surface's highlight exponent would
# be infinite.
_MIN_ROUGHNESS = 0.05


def gltf_material(m: GltfMaterial, texture: Texture | None) -> Material:
    """clray's Phong material for a glTF metallic-roughness one (docs/scene_format.md):
    a smooth metal mirrors, what it does not mirror is diffuse, the highlight narrows and
    brightens as roughness falls, a BLEND material's alpha lets light through unbent."""
    mirror = m.metallic * (1.0 - m.roughness)
    # Blinn-Phong's exponent for GGX's width alpha = roughness^2 is 2 / alpha^2 - 2; clray's
    # highlight is Phong's (R.V), whose lobe is about four times as wide for one exponent.
    alpha = max(m.roughness, _MIN_ROUGHNESS) ** 2
    return Material(
        name=m.name,
        color=m.color,
        ambient=1.0,
        diffuse=1.0 - mirror,
        specular=(1.0 - m.roughness) * (0.5 + 0.5 * m.metallic),
        shininess=min(max((2.0 / alpha**2 - 2.0) / 4.0, 1.0), L.MAX_SHININESS),
        reflect=mirror,
        transmit=1.0 - m.alpha,
        ior=1.0,
        texture=texture,
        emission=m.emission,
    )


def gltf_objects(spec: dict, key: str, in_group: bool, v: Values, assets: Assets,
                 materials: MaterialTable) -> tuple[SceneObject, ...]:
    """The objects of a `mesh` object with a glTF file. Its `material` replaces the file's;
    without one the file's are taken (and the default where a primitive has none)."""
    fkey = f"{key}.file"
    if "materials" in spec:
        raise v.error(f"{key}.materials", "a glTF file brings its own materials: give one "
                      "material, or none")
    model, identity = assets.gltf_model(spec["file"], fkey)
    table = _material_table(model, identity, spec, key, assets, materials)
    # Per-face materials where the file's are taken: the automatic scene (clray.model_scene)
    # tells a model that brings materials by them.
    own = "material" not in spec and bool(model.materials)
    tkey = f"{key}.transform"
    a, offset = parse_transform(spec.get("transform", {}), tkey, v)
    top = np.eye(4)
    top[:3, :3], top[:3, 3] = a, offset
    uses = Counter(m for m, _ in model.placements if model.meshes[m] is not None)
    emission = np.array([m.emission for m in materials.materials]).reshape(-1, 3)
    groups: dict[int, Group] = {}
    copies: list[ObjMesh] = []
    instances: list[Instance] = []
    boxes: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # each instanced mesh's, once
    copied = 0  # the triangles of `copies`
    for m, matrix in model.placements:
        obj = model.meshes[m]
        if obj is None:
            continue
        face_materials = table[obj.face_groups]
        world = top @ matrix
        glowing = np.any(emission[face_materials] > 0)
        if uses[m] > 1 and not in_group and not glowing:
            if m not in boxes:
                boxes[m] = (obj.vertices.min(axis=0).astype(np.float64),
                            obj.vertices.max(axis=0).astype(np.float64))
            instanced = _placeable(world, boxes[m])
        else:
            instanced = False
        if instanced:
            if m not in groups:
                assets.take_triangles(len(obj.faces), key)
                groups[m] = Group(f"{key}: {file_name(spec['file'])}: meshes[{m}]",
                                  (_mesh(obj, face_materials, own),))
            instances.append(Instance(groups[m], world[:3].copy()))
            continue
        if abs(np.linalg.det(world[:3, :3])) == 0.0:
            continue  # a node scaled to nothing (exporters hide parts so) draws nothing
        # Counted before the copy is made: a large mesh placed by many glowing nodes was
        # copied for each before the joined copies' triangles were counted.
        assets.fits_triangles(copied + len(obj.faces), key)
        copied += len(obj.faces)
        placed = transformed(obj, world[:3, :3], world[:3, 3], tkey, v)
        copies.append(dataclasses.replace(placed, face_groups=face_materials))
    if not copies and not instances:
        raise v.error(fkey, f"{file_name(spec['file'])}: no triangles to render (no node "
                      "places a mesh of triangles)")
    objects: list[SceneObject] = []
    if copies:
        joined = _joined(copies)
        assets.take_triangles(len(joined.faces), key)
        objects.append(_mesh(joined, joined.face_groups, own))
    return (*objects, *instances)


def _material_table(model: GltfModel, identity: tuple[int, int], spec: dict, key: str,
                    assets: Assets, materials: MaterialTable) -> np.ndarray:
    """The scene material of each glTF material, then (last, for index -1) of faces without
    one: the object's material replaces them all."""
    if "material" in spec:
        material = materials.for_object(spec, key)
        return np.full(len(model.materials) + 1, material, dtype=np.int64)
    refs = []
    textures: dict[int, Texture | None] = {}
    for i, m in enumerate(model.materials):
        ref = (identity, f"glTF materials[{i}]")
        if ref not in materials.from_libraries:
            texture = None
            if m.texture is not None:
                if m.texture not in textures:
                    textures[m.texture] = _texture(model, m.texture, spec, key, assets)
                texture = textures[m.texture]
            if texture is not None:
                # glTF multiplies the texels by baseColorFactor; clray's texture replaces
                # the colour, so the product is taken here.
                texture = dataclasses.replace(
                    texture, image=(texture.image * np.float32(m.color)).astype(np.float32))
            materials.from_libraries[ref] = materials.add(gltf_material(m, texture))
        refs.append(materials.from_libraries[ref])
    return np.array([*refs, materials.for_object(spec, key)], dtype=np.int64)


def _texture(model: GltfModel, index: int, spec: dict, key: str, assets: Assets
             ) -> Texture | None:
    """images[index] decoded from sRGB (glTF's base colour is always sRGB); None, with a
    warning, where it cannot be read."""
    where = f"{key}.file: {file_name(spec['file'])}: images[{index}]"
    try:
        # An animation's frames decode it once between them, from the glTF file kept.
        texels, _, told = assets.read_image(lambda: io.BytesIO(model.images[index]()),
                                            assets.base / spec["file"], f"glTF images[{index}]")
    except TextureError as exc:
        assets.warnings.append(f"{where}: {exc} (the material keeps its colour)")
        return None
    except SceneError as err:  # the image's file or buffer view cannot be read
        assets.warnings.append(f"{where}: {err.message} (the material keeps its colour)")
        return None
    assets.warnings.extend(f"{where}: {w}" for w in told)
    return Texture(kind="image", image=assets.decoded(texels), colorspace="srgb")


def _placeable(world: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> bool:
    """An instance's matrix, and the mesh's box it places, within the kernels' limits (as
    ObjectParser.placement checks). Where not, the copy placed on the host names the
    problem."""
    singular = np.linalg.svd(world[:3, :3], compute_uv=False)
    return bool(np.all(np.abs(world[:3, 3]) <= L.MAX_MAGNITUDE)
                and singular.max() <= L.MAX_MAGNITUDE and singular.min() >= L.MIN_LENGTH
                and placed_magnitude(*box, world[:3, :3], world[:3, 3]) <= L.MAX_MAGNITUDE)


def _joined(parts: list[ObjMesh]) -> ObjMesh:
    """One mesh of several, as gltf._merged joins primitives: normals where any part has
    them (its face normals, flat_corners, for a part without: the others keep their smooth
    shading), uvs and colours where any has (zero uvs elsewhere: only a textured material
    reads them; white, which tints nothing, for colours)."""
    if len(parts) == 1:  # one placed mesh: its arrays as they are, no copies
        return dataclasses.replace(parts[0], material_names=(), material_libraries=())
    if any(p.normals is not None for p in parts):
        parts = [p if p.normals is not None else _flat(p) for p in parts]
    starts = np.cumsum([0] + [len(p.vertices) for p in parts])

    def joined(name: str, width: int, fill: float | None) -> np.ndarray | None:
        values = [getattr(p, name) for p in parts]
        missing = [x is None for x in values]
        if all(missing) or (fill is None and any(missing)):
            return None
        return np.concatenate([np.full((len(p.vertices), width), fill) if x is None else x
                               for p, x in zip(parts, values, strict=True)])

    return ObjMesh(np.concatenate([p.vertices for p in parts]),
                   np.concatenate([p.faces + s for p, s in zip(parts, starts, strict=False)]),
                   joined("normals", 3, None), joined("uvs", 2, 0.0), (),
                   joined("face_groups", 1, None), colors=joined("colors", 3, 1.0))


def _flat(part: ObjMesh) -> ObjMesh:
    """`part` given a vertex a face corner, each with its face's normal."""
    corners, faces, normals = flat_corners(part.vertices, part.faces)
    return dataclasses.replace(
        part, vertices=part.vertices[corners], faces=faces, normals=normals,
        uvs=None if part.uvs is None else part.uvs[corners],
        colors=None if part.colors is None else part.colors[corners])


def _mesh(obj: ObjMesh, face_materials: np.ndarray, own: bool) -> Mesh:
    """The Mesh of `obj`; `own`: its faces take the file's materials (else all faces take
    face_materials[0], the object's material or the default)."""
    return Mesh(vertices=np.ascontiguousarray(obj.vertices, dtype=np.float64),
                faces=np.ascontiguousarray(obj.faces, dtype=np.int64),
                material=int(face_materials[0]), normals=obj.normals, uvs=obj.uvs,
                colors=obj.colors,
                face_materials=None if not own else np.ascontiguousarray(face_materials,
                                                                          dtype=np.int64))
