"""numpy twins of the structs in kernels/clray_types.h, field for field and name for name.

tests/test_layout.py compares these against sizeof/offsetof measured on the device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The layouts the host algorithms define (clray.accel), mirrored by the kernels like the rest.
from clray.accel.bvh import BINARY_NODE as BINARY_NODE
from clray.accel.bvh import N_BINS as N_BINS
from clray.accel.prim_refs import PRIM_INDEX_MASK as PRIM_INDEX_MASK
from clray.accel.prim_refs import PRIM_INSTANCE as PRIM_INSTANCE
from clray.accel.prim_refs import PRIM_PLANE as PRIM_PLANE
from clray.accel.prim_refs import PRIM_TRIANGLE as PRIM_TRIANGLE
from clray.accel.prim_refs import PRIM_TYPE_SHIFT as PRIM_TYPE_SHIFT
from clray.accel.wide import BVH_WIDTHS as BVH_WIDTHS
from clray.accel.wide import LEAF_FIELD_MASK as LEAF_FIELD_MASK
from clray.accel.wide import LEAF_SPHERE_SHIFT as LEAF_SPHERE_SHIFT
from clray.accel.wide import LEAF_TRIANGLE_SHIFT as LEAF_TRIANGLE_SHIFT
from clray.accel.wide import PACKET_WIDTH as PACKET_WIDTH
from clray.accel.wide import bvh_node_dtype as bvh_node_dtype
from clray.lights import LIGHTS
from clray.shapes import SHAPES

# Each analytic shape's PRIM_* code under its name in clray_types.h (PRIM_SPHERE, PRIM_TORUS),
# set from its module (clray.shapes) so that a new shape needs no line here.
PRIMS: dict[str, int] = {shape.prim_name: shape.prim for shape in SHAPES}
globals().update(PRIMS)

# Each light kind's LIGHT_* label under its name in clray_types.h (LIGHT_RECT), set from its
# module (clray.lights) as the shapes' codes are.
LIGHT_CODES: dict[str, int] = {light.code_name: light.code for light in LIGHTS}
globals().update(LIGHT_CODES)

TEXTURE_NONE = -1
TEXTURE_CHECKER = 0
TEXTURE_IMAGE = 1

_F4 = ("<f4", (4,))
_PAD = [("pad0", "<i4"), ("pad1", "<i4"), ("pad2", "<i4")]


def _struct(fields: list) -> np.dtype:
    return np.dtype([(name, *spec) if isinstance(spec, tuple) else (name, spec)
                     for name, spec in fields])


PLANE = _struct([("point", _F4), ("normal", _F4), ("material", "<i4"), *_PAD])
TRIANGLE = _struct([("v0", "<i4"), ("v1", "<i4"), ("v2", "<i4"), ("material", "<i4")])
MATERIAL = _struct([("color", _F4), ("ambient", "<f4"), ("diffuse", "<f4"),
                    ("specular", "<f4"), ("shininess", "<f4"), ("reflect", "<f4"),
                    ("transmit", "<f4"), ("ior", "<f4"), ("texture", "<i4"), ("fresnel", "<i4"),
                    *_PAD, ("emission", _F4)])
TEXTURE = _struct([("color2", _F4), ("size", "<f4"), ("repeat_u", "<f4"), ("repeat_v", "<f4"),
                   ("blend", "<f4"), ("kind", "<i4"), ("texel_offset", "<i4"),
                   ("width", "<i4"), ("height", "<i4")])
LIGHT = _struct([("position", _F4), ("color", _F4), ("attenuation", _F4), ("axis_u", _F4),
                 ("axis_v", _F4), ("kind", "<i4"), *_PAD])
CAMERA = _struct([("position", _F4), ("forward", _F4), ("right", _F4), ("up", _F4),
                  ("world", _F4), ("lens_u", _F4), ("lens_v", _F4)])
PARAMS = _struct([("background", _F4), ("ambient", _F4), ("width", "<i4"), ("height", "<i4"),
                  ("spp", "<i4"), ("max_depth", "<i4"), ("seed", "<u4"), ("n_planes", "<i4"),
                  ("n_lights", "<i4"), ("n_nodes", "<i4"), ("min_weight", "<f4"),
                  ("background_texels", "<i4"), ("background_width", "<i4"),
                  ("background_height", "<i4"), ("background_top", _F4)])
INSTANCE = _struct([("to_object", ("<f4", (3, 4))), ("root", "<i4"), ("material", "<i4"),
                    ("pad0", "<i4"), ("pad1", "<i4")])
# Traversal-stack entries and node lanes that are not nodes or leaves (kernels/bvh.h): count < 0.
ENTER_INSTANCE = -1
LEAVE_INSTANCE = -2

TRIANGLE_PACKET = _struct([(f"{c}{k}", _F4) for k in range(3) for c in "xyz"])
SPHERE_PACKET = _struct([("x", _F4), ("y", _F4), ("z", _F4), ("radius", _F4)])

# The device BVH build's records (kernels/bvh_build.cl): a primitive's bounds rounded outwards
# and its centroid, its index in the centroid's w; a subtree still to build (the kernels' struct
# ends in padding to its float4 alignment).
BUILD_PRIM = _struct([("lo", _F4), ("hi", _F4), ("c", _F4)])
BUILD_TASK = _struct([("lo", _F4), ("hi", _F4), ("clo", _F4), ("chi", _F4), ("start", "<i4"),
                      ("count", "<i4"), ("pos", "<i4"), ("pad0", "<i4")])

# Struct name in clray_types.h -> dtype; the layout test walks this.
STRUCTS: dict[str, np.dtype] = {
    "Plane": PLANE,
    **{shape.struct: shape.record for shape in SHAPES},
    "Triangle": TRIANGLE,
    "Material": MATERIAL,
    "Texture": TEXTURE,
    "Light": LIGHT,
    "Camera": CAMERA,
    "Params": PARAMS,
    "BvhNode": bvh_node_dtype(8),
    "BinaryNode": BINARY_NODE,
    "BuildPrim": BUILD_PRIM,
    "BuildTask": BUILD_TASK,
    "TrianglePacket": TRIANGLE_PACKET,
    "SpherePacket": SPHERE_PACKET,
    "Instance": INSTANCE,
}

TRIANGLE_MATERIAL_MASK = 0x00FFFFFF
TRIANGLE_SMOOTH = 1 << 24
TRIANGLE_UV = 1 << 25
TRIANGLE_COLOR = 1 << 26


@dataclass(frozen=True)
class SceneBuffer:
    """One of the scene's device buffers: its name (PackedScene's field, the kernels'
    parameter and SceneRefs' field) and its element type in the kernels."""

    name: str
    element: str  # a struct of kernels/clray_types.h or an OpenCL C type


