"""Surfaces and direct light of the oracle (kernels/surface.h, the shapes' headers and
direct.h): each shape's outward normal and (u, v) at a hit (the analytic shapes' from their
modules, clray.shapes), the surface record of a hit, the offset that starts a spawned ray off
it, and shade_direct, the ambient, diffuse and specular light that reaches it from every light."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from clray.lights import LIGHT_OF
from clray.lights.light import Toward
from clray.reference.sampling import SampleKey, light_pick, light_square
from clray.reference.texture import MaterialTable
from clray.scene.model import Light, Plane
from clray.shapes import SHAPES
from clray.vectors import dot, frame, vec

# Shadow rays towards a light at a place end this fraction of their length short of it
# (docs/rendering.md): 16 float32 roundings, the kernels' gamma_f32(ERR_ROUNDINGS) (kernels/
# lights.h, real.h), pbrt's bound n u / (1 - n u) with n = 16 and u = 2^-24, in both builds.
# The reference reads the float64 scene, not the float32 records the kernels do, so its light
# lies on its plane to float64 roundings, far inside this margin; a blocker between the light
# and the margin's end (a surface a few float32 roundings short of the light) is counted, or
# not, exactly as the kernels count it.
_ERR_ROUNDINGS = 16
_U_F32 = np.finfo(np.float32).eps / 2.0
SHADOW_MARGIN = _ERR_ROUNDINGS * _U_F32 / (1.0 - _ERR_ROUNDINGS * _U_F32)

# (origins, directions, tmax, filters) -> (N, 3): the filter of every crossing before tmax.
Transmission = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _plane_surface(pl: Plane, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = vec(pl.normal)
    e1, e2 = frame(n)
    q = p - vec(pl.point)
    return np.broadcast_to(n, p.shape).copy(), np.stack([q @ e1, q @ e2], axis=-1)


# A shape's (outward geometric normal, uv) at points p on it, `part` the face its crossing hit.
# The analytic shapes' are in their modules (clray.shapes).
SHAPE_SURFACE: dict[type, Callable[..., tuple[np.ndarray, np.ndarray]]] = {
    Plane: _plane_surface, **{shape.model: shape.surface for shape in SHAPES}}


class Surface(NamedTuple):
    """What shading needs of N hits: n_g and n face the incoming ray (n_g is the kernels'
    n_f; flipped where d . n >= 0, so a tangent ray's is the flipped one), n_out is n_g as the
    shape gives it (outward), whose side offset_origin goes by, as the kernels' does."""

    p: np.ndarray  # (N, 3) hit point
    err: np.ndarray  # (N,) how far p may be off the surface
    n_g: np.ndarray  # (N, 3) geometric normal, facing the ray
    n_out: np.ndarray  # (N, 3) geometric normal, outward (as given): offset_origin's
    n: np.ndarray  # (N, 3) shading normal, facing the ray
    entering: np.ndarray  # (N,) the ray arrives on the outward side
    uv: np.ndarray  # (N, 2)
    material: np.ndarray  # (N,)


def surface_at(o: np.ndarray, d: np.ndarray, t: np.ndarray, normal: np.ndarray,
               shading_normal: np.ndarray, uv: np.ndarray, material: np.ndarray) -> Surface:
    """The surface record of rays (o, d) that hit at t with these outward normals."""
    p = o + t[:, None] * d
    # Both normals face the incoming ray, each by its own sign, as kernels/shading.h
    # (shade_point) has it: kept where d . n < 0, else flipped, so a ray exactly along the
    # surface (d . n = 0) sees the flipped normal, the one of a ray that is not entering.
    entering = dot(d, normal) < 0.0
    n_g = np.where(entering[:, None], normal, -normal)
    n = np.where((dot(d, shading_normal) < 0.0)[:, None], shading_normal, -shading_normal)
    return Surface(p, _error_bound(o, d, t), n_g, normal, n, entering, uv, material)


def _error_bound(o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    """How far a float64 hit point p = o + t d may be off its surface: 1e-10 of the
    magnitudes that make it, |o| + |t d| in the largest coordinate, about 1e6 float64
    roundings of them. Relative only, so that it shrinks with the scene (an absolute floor
    outgrows a scene 1e-10 across and offsets every shadow ray past its light), and of those
    magnitudes rather than |p|, which vanishes at a hit near the origin however far the ray
    came: an offset of 1e-10 |p| there leaves p on the wrong side of its surface."""
    return 1e-10 * np.max(np.abs(o) + np.abs(t[:, None] * d), axis=-1)


def offset_origin(p: np.ndarray, n_out: np.ndarray, w: np.ndarray,
                  err: np.ndarray) -> np.ndarray:
    """Move p off the surface along the outward geometric normal n_out, to the side w leaves
    on: outwards where w . n_out > 0, else inwards, as kernels/surface.h has it (so a w along
    the surface, w . n_out = 0, starts inside, whichever side the ray came from)."""
    side = np.where(dot(w, n_out) > 0.0, 1.0, -1.0)
    return p + (side * err)[:, None] * n_out


def shade_direct(sf: Surface, d: np.ndarray, c: np.ndarray, mats: MaterialTable,
                 lights: tuple[Light, ...], ambient_light: np.ndarray, key: SampleKey,
                 transmission: Transmission) -> np.ndarray:
    """(N, 3): ambient plus, for each light on the lit side, diffuse and specular times the
    light that reaches p through the shadow ray; `d` the incoming rays, `c` the surface
    colour, `key` each ray's sample (which picks area lights' samples)."""
    m, n = sf.material, sf.n
    result = mats.ambient[m, None] * c * ambient_light + mats.emission[m]
    for index, light in enumerate(lights):
        target, l_dir, atten, usable = _light_toward(light, index, sf, key)
        ndotl = dot(n, l_dir)
        lit = usable & (ndotl > 0.0)
        if not lit.any():
            continue
        shadow = np.zeros((len(sf.p), 3))
        shadow[lit] = _shadow_filter(sf, lit, l_dir, target, mats, transmission)
        r = 2.0 * ndotl[:, None] * n - l_dir
        rv = dot(r, -d)
        spec = np.zeros(len(sf.p))
        pos = rv > 0.0
        spec[pos] = rv[pos] ** mats.shininess[m[pos]]
        term = mats.diffuse[m, None] * c * ndotl[:, None] + (mats.specular[m] * spec)[:, None]
        result += np.where(lit[:, None], atten[:, None] * vec(light.color) * shadow * term, 0.0)
    return result


def _light_toward(light: Light, index: int, sf: Surface, key: SampleKey) -> Toward:
    """What light number `index` brings to the surface points (clray.lights.light.Toward);
    area lights sample the pixel sample's point of the unit square picked for them."""
    kind = LIGHT_OF[type(light)]
    square = (light_square(key.seed, key.pixel, key.sample, key.spp, index) if kind.area
              else None)
    if kind.parts is not None:  # a sample picks one of its parts (a mesh light's faces)
        return kind.toward(light, sf.p, sf.err, square,
                           light_pick(key.seed, key.pixel, key.sample, key.spp, index))
    return kind.toward(light, sf.p, sf.err, square)


def _shadow_filter(sf: Surface, lit: np.ndarray, l_dir: np.ndarray, target: np.ndarray | None,
                   mats: MaterialTable, transmission: Transmission) -> np.ndarray:
    """The filter of the shadow rays of the `lit` hits, from their offset origins."""
    origin = offset_origin(sf.p[lit], sf.n_out[lit], l_dir[lit], sf.err[lit])
    shadow_dir, span = l_dir[lit], np.full(int(lit.sum()), np.inf)
    if target is not None:
        # Aimed from the offset origin, as the kernels do (docs/rendering.md).
        to_light = target[lit] - origin
        span = np.linalg.norm(to_light, axis=-1)
        shadow_dir = np.where((span > 0.0)[:, None],
                              to_light / np.where(span > 0.0, span, 1.0)[:, None],
                              shadow_dir)
        # Short of the light, so that a surface it lies on (a point or rect light set into
        # a ceiling, an emissive face at its own sample) does not shadow it: that surface's
        # computed crossing lands a rounding before or after the light.
        span = span * (1.0 - SHADOW_MARGIN)
    return transmission(origin, shadow_dir, span, mats.filter)
