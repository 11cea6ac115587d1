"""Primitive references, as the BVH's leaves hold them: the primitive's type code in the top
bits, its index into that type's array below. The type codes also order ties in t
(docs/rendering.md), planes (not in the BVH) first. The analytic shapes' codes are in their
modules (clray.shapes: Shape.prim); these are the others'. kernels/clray_types.h has the same
values, which tests/test_layout.py checks on the device."""

from __future__ import annotations

from collections.abc import Iterable

from clray.shapes import SHAPES
from clray.shapes.shape import Shape

PRIM_PLANE = 0
PRIM_TRIANGLE = 5
PRIM_INSTANCE = 6
PRIM_TYPE_SHIFT = 28
PRIM_INDEX_MASK = 0x0FFFFFFF
# Type codes a reference can hold: code << PRIM_TYPE_SHIFT stays below int32's sign bit. A
# code of 8 would make negative references, whose ref >> PRIM_TYPE_SHIFT (on the host and in
# the kernels) is negative: no primitive's code.
PRIM_CODES = 1 << (31 - PRIM_TYPE_SHIFT)


def check_codes(shapes: Iterable[Shape]) -> None:
    """Raise ValueError unless every primitive type code, the shapes' (Shape.prim) and the
    others' above, fits a reference: from 0 to PRIM_CODES - 1. Checked on import for the
    registry (clray.shapes.SHAPES), so that a new shape with too large a code fails at once."""
    codes = {"PRIM_PLANE": PRIM_PLANE, "PRIM_TRIANGLE": PRIM_TRIANGLE,
             "PRIM_INSTANCE": PRIM_INSTANCE, **{s.prim_name: s.prim for s in shapes}}
    for name, code in codes.items():
        if not 0 <= code < PRIM_CODES:
            raise ValueError(
                f"{name} is {code}: a primitive type code must be from 0 to {PRIM_CODES - 1} "
                f"(below 1 << (31 - PRIM_TYPE_SHIFT)), or its references, code << "
                f"PRIM_TYPE_SHIFT | index in an int32, are negative")


check_codes(SHAPES)
