"""Tori: rings about an axis (kernels/torus.h)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from clray.errors import show
from clray.shapes.shape import (
    Checks,
    Crossings,
    Packed,
    Shape,
    disc_extent,
    f4,
    moved_direction,
    moved_point,
    similarity_scale,
    uneven,
)
from clray.vectors import Vec3, dot, frame, safe_normalize, vec


@dataclass(frozen=True)
class Torus:
    """The points at distance `minor_radius` from the circle of radius `major_radius` about
    `axis` through `center` (a ring: minor_radius <= major_radius)."""

    center: Vec3
    axis: Vec3  # unit, the circle's normal
    major_radius: float
    minor_radius: float
    material: int


def parse(spec: dict, key: str, material: int, v: Checks) -> Torus:
    major = v.length(spec["major_radius"], f"{key}.major_radius")
    minor = v.length(spec["minor_radius"], f"{key}.minor_radius")
    # A minor radius past the major one folds the tube through the axis (a spindle torus),
    # whose inner surface the ring's formulas do not describe.
    if minor > major:
        raise v.error(f"{key}.minor_radius",
                      f"must be at most major_radius ({show(major)}), got {show(minor)}")
    return Torus(v.vec3(spec["center"], f"{key}.center"),
                 v.direction(spec["axis"], f"{key}.axis"), major, minor, material)


def place(obj: Torus, a: np.ndarray, t: np.ndarray) -> Torus | str:
    s = similarity_scale(a)
    if s is None:
        return uneven("torus")
    return replace(obj, center=moved_point(a, t, obj.center), axis=moved_direction(a, obj.axis),
                   major_radius=obj.major_radius * s, minor_radius=obj.minor_radius * s)


def centre_size(obj: Torus) -> tuple[np.ndarray, float]:
    # The tube is what a ray must resolve: a thin ring far away is the hard case.
    return np.asarray(obj.center, dtype=np.float64), float(obj.minor_radius)


RECORD = np.dtype([("centre_major", "<f4", (4,)), ("axis_minor", "<f4", (4,)),
                   ("material", "<i4"), ("pad0", "<i4"), ("pad1", "<i4"), ("pad2", "<i4")])


def pack(objects: list[Torus], origins: np.ndarray) -> Packed:
    tori = np.zeros(len(objects), dtype=RECORD)
    for i, (o, origin) in enumerate(zip(objects, origins, strict=True)):
        tori[i]["centre_major"] = f4(np.asarray(o.center) - origin, o.major_radius)
        tori[i]["axis_minor"] = f4(o.axis, o.minor_radius)
        tori[i]["material"] = o.material
    # Bounds of the stored (float32) shape: the circle's extent on each world axis, and the
    # tube's radius around it.
    centre = tori["centre_major"][:, :3].astype(np.float64)
    axis = tori["axis_minor"][:, :3].astype(np.float64)
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    ext = (disc_extent(axis, tori["centre_major"][:, 3:].astype(np.float64))
           + tori["axis_minor"][:, 3:].astype(np.float64))
    return tori, centre - ext, centre + ext


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


def torus_surface(tr: Torus, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Away from the circle's nearest point; (u, v) around the axis and around the tube (0.5
    on the outer equator)."""
    centre, axis = vec(tr.center), vec(tr.axis)
    e1, e2 = frame(axis)
    q = p - centre
    radial = q - (q @ axis)[:, None] * axis
    rho = np.linalg.norm(radial, axis=-1)
    nr = np.where((rho > 0.0)[:, None], radial / np.where(rho > 0.0, rho, 1.0)[:, None], e1)
    n = safe_normalize(q - tr.major_radius * nr)
    uv = np.stack([0.5 + np.arctan2(q @ e2, q @ e1) / (2 * np.pi),
                   0.5 + np.arctan2(n @ axis, np.sum(n * nr, axis=-1)) / (2 * np.pi)], axis=-1)
    return n, uv


TORUS = Shape(
    kind="torus", model=Torus, keys=(("center", "axis", "major_radius", "minor_radius"), ()),
    lengths=("major_radius", "minor_radius"), parse=parse, place=place,
    centre_size=centre_size, prim=7, record=RECORD, buffer="tori", switch="has_tori", pack=pack,
    intersect=intersect_torus, surface=torus_surface,
)
