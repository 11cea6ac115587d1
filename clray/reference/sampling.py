"""The oracle's samples and camera rays (kernels/rng.h and kernels/camera.h): the hash, the
pixel and lens samples, the area lights' stratified squares, and the primary rays."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clray.scene.check import check_scene
from clray.scene.model import Camera, Scene
from clray.vectors import safe_normalize as _normalize


def pcg_hash(x: np.ndarray | int) -> np.ndarray:
    """The PCG output hash of docs/rendering.md in wrapping uint32 arithmetic."""
    state = np.asarray(x).astype(np.uint32)
    with np.errstate(over="ignore"):
        state = state * np.uint32(747796405) + np.uint32(2891336453)
        word = ((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * np.uint32(277803737)
    return (word >> np.uint32(22)) ^ word


def rng_bits(seed: int, pixel: np.ndarray, sample: np.ndarray, dim: int) -> np.ndarray:
    """The 32 hashed bits behind r_dim of docs/rendering.md."""
    seed_hash = pcg_hash(np.uint32(seed & 0xFFFFFFFF))
    pixel = np.asarray(pixel).astype(np.uint32)
    sample = np.asarray(sample).astype(np.uint32)
    with np.errstate(over="ignore"):
        counter = np.uint32(4) * sample + np.uint32(dim)
    return pcg_hash(pcg_hash(seed_hash ^ pixel) ^ counter)


def rng_uniform(seed: int, pixel: np.ndarray, sample: np.ndarray, dim: int) -> np.ndarray:
    """r_dim of docs/rendering.md: 24 random bits of the key, in [0, 1)."""
    return (rng_bits(seed, pixel, sample, dim) >> np.uint32(8)).astype(np.float64) * 2.0**-24


def _permute_round(i: np.ndarray, w: np.uint32, key: np.ndarray) -> np.ndarray:
    """One walk step of permute_stratum: a bijection on [0, w]."""
    u = np.uint32
    with np.errstate(over="ignore"):
        i = i ^ key
        i = i * u(0xE170893D)
        i = i ^ (key >> u(16))
        i = i ^ ((i & w) >> u(4))
        i = i ^ (key >> u(8))
        i = i * u(0x0929EB3F)
        i = i ^ (key >> u(23))
        i = i ^ ((i & w) >> u(1))
        i = i * (u(1) | (key >> u(27)))
        i = i * u(0x6935FA69)
        i = i ^ ((i & w) >> u(11))
        i = i * u(0x74DCB303)
        i = i ^ ((i & w) >> u(2))
        i = i * u(0x9E501CC3)
        i = i ^ ((i & w) >> u(2))
        i = i * u(0xC860A3DF)
        i = i & w
        return i ^ (i >> u(5))


def permute_stratum(i: np.ndarray, n: int, key: np.ndarray) -> np.ndarray:
    """The stratum of 0..n-1 that sample i takes: kernels/rng.h's permutation per key
    (docs/rendering.md, What the sampler guarantees), walked until below n."""
    key = np.broadcast_to(np.asarray(key).astype(np.uint32), np.shape(i))
    w = (1 << max(n - 1, 0).bit_length()) - 1
    out = _permute_round(np.asarray(i).astype(np.uint32), np.uint32(w), key)
    above = out >= n
    while above.any():
        out[above] = _permute_round(out[above], np.uint32(w), key[above])
        above = out >= n
    return ((out + key % np.uint32(n)) % np.uint32(n)).astype(np.int64)


def grid_columns(spp: int) -> int:
    """The strata's columns: ceil(sqrt(spp)), computed in integers."""
    nx = math.isqrt(spp)
    return nx + 1 if nx * nx < spp else nx


class SampleKey(NamedTuple):
    """What picks each ray's area light samples: the image seed, and the ray's pixel and
    sample (arrays, one per ray) of spp."""

    seed: int
    pixel: np.ndarray
    sample: np.ndarray
    spp: int


