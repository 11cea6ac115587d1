"""The [[objects]] array and the [groups] that instances place: every primitive type, placed
by its transform (baked into the primitive where the shape allows, an instance where not)."""

from __future__ import annotations

import dataclasses

import numpy as np

from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.gltf import is_gltf_file
from clray.scene.model import Group, Instance, Plane, SceneObject, Triangle
from clray.scene.parse_gltf import gltf_objects
from clray.scene.parse_materials import MaterialTable
from clray.scene.parse_mesh import parse_mesh
from clray.scene.parse_spheres import parse_spheres
from clray.scene.parse_transform import parse_transform
from clray.scene.transform import object_bounds, place, placed_magnitude
from clray.scene.values import Values, show, show_defined
from clray.shapes import SHAPE_KINDS, SHAPE_OF

# Per object type: (required keys, optional keys), besides `type`, `material` and `transform`:
# the shapes' (clray.shapes), then the types that are not shapes of that kind.
OBJECT_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    **{kind: shape.keys for kind, shape in SHAPE_KINDS.items()},
    "plane": (("point", "normal"), ()),
    "triangle": (("vertices",), ()),
    "mesh": ((), ("file", "vertices", "faces", "normals", "uvs", "colors", "materials",
                  "material_index")),
    "spheres": ((), ("file", "centers", "radii", "radius", "materials", "material_index")),
    "instance": (("group",), ()),
}


