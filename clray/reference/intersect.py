"""Ray-primitive crossings of the oracle (the intersect_* functions of
kernels/sphere.h, plane.h, box.h, cylinder.h, cone.h, torus.h and triangle.h), in float64 by the
textbook formulas: every place a ray's line crosses a surface, as (t, part) pairs with t = inf where
there is none (t may be negative: callers keep t > 0). `part` tells the surface function
(clray.reference.shading) which face was hit."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from clray.reference.vectors import dot, vec
from clray.scene.model import Box, Cone, Cylinder, Plane, Sphere, Torus

Crossings = list[tuple[np.ndarray, np.ndarray]]


def quadratic_roots(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots of a t^2 + b t + c = 0 as (smaller, larger), inf where a root does not exist;
    a == 0 degrades to the linear root."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * c
        # Press et al.: q adds two numbers of the same sign, so neither root cancels.
        q = -0.5 * (b + np.where(b < 0.0, -1.0, 1.0) * np.sqrt(np.maximum(disc, 0.0)))
        r0, r1 = q / a, c / q
        linear = -c / b
    t0 = np.where(a == 0.0, linear, np.minimum(r0, r1))
    t1 = np.where(a == 0.0, np.inf, np.maximum(r0, r1))
    missing = (a != 0.0) & (disc < 0.0)
    t0 = np.where(missing | np.isnan(t0), np.inf, t0)
    t1 = np.where(missing | np.isnan(t1), np.inf, t1)
    return t0, t1


def intersect_sphere(s: Sphere, o: np.ndarray, d: np.ndarray) -> Crossings:
    oc = o - vec(s.center)
    t0, t1 = quadratic_roots(dot(d, d), 2.0 * dot(oc, d), dot(oc, oc) - s.radius**2)
    zero = np.zeros(len(o), dtype=np.int64)
    return [(t0, zero), (t1, zero)]


def intersect_plane(pl: Plane, o: np.ndarray, d: np.ndarray) -> Crossings:
    n = vec(pl.normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = dot(vec(pl.point) - o, n) / dot(d, n)
    return [(np.where(np.isnan(t), np.inf, t), np.zeros(len(o), dtype=np.int64))]


def intersect_box(b: Box, o: np.ndarray, d: np.ndarray) -> Crossings:
    lo, hi = vec(b.min), vec(b.max)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    # A ray parallel to a slab is inside it for all t or for none (this also avoids 0/0).
    parallel = d == 0.0
    inside = (o >= lo) & (o <= hi)
    near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    rows = np.arange(len(o))
    near_axis, far_axis = np.argmax(near, axis=1), np.argmin(far, axis=1)
    t_near, t_far = near[rows, near_axis], far[rows, far_axis]
    hit = t_near <= t_far
    # part = 2 * axis + (1 for the max face): entering through the min face when d[axis] > 0.
    near_part = 2 * near_axis + (d[rows, near_axis] < 0.0)
    far_part = 2 * far_axis + (d[rows, far_axis] > 0.0)
    return [
        (np.where(hit, t_near, np.inf), near_part),
        (np.where(hit, t_far, np.inf), far_part),
    ]


def _disc_crossing(
    center: np.ndarray, normal: np.ndarray, radius: float, o: np.ndarray, d: np.ndarray
) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = dot(center - o, normal) / dot(d, normal)
        off = o + t[:, None] * d - center
        inside = dot(off, off) <= radius * radius
    return np.where(inside & ~np.isnan(t), t, np.inf)


def _within_height(
    t: np.ndarray, o: np.ndarray, d: np.ndarray, start: np.ndarray, axis: np.ndarray, height: float
) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        h = dot(o + t[:, None] * d - start, axis)
    return np.where((h >= 0.0) & (h <= height), t, np.inf)


def intersect_cylinder(c: Cylinder, o: np.ndarray, d: np.ndarray) -> Crossings:
    base, axis = vec(c.base), vec(c.axis)
    q = o - base
    q_perp = q - dot(q, axis)[:, None] * axis
    d_perp = d - dot(d, axis)[:, None] * axis
    t0, t1 = quadratic_roots(
        dot(d_perp, d_perp), 2.0 * dot(d_perp, q_perp), dot(q_perp, q_perp) - c.radius**2
    )
    side = np.zeros(len(o), dtype=np.int64)
    out = [
        (_within_height(t0, o, d, base, axis, c.height), side),
        (_within_height(t1, o, d, base, axis, c.height), side),
    ]
    if c.capped:
        top = base + c.height * axis
        out.append((_disc_crossing(base, -axis, c.radius, o, d), side + 1))
        out.append((_disc_crossing(top, axis, c.radius, o, d), side + 2))
    return out


def intersect_cone(c: Cone, o: np.ndarray, d: np.ndarray) -> Crossings:
    apex, axis = vec(c.apex), vec(c.axis)
    cos2 = math.cos(math.radians(c.angle)) ** 2
    q = o - apex
    # Points x with ((x - apex).axis)^2 = cos^2(angle) |x - apex|^2: both nappes; the height
    # test keeps the one along +axis.
    da, qa = dot(d, axis), dot(q, axis)
    t0, t1 = quadratic_roots(
        da * da - cos2 * dot(d, d),
        2.0 * (da * qa - cos2 * dot(d, q)),
        qa * qa - cos2 * dot(q, q),
    )
    side = np.zeros(len(o), dtype=np.int64)
    out = [
        (_within_height(t0, o, d, apex, axis, c.height), side),
        (_within_height(t1, o, d, apex, axis, c.height), side),
    ]
    if c.capped:
        radius = c.height * math.tan(math.radians(c.angle))
        out.append((_disc_crossing(apex + c.height * axis, axis, radius, o, d), side + 1))
    return out


def _tube_distance(tr: Torus, q: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho - R)^2 + z^2 - r^2 at q (relative to the centre; negative inside the tube, and
    well-conditioned near it) and its derivative along the unit direction u."""
    axis = vec(tr.axis)
    z, uz = q @ axis, u @ axis
    radial = q - z[..., None] * axis
    rho = np.linalg.norm(radial, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_slope = np.where(rho > 0.0, np.sum(radial * u, axis=-1) / rho, 0.0)
    return ((rho - tr.major_radius) ** 2 + z * z - tr.minor_radius**2,
            2.0 * (rho - tr.major_radius) * rho_slope + 2.0 * z * uz)


def intersect_torus(tr: Torus, o: np.ndarray, d: np.ndarray) -> Crossings:
    """The textbook quartic (|p|^2 + R^2 - r^2)^2 = 4 R^2 rho^2 along the unit direction from
    the line's point nearest the centre (where its coefficients are smallest), its roots the
    eigenvalues of its companion matrix; each real one polished by Newton steps on the
    distance form, which the quartic's float64 roundings would otherwise leave about 1e-8 off
    for thin tori. Four crossings, inf where there are fewer."""
    centre, axis = vec(tr.center), vec(tr.axis)
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    s0 = -dot(o - centre, u)
    q = o - centre + s0[:, None] * u
    qq = dot(q, q)
    big_s = qq + tr.major_radius**2 - tr.minor_radius**2
    qa, ua = q @ axis, u @ axis
    r2 = 4.0 * tr.major_radius**2
    # (s^2 + S)^2 - 4 R^2 (s^2 + q.q - (qa + s ua)^2), as q.u = 0: monic, no cubic term.
    coeffs = np.stack([np.zeros_like(qa), 2.0 * big_s - r2 * (1.0 - ua * ua),
                       2.0 * r2 * qa * ua, big_s * big_s - r2 * (qq - qa * qa)], axis=-1)
    companion = np.zeros((len(o), 4, 4))
    companion[:, 0, :] = -coeffs
    companion[:, 1, 0] = companion[:, 2, 1] = companion[:, 3, 2] = 1.0
    roots = np.linalg.eigvals(companion)
    real = np.abs(roots.imag) <= 1e-7 * (tr.major_radius + tr.minor_radius)
    s = np.where(real, roots.real, np.nan)
    for _ in range(8):
        g, slope = _tube_distance(tr, q[:, None, :] + s[..., None] * u[:, None, :],
                                  u[:, None, :])
        with np.errstate(divide="ignore", invalid="ignore"):
            s = s - np.where(slope != 0.0, g / slope, 0.0)
    t = np.sort(np.where(np.isfinite(s), (s + s0[:, None]) / length[:, None], np.inf), axis=1)
    part = np.zeros(len(o), dtype=np.int64)
    return [(t[:, k], part) for k in range(4)]


# The bounded and unbounded shapes intersected one by one; triangles go in batches.
INTERSECT: dict[type, Callable[..., Crossings]] = {
    Plane: intersect_plane,
    Sphere: intersect_sphere,
    Box: intersect_box,
    Cylinder: intersect_cylinder,
    Cone: intersect_cone,
    Torus: intersect_torus,
}


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
