"""The analytic shapes, one module each, and the registry the other layers consult.

SHAPES is the one list that names them, in the order their records and bounds are packed (a
new shape goes at the end: the BVH's input, and so its tree, stay as they were for scenes
without it). Planes (unbounded: a list beside the BVH, not in it), triangles (meshes: shared
vertex arrays, packets, vertex normals, uvs and colours) and instances (groups placed by a
matrix) are not shapes of this kind: each layer handles those three by name.
"""

from __future__ import annotations

from clray.shapes.box import BOX
from clray.shapes.cone import CONE
from clray.shapes.cylinder import CYLINDER
from clray.shapes.shape import Shape
from clray.shapes.sphere import SPHERE
from clray.shapes.torus import TORUS

SHAPES: tuple[Shape, ...] = (SPHERE, BOX, CYLINDER, CONE, TORUS)

# Each model class (a `spheres` array's too) -> the shape whose array it packs into.
SHAPE_OF: dict[type, Shape] = {t: shape for shape in SHAPES for t in shape.types}
# The scene file's `type` -> its shape.
SHAPE_KINDS: dict[str, Shape] = {shape.kind: shape for shape in SHAPES}
