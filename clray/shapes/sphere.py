"""Spheres (kernels/sphere.h): one in the scene file, or many as a `spheres` array
(clray.scene.parse_spheres reads those), both packed into one array of Sphere records.

Spheres are the one shape with more than its own header: the BVH's leaves keep them in SoA
packets too (clray.accel.wide, SpherePacket), and a sphere far from the eye for its size is
intersected in float64 (clray.scene.scale, KernelConfig.fp64_spheres)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from clray.shapes.shape import (
    Checks,
    Crossings,
    Packed,
    Shape,
    moved_point,
    quadratic_roots,
    similarity_scale,
    uneven,
)
from clray.vectors import Vec3, dot, safe_normalize, vec


@dataclass(frozen=True)
class Sphere:
    center: Vec3
    radius: float
    material: int


@dataclass(frozen=True, eq=False)
class Spheres:
    """Many spheres given as arrays (particles, molecules): one object in the scene, packed and
    intersected exactly as that many Sphere objects in this order would be."""

    centers: np.ndarray  # (N, 3) float64
    radii: np.ndarray  # (N,) float64, each > 0
    materials: np.ndarray  # (N,) int64 indices into Scene.materials


def parse(spec: dict, key: str, material: int, v: Checks) -> Sphere:
    radius = v.length(spec["radius"], f"{key}.radius")
    return Sphere(v.vec3(spec["center"], f"{key}.center"), radius, material)


def place(obj: Sphere | Spheres, a: np.ndarray, t: np.ndarray) -> Sphere | Spheres | str:
    s = similarity_scale(a)
    if s is None:
        return uneven("sphere")
    if isinstance(obj, Spheres):
        return replace(obj, centers=obj.centers @ a.T + t, radii=obj.radii * s)
    return replace(obj, center=moved_point(a, t, obj.center), radius=obj.radius * s)


def centre_size(obj: Sphere) -> tuple[np.ndarray, float]:
    return np.asarray(obj.center, dtype=np.float64), float(obj.radius)


RECORD = np.dtype([("center_radius", "<f4", (4,)), ("material", "<i4"), ("pad0", "<i4"),
                   ("pad1", "<i4"), ("pad2", "<i4")])


def pack(objects: list[Sphere | Spheres], origins: np.ndarray) -> Packed:
    """Sphere objects and `spheres` arrays, in scene order: one record per sphere."""
    blocks = [(o.centers, o.radii, o.materials) if isinstance(o, Spheres) else
              ([o.center], [o.radius], [o.material]) for o in objects]
    centers, radii, materials = (
        np.concatenate([np.asarray(b[k], dtype=dtype).reshape(shape) for b in blocks])
        if blocks else np.zeros((0, *shape[1:]), dtype=dtype)
        for k, dtype, shape in ((0, np.float64, (-1, 3)), (1, np.float64, (-1,)),
                                (2, np.int32, (-1,))))
    sizes = [len(b[1]) for b in blocks]
    spheres = np.zeros(len(centers), dtype=RECORD)
    spheres["center_radius"][:, :3] = centers - np.repeat(origins, sizes, axis=0)
    spheres["center_radius"][:, 3] = radii
    spheres["material"] = materials
    cr = spheres["center_radius"].astype(np.float64)
    return spheres, cr[:, :3] - cr[:, 3:], cr[:, :3] + cr[:, 3:]


def intersect_sphere(s: Sphere, o: np.ndarray, d: np.ndarray) -> Crossings:
    oc = o - vec(s.center)
    t0, t1 = quadratic_roots(dot(d, d), 2.0 * dot(oc, d), dot(oc, oc) - s.radius**2)
    zero = np.zeros(len(o), dtype=np.int64)
    return [(t0, zero), (t1, zero)]


def sphere_surface(s: Sphere, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = (p - vec(s.center)) / s.radius
    u = 0.5 + np.arctan2(q[:, 0], q[:, 2]) / (2.0 * np.pi)
    v = 0.5 + np.arcsin(np.clip(q[:, 1], -1.0, 1.0)) / np.pi
    return safe_normalize(q), np.stack([u, v], axis=-1)


SPHERE = Shape(
    kind="sphere", model=Sphere, keys=(("center", "radius"), ()),
    lengths=("radius", "radii"), parse=parse, place=place,
    centre_size=centre_size, prim=1, record=RECORD, buffer="spheres", switch="has_spheres",
    pack=pack, intersect=intersect_sphere, surface=sphere_surface, also=(Spheres,),
    primitives=lambda obj: len(obj.radii) if isinstance(obj, Spheres) else 1,
)
