"""Finite cylinders, capped or open (kernels/cylinder.h)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from clray.shapes.shape import (
    Checks,
    Crossings,
    Packed,
    Shape,
    bounds_of,
    disc_crossing,
    disc_extent,
    f4,
    moved_direction,
    moved_point,
    quadratic_roots,
    similarity_scale,
    uneven,
    within_height,
)
from clray.vectors import Vec3, dot, frame, safe_normalize, vec


@dataclass(frozen=True)
class Cylinder:
    base: Vec3  # centre of the bottom cap
    axis: Vec3  # unit, from the bottom cap to the top cap
    radius: float
    height: float
    material: int
    capped: bool = True


def parse(spec: dict, key: str, material: int, v: Checks) -> Cylinder:
    capped = v.boolean(spec.get("capped", True), f"{key}.capped")
    axis = v.direction(spec["axis"], f"{key}.axis")
    height = v.length(spec["height"], f"{key}.height")
    return Cylinder(base=v.vec3(spec["base"], f"{key}.base"), axis=axis,
                    radius=v.length(spec["radius"], f"{key}.radius"), height=height,
                    material=material, capped=capped)


def place(obj: Cylinder, a: np.ndarray, t: np.ndarray) -> Cylinder | str:
    s = similarity_scale(a)
    if s is None:
        return uneven("cylinder")
    return replace(obj, base=moved_point(a, t, obj.base), axis=moved_direction(a, obj.axis),
                   radius=obj.radius * s, height=obj.height * s)


def centre_size(obj: Cylinder) -> tuple[np.ndarray, float]:
    base, axis = np.asarray(obj.base), np.asarray(obj.axis)
    return base + axis * obj.height / 2.0, float(max(obj.radius, obj.height))


RECORD = np.dtype([("base_radius", "<f4", (4,)), ("axis_height", "<f4", (4,)),
                   ("material", "<i4"), ("capped", "<i4"), ("pad0", "<i4"), ("pad1", "<i4")])


def pack(objects: list[Cylinder], origins: np.ndarray) -> Packed:
    cylinders = np.zeros(len(objects), dtype=RECORD)
    lo, hi = [], []
    for i, (o, origin) in enumerate(zip(objects, origins, strict=True)):
        rec = cylinders[i]
        rec["base_radius"] = f4(np.asarray(o.base) - origin, o.radius)
        rec["axis_height"] = f4(o.axis, o.height)
        rec["material"] = o.material
        rec["capped"] = int(o.capped)
        base = rec["base_radius"][:3].astype(np.float64)
        axis = rec["axis_height"][:3].astype(np.float64)
        top = base + axis * float(rec["axis_height"][3])
        ext = disc_extent(axis, float(rec["base_radius"][3]))
        lo.append(np.minimum(base, top) - ext)
        hi.append(np.maximum(base, top) + ext)
    return cylinders, *bounds_of(lo, hi)


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
        (within_height(t0, o, d, base, axis, c.height), side),
        (within_height(t1, o, d, base, axis, c.height), side),
    ]
    if c.capped:
        top = base + c.height * axis
        out.append((disc_crossing(base, -axis, c.radius, o, d), side + 1))
        out.append((disc_crossing(top, axis, c.radius, o, d), side + 2))
    return out


def cylinder_surface(c: Cylinder, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    base, axis = vec(c.base), vec(c.axis)
    e1, e2 = frame(axis)
    q = p - base
    h = q @ axis
    side_n = safe_normalize(q - h[:, None] * axis)
    n = np.where((part == 0)[:, None], side_n, np.where((part == 1)[:, None], -axis, axis))
    side_uv = np.stack([0.5 + np.arctan2(q @ e2, q @ e1) / (2 * np.pi), h / c.height], axis=-1)
    cap_uv = np.stack([0.5 + 0.5 * (q @ e1) / c.radius, 0.5 + 0.5 * (q @ e2) / c.radius], axis=-1)
    return n, np.where((part == 0)[:, None], side_uv, cap_uv)


CYLINDER = Shape(
    kind="cylinder", model=Cylinder, keys=(("base", "axis", "radius", "height"), ("capped",)),
    lengths=("radius", "height"), parse=parse, place=place, centre_size=centre_size, prim=3,
    record=RECORD, buffer="cylinders", switch="has_cylinders", pack=pack,
    intersect=intersect_cylinder, surface=cylinder_surface,
)
