"""Emissive faces as area lights: each triangle of a scene's mesh whose material emits (MTL
`Ke`, a material's `emission`) becomes a triangle light of that radiance, sampled by area with
one shadow ray per pixel sample like the rect and disc lights (docs/rendering.md, Lights).

Both the kernels' packing and the reference renderer take a scene's lights from here, so they
light the scene alike. Only the scene's own meshes emit light: a group's meshes, placed by
instances, are seen glowing (camera and secondary rays see `emission`) but light nothing.
"""

from __future__ import annotations

import numpy as np

from clray.lights.rect import resolved_in_float32
from clray.scene import limits as L
from clray.scene.model import Light, Mesh, Scene, TriangleLight


def emissive_triangles(scene: Scene) -> tuple[TriangleLight, ...]:
    """The scene meshes' triangles whose material emits, in object and face order; faces of
    no area (which emit nothing), or none the kernels' float32 edges resolve
    (clray.lights.rect.resolved_in_float32), are left out."""
    emission = np.array([m.emission for m in scene.materials], dtype=np.float64).reshape(-1, 3)
    if not np.any(emission > 0):
        return ()
    lights = []
    for obj in scene.objects:
        if not isinstance(obj, Mesh):
            continue
        material = (np.full(len(obj.faces), obj.material) if obj.face_materials is None
                    else np.asarray(obj.face_materials))
        glowing = np.flatnonzero(np.any(emission[material] > 0, axis=1))
        if len(glowing) == 0:
            continue
        corners = obj.vertices[obj.faces[glowing]].astype(np.float64)  # float32 from a PLY
        area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                       corners[:, 2] - corners[:, 0]), axis=1) / 2.0
        for k in np.flatnonzero(area >= L.MIN_LENGTH).tolist():
            if not resolved_in_float32(corners[k, 1] - corners[k, 0],
                                       corners[k, 2] - corners[k, 0]):
                continue  # the kernels' float32 normal of the face would be zero or wrong
            a, b, c = (tuple(map(float, v)) for v in corners[k])
            r, g, bl = map(float, emission[material[glowing[k]]])
            lights.append(TriangleLight((a, b, c), (r, g, bl)))
    return tuple(lights)


def scene_lights(scene: Scene) -> tuple[Light, ...]:
    """The scene's lights, then its emissive triangles: the lights the renderers loop over."""
    return scene.lights + emissive_triangles(scene)
