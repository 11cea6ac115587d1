"""An independent float64 numpy renderer: the test oracle for the OpenCL kernels.

It implements docs/rendering.md literally and shares no code with the kernels or the packer
(each analytic shape's crossings and surface sit in the shape's module, clray.shapes, beside
its packer but sharing no formula with it):
every ray is intersected with every primitive by brute force, and the ray tree is walked as a
wavefront (all live rays of one generation in arrays, their reflected and refracted children
forming the next generation). Slow, but each formula can be checked against the page by eye.

Its modules mirror the kernel headers, and its functions carry the kernels' names, so the two
can be read side by side: sampling (kernels/rng.h, camera.h), intersect (plane.h, triangle.h;
the shapes' intersect_* are clray.shapes'), bvh (bvh.h: closest_hit,
transmission), shading (surface.h: surface_at, offset_origin; direct.h: shade_direct), lights
(lights.h), fresnel (fresnel.h), texture (texture.h), background (background.h), render
(ray_tree.h: refract_media, the ray tree); clray.vectors mirrors real.h.
"""

from clray.reference.background import (
    background_radiance,
    environment_bilinear,
    environment_texel,
    equirect_uv,
)
from clray.reference.bvh import SceneHit, intersect_scene, transmission
from clray.reference.fresnel import fresnel_polarised, fresnel_reflectance, fresnel_schlick
from clray.reference.render import render_reference, trace
from clray.reference.sampling import (
    camera_rays,
    grid_columns,
    lens_sample,
    light_square,
    pcg_hash,
    rng_uniform,
    sample_positions,
)
from clray.reference.texture import checker_texel, image_texel

__all__ = [
    "SceneHit",
    "background_radiance",
    "camera_rays",
    "checker_texel",
    "environment_bilinear",
    "environment_texel",
    "equirect_uv",
    "fresnel_polarised",
    "fresnel_reflectance",
    "fresnel_schlick",
    "grid_columns",
    "image_texel",
    "intersect_scene",
    "lens_sample",
    "light_square",
    "pcg_hash",
    "render_reference",
    "rng_uniform",
    "sample_positions",
    "trace",
    "transmission",
]
