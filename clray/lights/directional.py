"""Directional lights: a direction of travel and a colour, from infinitely far away."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.lights.light import LightChecks, LightKind, Square, Toward
from clray.shapes.shape import f4
from clray.vectors import Vec3, vec


@dataclass(frozen=True)
class DirectionalLight:
    direction: Vec3  # unit; the way the light travels
    color: Vec3 = (1.0, 1.0, 1.0)


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> DirectionalLight:
    return DirectionalLight(v.direction(spec["direction"], f"{key}.direction"), color)


def fields(rec: np.void, light: DirectionalLight, eye: np.ndarray) -> None:
    rec["position"] = f4(light.direction)


def toward(light: DirectionalLight, p: np.ndarray, err: np.ndarray,
           square: Square | None) -> Toward:
    l_dir = np.broadcast_to(-vec(light.direction), p.shape)
    return Toward(None, l_dir, np.ones(len(p)), np.ones(len(p), dtype=bool))


DIRECTIONAL = LightKind(kind="directional", model=DirectionalLight,
                        keys=(("direction",), ("color",)), parse=parse, code=1, fields=fields,
                        toward=toward)
