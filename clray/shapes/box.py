"""Axis-aligned boxes (kernels/box.h)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from clray.errors import show
from clray.shapes.shape import Checks, Crossings, Packed, Shape, f4
from clray.vectors import Vec3, vec

# Below this, relative to the largest entry of its column, a matrix entry is rounding noise:
# cos(90 degrees) is 6e-17, not 0, and must not make a quarter-turned box "off the axes". Each
# column of A = R S carries one axis's scale, which may differ from another's by up to 1e60:
# judged against the whole matrix, a small axis's real entries would be taken for noise.
_NOISE = 1e-12


@dataclass(frozen=True)
class Box:
    min: Vec3
    max: Vec3
    material: int


def parse(spec: dict, key: str, material: int, v: Checks) -> Box:
    lo = v.vec3(spec["min"], f"{key}.min")
    hi = v.vec3(spec["max"], f"{key}.max")
    if any(a > b for a, b in zip(lo, hi, strict=True)):
        raise v.error(
            f"{key}.max", f"must be >= min on every axis, got min {show(lo)}, max {show(hi)}"
        )
    # A box flat on one axis is a rectangle and still renders; one on all three is not.
    if lo == hi:
        raise v.error(f"{key}.max", f"must differ from min, got {show(hi)} for both")
    return Box(lo, hi, material)


def place(obj: Box, a: np.ndarray, t: np.ndarray) -> Box | str:
    """A box stays one only when A maps axes onto axes (a signed permutation times a diagonal
    scale)."""
    column = np.max(np.abs(a), axis=0, keepdims=True)
    clean = np.where(np.abs(a) <= _NOISE * column, 0.0, a)
    if np.any(np.count_nonzero(clean, axis=0) != 1):
        return "rotates the box off the axes (only quarter turns keep a box axis-aligned)"
    corners = np.array([obj.min, obj.max], dtype=np.float64) @ clean.T + t
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return replace(obj, min=tuple(lo.tolist()), max=tuple(hi.tolist()))


def centre_size(obj: Box) -> tuple[np.ndarray, float]:
    lo, hi = np.asarray(obj.min, dtype=np.float64), np.asarray(obj.max, dtype=np.float64)
    return (lo + hi) / 2.0, float(np.max(hi - lo))


RECORD = np.dtype([("lo", "<f4", (4,)), ("hi", "<f4", (4,)), ("material", "<i4"),
                   ("pad0", "<i4"), ("pad1", "<i4"), ("pad2", "<i4")])


def pack(objects: list[Box], origins: np.ndarray) -> Packed:
    boxes = np.zeros(len(objects), dtype=RECORD)
    for i, (o, origin) in enumerate(zip(objects, origins, strict=True)):
        boxes[i]["lo"] = f4(np.asarray(o.min) - origin)
        boxes[i]["hi"] = f4(np.asarray(o.max) - origin)
        boxes[i]["material"] = o.material
    return (boxes, boxes["lo"][:, :3].astype(np.float64),
            boxes["hi"][:, :3].astype(np.float64))


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


def box_surface(b: Box, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = vec(b.min), vec(b.max)
    axis = part // 2
    rows = np.arange(len(p))
    n = np.zeros_like(p)
    n[rows, axis] = np.where(part % 2 == 1, 1.0, -1.0)
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    return n, np.stack([_along(p[rows, a1], lo[a1], hi[a1]),
                        _along(p[rows, a2], lo[a2], hi[a2])], axis=-1)


def _along(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(x - lo) / (hi - lo), or 0 where the box is flat on that axis (kernels/box.h)."""
    width = hi - lo
    return np.where(width > 0.0, (x - lo) / np.where(width > 0.0, width, 1.0), 0.0)


BOX = Shape(
    kind="box", model=Box, keys=(("min", "max"), ()), lengths=(), parse=parse, place=place,
    centre_size=centre_size, prim=2, record=RECORD, buffer="boxes", switch="has_boxes",
    pack=pack, intersect=intersect_box, surface=box_surface,
)
