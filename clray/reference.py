"""An independent float64 numpy renderer: the test oracle for the OpenCL kernels.

It implements docs/rendering.md literally and shares no code with the kernels or the packer:
every ray is intersected with every primitive by brute force, and the ray tree is walked as a
wavefront (all live rays of one generation in arrays, their reflected and refracted children
forming the next generation). Slow, but each formula can be checked against the page by eye.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from clray.scene.model import (
    Background,
    Box,
    Camera,
    Cone,
    Cylinder,
    DirectionalLight,
    DiscLight,
    Instance,
    Material,
    Mesh,
    Plane,
    PointLight,
    RectLight,
    Scene,
    SceneObject,
    Sphere,
    SphereLight,
    Spheres,
    SpotLight,
    Texture,
    Triangle,
)

MAX_MEDIA = 4  # nesting depth of the media stack a ray carries
# Ties in t go to the earlier type in this order, then to the earlier object in the scene.
# Triangles (loose and mesh) come last and are intersected as one batch.
TIE_ORDER: tuple[type, ...] = (Plane, Sphere, Box, Cylinder, Cone)
# Rays x triangles handled per numpy step: bounds memory to a few tens of MB.
_TRIANGLE_BATCH = 1 << 17
# Crossings whose t differ by at most this, relative to t, tie (docs/rendering.md): 64 roundings,
# gamma(64) in float64 as the kernels' double build has it.
TIE_TOLERANCE = 64 * (np.finfo(np.float64).eps / 2) / (1 - 64 * np.finfo(np.float64).eps / 2)


# ---------------------------------------------------------------------------------------------
# Samples and camera rays


def pcg_hash(x: np.ndarray | int) -> np.ndarray:
    """The PCG output hash of docs/rendering.md in wrapping uint32 arithmetic."""
    state = np.asarray(x).astype(np.uint32)
    with np.errstate(over="ignore"):
        state = state * np.uint32(747796405) + np.uint32(2891336453)
        word = ((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * np.uint32(277803737)
    return (word >> np.uint32(22)) ^ word


def sample_uniform(seed: int, pixel: np.ndarray, sample: np.ndarray, dim: int) -> np.ndarray:
    """r_dim of docs/rendering.md: 24 random bits of the key, in [0, 1)."""
    seed_hash = pcg_hash(np.uint32(seed & 0xFFFFFFFF))
    pixel = np.asarray(pixel).astype(np.uint32)
    sample = np.asarray(sample).astype(np.uint32)
    with np.errstate(over="ignore"):
        counter = np.uint32(4) * sample + np.uint32(dim)
    key = pcg_hash(pcg_hash(seed_hash ^ pixel) ^ counter)
    return (key >> np.uint32(8)).astype(np.float64) * 2.0**-24


def sample_grid(spp: int) -> tuple[int, int]:
    """(nx, ny): nx = ceil(sqrt(spp)) computed in integers, ny = ceil(spp / nx)."""
    nx = math.isqrt(spp)
    if nx * nx < spp:
        nx += 1
    return nx, -(-spp // nx)


def light_square(
    seed: int, pixel: np.ndarray, sample: np.ndarray, spp: int, light: int
) -> tuple[np.ndarray, np.ndarray]:
    """(u1, u2) in the unit square: light `light`'s stratified sample for each (pixel,
    sample) of docs/rendering.md (Area lights)."""
    pixel = np.asarray(pixel).astype(np.uint32)
    sample = np.asarray(sample).astype(np.int64)
    key = pcg_hash(pcg_hash(pcg_hash(np.uint32(seed & 0xFFFFFFFF)) ^ pixel)
                   ^ np.uint32(0x80000000 | light))
    stratum = (sample + (key % np.uint32(spp)).astype(np.int64)) % spp
    nx, _ = sample_grid(spp)
    row, col = stratum // nx, stratum % nx
    cells = np.minimum(nx, spp - row * nx)

    def uniform(dim: int) -> np.ndarray:
        counter = (2 * sample + dim).astype(np.uint32)
        return (pcg_hash(key ^ counter) >> np.uint32(8)).astype(np.float64) * 2.0**-24

    return (col + uniform(0)) / cells, (row * nx + uniform(1) * cells) / spp


def sample_positions(
    width: int, height: int, spp: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sx, sy, pixel) for every sample, pixel-major (all samples of pixel 0 first), in pixel
    units with y = 0 at the top row; pixel = y * width + x."""
    pixel = np.repeat(np.arange(width * height, dtype=np.int64), spp)
    sample = np.tile(np.arange(spp, dtype=np.int64), width * height)
    x = (pixel % width).astype(np.float64)
    y = (pixel // width).astype(np.float64)
    if spp == 1:
        return x + 0.5, y + 0.5, pixel
    nx, ny = sample_grid(spp)
    r0 = sample_uniform(seed, pixel, sample, 0)
    r1 = sample_uniform(seed, pixel, sample, 1)
    sx = x + ((sample % nx) + r0) / nx
    sy = y + ((sample // nx) + r1) / ny
    return sx, sy, pixel


def camera_rays(
    scene: Scene,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    seed: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origins (N, 3), unit directions (N, 3), pixel (N,)) of every sample, ordered as
    `sample_positions`; None takes the scene's setting."""
    width, height, spp, _, seed = _settings(scene, width, height, spp, None, seed)
    sx, sy, pixel = sample_positions(width, height, spp, seed)
    camera = scene.camera
    forward, right, up, half_w, half_h = _camera_basis(camera, width, height)
    px = 2.0 * sx / width - 1.0
    py = 1.0 - 2.0 * sy / height
    across = (px * half_w)[:, None] * right + (py * half_h)[:, None] * up
    eye = np.asarray(camera.position, dtype=np.float64)
    if camera.type == "orthographic":
        origins = eye + across
        aim = np.broadcast_to(forward, across.shape)
    else:
        origins = np.broadcast_to(eye, across.shape).copy()
        aim = forward + across
    # aim: from the ray's origin to its point on the focus plane, per unit of focus distance.
    if camera.aperture > 0.0:
        sample = np.tile(np.arange(spp, dtype=np.int64), width * height)
        lens = lens_offsets(camera.aperture / 2.0, spp, seed, pixel, sample)
        lens = lens[:, :1] * right + lens[:, 1:] * up
        focus = _focus_distance(camera)
        return origins + lens, _normalize(aim - lens / focus), pixel
    return origins, _normalize(aim), pixel


def lens_offsets(radius: float, spp: int, seed: int, pixel: np.ndarray, sample: np.ndarray
                 ) -> np.ndarray:
    """(N, 2): each sample's point on the lens disc of `radius`, in (right, up) coordinates
    (docs/rendering.md, Depth of field)."""
    # The pixel's shift of the angular strata: r_2 of the sample index spp, which no sample uses.
    shift_bits = (sample_uniform(seed, pixel, np.full_like(sample, spp), 2)
                  * 2.0**24).astype(np.int64)
    shift = (shift_bits * spp) >> 24
    stratum = (sample + shift) % spp
    angle = 2.0 * np.pi * (stratum + sample_uniform(seed, pixel, sample, 2)) / spp
    rho = radius * np.sqrt(sample_uniform(seed, pixel, sample, 3))
    return np.stack([rho * np.cos(angle), rho * np.sin(angle)], axis=-1)


def _focus_distance(camera: Camera) -> float:
    if camera.focus_distance is not None:
        return camera.focus_distance
    return float(np.linalg.norm(np.subtract(camera.look_at, camera.position)))


def _camera_basis(camera: Camera, width: int, height: int) -> tuple[np.ndarray, ...]:
    """(forward, right, up', half_w, half_h) of docs/rendering.md, computed here rather than
    taken from the model's Camera.basis: the kernels' camera comes from the model, and an
    oracle sharing that code could not notice a mistake in it."""
    eye = np.asarray(camera.position, dtype=np.float64)
    forward = _normalize(np.asarray(camera.look_at, dtype=np.float64) - eye)
    right = _normalize(np.cross(forward, np.asarray(camera.up, dtype=np.float64)))
    up = np.cross(right, forward)
    if camera.type == "orthographic":
        if camera.width is not None:
            return forward, right, up, camera.width / 2.0, camera.width / 2.0 * height / width
        return forward, right, up, camera.height / 2.0 * width / height, camera.height / 2.0
    if camera.hfov is not None:
        half_w = math.tan(math.radians(camera.hfov) / 2.0)
        return forward, right, up, half_w, half_w * height / width
    half_h = math.tan(math.radians(camera.vfov) / 2.0)
    return forward, right, up, half_h * width / height, half_h


def _settings(
    scene: Scene,
    width: int | None,
    height: int | None,
    spp: int | None,
    max_depth: int | None,
    seed: int | None,
) -> tuple[int, int, int, int, int]:
    r = scene.render
    return (
        r.width if width is None else width,
        r.height if height is None else height,
        r.spp if spp is None else spp,
        r.max_depth if max_depth is None else max_depth,
        r.seed if seed is None else seed,
    )


# ---------------------------------------------------------------------------------------------
# Vector helpers


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _normalize(v: np.ndarray) -> np.ndarray:
    # A zero vector (a ray through a cone's apex) stays zero rather than becoming NaN.
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(length > 0.0, length, 1.0)


def _vec(v: tuple[float, float, float]) -> np.ndarray:
    return np.asarray(v, dtype=np.float64)


def frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """frame(a) of docs/rendering.md: two unit vectors completing the unit vector a."""
    h = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _normalize(np.cross(a, h))
    return e1, np.cross(a, e1)


def _solve_quadratic(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


# ---------------------------------------------------------------------------------------------
# Primitives. `_crossings` gives every place the ray's line crosses the surface as (t, part)
# pairs, t = inf where there is none (t may be negative: callers keep t > 0). `part` tells the
# surface function which face was hit. `_surface` gives the outward geometric normal and (u, v).

Crossings = list[tuple[np.ndarray, np.ndarray]]


def _sphere_crossings(s: Sphere, o: np.ndarray, d: np.ndarray) -> Crossings:
    oc = o - _vec(s.center)
    t0, t1 = _solve_quadratic(_dot(d, d), 2.0 * _dot(oc, d), _dot(oc, oc) - s.radius**2)
    zero = np.zeros(len(o), dtype=np.int64)
    return [(t0, zero), (t1, zero)]


def _sphere_surface(s: Sphere, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = (p - _vec(s.center)) / s.radius
    u = 0.5 + np.arctan2(q[:, 0], q[:, 2]) / (2.0 * np.pi)
    v = 0.5 + np.arcsin(np.clip(q[:, 1], -1.0, 1.0)) / np.pi
    return _normalize(q), np.stack([u, v], axis=-1)


def _plane_crossings(pl: Plane, o: np.ndarray, d: np.ndarray) -> Crossings:
    n = _vec(pl.normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _dot(_vec(pl.point) - o, n) / _dot(d, n)
    return [(np.where(np.isnan(t), np.inf, t), np.zeros(len(o), dtype=np.int64))]


def _plane_surface(pl: Plane, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = _vec(pl.normal)
    e1, e2 = frame(n)
    q = p - _vec(pl.point)
    return np.broadcast_to(n, p.shape).copy(), np.stack([q @ e1, q @ e2], axis=-1)


def _box_crossings(b: Box, o: np.ndarray, d: np.ndarray) -> Crossings:
    lo, hi = _vec(b.min), _vec(b.max)
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


def _box_surface(b: Box, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = _vec(b.min), _vec(b.max)
    axis = part // 2
    rows = np.arange(len(p))
    n = np.zeros_like(p)
    n[rows, axis] = np.where(part % 2 == 1, 1.0, -1.0)
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    u = (p[rows, a1] - lo[a1]) / (hi[a1] - lo[a1])
    v = (p[rows, a2] - lo[a2]) / (hi[a2] - lo[a2])
    return n, np.stack([u, v], axis=-1)


def _disc_crossing(
    center: np.ndarray, normal: np.ndarray, radius: float, o: np.ndarray, d: np.ndarray
) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _dot(center - o, normal) / _dot(d, normal)
        off = o + t[:, None] * d - center
        inside = _dot(off, off) <= radius * radius
    return np.where(inside & ~np.isnan(t), t, np.inf)


def _within_height(
    t: np.ndarray, o: np.ndarray, d: np.ndarray, start: np.ndarray, axis: np.ndarray, height: float
) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        h = _dot(o + t[:, None] * d - start, axis)
    return np.where((h >= 0.0) & (h <= height), t, np.inf)


def _cylinder_crossings(c: Cylinder, o: np.ndarray, d: np.ndarray) -> Crossings:
    base, axis = _vec(c.base), _vec(c.axis)
    q = o - base
    q_perp = q - _dot(q, axis)[:, None] * axis
    d_perp = d - _dot(d, axis)[:, None] * axis
    t0, t1 = _solve_quadratic(
        _dot(d_perp, d_perp), 2.0 * _dot(d_perp, q_perp), _dot(q_perp, q_perp) - c.radius**2
    )
    side = np.zeros(len(o), dtype=np.int64)
    out = [
        (_within_height(t0, o, d, base, axis, c.height), side),
        (_within_height(t1, o, d, base, axis, c.height), side),
    ]
    if c.capped:
        top = base + c.height * axis
        out.append((_disc_crossing(base, -axis, c.radius, o, d), side + 1))
        out.append((_disc_crossing(top, axis, c.radius, o, d), side + 2))
    return out


def _cylinder_surface(
    c: Cylinder, p: np.ndarray, part: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    base, axis = _vec(c.base), _vec(c.axis)
    e1, e2 = frame(axis)
    q = p - base
    h = q @ axis
    side_n = _normalize(q - h[:, None] * axis)
    n = np.where((part == 0)[:, None], side_n, np.where((part == 1)[:, None], -axis, axis))
    side_uv = np.stack([0.5 + np.arctan2(q @ e2, q @ e1) / (2 * np.pi), h / c.height], axis=-1)
    cap_uv = np.stack([0.5 + 0.5 * (q @ e1) / c.radius, 0.5 + 0.5 * (q @ e2) / c.radius], axis=-1)
    return n, np.where((part == 0)[:, None], side_uv, cap_uv)


def _cone_crossings(c: Cone, o: np.ndarray, d: np.ndarray) -> Crossings:
    apex, axis = _vec(c.apex), _vec(c.axis)
    cos2 = math.cos(math.radians(c.angle)) ** 2
    q = o - apex
    # Points x with ((x - apex).axis)^2 = cos^2(angle) |x - apex|^2: both nappes; the height
    # test keeps the one along +axis.
    da, qa = _dot(d, axis), _dot(q, axis)
    t0, t1 = _solve_quadratic(
        da * da - cos2 * _dot(d, d),
        2.0 * (da * qa - cos2 * _dot(d, q)),
        qa * qa - cos2 * _dot(q, q),
    )
    side = np.zeros(len(o), dtype=np.int64)
    out = [
        (_within_height(t0, o, d, apex, axis, c.height), side),
        (_within_height(t1, o, d, apex, axis, c.height), side),
    ]
    if c.capped:
        radius = c.height * math.tan(math.radians(c.angle))
        out.append((_disc_crossing(apex + c.height * axis, axis, radius, o, d), side + 1))
    return out


def _cone_surface(c: Cone, p: np.ndarray, part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    apex, axis = _vec(c.apex), _vec(c.axis)
    cos2 = math.cos(math.radians(c.angle)) ** 2
    radius = c.height * math.tan(math.radians(c.angle))
    e1, e2 = frame(axis)
    q = p - apex
    h = q @ axis
    # Minus the gradient of (q.axis)^2 - cos^2 |q|^2, which points out of the cone.
    side_n = _normalize(cos2 * q - h[:, None] * axis)
    n = np.where((part == 0)[:, None], side_n, axis)
    side_uv = np.stack([0.5 + np.arctan2(q @ e2, q @ e1) / (2 * np.pi), h / c.height], axis=-1)
    cap_uv = np.stack([0.5 + 0.5 * (q @ e1) / radius, 0.5 + 0.5 * (q @ e2) / radius], axis=-1)
    return n, np.where((part == 0)[:, None], side_uv, cap_uv)


_CROSSINGS: dict[type, Callable[..., Crossings]] = {
    Plane: _plane_crossings,
    Sphere: _sphere_crossings,
    Box: _box_crossings,
    Cylinder: _cylinder_crossings,
    Cone: _cone_crossings,
}
_SURFACE: dict[type, Callable[..., tuple[np.ndarray, np.ndarray]]] = {
    Plane: _plane_surface,
    Sphere: _sphere_surface,
    Box: _box_surface,
    Cylinder: _cylinder_surface,
    Cone: _cone_surface,
}


def _triangle_hits(
    v: np.ndarray, o: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moller-Trumbore for N rays x T triangles (v: (T, 3, 3)): (t, b1, b2), each (N, T), with
    t = inf where the ray misses or the hit is not at t > 0. Edges count as inside."""
    e1 = (v[:, 1] - v[:, 0])[None]
    e2 = (v[:, 2] - v[:, 0])[None]
    dd = d[:, None, :]
    pvec = np.cross(dd, e2)
    det = _dot(e1, pvec)
    tvec = o[:, None, :] - v[None, :, 0]
    qvec = np.cross(tvec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        b1 = _dot(tvec, pvec) * inv
        b2 = _dot(dd, qvec) * inv
        t = _dot(e2, qvec) * inv
        hit = (det != 0.0) & (b1 >= 0.0) & (b2 >= 0.0) & (b1 + b2 <= 1.0) & (t > 0.0)
    return np.where(hit, t, np.inf), b1, b2


# ---------------------------------------------------------------------------------------------
# The scene's geometry, flattened in tie order


def _tie_floor(best_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """A later primitive's t must be below this to beat best_t: nearer by more than a tie."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(best_t),
                        best_t - TIE_TOLERANCE * np.maximum(best_t, np.abs(t)), np.inf)


class SceneHit(NamedTuple):
    """Closest hits of N rays. On a miss: t = inf, normals and uv zero, indices -1."""

    t: np.ndarray  # (N,)
    normal: np.ndarray  # (N, 3) geometric normal n_g, outward / as given, not flipped
    shading_normal: np.ndarray  # (N, 3) n_g, or the blended vertex normals; not flipped
    uv: np.ndarray  # (N, 2) texture coordinates
    obj: np.ndarray  # (N,) index into scene.objects
    face: np.ndarray  # (N,) triangle index within a mesh (0 for a Triangle object), else -1
    material: np.ndarray  # (N,) index into scene.materials


def _expanded(spheres: Spheres) -> list[Sphere]:
    return [Sphere(tuple(c), float(r), int(m)) for c, r, m in
            zip(spheres.centers.tolist(), spheres.radii.tolist(), spheres.materials.tolist(),
                strict=True)]


class _Geometry:
    def __init__(self, objects: tuple[SceneObject, ...]) -> None:
        # A `spheres` array is that many Sphere objects at its place in the scene order.
        indexed = [(i, sphere) for i, ob in enumerate(objects)
                   for sphere in (_expanded(ob) if isinstance(ob, Spheres) else (ob,))]
        # Instances after every other shape (ties go to the scene's own shapes first), each
        # with its group's geometry, built once per group.
        groups: dict[int, _Geometry] = {}
        self.instances: list[_Placement] = []
        for i, ob in enumerate(objects):
            if isinstance(ob, Instance):
                if id(ob.group) not in groups:
                    groups[id(ob.group)] = _Geometry(ob.group.objects)
                self.instances.append(_Placement(i, ob, groups[id(ob.group)],
                                                 np.linalg.inv(ob.matrix[:, :3])))
        # Stable sort: within a type, scene order is kept.
        self.shapes: list[tuple[int, SceneObject]] = sorted(
            ((i, ob) for i, ob in indexed if type(ob) in _CROSSINGS),
            key=lambda item: TIE_ORDER.index(type(item[1])),
        )
        # Each list starts with an empty block so that a scene without triangles concatenates.
        verts, normals, uvs = [np.zeros((0, 3, 3))], [np.zeros((0, 3, 3))], [np.zeros((0, 3, 2))]
        obj, face, mat = ([np.zeros(0, dtype=np.int64)] for _ in range(3))
        for i, ob in indexed:
            if isinstance(ob, Triangle):
                tri = np.asarray(ob.vertices, dtype=np.float64)[None]
                verts.append(tri)
                normals.append(np.full((1, 3, 3), np.nan))
                uvs.append(np.full((1, 3, 2), np.nan))
                faces = np.zeros(1, dtype=np.int64)
            elif isinstance(ob, Mesh):
                f = np.asarray(ob.faces, dtype=np.int64)
                verts.append(np.asarray(ob.vertices, dtype=np.float64)[f])
                nrm = np.full((len(f), 3, 3), np.nan) if ob.normals is None else ob.normals[f]
                uv = np.full((len(f), 3, 2), np.nan) if ob.uvs is None else ob.uvs[f]
                normals.append(np.asarray(nrm, dtype=np.float64))
                uvs.append(np.asarray(uv, dtype=np.float64))
                faces = np.arange(len(f), dtype=np.int64)
            else:
                continue
            obj.append(np.full(len(faces), i, dtype=np.int64))
            face.append(faces)
            mat.append(np.full(len(faces), ob.material, dtype=np.int64))
        # NaN vertex normals / uvs mark triangles without them.
        self.tri_v = np.concatenate(verts)
        self.tri_n = np.concatenate(normals)
        self.tri_uv = np.concatenate(uvs)
        self.tri_obj = np.concatenate(obj)
        self.tri_face = np.concatenate(face)
        self.tri_mat = np.concatenate(mat)

    def _triangle_batches(self, n_rays: int) -> list[slice]:
        size = max(1, _TRIANGLE_BATCH // max(n_rays, 1))
        return [slice(start, start + size) for start in range(0, len(self.tri_v), size)]

    def closest(self, o: np.ndarray, d: np.ndarray) -> SceneHit:
        n = len(o)
        best_t = np.full(n, np.inf)
        best_shape = np.full(n, -1, dtype=np.int64)
        best_part = np.zeros(n, dtype=np.int64)
        for k, (_, ob) in enumerate(self.shapes):
            for t, part in _CROSSINGS[type(ob)](ob, o, d):
                # Shapes come in tie order: a later one wins only when nearer beyond a tie.
                better = (t > 0.0) & (t < _tie_floor(best_t, t))
                best_t[better] = t[better]
                best_shape[better] = k
                best_part[better] = part[better]
        best_tri = np.full(n, -1, dtype=np.int64)
        best_b = np.zeros((n, 2))
        rows = np.arange(n)
        for batch in self._triangle_batches(n):
            t, b1, b2 = _triangle_hits(self.tri_v[batch], o, d)
            # The first (in file order) of the triangles that tie with the batch's nearest.
            nearest = t.min(axis=1, keepdims=True)
            j = np.argmax(t <= nearest + TIE_TOLERANCE * nearest, axis=1)
            tj = t[rows, j]
            better = tj < _tie_floor(best_t, tj)
            best_t[better] = tj[better]
            best_shape[better] = -1
            best_tri[better] = batch.start + j[better]
            best_b[better] = np.stack([b1[rows, j], b2[rows, j]], axis=-1)[better]

        p = o + np.where(np.isfinite(best_t), best_t, 0.0)[:, None] * d
        normal = np.zeros((n, 3))
        shading = np.zeros((n, 3))
        uv = np.zeros((n, 2))
        obj = np.full(n, -1, dtype=np.int64)
        face = np.full(n, -1, dtype=np.int64)
        material = np.full(n, -1, dtype=np.int64)
        for k, (i, ob) in enumerate(self.shapes):
            m = best_shape == k
            if m.any():
                normal[m], uv[m] = _SURFACE[type(ob)](ob, p[m], best_part[m])
                shading[m] = normal[m]
                obj[m], material[m] = i, ob.material
        m = best_tri >= 0
        if m.any():
            tri = best_tri[m]
            b1, b2 = best_b[m, 0], best_b[m, 1]
            bary = np.stack([1.0 - b1 - b2, b1, b2], axis=-1)[:, :, None]
            v = self.tri_v[tri]
            normal[m] = _normalize(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))
            smooth = np.sum(bary * self.tri_n[tri], axis=1)
            # Without vertex normals (NaN) or where they cancel out, shade with n_g.
            usable = (np.linalg.norm(smooth, axis=-1) > 0.0)[:, None]
            shading[m] = np.where(usable, _normalize(smooth), normal[m])
            blended_uv = np.sum(bary * self.tri_uv[tri], axis=1)
            uv[m] = np.where(np.isnan(blended_uv), np.stack([b1, b2], axis=-1), blended_uv)
            obj[m], face[m], material[m] = self.tri_obj[tri], self.tri_face[tri], self.tri_mat[tri]
        hit = SceneHit(best_t, normal, shading, uv, obj, face, material)
        for placement in self.instances:
            hit = placement.nearer(hit, o, d)
        return hit

    def transmittance(
        self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, filters: np.ndarray
    ) -> np.ndarray:
        """Product of filters[material] over every surface crossing with 0 < t < tmax."""
        n = len(o)
        out = np.ones((n, 3))
        for _, ob in self.shapes:
            for t, _ in _CROSSINGS[type(ob)](ob, o, d):
                crossed = (t > 0.0) & (t < tmax)
                out[crossed] *= filters[ob.material]
        for batch in self._triangle_batches(n):
            t, _, _ = _triangle_hits(self.tri_v[batch], o, d)
            crossed = t < tmax[:, None]  # misses are inf, and t > 0 already holds
            tri_filters = filters[self.tri_mat[batch]]
            out *= np.prod(np.where(crossed[:, :, None], tri_filters[None], 1.0), axis=1)
        for placement in self.instances:
            inst = placement.instance
            mine = filters if inst.material is None else np.broadcast_to(
                filters[inst.material], filters.shape)
            out *= placement.group.transmittance(*placement.to_group(o, d), tmax, mine)
        return out


class _Placement(NamedTuple):
    """An instance (objects[index]) with its group's geometry and the inverse of its matrix's
    linear part."""

    index: int
    instance: Instance
    group: _Geometry
    inverse: np.ndarray

    def to_group(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays in the group's frame: d is mapped, not normalised, so t stays the same."""
        return (o - self.instance.matrix[:, 3]) @ self.inverse.T, d @ self.inverse.T

    def nearer(self, hit: SceneHit, o: np.ndarray, d: np.ndarray) -> SceneHit:
        """`hit` with this instance's hits where they are nearer beyond a tie. Normals go back
        by the inverse transpose of the instance's matrix."""
        local = self.group.closest(*self.to_group(o, d))
        better = (local.t > 0.0) & (local.t < _tie_floor(hit.t, local.t))
        if not better.any():
            return hit
        t, normal, shading, uv, obj, face, material = (np.array(field) for field in hit)
        t[better] = local.t[better]
        normal[better] = _normalize(local.normal[better] @ self.inverse)
        shading[better] = _normalize(local.shading_normal[better] @ self.inverse)
        uv[better] = local.uv[better]
        obj[better] = self.index
        face[better] = local.face[better]
        replaced = self.instance.material
        material[better] = local.material[better] if replaced is None else replaced
        return SceneHit(t, normal, shading, uv, obj, face, material)


def intersect_scene(scene: Scene, origins: np.ndarray, directions: np.ndarray) -> SceneHit:
    """Closest hit (t > 0, ties by docs/rendering.md) of each ray with the scene's objects."""
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return _Geometry(scene.objects).closest(o, d)


def shadow_transmittance(
    scene: Scene, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float
) -> np.ndarray:
    """(N, 3): the product of transmit * colour over every surface crossing with 0 < t < tmax."""
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(o),))
    filters = _MaterialTable(scene.materials).filter
    return _Geometry(scene.objects).transmittance(o, d, tmax, filters)


# ---------------------------------------------------------------------------------------------
# Materials and textures


class _MaterialTable:
    def __init__(self, materials: tuple[Material, ...]) -> None:
        self.materials = materials
        self.color = np.array([m.color for m in materials], dtype=np.float64).reshape(-1, 3)

        def column(name: str) -> np.ndarray:
            return np.array([getattr(m, name) for m in materials], dtype=np.float64)

        self.ambient = column("ambient")
        self.diffuse = column("diffuse")
        self.specular = column("specular")
        self.shininess = column("shininess")
        self.reflect = column("reflect")
        self.transmit = column("transmit")
        self.ior = column("ior")
        self.filter = self.transmit[:, None] * self.color  # shadow filter per crossing


def sample_image(
    image: np.ndarray, u: np.ndarray, v: np.ndarray, repeat: tuple[float, float]
) -> np.ndarray:
    """Bilinear, wrapping lookup of an (H, W, 3) image (row 0 at the top) at (u, v)."""
    texels = np.asarray(image, dtype=np.float64)
    height, width = texels.shape[:2]
    j, k = repeat
    uj, vk = u * j, v * k
    s = (uj - np.floor(uj)) * width - 0.5
    t = (1.0 - (vk - np.floor(vk))) * height - 0.5
    # A degenerate (u, v) (NaN from a zero-extent face) must not become a wild index.
    s = np.where(np.isfinite(s), s, 0.0)
    t = np.where(np.isfinite(t), t, 0.0)
    x0, y0 = np.floor(s), np.floor(t)
    fx, fy = (s - x0)[:, None], (t - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    x0, y0 = x0 % width, y0 % height
    return (
        (1 - fx) * (1 - fy) * texels[y0, x0]
        + fx * (1 - fy) * texels[y0, x1]
        + (1 - fx) * fy * texels[y1, x0]
        + fx * fy * texels[y1, x1]
    )


def checker_texel(
    texture: Texture, color: np.ndarray, p: np.ndarray, facing_normal: np.ndarray
) -> np.ndarray:
    """The 3D checker: `color` on even cells of q = p - size/4 * n_f, else texture.color2."""
    q = p - 0.25 * texture.size * facing_normal
    cells = np.sum(np.floor(q / texture.size), axis=-1)
    even = (cells % 2 == 0)[:, None]
    return np.where(even, color, _vec(texture.color2))


def _surface_color(
    mats: _MaterialTable, material: np.ndarray, p: np.ndarray, uv: np.ndarray, ngf: np.ndarray
) -> np.ndarray:
    c = mats.color[material]
    for idx, mat in enumerate(mats.materials):
        tex = mat.texture
        m = material == idx
        if tex is None or not m.any():
            continue
        if tex.kind == "checker":
            texel = checker_texel(tex, mats.color[idx], p[m], ngf[m])
        else:
            texel = sample_image(tex.image, uv[m, 0], uv[m, 1], tex.repeat)
        c[m] = tex.blend * texel + (1.0 - tex.blend) * mats.color[idx]
    return c


# ---------------------------------------------------------------------------------------------
# Fresnel and background


def fresnel_polarised(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(R_s, R_p): the dielectric reflectances of s- and p-polarised light going from IOR n1
    to n2, eta = n1 / n2, at incidence cosine cos_i and refraction cosine cos_t (both >= 0).
    Grazing with cos_i = cos_t = 0 (eta = 1 exactly) is the limit, 1."""
    eta, cos_i, cos_t = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64)
                                              for a in (eta, cos_i, cos_t)))
    ds, dp = eta * cos_i + cos_t, cos_i + eta * cos_t
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.where(ds > 0.0, (eta * cos_i - cos_t) / ds, 1.0)
        rp = np.where(dp > 0.0, (cos_i - eta * cos_t) / dp, 1.0)
    return rs * rs, rp * rp


def fresnel_exact(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray) -> np.ndarray:
    """Unpolarised dielectric reflectance (R_s + R_p) / 2."""
    r_s, r_p = fresnel_polarised(eta, cos_i, cos_t)
    return 0.5 * (r_s + r_p)


def fresnel_schlick(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray) -> np.ndarray:
    """Schlick's approximation R0 + (1 - R0)(1 - c)^5, c the cosine on the less dense side."""
    eta = np.asarray(eta, dtype=np.float64)
    r0 = ((1.0 - eta) / (1.0 + eta)) ** 2
    c = np.where(eta > 1.0, cos_t, cos_i)
    return r0 + (1.0 - r0) * (1.0 - c) ** 5


def equirect_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of unit directions in the environment image: u = 0.5 looks along -z, u grows
    towards +x; v = 1 straight up."""
    u = 0.5 + np.arctan2(d[:, 0], -d[:, 2]) / (2.0 * np.pi)
    v = 0.5 + np.arcsin(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    return u, v


def sample_environment(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an equirectangular (H, W, 3) image: wrapping across u, rows clamped
    at the poles (row 0 at v = 1)."""
    texels = np.asarray(image, dtype=np.float64)
    height, width = texels.shape[:2]
    s = (u - np.floor(u)) * width - 0.5
    t = np.clip((1.0 - v) * height - 0.5, 0.0, height - 1.0)
    x0, y0 = np.floor(s), np.floor(t)
    fx, fy = (s - x0)[:, None], (t - y0)[:, None]
    x0, y0 = x0.astype(np.int64) % width, y0.astype(np.int64)
    x1, y1 = (x0 + 1) % width, np.minimum(y0 + 1, height - 1)
    return ((1 - fx) * (1 - fy) * texels[y0, x0] + fx * (1 - fy) * texels[y0, x1]
            + (1 - fx) * fy * texels[y1, x0] + fx * fy * texels[y1, x1])


def background_radiance(background: tuple[float, float, float] | Background, d: np.ndarray
                        ) -> np.ndarray:
    """(N, 3): what rays of unit directions d that hit nothing see."""
    if not isinstance(background, Background):
        return np.broadcast_to(_vec(background), d.shape)
    d = _normalize(d)
    if background.kind == "gradient":
        t = np.clip(0.5 * (d[:, 1:2] + 1.0), 0.0, 1.0)
        return (1.0 - t) * _vec(background.bottom) + t * _vec(background.top)
    return sample_environment(background.image, *equirect_uv(d))


# ---------------------------------------------------------------------------------------------
# Tracing


def _error_bound(p: np.ndarray) -> np.ndarray:
    """How far a float64 hit point may be off its surface, scaled to its magnitude."""
    return 1e-9 * (1.0 + np.max(np.abs(p), axis=-1))


def _offset(p: np.ndarray, ngf: np.ndarray, new_d: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Move p off the surface along the facing geometric normal, to the side new_d leaves on."""
    side = np.where(_dot(new_d, ngf) >= 0.0, 1.0, -1.0)
    return p + (side * eps)[:, None] * ngf


# An area light sample's weight is clamped here, as in the kernels (kernels/lights.h).
AREA_WEIGHT_MAX = 1e20


def _spot_factor(light: SpotLight, l_dir: np.ndarray) -> np.ndarray:
    """1 inside the inner cone, 0 outside the outer, smoothstep in cos between."""
    inner = light.angle if light.inner_angle is None else light.inner_angle
    cos_o, cos_i = math.cos(math.radians(light.angle)), math.cos(math.radians(inner))
    cos_t = -(l_dir @ _vec(light.direction))
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


def _area_light_sample(
    light: RectLight | DiscLight | SphereLight,
    p: np.ndarray,
    eps: np.ndarray,
    u1: np.ndarray,
    u2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(target point on the light, weight, usable) of docs/rendering.md (Area lights): weight
    times the light's radiance estimates the irradiance on a surface facing the sample."""
    if isinstance(light, SphereLight):
        to_c = _vec(light.center) - p
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
        e1 = _normalize(np.cross(w_c, h))
        e2 = np.cross(w_c, e1)
        w = (cos_t[:, None] * w_c
             + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
        # The nearer of the two crossings of the sphere along w.
        t = safe * cos_t - np.sqrt(np.maximum(0.0, light.radius**2 - (safe * sin_t) ** 2))
        return p + t[:, None] * w, 2.0 * np.pi * k, usable
    if isinstance(light, RectLight):
        u, v = _vec(light.u), _vec(light.v)
        y = _vec(light.corner) + u1[:, None] * u + u2[:, None] * v
        normal = np.cross(u, v)
        area = float(np.linalg.norm(normal))
        normal = normal / area
    else:
        normal = _vec(light.normal)
        e1, e2 = frame(normal)
        a, b = concentric_disc(u1, u2)
        y = _vec(light.center) + light.radius * (a[:, None] * e1 + b[:, None] * e2)
        area = np.pi * light.radius**2
    to_y = y - p
    dist = np.linalg.norm(to_y, axis=-1)
    safe = np.where(dist > 0.0, dist, 1.0)
    cos_l = -(to_y @ normal) / safe
    usable = (dist > eps) & (cos_l > 0.0)  # one-sided: the back emits nothing
    weight = np.minimum(area * cos_l / (safe * safe), AREA_WEIGHT_MAX)
    return y, weight, usable


def _top_ior(stack: np.ndarray, count: np.ndarray, ior: np.ndarray) -> np.ndarray:
    top = stack[np.arange(len(stack)), np.maximum(count - 1, 0)]
    return np.where(count > 0, ior[np.maximum(top, 0)], 1.0)


def _media_transition(
    stack: np.ndarray,
    count: np.ndarray,
    material: np.ndarray,
    entering: np.ndarray,
    ior: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(n1, n2, new stack, new count) for rays crossing into (entering) or out of `material`."""
    rows = np.arange(len(stack))
    slots = np.arange(MAX_MEDIA)[None, :]
    # Entering: push, ignored when the stack is full.
    n1_in = _top_ior(stack, count, ior)
    pushed = stack.copy()
    room = count < MAX_MEDIA
    pushed[rows[room], count[room]] = material[room]
    count_in = np.minimum(count + 1, MAX_MEDIA)
    # Leaving: drop the topmost occurrence of the material, if it is on the stack at all.
    occurs = (stack == material[:, None]) & (slots < count[:, None])
    last = np.where(occurs.any(axis=1), MAX_MEDIA - 1 - np.argmax(occurs[:, ::-1], axis=1), -1)
    src = np.where((last[:, None] >= 0) & (slots >= last[:, None]), slots + 1, slots)
    popped = np.take_along_axis(np.pad(stack, ((0, 0), (0, 1)), constant_values=-1), src, axis=1)
    count_out = count - (last >= 0)
    n2_out = _top_ior(popped, count_out, ior)

    e = entering[:, None]
    n1 = np.where(entering, n1_in, ior[material])
    n2 = np.where(entering, ior[material], n2_out)
    return n1, n2, np.where(e, pushed, popped), np.where(entering, count_in, count_out)


def trace(
    scene: Scene,
    origins: np.ndarray,
    directions: np.ndarray,
    max_depth: int | None = None,
    schlick: bool = False,
    *,
    pixel: np.ndarray | None = None,
    sample: np.ndarray | None = None,
    spp: int = 1,
    seed: int | None = None,
) -> np.ndarray:
    """(N, 3) radiance along each ray (depth 0, starting in air), per docs/rendering.md.
    `schlick`: Fresnel materials use Schlick's approximation (the kernels' study variant).
    `pixel`, `sample` (per ray), `spp` and `seed` pick area lights' samples; by default ray i
    is sample 0 of 1 of pixel i."""
    max_depth = scene.render.max_depth if max_depth is None else max_depth
    seed = scene.render.seed if seed is None else seed
    min_weight = scene.render.min_weight
    geo = _Geometry(scene.objects)
    mats = _MaterialTable(scene.materials)
    background = scene.render.background
    fresnel = np.array([m.fresnel for m in scene.materials], dtype=bool)
    scene_ambient = _vec(scene.render.ambient)

    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = _normalize(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
    ray_pixel = np.arange(len(o)) if pixel is None else np.asarray(pixel).reshape(-1)
    ray_sample = np.zeros(len(o), dtype=np.int64) if sample is None else np.asarray(sample)
    radiance = np.zeros((len(o), 3))
    # The wavefront: one entry per live ray.
    owner = np.arange(len(o))  # which input ray this path's radiance belongs to
    weight = np.ones(len(o))
    depth = np.zeros(len(o), dtype=np.int64)
    stack = np.full((len(o), MAX_MEDIA), -1, dtype=np.int64)
    count = np.zeros(len(o), dtype=np.int64)

    while len(o):
        hit = geo.closest(o, d)
        miss = ~np.isfinite(hit.t)
        np.add.at(radiance, owner[miss],
                  weight[miss, None] * background_radiance(background, d[miss]))
        h = ~miss
        o, d, owner, weight, depth, stack, count = (
            a[h] for a in (o, d, owner, weight, depth, stack, count)
        )
        t, ng, ns, uv, m = (
            hit.t[h],
            hit.normal[h],
            hit.shading_normal[h],
            hit.uv[h],
            hit.material[h],
        )

        p = o + t[:, None] * d
        eps = _error_bound(p)
        entering = _dot(d, ng) < 0.0
        # Both normals face the incoming ray, each by its own sign.
        ngf = np.where((_dot(d, ng) > 0.0)[:, None], -ng, ng)
        n = np.where((_dot(d, ns) > 0.0)[:, None], -ns, ns)
        c = _surface_color(mats, m, p, uv, ngf)

        local = mats.ambient[m, None] * c * scene_ambient
        for index, light in enumerate(scene.lights):
            if isinstance(light, RectLight | DiscLight | SphereLight):
                u1, u2 = light_square(seed, ray_pixel[owner], ray_sample[owner], spp, index)
                target, atten, usable = _area_light_sample(light, p, eps, u1, u2)
                l_dir = _normalize(target - p)
            elif isinstance(light, PointLight | SpotLight):
                target = np.broadcast_to(_vec(light.position), p.shape)
                to_light = target - p
                dist = np.linalg.norm(to_light, axis=-1)
                l_dir = to_light / np.where(dist > 0.0, dist, 1.0)[:, None]
                kc, kl, kq = light.attenuation
                denom = kc + kl * dist + kq * dist * dist
                with np.errstate(divide="ignore"):
                    atten = np.where(denom > 0.0, np.minimum(1.0, 1.0 / denom), 1.0)
                usable = dist > eps
                if isinstance(light, SpotLight):
                    atten = atten * _spot_factor(light, l_dir)
                    usable &= atten > 0.0
            else:
                assert isinstance(light, DirectionalLight)
                target = None
                l_dir = np.broadcast_to(-_vec(light.direction), p.shape)
                atten = np.ones(len(p))
                usable = np.ones(len(p), dtype=bool)
            ndotl = _dot(n, l_dir)
            lit = usable & (ndotl > 0.0)
            if not lit.any():
                continue
            shadow = np.zeros((len(p), 3))
            origin = _offset(p[lit], ngf[lit], l_dir[lit], eps[lit])
            shadow_dir, span = l_dir[lit], np.full(int(lit.sum()), np.inf)
            if target is not None:
                # Aimed from the offset origin, as the kernels do (docs/rendering.md).
                to_light = target[lit] - origin
                span = np.linalg.norm(to_light, axis=-1)
                shadow_dir = np.where((span > 0.0)[:, None],
                                      to_light / np.where(span > 0.0, span, 1.0)[:, None],
                                      shadow_dir)
            shadow[lit] = geo.transmittance(origin, shadow_dir, span, mats.filter)
            r = 2.0 * ndotl[:, None] * n - l_dir
            rv = _dot(r, -d)
            spec = np.zeros(len(p))
            pos = rv > 0.0
            spec[pos] = rv[pos] ** mats.shininess[m[pos]]
            term = mats.diffuse[m, None] * c * ndotl[:, None] + (mats.specular[m] * spec)[:, None]
            local += np.where(lit[:, None], atten[:, None] * _vec(light.color) * shadow * term, 0.0)
        np.add.at(radiance, owner, weight[:, None] * local)

        # Secondary rays.
        go_on = depth < max_depth
        kr, kt = mats.reflect[m], mats.transmit[m]
        n1, n2, new_stack, new_count = _media_transition(stack, count, m, entering, mats.ior)
        eta = n1 / n2
        cos_i = -_dot(d, n)
        k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
        tir = k < 0.0
        kr = kr + np.where(tir, kt, 0.0)  # total internal reflection: transmit joins reflect
        split = fresnel[m] & ~tir
        if split.any():
            f_of = fresnel_schlick if schlick else fresnel_exact
            f = np.where(split, f_of(eta, cos_i, np.sqrt(np.maximum(k, 0.0))), 0.0)
            kr, kt = kr + f * kt, (1.0 - f) * kt
        # Rays fainter than min_weight are not traced, as in the kernels.
        refl = go_on & (kr > 0.0) & (weight * kr >= min_weight)
        refr = go_on & (kt > 0.0) & ~tir & (weight * kt >= min_weight)

        refl_d = d - 2.0 * _dot(d, n)[:, None] * n
        refr_d = eta[:, None] * d + (eta * cos_i - np.sqrt(np.maximum(k, 0.0)))[:, None] * n
        refl_o = _offset(p, ngf, refl_d, eps)
        refr_o = _offset(p, ngf, refr_d, eps)
        o = np.concatenate([refl_o[refl], refr_o[refr]])
        d = np.concatenate([refl_d[refl], _normalize(refr_d[refr])])
        owner = np.concatenate([owner[refl], owner[refr]])
        weight = np.concatenate([(weight * kr)[refl], (weight * kt)[refr]])
        depth = np.concatenate([depth[refl], depth[refr]]) + 1
        stack = np.concatenate([stack[refl], new_stack[refr]])
        count = np.concatenate([count[refl], new_count[refr]])
    return radiance


def render_reference(
    scene: Scene,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    max_depth: int | None = None,
    seed: int | None = None,
    schlick: bool = False,
) -> np.ndarray:
    """(H, W, 3) float64 linear RGB: the mean of each pixel's samples. None = the scene's value;
    `schlick` as for `trace`."""
    width, height, spp, max_depth, seed = _settings(scene, width, height, spp, max_depth, seed)
    origins, directions, pixel = camera_rays(scene, width, height, spp, seed)
    sample = np.tile(np.arange(spp, dtype=np.int64), width * height)
    radiance = trace(scene, origins, directions, max_depth, schlick, pixel=pixel, sample=sample,
                     spp=spp, seed=seed)
    image = np.zeros((width * height, 3))
    np.add.at(image, pixel, radiance)
    return (image / spp).reshape(height, width, 3)
