"""An independent float64 numpy renderer: the test oracle for the OpenCL kernels.

It implements docs/rendering.md literally: every ray is intersected with every primitive by
brute force, and the ray tree is walked as a wavefront (all live rays of one generation in
arrays, their reflected and refracted children forming the next generation). Slow, but each
formula can be checked against the page by eye.

It shares no code with the kernels, but some with the packer (clray.device.pack), so that a
fault in these is not seen by comparing the two renderers:
- the scene model, clray.scene.model;
- clray.scene.check.check_scene, the scene normalised as render() takes it;
- clray.scene.emitters.scene_lights, the light list (the scene's lights, then its emissive
  faces' lights: emissive_lights, which keeps a face only where clray.lights.rect's
  resolved_in_float32 finds its float32 edges resolved, and makes a mesh's many faces of a
  material one mesh light, whose pick thresholds (clray.lights.mesh) both renderers use);
- the modules of clray.lights and clray.shapes, which hold each light's and analytic shape's
  packer beside the reference's part of it (a light's `toward`; a shape's crossings and
  surface) and the helpers both use: spot.versine (the spot's cones, packed and in the
  falloff), clray.vectors.frame_helper (the helper axis of frame and of the packer's frames).
  The reference also takes clray.lights.light.AREA_WEIGHT_MAX from there, the clamp on an
  area sample's weight: a copy of kernels/lights.h's, which the packer does not use;
- clray.accel.prim_refs's type codes, which order ties (PRIM_TRIANGLE).

Its modules mirror the kernel headers, and its functions carry the kernels' names, so the two
can be read side by side: sampling (kernels/rng.h, camera.h), intersect (plane.h, triangle.h;
the shapes' intersect_* are clray.shapes'), bvh (bvh.h: closest_hit, transmission), shading
(surface.h: surface_at, offset_origin; direct.h: shade_direct; each light's part of lights.h is
its module's `toward`, clray.lights), fresnel (fresnel.h), texture (texture.h), background
(background.h), render (ray_tree.h: refract_media, the ray tree); clray.vectors mirrors real.h.
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
