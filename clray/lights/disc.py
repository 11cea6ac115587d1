"""Disc lights: a one-sided emitting disc, sampled over its area."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clray.lights.light import (
    LightChecks,
    LightKind,
    Square,
    Toward,
    area_sample,
    centre_and_radius,
)
from clray.shapes.shape import f4
from clray.vectors import Vec3, frame, vec


@dataclass(frozen=True)
class DiscLight:
    """A disc that emits to the side its (unit) normal points to."""

    center: Vec3
    normal: Vec3
    radius: float
    color: Vec3 = (1.0, 1.0, 1.0)


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> DiscLight:
    center, radius = centre_and_radius(spec, key, v)
    return DiscLight(center, v.direction(spec["normal"], f"{key}.normal"), radius, color)


def fields(rec: np.void, light: DiscLight, eye: np.ndarray) -> None:
    rec["position"] = f4(np.asarray(light.center) - eye, light.radius)
    rec["axis_u"] = f4(light.normal)
    rec["color"] = f4(light.color, math.pi * light.radius**2)


def concentric_disc(u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley and Chiu's area-preserving map of the unit square onto the unit disc."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    wide = np.abs(a) > np.abs(b)
    r = np.where(wide, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(wide, np.pi / 4 * (b / a), np.pi / 2 - np.pi / 4 * (a / b))
    phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def toward(light: DiscLight, p: np.ndarray, err: np.ndarray, square: Square) -> Toward:
    u1, u2 = square
    normal = vec(light.normal)
    e1, e2 = frame(normal)
    a, b = concentric_disc(u1, u2)
    y = vec(light.center) + light.radius * (a[:, None] * e1 + b[:, None] * e2)
    return area_sample(y, normal, np.pi * light.radius**2, p, err)


DISC = LightKind(kind="disc", model=DiscLight, keys=(("center", "normal", "radius"), ("color",)),
                 parse=parse, code=4, fields=fields, toward=toward, area=True)
