"""The [[lights]] array: point, directional, spot and area (rect, disc, sphere) lights."""

from __future__ import annotations

import math

from clray.scene import limits as L
from clray.scene.model import (
    DirectionalLight,
    DiscLight,
    Light,
    PointLight,
    RectLight,
    SphereLight,
    SpotLight,
    rect_area,
)
from clray.scene.values import Values, Vec3

LIGHT_KEYS = {
    "point": ("type", "position", "color", "attenuation"),
    "directional": ("type", "direction", "color"),
    "spot": ("type", "position", "direction", "angle", "inner_angle", "color", "attenuation"),
    "rect": ("type", "corner", "u", "v", "color"),
    "disc": ("type", "center", "normal", "radius", "color"),
    "sphere": ("type", "center", "radius", "color"),
}
# Keys every light of the type must have, after `type`.
_LIGHT_REQUIRED = {"point": 1, "directional": 1, "spot": 3, "rect": 3, "disc": 3, "sphere": 2}


def parse_light(spec: dict, key: str, v: Values) -> Light:
    kind = v.kind(spec, key, LIGHT_KEYS)
    v.keys(spec, key, LIGHT_KEYS[kind], LIGHT_KEYS[kind][1 : 1 + _LIGHT_REQUIRED[kind]])
    color = v.color(spec.get("color", (1.0, 1.0, 1.0)), f"{key}.color")
    if kind == "directional":
        return DirectionalLight(v.direction(spec["direction"], f"{key}.direction"), color)
    if kind in ("rect", "disc", "sphere"):
        return parse_area_light(kind, spec, key, color, v)
    akey = f"{key}.attenuation"
    attenuation = v.non_negative(spec.get("attenuation", (1.0, 0.0, 0.0)), akey)
    if not any(attenuation):
        raise v.error(akey, "must not be all zero")
    position = v.vec3(spec["position"], f"{key}.position")
    if kind == "point":
        return PointLight(position, color, attenuation)
    angle = v.open_range(spec["angle"], f"{key}.angle", 0, L.MAX_SPOT_ANGLE)
    inner = v.closed_range(spec.get("inner_angle", angle), f"{key}.inner_angle", 0, angle)
    return SpotLight(position, v.direction(spec["direction"], f"{key}.direction"), angle,
                     color, attenuation, inner)


def parse_area_light(kind: str, spec: dict, key: str, color: Vec3, v: Values) -> Light:
    if kind == "rect":
        corner = v.vec3(spec["corner"], f"{key}.corner")
        u, w = v.vec3(spec["u"], f"{key}.u"), v.vec3(spec["v"], f"{key}.v")
        _check_area(rect_area(u, w), f"{key}.v", "|u x v|", v)
        return RectLight(corner, u, w, color)
    radius = v.length(spec["radius"], f"{key}.radius")
    center = v.vec3(spec["center"], f"{key}.center")
    _check_area(math.pi * radius * radius, f"{key}.radius", "pi radius^2", v)
    if kind == "disc":
        return DiscLight(center, v.direction(spec["normal"], f"{key}.normal"), radius, color)
    return SphereLight(center, radius, color)


def _check_area(area: float, key: str, what: str, v: Values) -> None:
    """The kernels divide by and multiply with an emitting area: it must be a normal
    float32 number, far from overflow."""
    if not L.MIN_LENGTH <= area <= L.MAX_LIGHT_AREA:
        raise v.error(key, f"the light's area ({what}) must be in [{L.MIN_LENGTH:g}, "
                      f"{L.MAX_LIGHT_AREA:g}], got {area:.3g}")