# The scene's buffers in the kernels' parameter order: kernels/scene.h's SCENE_BUFFERS, which
# tests/test_layout.py checks against this on the device. PackedScene's fields, its
# device_bytes and the arguments of every kernel launch come from this one list.
SCENE_BUFFERS: tuple[SceneBuffer, ...] = tuple(SceneBuffer(name, element) for name, element in (
    ("camera", "Camera"),  # one record
    ("params", "Params"),  # one record
    ("planes", "Plane"),
    *((shape.buffer, shape.struct) for shape in SHAPES),  # one array a shape
    # A Triangle record a slot where some triangle has vertex normals, uvs or colours (the
    # kernels' HAS_VERTEX_ATTRIBUTES, kernels/scene.h); else none, and instead each slot's
    # material word alone, 4 bytes, as the kernels then read nothing else of the record.
    ("triangles", "Triangle"),
    ("triangle_materials", "int"),
    ("triangle_packets", "TrianglePacket"),  # one per PACKET_WIDTH slots of prim_refs
    ("sphere_packets", "SpherePacket"),  # likewise (spheres only)
    # No vertex positions: shading reads a triangle's corners from its packet (the same float32
    # numbers), so the device keeps only the per-vertex normals, uvs and colours, or nothing.
    ("normals", "float4"),
    ("uvs", "float2"),
    ("colors", "float4"),  # linear rgb, w unused
    ("nodes", "BvhNode"),  # bvh_node_dtype(bvh_width), root first
    ("prim_refs", "int"),  # leaves laid out as clray.accel.wide describes
    ("materials", "Material"),
    ("textures", "Texture"),
    ("texels", "float4"),  # every image texture's texels, then the environment's
    ("lights", "Light"),
    ("instances", "Instance"),  # their groups' primitives are in the arrays above
))
