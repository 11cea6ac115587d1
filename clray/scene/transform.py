"""Objects placed by an affine transform, applied on the host in float64 where that is exact.

A transform x -> A x + t maps a triangle to a triangle and a plane to a plane whatever A is.
Each shape of clray.shapes says which transforms it survives (a sphere, cylinder, cone or torus
only similarities, A = s R with R orthogonal; an axis-aligned box only those that map axes onto
axes) and places itself. Other transforms of those are intersected in the object's own frame
instead (the loader makes it an instance); `place` says why it cannot.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clray.scene import model as M
from clray.shapes import SHAPE_OF
from clray.shapes.shape import moved_point
from clray.vectors import unit


def rotation_matrix(degrees: tuple[float, float, float]) -> np.ndarray:
    """R = Rz Ry Rx for rotations about x, then y, then z (right-handed, degrees)."""
    rx, ry, rz = np.radians(degrees)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def object_bounds(obj: M.SceneObject) -> tuple[np.ndarray, np.ndarray]:
    """The float64 (lo, hi) box of a bounded object (no plane, no instance), in its own
    coordinates: what an instance's transform maps to the box the scene's BVH takes."""
    if isinstance(obj, M.Spheres):
        # The largest radius around every centre: a box a little larger than the union, in
        # reductions rather than (N, 3) temporaries the size of millions of spheres.
        r = float(obj.radii.max(initial=0.0))
        return obj.centers.min(axis=0) - r, obj.centers.max(axis=0) + r
    if isinstance(obj, M.Mesh | M.Triangle):
        vertices = np.asarray(obj.vertices).reshape(-1, 3)
        return (vertices.min(axis=0).astype(np.float64),
                vertices.max(axis=0).astype(np.float64))
    shape = SHAPE_OF.get(type(obj))
    if shape is None:
        raise TypeError(f"no bounds for {type(obj).__name__}")
    _, lo, hi = shape.pack([obj], np.zeros((1, 3)))
    return lo.min(axis=0), hi.max(axis=0)


def placed_magnitude(lo: np.ndarray, hi: np.ndarray, a: np.ndarray, t: np.ndarray) -> float:
    """The largest coordinate magnitude of the box (lo, hi) moved by x -> a x + t: its eight
    corners, as clray.device.pack bounds an instance."""
    pick = ((np.arange(8)[:, None] >> np.arange(3)) & 1).astype(bool)
    corners = np.where(pick, hi, lo) @ a.T + t
    return float(np.abs(corners).max())


def place(obj: M.SceneObject, a: np.ndarray, t: np.ndarray) -> M.SceneObject | str:
    """`obj` moved by x -> a x + t, or why that cannot be done exactly."""
    if isinstance(obj, M.Triangle):
        p0, p1, p2 = (moved_point(a, t, p) for p in obj.vertices)
        # A mirroring transform turns the winding: swap two corners to keep the outward side.
        return dataclasses.replace(obj, vertices=(p0, p2, p1) if np.linalg.det(a) < 0 else
                                   (p0, p1, p2))
    if isinstance(obj, M.Plane):
        # Normals follow the inverse transpose, which keeps them perpendicular to the plane.
        x, y, z = unit(np.linalg.inv(a).T @ np.asarray(obj.normal)).tolist()
        return dataclasses.replace(obj, point=moved_point(a, t, obj.point), normal=(x, y, z))
    shape = SHAPE_OF.get(type(obj))
    if shape is None:
        raise TypeError(f"no placement for {type(obj).__name__}")
    return shape.place(obj, a, t)
