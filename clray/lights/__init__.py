"""The light kinds, one module each, and the registry the other layers consult.

LIGHTS names them all; a scene file's [[lights]] may name those with a parser (LISTED), in
this order in error messages. Each kind's LIGHT_* code is a label (kernels/clray_types.h): the
kernels compare codes for equality only, so the order carries nothing.
"""

from __future__ import annotations

from clray.lights.directional import DIRECTIONAL
from clray.lights.disc import DISC
from clray.lights.light import LightKind
from clray.lights.mesh import MESH
from clray.lights.point import POINT
from clray.lights.rect import RECT
from clray.lights.sphere import SPHERE
from clray.lights.spot import SPOT
from clray.lights.triangle import TRIANGLE

LIGHTS: tuple[LightKind, ...] = (POINT, DIRECTIONAL, SPOT, RECT, DISC, SPHERE, TRIANGLE, MESH)

# Each model class -> its kind.
LIGHT_OF: dict[type, LightKind] = {light.model: light for light in LIGHTS}
# The scene file's `type` -> its kind, for the kinds a scene file may name.
LISTED: dict[str, LightKind] = {light.kind: light for light in LIGHTS if light.listed}
