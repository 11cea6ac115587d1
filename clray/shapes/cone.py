"""Cones: one nappe, capped or open (kernels/cone.h)."""

from __future__ import annotations

import math
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
class Cone:
    """One nappe: the apex, widening along `axis` to a base disc at distance `height`."""

    apex: Vec3
    axis: Vec3  # unit, from the apex towards the base
    angle: float  # half-angle, degrees, in (0, 90)
    height: float
    material: int
    capped: bool = True


def parse(spec: dict, key: str, material: int, v: Checks) -> Cone:
    capped = v.boolean(spec.get("capped", True), f"{key}.capped")
    axis = v.direction(spec["axis"], f"{key}.axis")
    height = v.length(spec["height"], f"{key}.height")
    return Cone(apex=v.vec3(spec["apex"], f"{key}.apex"), axis=axis,
                angle=v.open_range(spec["angle"], f"{key}.angle", 0, 90), height=height,
                material=material, capped=capped)


def place(obj: Cone, a: np.ndarray, t: np.ndarray) -> Cone | str:
    s = similarity_scale(a)
    if s is None:
        return uneven("cone")
    return replace(obj, apex=moved_point(a, t, obj.apex), axis=moved_direction(a, obj.axis),
                   height=obj.height * s)


def centre_size(obj: Cone) -> tuple[np.ndarray, float]:
    apex, axis = np.asarray(obj.apex), np.asarray(obj.axis)
    rim = obj.height * float(np.tan(np.radians(obj.angle)))
    return apex + axis * obj.height / 2.0, float(max(obj.height, rim))


def proportion(obj: Cone) -> tuple[float, str]:
    """The rim radius over the height, tan(angle): the kernels' side quadratic weighs its
    terms along the axis by tan^2, and past about 1e4 their float32 roundings swamp the
    terms across it, so a near-flat cone gets stray hits wherever it is seen from."""
    tan = float(np.tan(np.radians(obj.angle)))
    rim = obj.height * tan
    return tan, f"its rim radius {rim:.3g} is {tan:.3g} times its height {obj.height:.3g}"


def extents(obj: Cone) -> tuple[tuple[str, float], ...]:
    """The rim radius: height and angle within their limits make it any size (1e30 x
    tan(89.9999999 degrees) is 5.7e38, past float32)."""
    return (("rim radius (height x tan(angle))",
             obj.height * float(np.tan(np.radians(obj.angle)))),)


RECORD = np.dtype([("apex_tan", "<f4", (4,)), ("axis_height", "<f4", (4,)),
                   ("material", "<i4"), ("capped", "<i4"), ("pad0", "<i4"), ("pad1", "<i4")])


def pack(objects: list[Cone], origins: np.ndarray) -> Packed:
    cones = np.zeros(len(objects), dtype=RECORD)
    lo, hi = [], []
    for i, (o, origin) in enumerate(zip(objects, origins, strict=True)):
        rec = cones[i]
        rec["apex_tan"] = f4(np.asarray(o.apex) - origin, np.tan(np.radians(o.angle)))
        rec["axis_height"] = f4(o.axis, o.height)
        rec["material"] = o.material
        rec["capped"] = int(o.capped)
        apex = rec["apex_tan"][:3].astype(np.float64)
        axis = rec["axis_height"][:3].astype(np.float64)
        length = float(rec["axis_height"][3])
        base = apex + axis * length
        ext = disc_extent(axis, length * float(rec["apex_tan"][3]))
        lo.append(np.minimum(apex, base - ext))
        hi.append(np.maximum(apex, base + ext))
    return cones, *bounds_of(lo, hi)


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
        (within_height(t0, o, d, apex, axis, c.height), side),
        (within_height(t1, o, d, apex, axis, c.height), side),
    ]
    if c.capped:
        radius = c.height * math.tan(math.radians(c.angle))
        out.append((disc_crossing(apex + c.height * axis, axis, radius, o, d), side + 1))
    return out


def cone_surface(c: Cone, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    apex, axis = vec(c.apex), vec(c.axis)
    cos2 = math.cos(math.radians(c.angle)) ** 2
    radius = c.height * math.tan(math.radians(c.angle))
    e1, e2 = frame(axis)
    q = p - apex
    h = q @ axis
    # Minus the gradient of (q.axis)^2 - cos^2 |q|^2, which points out of the cone.
    side_n = safe_normalize(cos2 * q - h[:, None] * axis)
    n = np.where((part == 0)[:, None], side_n, axis)
    side_uv = np.stack([0.5 + np.arctan2(q @ e2, q @ e1) / (2 * np.pi), h / c.height], axis=-1)
    cap_uv = np.stack([0.5 + 0.5 * (q @ e1) / radius, 0.5 + 0.5 * (q @ e2) / radius], axis=-1)
    return n, np.where((part == 0)[:, None], side_uv, cap_uv)


CONE = Shape(
    kind="cone", model=Cone, keys=(("apex", "axis", "angle", "height"), ("capped",)),
    lengths=("height",), parse=parse, place=place, centre_size=centre_size, prim=4, record=RECORD,
    buffer="cones", switch="has_cones", pack=pack, intersect=intersect_cone, surface=cone_surface,
    proportion=proportion, extents=extents,
)
