"""The oracle's ray tree (kernels/ray_tree.h): camera rays traced as a wavefront, each
generation's hits shaded by shade_direct, their reflected and refracted children (with the
media each carries) forming the next generation."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clray.reference.background import background_radiance
from clray.reference.bvh import Geometry
from clray.reference.fresnel import fresnel_reflectance, fresnel_schlick
from clray.reference.sampling import SampleKey, _settings, camera_rays
from clray.reference.shading import Surface, offset_origin, shade_direct, surface_at
from clray.reference.texture import MaterialTable, surface_color
from clray.scene.check import check_scene
from clray.scene.emitters import scene_lights
from clray.scene.model import Scene
from clray.vectors import dot, safe_normalize, vec

MEDIA_DEPTH = 4  # nesting depth of the media stack a ray carries


class RayTasks(NamedTuple):
    """The wavefront: one entry per live ray."""

    o: np.ndarray  # (N, 3)
    d: np.ndarray  # (N, 3) unit
    owner: np.ndarray  # which input ray this path's radiance belongs to
    weight: np.ndarray  # the product of reflect / transmit along the path
    depth: np.ndarray
    media: np.ndarray  # (N, MEDIA_DEPTH) materials the ray is inside, innermost last
    media_count: np.ndarray

    def select(self, keep: np.ndarray) -> RayTasks:
        return RayTasks(*(a[keep] for a in self))


def medium_ior(media: np.ndarray, count: np.ndarray, ior: np.ndarray) -> np.ndarray:
    """The IOR of the innermost medium, 1 (air) for an empty stack."""
    top = media[np.arange(len(media)), np.maximum(count - 1, 0)]
    return np.where(count > 0, ior[np.maximum(top, 0)], 1.0)


def refract_media(
    media: np.ndarray,
    count: np.ndarray,
    material: np.ndarray,
    entering: np.ndarray,
    ior: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(n1, n2, new media, new count) for rays crossing into (entering) or out of `material`."""
    rows = np.arange(len(media))
    slots = np.arange(MEDIA_DEPTH)[None, :]
    # Entering: push, ignored when the stack is full.
    n1_in = medium_ior(media, count, ior)
    pushed = media.copy()
    room = count < MEDIA_DEPTH
    pushed[rows[room], count[room]] = material[room]
    count_in = np.minimum(count + 1, MEDIA_DEPTH)
    # Leaving: drop the topmost occurrence of the material, if it is on the stack at all.
    occurs = (media == material[:, None]) & (slots < count[:, None])
    last = np.where(occurs.any(axis=1), MEDIA_DEPTH - 1 - np.argmax(occurs[:, ::-1], axis=1), -1)
    src = np.where((last[:, None] >= 0) & (slots >= last[:, None]), slots + 1, slots)
    popped = np.take_along_axis(np.pad(media, ((0, 0), (0, 1)), constant_values=-1), src, axis=1)
    count_out = count - (last >= 0)
    n2_out = medium_ior(popped, count_out, ior)

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
    is sample 0 of 1 of pixel i. A scene built in Python is checked and normalised first, as
    render() takes it (clray.scene.check: unit directions and normals)."""
    scene = check_scene(scene)
    max_depth = scene.render.max_depth if max_depth is None else max_depth
    seed = scene.render.seed if seed is None else seed
    geo = Geometry(scene.objects)
    mats = MaterialTable(scene.materials)
    ambient_light = vec(scene.render.ambient)
    lights = scene_lights(scene)

    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    n_rays = len(o)
    ray_pixel = np.arange(n_rays) if pixel is None else np.asarray(pixel).reshape(-1)
    ray_sample = np.zeros(n_rays, dtype=np.int64) if sample is None else np.asarray(sample)
    radiance = np.zeros((n_rays, 3))
    tasks = RayTasks(o, safe_normalize(np.asarray(directions, dtype=np.float64).reshape(-1, 3)),
                     np.arange(n_rays), np.ones(n_rays), np.zeros(n_rays, dtype=np.int64),
                     np.full((n_rays, MEDIA_DEPTH), -1, dtype=np.int64),
                     np.zeros(n_rays, dtype=np.int64))

    while len(tasks.o):
        hit = geo.closest_hit(tasks.o, tasks.d)
        miss = ~np.isfinite(hit.t)
        np.add.at(radiance, tasks.owner[miss], tasks.weight[miss, None]
                  * background_radiance(scene.render.background, tasks.d[miss]))
        h = ~miss
        tasks = tasks.select(h)
        sf = surface_at(tasks.o, tasks.d, hit.t[h], hit.normal[h], hit.shading_normal[h],
                        hit.uv[h], hit.material[h])
        c = (surface_color(mats, sf.material, sf.p, sf.uv, sf.n_g, hit.ends_apart[h])
             * hit.tint[h])
        key = SampleKey(seed, ray_pixel[tasks.owner], ray_sample[tasks.owner], spp)
        local = shade_direct(sf, tasks.d, c, mats, lights, ambient_light, key,
                             geo.transmission)
        np.add.at(radiance, tasks.owner, tasks.weight[:, None] * local)
        tasks = spawn_secondary(tasks, sf, mats, max_depth, scene.render.min_weight, schlick)
    return radiance


def spawn_secondary(tasks: RayTasks, sf: Surface, mats: MaterialTable, max_depth: int,
                   min_weight: float, schlick: bool) -> RayTasks:
    """The next generation: each hit's reflected and refracted rays (spawn in the kernels),
    weighted by reflect and transmit (split by Fresnel, transmit joining reflect at total
    internal reflection), offset off the surface; rays fainter than min_weight are not traced,
    as in the kernels."""
    d, n, m, weight = tasks.d, sf.n, sf.material, tasks.weight
    go_on = tasks.depth < max_depth
    kr, kt = mats.reflect[m], mats.transmit[m]
    n1, n2, new_media, new_count = refract_media(tasks.media, tasks.media_count, m,
                                                 sf.entering, mats.ior)
    eta = n1 / n2
    cos_i = -dot(d, n)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    tir = k < 0.0
    kr = kr + np.where(tir, kt, 0.0)  # total internal reflection: transmit joins reflect
    split = mats.fresnel[m] & ~tir
    if split.any():
        f_of = fresnel_schlick if schlick else fresnel_reflectance
        f = np.where(split, f_of(eta, cos_i, np.sqrt(np.maximum(k, 0.0))), 0.0)
        kr, kt = kr + f * kt, (1.0 - f) * kt
    refl = go_on & (kr > 0.0) & (weight * kr >= min_weight)
    refr = go_on & (kt > 0.0) & ~tir & (weight * kt >= min_weight)

    refl_d = d - 2.0 * dot(d, n)[:, None] * n
    refr_d = eta[:, None] * d + (eta * cos_i - np.sqrt(np.maximum(k, 0.0)))[:, None] * n
    refl_o = offset_origin(sf.p, sf.n_out, refl_d, sf.err)
    refr_o = offset_origin(sf.p, sf.n_out, refr_d, sf.err)
    return RayTasks(
        np.concatenate([refl_o[refl], refr_o[refr]]),
        np.concatenate([refl_d[refl], safe_normalize(refr_d[refr])]),
        np.concatenate([tasks.owner[refl], tasks.owner[refr]]),
        np.concatenate([(weight * kr)[refl], (weight * kt)[refr]]),
        np.concatenate([tasks.depth[refl], tasks.depth[refr]]) + 1,
        np.concatenate([tasks.media[refl], new_media[refr]]),
        np.concatenate([tasks.media_count[refl], new_count[refr]]),
    )


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
    `schlick` as for `trace`; the scene is taken as render() takes it (see `trace`)."""
    scene = check_scene(scene)
    width, height, spp, max_depth, seed = _settings(scene, width, height, spp, max_depth, seed)
    origins, directions, pixel = camera_rays(scene, width, height, spp, seed)
    sample = np.tile(np.arange(spp, dtype=np.int64), width * height)
    radiance = trace(scene, origins, directions, max_depth, schlick, pixel=pixel, sample=sample,
                     spp=spp, seed=seed)
    image = np.zeros((width * height, 3))
    np.add.at(image, pixel, radiance)
    return (image / spp).reshape(height, width, 3)
