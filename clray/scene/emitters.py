"""Emissive faces as area lights: each triangle of a scene's mesh whose material emits (MTL
`Ke`, a material's `emission`) lights the scene with that radiance, sampled by area with one
shadow ray per pixel sample like the rect and disc lights (docs/rendering.md, Lights). A mesh's
faces of one material are triangle lights of their own up to EACH_FACE_UP_TO of them; beyond,
they are one mesh light (clray/lights/mesh.py), for whose one shadow ray each pixel sample picks
a face by area: a lamp of thousands of faces costs a shadow ray, not thousands.

Both the kernels' packing and the reference renderer take a scene's lights from here, so they
light the scene alike. Only the scene's own meshes emit light: a group's meshes, placed by
instances, are seen glowing (camera and secondary rays see `emission`) but light nothing.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from clray.lights.rect import resolved_in_float32
from clray.scene import limits as L
from clray.scene.model import Light, Mesh, MeshLight, Scene, TriangleLight

# A mesh's emissive faces of one material are lights of their own up to this many, a shadow
# ray each; more are one mesh light of one shadow ray. Up to it a lamp's few faces (the Cornell
# box's two, a box's twelve) each keep a sample, as a rect or disc light has one.
EACH_FACE_UP_TO = 16


def _glowing_faces(scene: Scene) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """For each scene mesh with emissive faces: the faces' materials (K,), corners (K, 3, 3)
    float64 and radiances (K, 3), in face order; faces of no area (which emit nothing), or none
    the kernels' float32 edges resolve (clray.lights.rect.resolved_in_float32), left out."""
    emission = np.array([m.emission for m in scene.materials], dtype=np.float64).reshape(-1, 3)
    if not np.any(emission > 0):
        return
    for obj in scene.objects:
        if not isinstance(obj, Mesh):
            continue
        material = (np.full(len(obj.faces), obj.material) if obj.face_materials is None
                    else np.asarray(obj.face_materials))
        glowing = np.flatnonzero(np.any(emission[material] > 0, axis=1))
        if len(glowing) == 0:
            continue
        corners = obj.vertices[obj.faces[glowing]].astype(np.float64)  # float32 from a PLY
        u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        area = np.linalg.norm(np.cross(u, v), axis=1) / 2.0
        kept = (area >= L.MIN_LENGTH) & resolved_in_float32(u, v)
        if kept.any():
            yield material[glowing[kept]], corners[kept], emission[material[glowing[kept]]]


def _face(corners: np.ndarray, radiance: np.ndarray) -> TriangleLight:
    a, b, c = (tuple(map(float, v)) for v in corners)
    return TriangleLight((a, b, c), tuple(map(float, radiance)))


def has_emissive_faces(scene: Scene) -> bool:
    """Whether a scene mesh has a face that emits light (emissive_triangles is not empty)."""
    return any(True for _ in _glowing_faces(scene))


def emissive_triangles(scene: Scene) -> tuple[TriangleLight, ...]:
    """The scene meshes' emissive faces, each as a triangle light, in object and face order."""
    return tuple(_face(c, e) for _, corners, radiance in _glowing_faces(scene)
                 for c, e in zip(corners, radiance, strict=True))


def emissive_lights(scene: Scene) -> tuple[TriangleLight | MeshLight, ...]:
    """The lights of the scene meshes' emissive faces, in object and face order: a mesh's faces
    of one material as triangle lights, or where there are more than EACH_FACE_UP_TO of them as
    one mesh light, in the place of the first."""
    lights: list[TriangleLight | MeshLight] = []
    for material, corners, radiance in _glowing_faces(scene):
        emitting, first, counts = np.unique(material, return_index=True, return_counts=True)
        many = counts > EACH_FACE_UP_TO
        pooled = np.isin(material, emitting[many])  # faces of a mesh light
        for i in np.sort(np.concatenate([np.flatnonzero(~pooled), first[many]])).tolist():
            if pooled[i]:  # the mesh light's first face: the light in its place
                lights.append(MeshLight(corners[material == material[i]],
                                        tuple(map(float, radiance[i]))))
            else:
                lights.append(_face(corners[i], radiance[i]))
    return tuple(lights)


def scene_lights(scene: Scene) -> tuple[Light, ...]:
    """The scene's lights, then its emissive faces' (emissive_lights): the lights the renderers
    loop over."""
    return scene.lights + emissive_lights(scene)