class ObjectParser:
    """Objects and groups of one scene, their materials from `materials`."""

    def __init__(self, v: Values, assets: Assets, materials: MaterialTable) -> None:
        self.v, self.assets, self.materials = v, assets, materials
        self.groups: dict[str, Group] = {}
        # Each group's box in its own frame, once however many instances place it.
        self.bounds: dict[Group, tuple[np.ndarray, np.ndarray]] = {}

    def group(self, value: object, key: str, name: str) -> Group:
        v = self.v
        spec = v.table(value, key)
        v.keys(spec, key, ("objects",), ("objects",))
        items = v.items(spec["objects"], f"{key}.objects", L.MAX_OBJECTS)
        if not items:
            raise v.error(f"{key}.objects", "a group needs at least one object")
        return Group(name, tuple(obj for i, item in enumerate(items)
                                 for obj in self.objects(item, f"{key}.objects[{i}]", True)))

    def objects(self, spec: dict, key: str, in_group: bool = False
                ) -> tuple[SceneObject, ...]:
        """An entry's object, or a glTF file's objects (clray.scene.parse_gltf)."""
        v = self.v
        kind = v.kind(spec, key, OBJECT_KEYS)
        allowed = ("type", "material", *OBJECT_KEYS[kind][0], *OBJECT_KEYS[kind][1],
                   "transform")
        required = OBJECT_KEYS[kind][0]
        v.keys(spec, key, allowed, required)
        if in_group and kind in ("instance", "plane"):
            raise v.error(f"{key}.type", "a group holds bounded primitives: no planes "
                          "(unbounded) and no instances (groups do not nest)")
        if kind == "mesh" and "file" in spec and is_gltf_file(v.string(spec["file"],
                                                                       f"{key}.file")):
            if "vertices" in spec or "faces" in spec:
                raise v.error(key, "give file or vertices + faces, not both")
            return gltf_objects(spec, key, in_group, v, self.assets, self.materials)
        return (self.object(spec, key, kind, in_group),)

    def object(self, spec: dict, key: str, kind: str, in_group: bool) -> SceneObject:
        """One object of a checked entry of type `kind`."""
        v = self.v
        if kind == "instance":
            return self.instance(spec, key)
        obj = self.unplaced(spec, key, kind)
        if (problem := _extent_problem(obj)) is not None:
            raise v.error(key, f"{problem[0]} is {problem[1]}")
        if kind == "mesh" or "transform" not in spec:
            return obj
        tkey = f"{key}.transform"
        a, offset = parse_transform(spec["transform"], tkey, v)
        placed = place(obj, a, offset)
        if not isinstance(placed, str):
            return self.within_limits(placed, tkey)
        if in_group:
            raise v.error(tkey, f"{placed}, and inside a group that would need a group in a "
                          "group: place the instance by that transform instead")
        # A shape the transform does not keep (an ellipsoid, a box at an angle) is intersected
        # in its own frame, as a one-object group.
        group = Group(key, (obj,))
        return Instance(group, self.placement(a, offset, tkey, group))

    def instance(self, spec: dict, key: str) -> Instance:
        v = self.v
        name = v.string(spec["group"], f"{key}.group")
        if name not in self.groups:
            raise v.error(f"{key}.group", f"unknown group {show(name)} (defined: "
                          f"{show_defined(list(self.groups))})")
        material = (self.materials.ref(spec["material"], f"{key}.material")
                    if "material" in spec else None)
        tkey = f"{key}.transform"
        a, offset = parse_transform(spec.get("transform", {}), tkey, v)
        group = self.groups[name]
        return Instance(group, self.placement(a, offset, tkey, group), material)

    def placement(self, a: np.ndarray, offset: np.ndarray, key: str, group: Group
                  ) -> np.ndarray:
        """The (3, 4) matrix [A | t] of an instance of `group`, within the magnitudes the
        kernels take."""
        if not np.all(np.abs(offset) <= L.MAX_MAGNITUDE):
            raise self.v.error(key, f"moves the object beyond {L.MAX_MAGNITUDE:g} in magnitude")
        singular = np.linalg.svd(a, compute_uv=False)
        if singular.max() > L.MAX_MAGNITUDE or singular.min() < L.MIN_LENGTH:
            raise self.v.error(key, f"stretches or shrinks by more than {L.MAX_MAGNITUDE:g}")
        # A and t within limits each can still carry the group's box past float32's range
        # (a sphere at 1e20 stretched by 1e20): its placed corners are what the BVH bounds.
        if group not in self.bounds:
            boxes = [object_bounds(obj) for obj in group.objects]
            self.bounds[group] = (np.min([b[0] for b in boxes], axis=0),
                                  np.max([b[1] for b in boxes], axis=0))
        largest = placed_magnitude(*self.bounds[group], a, offset)
        if not largest <= L.MAX_MAGNITUDE:
            raise self.v.error(key, f"moves the object beyond {L.MAX_MAGNITUDE:g} in magnitude "
                               f"(largest {largest:.3g})")
        return np.hstack([a, offset[:, None]])

    def within_limits(self, obj: SceneObject, key: str) -> SceneObject:
        """A placed object's numbers still within what the kernels take."""
        values = [np.asarray(x, dtype=np.float64) for f in dataclasses.fields(obj)
                  if f.name != "material" and not isinstance(x := getattr(obj, f.name), bool)
                  and isinstance(x, float | tuple | np.ndarray)]
        if not all(np.all(np.abs(x) <= L.MAX_MAGNITUDE) for x in values):
            raise self.v.error(key, f"moves the object beyond {L.MAX_MAGNITUDE:g} in magnitude")
        shape = SHAPE_OF.get(type(obj))
        lengths = [getattr(obj, n) for n in (shape.lengths if shape else ()) if hasattr(obj, n)]
        if any(np.any(np.asarray(x) < L.MIN_LENGTH) for x in lengths):
            raise self.v.error(key, f"shrinks the object below {L.MIN_LENGTH:g}")
        if (problem := _extent_problem(obj)) is not None:
            raise self.v.error(key, f"makes {problem[0]} {problem[1]}")
        return obj

    def unplaced(self, spec: dict, key: str, kind: str) -> SceneObject:
        """A primitive in the coordinates its keys give, before its transform."""
        v, assets = self.v, self.assets
        if kind in ("spheres", "mesh") and "materials" in spec:
            if "material" in spec:
                raise v.error(key, "give material or materials, not both")
            if kind == "mesh":
                return parse_mesh(spec, key, None, v, assets, self.materials)
            return parse_spheres(spec, key, None, v, assets, self.materials)
        material = self.materials.for_object(spec, key)
        if kind == "spheres":
            return parse_spheres(spec, key, material, v, assets, self.materials)
        if kind in SHAPE_KINDS:
            return SHAPE_KINDS[kind].parse(spec, key, material, v)
        if kind == "plane":
            normal = v.direction(spec["normal"], f"{key}.normal")
            return Plane(v.vec3(spec["point"], f"{key}.point"), normal, material)
        if kind == "triangle":
            return Triangle(v.points(spec["vertices"], f"{key}.vertices", exactly=3), material)
        return parse_mesh(spec, key, material, v, assets, self.materials)


def _extent_problem(obj: SceneObject) -> tuple[str, str] | None:
    """(what, its value and the limit) for a length the shape derives from its numbers
    (Shape.extents) past MAX_MAGNITUDE, or None."""
    shape = SHAPE_OF.get(type(obj))
    for what, value in shape.extents(obj) if shape else ():
        if not abs(value) <= L.MAX_MAGNITUDE:  # a NaN too
            return (f"the {shape.kind}'s {what}",
                    f"{value:.3g}, beyond {L.MAX_MAGNITUDE:g} in magnitude")
    return None
