"""A light kind on every layer, in one record (as clray/shapes/shape.py is for the shapes).

Each light kind's module (clray/lights/point.py, rect.py, ...) ends with its `LightKind`: the
scene's keys and their checks, the fields of its device record, its kernel switch, and how the
float64 reference renderer lights a point by it. The layers above consult the registry
(clray.lights.LIGHTS) instead of naming light classes, so that a new light is a new module, its
code in kernels/clray_types.h and its case in kernels/lights.h. Nothing here imports above the
base layer: a light's parser gets the scene's value checks (`LightChecks`) from its caller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from clray.shapes.shape import Checks
from clray.vectors import Vec3, safe_normalize

# An area light sample's weight is clamped here, as in the kernels (kernels/lights.h).
AREA_WEIGHT_MAX = 1e20


class LightChecks(Checks, Protocol):
    """The scene value checks a light's parser uses beside a shape's:
    clray.scene.values.Values."""

    def color(self, value: Any, key: str) -> Vec3: ...

    def non_negative(self, value: Any, key: str) -> Vec3: ...

    def closed_range(self, value: Any, key: str, low: float, high: float) -> float: ...

    def light_area(self, area: float, key: str, what: str) -> float: ...


# The pixel sample's point (u1, u2) of the unit square for a light, one a ray: where an area
# light is sampled (docs/rendering.md, Area lights).
Square = tuple[np.ndarray, np.ndarray]


class Toward(NamedTuple):
    """What a light brings to the points p (N, 3) of a surface, for the reference renderer:
    where their shadow rays aim (None: a direction, not a place), the unit direction towards
    the light, the attenuation (or an area sample's weight) and whether it lights them at all."""

    target: np.ndarray | None
    l_dir: np.ndarray
    atten: np.ndarray
    usable: np.ndarray


@dataclass(frozen=True)
class LightKind:
    """One kind of light, everything the layers need of it. Its names are one name: the model
    class `RectLight`, the scene file's `rect` and its LIGHT_RECT code."""

    kind: str  # the scene file's `type` (its models' name without Light, lower case)
    model: type  # its frozen dataclass, float64 world units (clray.scene.model re-exports it)
    # (required, optional) keys besides `type`, in the order error messages list them; none
    # for a light that no scene file names (an emissive face).
    keys: tuple[tuple[str, ...], tuple[str, ...]]
    # (spec, key, color, checks) -> the light its checked keys describe; None where the loader
    # makes the lights itself (clray.scene.emitters).
    parse: Callable[[dict, str, Vec3, LightChecks], Any] | None
    code: int  # its LIGHT_* label in kernels/clray_types.h: compared for equality, not ordered
    # (record, light, eye) -> its Light record's fields beside `kind` and `color`'s rgb.
    fields: Callable[[np.void, Any, np.ndarray], None]
    # (light, p (N, 3), err (N,), square) -> what it brings to p, in float64; the square is
    # given to area lights only (None for the others), and a light with parts is also given
    # each ray's pick, a uint32 (clray.reference.sampling.light_pick).
    toward: Callable[..., Toward]
    area: bool = False  # sampled over its area: kernels/lights.h's is_area_light, HAS_AREA_LIGHTS
    switch: str | None = None  # a KernelConfig switch of its own (-DHAS_SPOT_LIGHTS)
    # light -> how many parts a sample picks one of (a mesh light's faces, clray/lights/
    # mesh.py), their records packed after the scene's lights by part_fields(records, light,
    # eye), the light's own pointing to them (kernels/clray_types.h). None: sampled whole.
    parts: Callable[[Any], int] | None = None
    part_fields: Callable[[np.ndarray, Any, np.ndarray], None] | None = None

    @property
    def code_name(self) -> str:
        """Its label in kernels/clray_types.h: LIGHT_RECT."""
        return f"LIGHT_{self.kind.upper()}"

    @property
    def listed(self) -> bool:
        """Whether a scene file may name it."""
        return self.parse is not None


def centre_and_radius(spec: dict, key: str, v: LightChecks) -> tuple[Vec3, float]:
    """A round light's `center` and `radius` (disc, sphere), its area pi radius^2 within the
    kernels' range."""
    radius = v.length(spec["radius"], f"{key}.radius")
    center = v.vec3(spec["center"], f"{key}.center")
    v.light_area(math.pi * radius * radius, f"{key}.radius", "pi radius^2")
    return center, radius


def area_sample(y: np.ndarray, normal: np.ndarray, area: float | np.ndarray, p: np.ndarray,
                err: np.ndarray) -> Toward:
    """The sample points y (N, 3) of a flat one-sided light of this unit normal (3,) and area,
    or of one a point ((N, 3), (N,): a mesh light's faces), seen from p: the weight that times
    its radiance estimates the irradiance on a surface facing the sample (docs/rendering.md,
    Area lights)."""
    to_y = y - p
    dist = np.linalg.norm(to_y, axis=-1)
    safe = np.where(dist > 0.0, dist, 1.0)
    cos_l = -np.sum(to_y * normal, axis=-1) / safe
    usable = (dist > err) & (cos_l > 0.0)  # one-sided: the back emits nothing
    weight = np.minimum(area * cos_l / (safe * safe), AREA_WEIGHT_MAX)
    return aimed(y, p, weight, usable)


def aimed(target: np.ndarray, p: np.ndarray, weight: np.ndarray, usable: np.ndarray) -> Toward:
    """An area light's samples `target` seen from p."""
    return Toward(target, safe_normalize(target - p), weight, usable)
