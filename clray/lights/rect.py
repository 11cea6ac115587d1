"""Rect lights: a one-sided emitting parallelogram, sampled over its area."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.lights.light import LightChecks, LightKind, Square, Toward, area_sample
from clray.shapes.shape import f4
from clray.vectors import Vec3, vec


@dataclass(frozen=True)
class RectLight:
    """The parallelogram corner + s u + t v (s, t in [0, 1]); emits to the side of
    cross(u, v) only."""

    corner: Vec3
    u: Vec3
    v: Vec3
    color: Vec3 = (1.0, 1.0, 1.0)


def rect_area(u: Vec3, v: Vec3) -> float:
    """|u x v|, the parallelogram's area, computed with both edges scaled to unit length first
    so that no product underflows or overflows."""
    nu, nv = float(np.max(np.abs(u))), float(np.max(np.abs(v)))
    if nu == 0.0 or nv == 0.0:
        return 0.0
    return float(np.linalg.norm(np.cross(np.asarray(u) / nu, np.asarray(v) / nv))) * nu * nv


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> RectLight:
    corner = v.vec3(spec["corner"], f"{key}.corner")
    u, w = v.vec3(spec["u"], f"{key}.u"), v.vec3(spec["v"], f"{key}.v")
    v.light_area(rect_area(u, w), f"{key}.v", "|u x v|")
    return RectLight(corner, u, w, color)


def fields(rec: np.void, light: RectLight, eye: np.ndarray) -> None:
    rec["position"] = f4(np.asarray(light.corner) - eye)
    rec["axis_u"], rec["axis_v"] = f4(light.u), f4(light.v)
    rec["color"] = f4(light.color, rect_area(light.u, light.v))


def toward(light: RectLight, p: np.ndarray, err: np.ndarray, square: Square) -> Toward:
    u1, u2 = square
    u, v = vec(light.u), vec(light.v)
    y = vec(light.corner) + u1[:, None] * u + u2[:, None] * v
    normal = np.cross(u, v)
    area = float(np.linalg.norm(normal))
    return area_sample(y, normal / area, area, p, err)


RECT = LightKind(kind="rect", model=RectLight, keys=(("corner", "u", "v"), ("color",)),
                 parse=parse, code=3, fields=fields, toward=toward, area=True)
