"""Point lights: a position, a colour and a distance attenuation (kernels/lights.h)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.lights.light import LightChecks, LightKind, Square, Toward
from clray.shapes.shape import f4
from clray.vectors import Vec3, vec


@dataclass(frozen=True)
class PointLight:
    position: Vec3
    color: Vec3 = (1.0, 1.0, 1.0)
    attenuation: Vec3 = (1.0, 0.0, 0.0)  # constant, linear, quadratic


def attenuation(spec: dict, key: str, v: LightChecks) -> Vec3:
    """The (constant, linear, quadratic) attenuation of a light at a point (point, spot)."""
    akey = f"{key}.attenuation"
    found = v.non_negative(spec.get("attenuation", (1.0, 0.0, 0.0)), akey)
    if not any(found):
        raise v.error(akey, "must not be all zero")
    return found


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> PointLight:
    atten = attenuation(spec, key, v)
    return PointLight(v.vec3(spec["position"], f"{key}.position"), color, atten)


def fields(rec: np.void, light: PointLight, eye: np.ndarray) -> None:
    rec["position"] = f4(np.asarray(light.position) - eye)
    rec["attenuation"] = f4(light.attenuation)


def toward(light: PointLight, p: np.ndarray, err: np.ndarray, square: Square | None) -> Toward:
    """The light from its position, attenuated by 1 / (kc + kl d + kq d^2), at most 1."""
    target = np.broadcast_to(vec(light.position), p.shape)
    to_light = target - p
    dist = np.linalg.norm(to_light, axis=-1)
    l_dir = to_light / np.where(dist > 0.0, dist, 1.0)[:, None]
    kc, kl, kq = light.attenuation
    denom = kc + kl * dist + kq * dist * dist
    with np.errstate(divide="ignore"):
        atten = np.where(denom > 0.0, np.minimum(1.0, 1.0 / denom), 1.0)
    return Toward(target, l_dir, atten, dist > err)


POINT = LightKind(kind="point", model=PointLight, keys=(("position",), ("color", "attenuation")),
                  parse=parse, code=0, fields=fields, toward=toward)
