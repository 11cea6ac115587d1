"""A shape on every layer, in one record, and what the shapes share (as kernels/shape.h is
for their kernel headers).

Each analytic shape's module (clray/shapes/sphere.py, box.py, ...) ends with its `Shape`: the
scene's keys and their checks, its placement by a transform, the length float32 must resolve,
its device record and packer with the bounds the BVH takes, its primitive code and build
switch, and its float64 reference crossings and surface. The layers above consult the registry
(clray.shapes.SHAPES) instead of naming shapes, so that a new shape is a new module and a new
kernel header, not an edit in every layer. Nothing here imports above the base layer: a
shape's parser gets the scene's value checks (`Checks`) from its caller.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from clray.vectors import Vec3, dot, unit

# Every place a ray's line crosses a surface, as (t, part) pairs with t = inf where there is
# none (t may be negative: callers keep t > 0); `part` tells the surface which face was hit.
Crossings = list[tuple[np.ndarray, np.ndarray]]
# (records, lo, hi): a shape's packed records and the bounds of each, (n, 3) float64.
Packed = tuple[np.ndarray, np.ndarray, np.ndarray]


class Checks(Protocol):
    """The scene value checks a shape's parser uses: clray.scene.values.Values, whose rules
    and wording every parser shares."""

    def error(self, key: str | None, message: str) -> Exception: ...

    def vec3(self, value: Any, key: str) -> Vec3: ...

    def direction(self, value: Any, key: str) -> Vec3: ...

    def length(self, value: Any, key: str) -> float: ...

    def boolean(self, value: Any, key: str) -> bool: ...

    def open_range(self, value: Any, key: str, low: float, high: float) -> float: ...


def _one(obj: object) -> int:
    return 1


@dataclass(frozen=True)
class Shape:
    """One analytic primitive, everything the layers need of it. Its names are one name: the
    model class, the struct of kernels/clray_types.h and its PRIM_* code all read `Torus`."""

    kind: str  # the scene file's `type`
    model: type  # its frozen dataclass, float64 world units (clray.scene.model re-exports it)
    # (required, optional) keys besides `type`, `material` and `transform`.
    keys: tuple[tuple[str, ...], tuple[str, ...]]
    # The model's fields (or an `also` class's) that are strictly positive lengths: the
    # loader refuses a transform that shrinks one below MIN_LENGTH, as the scene's own value.
    lengths: tuple[str, ...]
    # (spec, key, material, checks) -> the object its checked keys describe.
    parse: Callable[[dict, str, int, Checks], Any]
    # (object, A, t) -> the object moved by x -> A x + t, or why the shape does not survive it
    # (the loader then intersects it in its own frame, as an instance).
    place: Callable[[Any, np.ndarray, np.ndarray], Any]
    # object -> a representative centre and the length its crossings must resolve
    # (clray.scene.scale's float32 warnings).
    centre_size: Callable[[Any], tuple[np.ndarray, float]]
    # Its PRIM_* code: kernels/clray_types.h's, and its place in the tie order; below
    # 1 << (31 - PRIM_TYPE_SHIFT), 8, or its references are negative (the int32 code <<
    # PRIM_TYPE_SHIFT | index): clray.accel.prim_refs.check_codes refuses it.
    prim: int
    record: np.dtype  # the numpy twin of its struct in kernels/clray_types.h
    buffer: str  # its scene buffer: PackedScene's field, kernels/scene.h's parameter
    switch: str  # its KernelConfig field, -DHAS_... in the build
    # (objects, origins) -> the records (positions relative to each object's origin) and the
    # bounds of the stored float32 shape, so that they hold what the kernels intersect.
    pack: Callable[[list, np.ndarray], Packed]
    # (object, origins (N, 3), directions (N, 3)) -> its Crossings, in float64.
    intersect: Callable[[Any, np.ndarray, np.ndarray], Crossings]
    # (object, points (N, 3), part (N,)) -> (outward geometric normal, uv) at those points.
    surface: Callable[[Any, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    # Other model classes that pack into its array (a `spheres` array's spheres).
    also: tuple[type, ...] = ()
    # object -> how many records it packs into.
    primitives: Callable[[Any], int] = _one
    # object -> where its own proportions, not its distance, strain float32: its largest
    # length over the smallest its crossings must resolve, and the message that says so (a
    # near-flat cone's rim radius over its height); clray.scene.scale warns above RATIO_LIMIT.
    proportion: Callable[[Any], tuple[float, str]] | None = None
    # object -> the lengths it derives from its numbers, (what, value) (a cone's rim radius,
    # height x tan(angle)): each number within its limit, they can still carry the shape's
    # bounds past float32, so the loader holds them to the numbers' own limit, MAX_MAGNITUDE,
    # as parsed and as a transform leaves them.
    extents: Callable[[Any], tuple[tuple[str, float], ...]] = lambda obj: ()

    @property
    def struct(self) -> str:
        return self.model.__name__

    @property
    def prim_name(self) -> str:
        return f"PRIM_{self.struct.upper()}"

    @property
    def types(self) -> tuple[type, ...]:
        """The model classes that pack into its array."""
        return (self.model, *self.also)


# Placement by a transform.


def similarity_scale(a: np.ndarray) -> float | None:
    """s where A = s R with R orthogonal (within rounding), else None."""
    gram = a.T @ a
    s2 = np.trace(gram) / 3.0
    if not np.allclose(gram, s2 * np.eye(3), rtol=0, atol=1e-9 * s2):
        return None
    return float(np.sqrt(s2))


def uneven(kind: str) -> str:
    """Why a shape that only similarities keep is not kept."""
    return f"scales or shears unevenly, which a {kind} does not survive"


def moved_point(a: np.ndarray, t: np.ndarray, p: tuple) -> Vec3:
    x, y, z = (a @ np.asarray(p, dtype=np.float64) + t).tolist()
    return (x, y, z)


def moved_direction(a: np.ndarray, d: tuple) -> Vec3:
    x, y, z = unit(a @ np.asarray(d, dtype=np.float64)).tolist()
    return (x, y, z)


# Packing.


def f4(v: np.ndarray | tuple, w: float = 0.0) -> np.ndarray:
    """A float4 of the kernels: three coordinates and a scalar in w."""
    return np.array([*np.asarray(v, dtype=np.float64), w], dtype=np.float32)


def disc_extent(axis: np.ndarray, radius: float) -> np.ndarray:
    """Half-extent per world axis of a disc of this radius across unit `axis`."""
    return radius * np.sqrt(np.clip(1.0 - axis * axis, 0.0, 1.0))


def bounds_of(lo: list[np.ndarray], hi: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-record bounds gathered in a loop, as (n, 3) arrays even when there are none."""
    return np.array(lo).reshape(-1, 3), np.array(hi).reshape(-1, 3)


# Float64 crossings shared by the quadrics (the reference renderer's textbook formulas).


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


def disc_crossing(
    center: np.ndarray, normal: np.ndarray, radius: float, o: np.ndarray, d: np.ndarray
) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = dot(center - o, normal) / dot(d, normal)
        off = o + t[:, None] * d - center
        inside = dot(off, off) <= radius * radius
    return np.where(inside & ~np.isnan(t), t, np.inf)


def within_height(
    t: np.ndarray, o: np.ndarray, d: np.ndarray, start: np.ndarray, axis: np.ndarray, height: float
) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        h = dot(o + t[:, None] * d - start, axis)
    return np.where((h >= 0.0) & (h <= height), t, np.inf)
