"""Spot lights: a point light that lights only a cone (kernels/lights.h, spot_factor)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clray.lights import point
from clray.lights.light import LightChecks, LightKind, Square, Toward
from clray.shapes.shape import f4
from clray.vectors import Vec3, dot, vec

MAX_SPOT_ANGLE = 180.0  # a spot light's half-angle, degrees: below it, exclusive


@dataclass(frozen=True)
class SpotLight:
    """A point light lighting only a cone: full inside `inner_angle`, nothing outside
    `angle` (half-angles in degrees), smoothstep in the versine (1 - cos) between."""

    position: Vec3
    direction: Vec3  # unit; the cone's axis, the way the light travels
    angle: float
    color: Vec3 = (1.0, 1.0, 1.0)
    attenuation: Vec3 = (1.0, 0.0, 0.0)  # constant, linear, quadratic
    inner_angle: float | None = None  # None: equal to `angle`, a hard edge


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> SpotLight:
    atten = point.attenuation(spec, key, v)
    position = v.vec3(spec["position"], f"{key}.position")
    angle = v.open_range(spec["angle"], f"{key}.angle", 0, MAX_SPOT_ANGLE)
    inner = v.closed_range(spec.get("inner_angle", angle), f"{key}.inner_angle", 0, angle)
    return SpotLight(position, v.direction(spec["direction"], f"{key}.direction"), angle,
                     color, atten, inner)


def versine(angle: float) -> float:
    """1 - cos(angle), angle in degrees, as 2 sin^2(angle / 2): no cancellation for a small
    angle, whose cos rounds to 1 in float32 below about 0.02 degrees."""
    return 2.0 * math.sin(math.radians(angle) / 2.0) ** 2


def fields(rec: np.void, light: SpotLight, eye: np.ndarray) -> None:
    point.fields(rec, light, eye)
    inner = light.angle if light.inner_angle is None else light.inner_angle
    rec["axis_u"] = f4(light.direction, versine(light.angle))
    rec["axis_v"] = f4((0.0, 0.0, 0.0), versine(inner))


def spot_factor(light: SpotLight, l_dir: np.ndarray) -> np.ndarray:
    """1 inside the inner cone, 0 outside the outer, smoothstep in the versine between, as
    kernels/lights.h has it: the ray's versine vers_t = |l + direction|^2 / 2 (unit vectors,
    l towards the light), which does not cancel near the axis as 1 + l.direction would."""
    inner = light.angle if light.inner_angle is None else light.inner_angle
    vers_o, vers_i = versine(light.angle), versine(inner)
    s = l_dir + vec(light.direction)
    vers_t = dot(s, s) / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((vers_o - vers_t) / (vers_o - vers_i), 0.0, 1.0)
    return np.where(vers_t >= vers_o, 0.0,
                    np.where(vers_t <= vers_i, 1.0, t * t * (3.0 - 2.0 * t)))


def toward(light: SpotLight, p: np.ndarray, err: np.ndarray, square: Square | None) -> Toward:
    lit = point.toward(light, p, err, square)
    atten = lit.atten * spot_factor(light, lit.l_dir)
    return lit._replace(atten=atten, usable=lit.usable & (atten > 0.0))


SPOT = LightKind(kind="spot", model=SpotLight,
                 keys=(("position", "direction", "angle"), ("inner_angle", "color", "attenuation")),
                 parse=parse, code=2, fields=fields, toward=toward, switch="has_spot_lights")
