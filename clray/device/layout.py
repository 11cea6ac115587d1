"""numpy twins of the structs in kernels/clray_types.h, field for field and name for name.

tests/test_layout.py compares these against sizeof/offsetof measured on the device.
"""

from __future__ import annotations

import numpy as np

PRIM_PLANE = 0
PRIM_SPHERE = 1
PRIM_BOX = 2
PRIM_CYLINDER = 3
PRIM_CONE = 4
PRIM_TRIANGLE = 5
PRIM_INSTANCE = 6
PRIM_TYPE_SHIFT = 28
PRIM_INDEX_MASK = 0x0FFFFFFF

LIGHT_POINT = 0
LIGHT_DIRECTIONAL = 1
LIGHT_SPOT = 2
LIGHT_RECT = 3
LIGHT_DISC = 4
LIGHT_SPHERE = 5

TEXTURE_NONE = -1
TEXTURE_CHECKER = 0
TEXTURE_IMAGE = 1

_F4 = ("<f4", (4,))
_PAD = [("pad0", "<i4"), ("pad1", "<i4"), ("pad2", "<i4")]


def _struct(fields: list) -> np.dtype:
    return np.dtype([(name, *spec) if isinstance(spec, tuple) else (name, spec)
                     for name, spec in fields])


SPHERE = _struct([("center_radius", _F4), ("material", "<i4"), *_PAD])
PLANE = _struct([("point", _F4), ("normal", _F4), ("material", "<i4"), *_PAD])
BOX = _struct([("lo", _F4), ("hi", _F4), ("material", "<i4"), *_PAD])
CYLINDER = _struct([("base_radius", _F4), ("axis_height", _F4), ("material", "<i4"),
                    ("capped", "<i4"), ("pad0", "<i4"), ("pad1", "<i4")])
CONE = _struct([("apex_tan", _F4), ("axis_height", _F4), ("material", "<i4"),
                ("capped", "<i4"), ("pad0", "<i4"), ("pad1", "<i4")])
TRIANGLE = _struct([("v0", "<i4"), ("v1", "<i4"), ("v2", "<i4"), ("material", "<i4")])
MATERIAL = _struct([("color", _F4), ("ambient", "<f4"), ("diffuse", "<f4"),
                    ("specular", "<f4"), ("shininess", "<f4"), ("reflect", "<f4"),
                    ("transmit", "<f4"), ("ior", "<f4"), ("texture", "<i4"), ("fresnel", "<i4"),
                    *_PAD])
TEXTURE = _struct([("color2", _F4), ("size", "<f4"), ("repeat_u", "<f4"), ("repeat_v", "<f4"),
                   ("blend", "<f4"), ("kind", "<i4"), ("texel_offset", "<i4"),
                   ("width", "<i4"), ("height", "<i4")])
LIGHT = _struct([("position", _F4), ("color", _F4), ("attenuation", _F4), ("axis_u", _F4),
                 ("axis_v", _F4), ("kind", "<i4"), *_PAD])
CAMERA = _struct([("position", _F4), ("forward", _F4), ("right", _F4), ("up", _F4),
                  ("world", _F4), ("lens_u", _F4), ("lens_v", _F4)])
PARAMS = _struct([("background", _F4), ("ambient", _F4), ("width", "<i4"), ("height", "<i4"),
                  ("spp", "<i4"), ("max_depth", "<i4"), ("seed", "<u4"), ("n_planes", "<i4"),
                  ("n_lights", "<i4"), ("bvh_root_count", "<i4"), ("min_weight", "<f4"),
                  ("background_texels", "<i4"), ("background_width", "<i4"),
                  ("background_height", "<i4"), ("background_top", _F4)])
# The binary tree the builder makes (host only; clray/accel/bvh.py). The kernels walk the wide
# tree that clray/accel/wide.py collapses it into.
BVH_NODE = _struct([("lo", ("<f4", (3,))), ("first", "<i4"), ("hi", ("<f4", (3,))),
                    ("count", "<i4")])
BVH_WIDTHS = (4, 8)


def bvh_node_dtype(width: int) -> np.dtype:
    """BvhNode of kernels/clray_types.h for -DBVH_WIDTH=width: children's bounds axis by axis."""
    lane_f = ("<f4", (width,))
    lane_i = ("<i4", (width,))
    return _struct([*[(f"{side}_{axis}", lane_f) for side in ("lo", "hi") for axis in "xyz"],
                    ("child", lane_i), ("count", lane_i)])


INSTANCE = _struct([("to_object", ("<f4", (3, 4))), ("to_world", ("<f4", (3, 4))),
                    ("lo", _F4), ("hi", _F4), ("root_child", "<i4"), ("root_count", "<i4"),
                    ("material", "<i4"), ("pad0", "<i4")])
# Traversal-stack entries that are not nodes or leaves (kernels/bvh.h): count < 0.
ENTER_INSTANCE = -1
LEAVE_INSTANCE = -2

TRIANGLE_PACKET = _struct([(f"{c}{k}", _F4) for k in range(3) for c in "xyz"])
SPHERE_PACKET = _struct([("x", _F4), ("y", _F4), ("z", _F4), ("radius", _F4)])

# Struct name in clray_types.h -> dtype; the layout test walks this.
STRUCTS: dict[str, np.dtype] = {
    "Sphere": SPHERE,
    "Plane": PLANE,
    "Box": BOX,
    "Cylinder": CYLINDER,
    "Cone": CONE,
    "Triangle": TRIANGLE,
    "Material": MATERIAL,
    "Texture": TEXTURE,
    "Light": LIGHT,
    "Camera": CAMERA,
    "Params": PARAMS,
    "BvhNode": bvh_node_dtype(8),
    "TrianglePacket": TRIANGLE_PACKET,
    "SpherePacket": SPHERE_PACKET,
    "Instance": INSTANCE,
}

TRIANGLE_MATERIAL_MASK = 0x00FFFFFF
TRIANGLE_SMOOTH = 1 << 24
TRIANGLE_UV = 1 << 25
