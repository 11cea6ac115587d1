"""Ray-primitive crossings of the oracle, in float64 by the textbook formulas: every place a
ray's line crosses a surface, as (t, part) pairs with t = inf where there is none (t may be
negative: callers keep t > 0). `part` tells the surface function (clray.reference.shading)
which face was hit. The analytic shapes' (the intersect_* functions of kernels/sphere.h, box.h,
cylinder.h, cone.h and torus.h) are in their modules (clray.shapes); here are the plane's
(plane.h) and the triangles' (triangle.h)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from clray.scene.model import Plane
from clray.shapes import SHAPES
from clray.shapes.shape import Crossings
from clray.vectors import dot, vec


def intersect_plane(pl: Plane, o: np.ndarray, d: np.ndarray) -> Crossings:
    n = vec(pl.normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = dot(vec(pl.point) - o, n) / dot(d, n)
    return [(np.where(np.isnan(t), np.inf, t), np.zeros(len(o), dtype=np.int64))]


# The bounded and unbounded shapes intersected one by one (each shape's from its module,
# clray.shapes); triangles go in batches.
INTERSECT: dict[type, Callable[..., Crossings]] = {
    Plane: intersect_plane, **{shape.model: shape.intersect for shape in SHAPES}}


def intersect_triangle(
    v: np.ndarray, o: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moller-Trumbore for N rays x T triangles (v: (T, 3, 3)): (t, b1, b2), each (N, T), with
    t = inf where the ray misses or the hit is not at t > 0. Edges count as inside."""
    e1 = (v[:, 1] - v[:, 0])[None]
    e2 = (v[:, 2] - v[:, 0])[None]
    dd = d[:, None, :]
    pvec = np.cross(dd, e2)
    det = dot(e1, pvec)
    tvec = o[:, None, :] - v[None, :, 0]
    qvec = np.cross(tvec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        b1 = dot(tvec, pvec) * inv
        b2 = dot(dd, qvec) * inv
        t = dot(e2, qvec) * inv
        hit = (det != 0.0) & (b1 >= 0.0) & (b2 >= 0.0) & (b1 + b2 <= 1.0) & (t > 0.0)
    return np.where(hit, t, np.inf), b1, b2
