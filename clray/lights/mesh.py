"""Mesh lights: the emissive faces of one material in one mesh, sampled as one light
(clray.scene.emitters makes them where the faces are many). Each pixel sample's shadow ray picks
one face, with probability its share of the faces' area, and a point uniform on it, so that the
mesh costs one shadow ray, not one a face; the estimate's mean is the faces' sum (docs/
rendering.md, Lights: Mesh lights). No scene file names them.

On the device a mesh light's record holds the radiance and, in pad0 and pad1, where its faces'
records start and how many there are: triangle lights packed after the scene's lights, each
with its pick threshold in pad0 (`thresholds`; kernels/lights.h, mesh_face).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from clray.lights.light import AREA_WEIGHT_MAX, LightKind, Square, Toward, area_sample
from clray.lights.rect import rect_area
from clray.lights.triangle import TRIANGLE, triangle_point
from clray.shapes.shape import f4
from clray.vectors import Vec3

# Picks are uint32 (kernels/sampling.h, light_pick): face k's share of them is its width.
PICKS = 2**32


@dataclass(frozen=True, eq=False)
class MeshLight:
    """Emissive faces of one radiance, each one-sided (to the side of cross(v1 - v0, v2 - v0)),
    sampled as one light. `corners` (K, 3, 3) float64 in world units, K >= 2, as the faces'
    TriangleLights have them; made by the loader, never given in a scene file."""

    corners: np.ndarray
    color: Vec3 = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        corners = np.array(self.corners, dtype=np.float64).reshape(-1, 3, 3)
        corners.setflags(write=False)
        object.__setattr__(self, "corners", corners)
        # The loader gives it emissive_lights' faces, each of area >= 1e-30, more than 16.
        if len(corners) < 2 or not np.sum(self.areas) > 0.0:
            raise ValueError("a mesh light needs two or more faces of some area")

    @cached_property
    def areas(self) -> np.ndarray:
        """(K,) the faces' areas (clray.lights.rect.rect_area, which scales the edges so that no
        product underflows or overflows)."""
        c = self.corners
        return rect_area(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]) / 2.0

    @cached_property
    def thresholds(self) -> np.ndarray:
        """(K,) uint64: a pick (a uint32) takes the first face whose threshold is above it, the
        thresholds being the faces' cumulative share of the area in units of 2^-32, the last
        2^32. A face whose share rounds to nothing is never picked."""
        areas = self.areas
        share = np.cumsum(areas) / float(np.sum(areas))
        out = np.minimum(np.floor(share * PICKS), PICKS - 1).astype(np.uint64)
        out[-1] = PICKS
        return out


def fields(rec: np.void, light: MeshLight, eye: np.ndarray) -> None:
    # pad0 and pad1, where its faces' records are (kernels/clray_types.h), are the packer's.
    rec["color"] = f4(light.color, float(np.sum(light.areas)))


def part_fields(records: np.ndarray, light: MeshLight, eye: np.ndarray) -> None:
    """Its faces' records, as triangle lights' (clray/lights/triangle.py, in bulk), with each
    face's pick threshold as a uint32 in pad0 (the last's 2^32 as 0, which kernels/lights.h's
    mesh_face never compares a pick with)."""
    c = light.corners
    records["kind"] = TRIANGLE.code
    records["position"][:, :3] = c[:, 0] - eye
    records["axis_u"][:, :3], records["axis_v"][:, :3] = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    records["color"] = np.append(light.color, 0.0)
    records["color"][:, 3] = light.areas
    records["pad0"] = (light.thresholds % PICKS).astype(np.uint32).view(np.int32)


def face_picked(light: MeshLight, pick: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(face index, 2^32 over the face's width) for each uint32 pick, as kernels/lights.h's
    mesh_face: the first face whose threshold is above the pick."""
    thresholds = light.thresholds
    face = np.searchsorted(thresholds, np.asarray(pick, dtype=np.uint64), side="right")
    below = np.where(face > 0, thresholds[np.maximum(face - 1, 0)], 0)
    return face, PICKS / (thresholds[face] - below).astype(np.float64)


def toward(light: MeshLight, p: np.ndarray, err: np.ndarray, square: Square,
           pick: np.ndarray) -> Toward:
    face, pick_weight = face_picked(light, pick)
    v0, v1, v2 = (light.corners[face, i] for i in range(3))
    u, v = v1 - v0, v2 - v0
    normal = np.cross(u, v)
    sample = area_sample(triangle_point(v0, u, v, square),
                         normal / np.linalg.norm(normal, axis=1)[:, None], light.areas[face],
                         p, err)
    # The face's weight over the pick's probability, clamped again as the kernels do.
    return sample._replace(atten=np.minimum(sample.atten * pick_weight, AREA_WEIGHT_MAX))


MESH = LightKind(kind="mesh", model=MeshLight, keys=((), ()), parse=None, code=7,
                 fields=fields, toward=toward, area=True, switch="has_mesh_lights",
                 parts=lambda light: len(light.corners), part_fields=part_fields)
