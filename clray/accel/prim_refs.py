"""Primitive references, as the BVH's leaves hold them: the primitive's type code in the top
bits, its index into that type's array below. The type codes also order ties in t
(docs/rendering.md), planes (not in the BVH) first. The analytic shapes' codes are in their
modules (clray.shapes: Shape.prim); these are the others'. kernels/clray_types.h has the same
values, which tests/test_layout.py checks on the device."""

PRIM_PLANE = 0
PRIM_TRIANGLE = 5
PRIM_INSTANCE = 6
PRIM_TYPE_SHIFT = 28
PRIM_INDEX_MASK = 0x0FFFFFFF
