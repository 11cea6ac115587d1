"""Lights of the oracle (kernels/lights.h): the spot cone, and the samples of area lights."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clray.scene.model import DiscLight, RectLight, SphereLight, SpotLight, TriangleLight
from clray.vectors import frame, safe_normalize, vec

# An area light sample's weight is clamped here, as in the kernels (kernels/lights.h).
AREA_WEIGHT_MAX = 1e20


class SampleKey(NamedTuple):
    """What picks each ray's area light samples: the image seed, and the ray's pixel and
    sample (arrays, one per ray) of spp."""

    seed: int
    pixel: np.ndarray
    sample: np.ndarray
    spp: int


def spot_factor(light: SpotLight, l_dir: np.ndarray) -> np.ndarray:
    """1 inside the inner cone, 0 outside the outer, smoothstep in cos between."""
    inner = light.angle if light.inner_angle is None else light.inner_angle
    cos_o, cos_i = math.cos(math.radians(light.angle)), math.cos(math.radians(inner))
    cos_t = -(l_dir @ vec(light.direction))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((cos_t - cos_o) / (cos_i - cos_o), 0.0, 1.0)
    return np.where(cos_t <= cos_o, 0.0, np.where(cos_t >= cos_i, 1.0, t * t * (3.0 - 2.0 * t)))


def concentric_disc(u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley and Chiu's area-preserving map of the unit square onto the unit disc."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    wide = np.abs(a) > np.abs(b)
    r = np.where(wide, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(wide, np.pi / 4 * (b / a), np.pi / 2 - np.pi / 4 * (a / b))
    phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def sample_area_light(
    light: RectLight | DiscLight | SphereLight | TriangleLight,
    p: np.ndarray,
    eps: np.ndarray,
    u1: np.ndarray,
    u2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(target point on the light, weight, usable) of docs/rendering.md (Area lights): weight
    times the light's radiance estimates the irradiance on a surface facing the sample."""
    if isinstance(light, SphereLight):
        return _sample_sphere_light(light, p, u1, u2)
    if isinstance(light, RectLight):
        u, v = vec(light.u), vec(light.v)
        y = vec(light.corner) + u1[:, None] * u + u2[:, None] * v
        normal = np.cross(u, v)
        area = float(np.linalg.norm(normal))
        normal = normal / area
    elif isinstance(light, TriangleLight):
        v0, v1, v2 = (vec(v) for v in light.vertices)
        u, v = v1 - v0, v2 - v0
        # The square's far half folded onto its near one, as the kernels do.
        far = u1 + u2 > 1.0
        u1, u2 = np.where(far, 1.0 - u1, u1), np.where(far, 1.0 - u2, u2)
        y = v0 + u1[:, None] * u + u2[:, None] * v
        normal = np.cross(u, v)
        area = float(np.linalg.norm(normal)) / 2.0
        normal = normal / (2.0 * area)
    else:
        normal = vec(light.normal)
        e1, e2 = frame(normal)
        a, b = concentric_disc(u1, u2)
        y = vec(light.center) + light.radius * (a[:, None] * e1 + b[:, None] * e2)
        area = np.pi * light.radius**2
    to_y = y - p
    dist = np.linalg.norm(to_y, axis=-1)
    safe = np.where(dist > 0.0, dist, 1.0)
    cos_l = -(to_y @ normal) / safe
    usable = (dist > eps) & (cos_l > 0.0)  # one-sided: the back emits nothing
    weight = np.minimum(area * cos_l / (safe * safe), AREA_WEIGHT_MAX)
    return y, weight, usable


def _sample_sphere_light(light: SphereLight, p: np.ndarray, u1: np.ndarray, u2: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A direction uniform in the cone the sphere subtends from p, and its nearer point."""
    to_c = vec(light.center) - p
    dist = np.linalg.norm(to_c, axis=-1)
    usable = dist > light.radius
    safe = np.where(usable, dist, 2.0 * light.radius)
    s = light.radius / safe
    k = 1.0 - np.sqrt(1.0 - s * s)
    one_minus_cos = u1 * k
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * np.pi * u2
    w_c = to_c / safe[:, None]
    h = np.where((np.abs(w_c[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = safe_normalize(np.cross(w_c, h))
    e2 = np.cross(w_c, e1)
    w = (cos_t[:, None] * w_c
         + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
    # The nearer of the two crossings of the sphere along w.
    t = safe * cos_t - np.sqrt(np.maximum(0.0, light.radius**2 - (safe * sin_t) ** 2))
    return p + t[:, None] * w, 2.0 * np.pi * k, usable
