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


def rect_area(u: Vec3 | np.ndarray, v: Vec3 | np.ndarray) -> float | np.ndarray:
    """|u x v|, the parallelogram's area, computed with both edges scaled to unit length first
    so that no product underflows or overflows; 0 where an edge is zero. For one pair of edges
    (3,) a float, for many (N, 3) N of them."""
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    nu, nv = np.max(np.abs(u), axis=-1), np.max(np.abs(v), axis=-1)
    zero = (nu == 0.0) | (nv == 0.0)
    nu, nv = np.where(zero, 1.0, nu), np.where(zero, 1.0, nv)
    cross = np.cross(u / nu[..., None], v / nv[..., None])
    area = np.where(zero, 0.0, np.linalg.norm(cross, axis=-1) * nu * nv)
    return float(area) if area.ndim == 0 else area


# The rounding error of each component of a float32 cross product, a_j b_k - a_k b_j, in units
# of |a_j b_k| + |a_k b_j|: gamma(2) of float32, the products and their difference each rounded
# once, fused or not.
F32_CROSS_ROUNDING = 2 * 2.0**-24 / (1 - 2 * 2.0**-24)


def resolved_in_float32(u: Vec3 | np.ndarray, v: Vec3 | np.ndarray) -> np.bool_ | np.ndarray:
    """Whether the kernels' normal of these edges, the float32 cross product of their float32
    copies, is nonzero and on the emitting side: its products are float32 numbers, and the
    float32 edges' |u x v| (exact products in float64) is beyond its rounding error. Not so
    for edges parallel to float32 precision, whose light would emit nothing on the device.
    For one pair of edges (3,) or many (N, 3): a boolean, or N of them."""
    a, b = (np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)
            for x in (u, v))
    products = np.abs(np.stack([a[..., [1, 2, 0]] * b[..., [2, 0, 1]],
                                a[..., [2, 0, 1]] * b[..., [1, 2, 0]]]))
    finite = np.all(products <= np.finfo(np.float32).max, axis=(0, -1))
    bound = F32_CROSS_ROUNDING * np.where(np.isfinite(products), products, 0.0).sum(axis=0)
    with np.errstate(over="ignore", invalid="ignore"):
        crossed = np.linalg.norm(np.cross(a, b), axis=-1) > np.linalg.norm(bound, axis=-1)
    return finite & crossed


def parse(spec: dict, key: str, color: Vec3, v: LightChecks) -> RectLight:
    corner = v.vec3(spec["corner"], f"{key}.corner")
    u, w = v.vec3(spec["u"], f"{key}.u"), v.vec3(spec["v"], f"{key}.v")
    v.light_area(rect_area(u, w), f"{key}.v", "|u x v|")
    if not resolved_in_float32(u, w):
        raise v.error(f"{key}.v", "u and v are parallel to float32 precision: the kernels' "
                                  "float32 |u x v| is within its rounding error")
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
