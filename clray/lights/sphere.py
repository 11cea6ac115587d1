"""Sphere lights: an emitting sphere, sampled over the cone it subtends."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.lights.light import LightChecks, LightKind, Square, Toward, aimed, centre_and_radius
from clray.shapes.shape import f4
from clray.vectors import Vec3, frame, vec


@dataclass(frozen=True)
class SphereLight:
    """A sphere that emits outwards from every point of its surface."""

    center: Vec3
    radius: float
    color: Vec3 = (1.0, 1.0, 1.0)


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> SphereLight:
    center, radius = centre_and_radius(spec, key, v)
    return SphereLight(center, radius, color)


def fields(rec: np.void, light: SphereLight, eye: np.ndarray) -> None:
    rec["position"] = f4(np.asarray(light.center) - eye, light.radius)


def toward(light: SphereLight, p: np.ndarray, err: np.ndarray, square: Square) -> Toward:
    """A direction uniform in the cone the sphere subtends from p, and its nearer point."""
    u1, u2 = square
    to_c = vec(light.center) - p
    dist = np.linalg.norm(to_c, axis=-1)
    usable = dist > light.radius
    safe = np.where(usable, dist, 2.0 * light.radius)
    s = light.radius / safe
    # 1 - cos_max without cancellation for a small or distant sphere (kernels/lights.h).
    k = s * s / (1.0 + np.sqrt(np.maximum(0.0, 1.0 - s * s)))
    one_minus_cos = u1 * k
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * np.pi * u2
    w_c = to_c / safe[:, None]
    e1, e2 = frame(w_c)
    w = (cos_t[:, None] * w_c
         + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
    # The nearer of the two crossings of the sphere along w.
    t = safe * cos_t - np.sqrt(np.maximum(0.0, light.radius**2 - (safe * sin_t) ** 2))
    return aimed(p + t[:, None] * w, p, 2.0 * np.pi * k, usable)


SPHERE = LightKind(kind="sphere", model=SphereLight, keys=(("center", "radius"), ("color",)),
                   parse=parse, code=5, fields=fields, toward=toward, area=True)
