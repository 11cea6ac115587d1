"""Triangle lights: the emissive faces of meshes (clray.scene.emitters), one-sided, sampled over
their area. No scene file names them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.lights.light import LightKind, Square, Toward, area_sample
from clray.lights.rect import rect_area
from clray.shapes.shape import f4
from clray.vectors import Vec3, vec


@dataclass(frozen=True)
class TriangleLight:
    """An emissive mesh face (clray.scene.emitters): emits to the side of
    cross(v1 - v0, v2 - v0) only. Made from the meshes, never given in a scene file."""

    vertices: tuple[Vec3, Vec3, Vec3]
    color: Vec3 = (1.0, 1.0, 1.0)


def fields(rec: np.void, light: TriangleLight, eye: np.ndarray) -> None:
    v0, v1, v2 = (np.asarray(v, dtype=np.float64) for v in light.vertices)
    rec["position"] = f4(v0 - eye)
    rec["axis_u"], rec["axis_v"] = f4(v1 - v0), f4(v2 - v0)
    rec["color"] = f4(light.color, rect_area(v1 - v0, v2 - v0) / 2.0)


def triangle_point(v0: np.ndarray, u: np.ndarray, v: np.ndarray, square: Square) -> np.ndarray:
    """The points (N, 3) of the triangle v0, v0 + u, v0 + v (one, or one a point: (N, 3)) that
    the square's points take, uniform by area: the square's far half folded onto its near one,
    as the kernels do."""
    u1, u2 = square
    far = u1 + u2 > 1.0
    u1, u2 = np.where(far, 1.0 - u1, u1), np.where(far, 1.0 - u2, u2)
    return v0 + u1[:, None] * u + u2[:, None] * v


def toward(light: TriangleLight, p: np.ndarray, err: np.ndarray, square: Square) -> Toward:
    v0, v1, v2 = (vec(v) for v in light.vertices)
    u, v = v1 - v0, v2 - v0
    normal = np.cross(u, v)
    area = float(np.linalg.norm(normal)) / 2.0
    return area_sample(triangle_point(v0, u, v, square), normal / (2.0 * area), area, p, err)


TRIANGLE = LightKind(kind="triangle", model=TriangleLight, keys=((), ()), parse=None, code=6,
                     fields=fields, toward=toward, area=True)
