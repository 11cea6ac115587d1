"""Objects placed by an affine transform, applied on the host in float64 where that is exact.

A transform x -> A x + t maps a triangle to a triangle and a plane to a plane whatever A is. A
sphere, cylinder, cone or torus stays one only under a similarity (A = s R, R orthogonal:
rotation, uniform scale, mirroring), and an axis-aligned box stays one only when A maps axes
onto axes (a signed permutation times a diagonal scale). Other transforms of those are
intersected in the object's own frame instead (the loader makes it an instance); `place` says
why it cannot.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clray.scene import model as M
from clray.scene.model import unit

# Below this, relative to the largest entry, a matrix entry is rounding noise: cos(90 degrees)
# is 6e-17, not 0, and must not make a quarter-turned box "off the axes".
_NOISE = 1e-12


def rotation_matrix(degrees: tuple[float, float, float]) -> np.ndarray:
    """R = Rz Ry Rx for rotations about x, then y, then z (right-handed, degrees)."""
    rx, ry, rz = np.radians(degrees)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def _clean(a: np.ndarray) -> np.ndarray:
    return np.where(np.abs(a) <= _NOISE * np.max(np.abs(a)), 0.0, a)


def similarity_scale(a: np.ndarray) -> float | None:
    """s where A = s R with R orthogonal (within rounding), else None."""
    gram = a.T @ a
    s2 = np.trace(gram) / 3.0
    if not np.allclose(gram, s2 * np.eye(3), rtol=0, atol=1e-9 * s2):
        return None
    return float(np.sqrt(s2))


def _point(a: np.ndarray, t: np.ndarray, p: tuple) -> tuple[float, float, float]:
    x, y, z = (a @ np.asarray(p, dtype=np.float64) + t).tolist()
    return (x, y, z)


def _direction(a: np.ndarray, d: tuple) -> tuple[float, float, float]:
    x, y, z = unit(a @ np.asarray(d, dtype=np.float64)).tolist()
    return (x, y, z)


def place(obj: M.SceneObject, a: np.ndarray, t: np.ndarray) -> M.SceneObject | str:
    """`obj` moved by x -> a x + t, or why that cannot be done exactly."""
    if isinstance(obj, M.Triangle):
        p0, p1, p2 = (_point(a, t, p) for p in obj.vertices)
        # A mirroring transform turns the winding: swap two corners to keep the outward side.
        return dataclasses.replace(obj, vertices=(p0, p2, p1) if np.linalg.det(a) < 0 else
                                   (p0, p1, p2))
    if isinstance(obj, M.Plane):
        # Normals follow the inverse transpose, which keeps them perpendicular to the plane.
        x, y, z = unit(np.linalg.inv(a).T @ np.asarray(obj.normal)).tolist()
        return dataclasses.replace(obj, point=_point(a, t, obj.point), normal=(x, y, z))
    if isinstance(obj, M.Box):
        clean = _clean(a)
        if np.count_nonzero(clean, axis=0).max() != 1:
            return "rotates the box off the axes (only quarter turns keep a box axis-aligned)"
        corners = np.array([obj.min, obj.max], dtype=np.float64) @ clean.T + t
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        return dataclasses.replace(obj, min=tuple(lo.tolist()), max=tuple(hi.tolist()))
    s = similarity_scale(a)
    if s is None:
        return ("scales or shears unevenly, which a sphere, cylinder, cone or torus does not "
                "survive")
    if isinstance(obj, M.Sphere):
        return dataclasses.replace(obj, center=_point(a, t, obj.center), radius=obj.radius * s)
    if isinstance(obj, M.Cylinder):
        return dataclasses.replace(obj, base=_point(a, t, obj.base),
                                   axis=_direction(a, obj.axis), radius=obj.radius * s,
                                   height=obj.height * s)
    if isinstance(obj, M.Cone):
        return dataclasses.replace(obj, apex=_point(a, t, obj.apex),
                                   axis=_direction(a, obj.axis), height=obj.height * s)
    if isinstance(obj, M.Torus):
        return dataclasses.replace(obj, center=_point(a, t, obj.center),
                                   axis=_direction(a, obj.axis), major_radius=obj.major_radius * s,
                                   minor_radius=obj.minor_radius * s)
    if isinstance(obj, M.Spheres):
        return dataclasses.replace(obj, centers=obj.centers @ a.T + t, radii=obj.radii * s)
    raise TypeError(f"no placement for {type(obj).__name__}")