def light_key(seed: int, pixel: np.ndarray, light: int) -> np.ndarray:
    """Light `light`'s random stream at each pixel (kernels/sampling.h, light_key): its counter
    2^31 | light above every counter of the pixel's jitter."""
    pixel = np.asarray(pixel).astype(np.uint32)
    return pcg_hash(pcg_hash(pcg_hash(np.uint32(seed & 0xFFFFFFFF)) ^ pixel)
                    ^ np.uint32(0x80000000 | light))


def light_square(
    seed: int, pixel: np.ndarray, sample: np.ndarray, spp: int, light: int
) -> tuple[np.ndarray, np.ndarray]:
    """(u1, u2) in the unit square: light `light`'s stratified sample for each (pixel,
    sample) of docs/rendering.md (Area lights)."""
    sample = np.asarray(sample).astype(np.int64)
    key = light_key(seed, pixel, light)
    stratum = permute_stratum(sample, spp, key)

    def uniform(dim: int) -> np.ndarray:
        counter = (2 * sample + dim).astype(np.uint32)
        return (pcg_hash(key ^ counter) >> np.uint32(8)).astype(np.float64) * 2.0**-24

    return stratum_point(stratum, spp, uniform(0), uniform(1))


def light_pick(seed: int, pixel: np.ndarray, sample: np.ndarray, spp: int,
               light: int) -> np.ndarray:
    """Light `light`'s uint32 pick for each (pixel, sample), which face of a mesh light its
    shadow ray aims at: the samples take the spp strata of the picks, each once
    (kernels/sampling.h, light_pick; docs/rendering.md, Area lights)."""
    key = pcg_hash(light_key(seed, pixel, light) ^ np.uint32(0x40000000))
    sample = np.asarray(sample).astype(np.uint32)
    stratum = permute_stratum(sample, spp, key).astype(np.uint64)
    r = pcg_hash(key ^ sample).astype(np.uint64)
    return (((stratum << np.uint64(32)) | r) // np.uint64(spp)).astype(np.uint32)


def stratum_point(stratum: np.ndarray, spp: int, r0: np.ndarray, r1: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A point of the unit square in stratum `stratum` of spp (docs/rendering.md): rows of nx
    cells, nx / spp high, and a last row of the cells that remain, as much wider and lower, so
    that the strata tile the square, each of area 1 / spp; (r0, r1) in [0, 1) place it."""
    nx = grid_columns(spp)
    row, col = stratum // nx, stratum % nx
    cells = np.minimum(nx, spp - row * nx)
    return (col + r0) / cells, (row * nx + r1 * cells) / spp


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
    r0 = rng_uniform(seed, pixel, sample, 0)
    r1 = rng_uniform(seed, pixel, sample, 1)
    u, v = stratum_point(sample, spp, r0, r1)
    return x + u, y + v, pixel


def camera_rays(
    scene: Scene,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    seed: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origins (N, 3), unit directions (N, 3), pixel (N,)) of every sample, ordered as
    `sample_positions`; None takes the scene's setting. The scene is checked as render()
    takes it (clray.scene.check)."""
    scene = check_scene(scene)
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
        lens = lens_sample(camera.aperture / 2.0, spp, seed, pixel, sample)
        lens = lens[:, :1] * right + lens[:, 1:] * up
        focus = _focus_distance(camera)
        return origins + lens, _normalize(aim - lens / focus), pixel
    return origins, _normalize(aim), pixel


def lens_sample(radius: float, spp: int, seed: int, pixel: np.ndarray, sample: np.ndarray
                 ) -> np.ndarray:
    """(N, 2): each sample's point on the lens disc of `radius`, in (right, up) coordinates
    (docs/rendering.md, Depth of field)."""
    # The pixel's order of the angular strata, keyed by r_2 of the sample index spp, which no
    # sample uses.
    stratum = permute_stratum(sample, spp, rng_bits(seed, pixel, np.full_like(sample, spp), 2))
    angle = 2.0 * np.pi * (stratum + rng_uniform(seed, pixel, sample, 2)) / spp
    rho = radius * np.sqrt(rng_uniform(seed, pixel, sample, 3))
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
