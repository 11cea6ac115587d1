"""Passes (AOVs; docs/passes.md): what a render's primary rays meet, as named arrays beside the
image. The kernel (kernels/passes.h, render.cl's render_passes) writes four raw outputs;
this module names the passes, turns those outputs into them (the primitive references into
the scene's object indices) and draws the false-colour previews."""

from __future__ import annotations

import numpy as np

from clray.device import layout as L
from clray.scene import model as M

# The passes a render can ask for, in the order files list them.
PASS_NAMES = ("depth", "normal", "albedo", "position", "object", "material", "instance")
# The passes of one number a pixel: depth float32, the indices int32 (-1 on a miss).
SCALAR_PASSES = ("depth", "object", "material", "instance")
INDEX_PASSES = ("object", "material", "instance")


def pass_problem(names: object) -> str | None:
    """What is wrong with a tuple of pass names, or None."""
    if not isinstance(names, tuple) or not all(isinstance(n, str) for n in names):
        return "expected a tuple of pass names"
    unknown = [n for n in names if n not in PASS_NAMES]
    if unknown:
        return (f"unknown pass {unknown[0]!r}; expected some of {', '.join(PASS_NAMES)}")
    if len(set(names)) != len(names):
        return "a pass is named twice"
    return None


# Each primitive kind's packed array, with the scene objects that pack into it
# (clray.device.pack._by_kind: Sphere with Spheres, Triangle with Mesh) and the primitives
# each object makes there.
_KINDS = ((L.PRIM_PLANE, (M.Plane,)), (L.PRIM_SPHERE, (M.Sphere, M.Spheres)),
          (L.PRIM_BOX, (M.Box,)), (L.PRIM_CYLINDER, (M.Cylinder,)), (L.PRIM_CONE, (M.Cone,)),
          (L.PRIM_TRIANGLE, (M.Triangle, M.Mesh)))


def _primitives(obj: M.SceneObject) -> int:
    if isinstance(obj, M.Spheres):
        return len(obj.radii)
    if isinstance(obj, M.Mesh):
        return len(obj.faces)
    return 1


def object_of_primitive(scene: M.Scene) -> dict[int, np.ndarray]:
    """Per primitive kind (layout.PRIM_*), the scene object (index in scene.objects) of each
    primitive the packer stores in that kind's array, in its order: the scene's own objects
    first, in scene order, then the groups' (-1: the object is the instance the hit was in)."""
    instances = [obj for obj in scene.objects if isinstance(obj, M.Instance)]
    groups = list({id(inst.group): inst.group for inst in instances}.values())
    table = {}
    for kind, types in _KINDS:
        owners = [(i, obj) for i, obj in enumerate(scene.objects) if isinstance(obj, types)]
        if kind != L.PRIM_PLANE:
            owners += [(-1, obj) for group in groups for obj in group.objects
                       if isinstance(obj, types)]
        table[kind] = np.repeat(np.array([i for i, _ in owners], dtype=np.int32),
                                [_primitives(obj) for _, obj in owners]).astype(np.int32)
    return table


def instance_objects(scene: M.Scene) -> np.ndarray:
    """The index in scene.objects of each instance, in the order the packer numbers them."""
    return np.array([i for i, obj in enumerate(scene.objects) if isinstance(obj, M.Instance)],
                    dtype=np.int32)


def object_indices(scene: M.Scene, refs: np.ndarray, instances: np.ndarray) -> np.ndarray:
    """The scene object of each primitive reference (-1: none) met in instance `instances`
    (-1: in none): its own object's index, or the instance's."""
    objects = np.full(refs.shape, -1, dtype=np.int32)
    kinds = refs >> L.PRIM_TYPE_SHIFT
    index = refs & L.PRIM_INDEX_MASK
    for kind, table in object_of_primitive(scene).items():
        mine = (refs >= 0) & (kinds == kind)
        objects[mine] = table[index[mine]]
    inside = instances >= 0
    objects[inside] = instance_objects(scene)[instances[inside]]
    return objects


def passes_of(raw: dict[str, np.ndarray], scene: M.Scene,
              names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The passes `names` from render_passes' outputs (clray.device.launch.PASS_OUTPUTS, by
    name, (H, W, 4) each)."""
    geometry, indices = raw["geometry"], raw["indices"]
    made = {
        "depth": lambda: geometry[..., 3],
        "normal": lambda: geometry[..., :3],
        "albedo": lambda: raw["albedo"][..., :3],
        "position": lambda: raw["position"][..., :3],
        "object": lambda: object_indices(scene, indices[..., 0], indices[..., 1]),
        "instance": lambda: indices[..., 1],
        "material": lambda: indices[..., 2],
    }
    return {name: np.ascontiguousarray(made[name]()) for name in names}


def preview(name: str, values: np.ndarray) -> np.ndarray:
    """A false-colour (H, W, 3) float32 picture of pass `name` in [0, 1] for a PNG: depth from
    near (white) to far (black) over its finite range, normals and positions mapped from their
    range to [0, 1] per axis, albedo as it is, indices as distinct hues; black on a miss."""
    if name == "albedo":
        return np.clip(values, 0.0, 1.0).astype(np.float32)
    if name in INDEX_PASSES:
        # A golden-ratio walk round the hue circle: neighbouring indices far apart.
        hue = (values.astype(np.float64) * 0.618033988749895) % 1.0
        rgb = np.clip(np.abs((hue[..., None] * 6.0 + np.array([0.0, 4.0, 2.0])) % 6.0 - 3.0)
                      - 1.0, 0.0, 1.0)
        rgb[values < 0] = 0.0
        return rgb.astype(np.float32)
    if name == "depth":
        finite = np.isfinite(values)
        near, far = ((values[finite].min(), values[finite].max()) if finite.any()
                     else (0.0, 1.0))
        span = far - near if far > near else 1.0
        grey = np.where(finite, 1.0 - 0.9 * (values - near) / span, 0.0)
        return np.repeat(grey[..., None], 3, axis=2).astype(np.float32)
    if name == "normal":
        rgb = np.clip(0.5 * values + 0.5, 0.0, 1.0)
        rgb[~values.any(axis=2)] = 0.0
        return rgb.astype(np.float32)
    lo, hi = values.min(axis=(0, 1)), values.max(axis=(0, 1))
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.clip((values - lo) / span, 0.0, 1.0).astype(np.float32)
