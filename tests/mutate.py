"""Mutation testing: does the suite catch small, realistic bugs in kernels/ and clray/?

    python -m tests.mutate                 # every mutation, a table, then the JSON report
    python -m tests.mutate --list          # the mutations and the tests each one runs
    python -m tests.mutate --only NAME ... # some of them (names or prefixes: "shading.")
    python -m tests.mutate --json report.json --rev HEAD

Each mutation replaces one snippet of one file (exactly one occurrence, so a mutation that no
longer applies is reported as stale instead of silently testing nothing) in a scratch copy of
the repository, runs the test files it names there, and restores the file. A mutation is killed
when a test fails, errors, crashes or times out, and survives when they all pass. The shared
checkout is never written: the scratch copy is the working tree's tracked and untracked
(not ignored) files, or with --rev the files of that commit.

The scratch copy's unmutated tests run first (the baseline); a failing baseline stops the run,
since every mutation would then look killed. CLRAY_REQUIRE_DEVICE=1 makes a missing OpenCL
device fail rather than skip. Kernels are built from their inlined full text (clray.device.
program.kernel_source), so PoCL's cache, here one per run, never serves a stale binary.

Not collected by pytest (the name does not start with test_): it takes about 15 minutes on two
CPU cores with PoCL (two runs with disjoint --only lists can share the machine).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Test files by topic; a mutation runs the ones that should notice it.
RENDER = "tests/test_render.py"
FEATURES = "tests/test_feature_paths.py"
INTERSECT = "tests/test_intersect.py"
MESH = "tests/test_mesh_render.py"
HARD = "tests/hard_cases/test_hard_cases.py"
SHADOW = "tests/test_shadow_rays.py"
REFERENCE = "tests/test_reference.py"
BVH = "tests/test_bvh.py"
WIDE = "tests/test_wide.py"
LAYOUT = "tests/test_layout.py"
LOAD = "tests/test_load.py"
OBJ = "tests/test_obj.py"
SCALE = "tests/test_scale.py"
IMAGE_IO = "tests/test_image_io.py"
SRGB = "tests/test_srgb.py"
COLOUR = "tests/test_colour.py"
METRICS = "tests/test_metrics.py"
CLI = "tests/test_cli.py"
STUDY = "tests/test_study.py"
DEVICE = "tests/test_device_fixture.py"
LIGHTS = "tests/test_area_lights.py"
EMISSION = "tests/test_emission.py"
INSTANCES = "tests/test_instances.py"
CAMERA = "tests/test_camera.py"
FRESNEL = "tests/test_fresnel.py"
BACKGROUND = "tests/test_background.py"
PASSES = "tests/test_passes.py"
# The kernel-vs-reference scenes and the closed forms, without test_render.py's slower checks.
KERNEL_SCENES = (f"{RENDER}::test_kernel_matches_reference",
                 f"{RENDER}::test_plane_under_directional_light_is_uniform",
                 f"{RENDER}::test_lone_sphere_follows_lambert", FEATURES)


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


def m(name: str, path: str, old: str, new: str, *tests: str) -> Mutation:
    return Mutation(name, path, old, new, tests)


MUTATIONS: tuple[Mutation, ...] = (
    # instances (kernels/bvh.h, kernels/surface.h, clray/device/pack.py)
    m("instances.to_world_not_the_inverse", "kernels/surface.h",
      "c1 = cross(r2, r0)", "c1 = cross(r0, r2)", INSTANCES, HARD),
    m("instances.one_row_factor_for_all", "kernels/surface.h",
      "REAL3 column = (REAL3)(d0, d1, d2) * inv_det;", "REAL3 column = (REAL3)(d0) * inv_det;",
      INSTANCES, HARD),
    m("instances.double_bound_in_double_roundings", "kernels/surface.h",
      "REAL gamma = fmax(gamma_n(ERR_ROUNDINGS), (REAL)(ERR_ROUNDINGS * FLT_EPSILON));",
      "REAL gamma = gamma_n(ERR_ROUNDINGS);", HARD),
    m("instances.scene_ray_not_restored", "kernels/bvh.h",
      "instance = -1;\n            r = &own;\n#endif\n        } else {",
      "instance = -1;\n#endif\n        } else {", INSTANCES),
    m("instances.material_not_replaced", "kernels/surface.h",
      "if (in->material >= 0) sf.material = in->material;", "", INSTANCES),
    m("instances.bounds_not_mapped", "clray/device/pack.py",
      'placed = np.einsum("nij,nkj->nki", to_world[:, :, :3], corners) + to_world[:, None, :, 3]',
      "placed = corners + to_world[:, None, :, 3]", INSTANCES),
    # kernels/camera.h and sampling.h (the pixel's and the lens's samples)
    m("camera.jitter_dims_shared", "kernels/sampling.h",
      "(REAL)x + jitter((REAL)(s % nx), r0, (REAL)1, (REAL)cells)",
      "(REAL)x + jitter((REAL)(s % nx), r1, (REAL)1, (REAL)cells)", *KERNEL_SCENES),
    # The pixel's and the lights' strata alike (sampling.h row_cells).
    m("camera.last_row_as_full", "kernels/sampling.h",
      "return min(nx, spp - row * nx);", "return nx;", CAMERA, "tests/test_area_lights.py",
      *KERNEL_SCENES),
    m("camera.py_flipped", "kernels/camera.h",
      "(REAL)1 - q.y", "q.y - (REAL)1",
      *KERNEL_SCENES),
    m("camera.px_over_height", "kernels/camera.h",
      "(REAL2)((REAL)width, (REAL)height)", "(REAL2)((REAL)height, (REAL)height)",
      *KERNEL_SCENES),
    m("camera.lens_radius_linear", "kernels/sampling.h",
      "REAL rho = sqrt(rng_uniform(seed, pixel, (uint)s, 3u));",
      "REAL rho = rng_uniform(seed, pixel, (uint)s, 3u);", CAMERA),
    m("camera.lens_strata_unpermuted", "kernels/sampling.h",
      "permute_stratum((uint)s, (uint)spp, rng_bits(seed, pixel, (uint)spp, 2u))", "(uint)s",
      CAMERA),
    m("camera.lens_aim_unscaled", "kernels/camera.h",
      "*d = normalize3(aim - TO_REAL(camera->lens_u.w) * lens);", "*d = normalize3(aim - lens);",
      CAMERA),
    m("camera.orthographic_rays_spread", "kernels/camera.h",
      "REAL3 aim = TO_REAL3(camera->forward);\n#else",
      "REAL3 aim = TO_REAL3(camera->forward) + across;\n#else", CAMERA),
    # kernels/fresnel.h and its use
    m("fresnel.p_as_s", "kernels/fresnel.h", "rp = (cos_i - eta * cos_t) / dp",
      "rp = (eta * cos_i - cos_t) / ds", FRESNEL),
    m("fresnel.transmit_kept_whole", "kernels/ray_tree.h", "kt *= (REAL)1 - f;", "", FRESNEL),
    m("fresnel.schlick_incident_cosine_always", "kernels/fresnel.h",
      "(eta > (REAL)1 ? cos_t : cos_i)", "cos_i", FRESNEL),
    # kernels/background.h
    m("background.gradient_upside_down", "kernels/background.h",
      "mix(TO_REAL3(params->background), TO_REAL3(params->background_top), t)",
      "mix(TO_REAL3(params->background_top), TO_REAL3(params->background), t)", BACKGROUND),
    m("background.panorama_mirrored", "kernels/background.h", "atan2(u.x, -u.z)",
      "atan2(-u.x, -u.z)", BACKGROUND),
    m("background.panorama_poles_unclamped", "kernels/background.h",
      "clamp(((REAL)1 - ev) * (REAL)h - REAL_C(0.5), (REAL)0, (REAL)(h - 1))",
      "((REAL)1 - ev) * (REAL)h - REAL_C(0.5)", BACKGROUND),
    # kernels/rng.h
    m("rng.23_bits", "kernels/rng.h", "(REAL)(rng_bits(seed, pixel, sample, dim) >> 8)",
      "(REAL)(rng_bits(seed, pixel, sample, dim) >> 9)", *KERNEL_SCENES),
    m("rng.counter_without_stride", "kernels/rng.h", "^ (4u * sample + dim)", "^ (sample + dim)",
      *KERNEL_SCENES),
    m("rng.multiplier", "kernels/rng.h", "* 277803737u", "* 277803739u", *KERNEL_SCENES),
    # kernels/real.h
    m("real.no_error_bound", "kernels/real.h",
      "return (REAL)n * u / ((REAL)1 - (REAL)n * u);", "return (REAL)0;",
      RENDER, HARD, MESH, FEATURES),
    m("real.frame_helper_swapped", "kernels/real.h",
      "fabs(x) < 0.9f ? (REAL3)(1, 0, 0) : (REAL3)(0, 1, 0)",
      "fabs(x) < 0.9f ? (REAL3)(0, 1, 0) : (REAL3)(1, 0, 0)", *KERNEL_SCENES),
    m("real.lowest_bit_is_highest", "kernels/real.h",
      "return 31 - clz(bits & -bits);", "return 31 - clz(bits);", INTERSECT, RENDER),
    # One definition for the single-ray, leaf-packet and lane-wise forms (real.h, Twins).
    m("real.no_fma_error_term", "kernels/real.h",
      "T err = fma(-c, d, cd);", "T err = (T)(0);", INTERSECT, HARD),
    # kernels/clray_types.h
    m("scene.buffers_cylinders_after_cones", "kernels/scene.h",
      "    X(Cylinder, cylinders) SEP              \\\n    X(Cone, cones) SEP",
      "    X(Cone, cones) SEP                      \\\n    X(Cylinder, cylinders) SEP", LAYOUT),
    m("types.prim_cone_code", "kernels/clray_types.h",
      "#define PRIM_CONE 4", "#define PRIM_CONE 7", LAYOUT),
    m("types.point_light_code", "kernels/clray_types.h",
      "#define LIGHT_POINT 0", "#define LIGHT_POINT 2", LAYOUT, *KERNEL_SCENES),
    m("types.material_fields_swapped", "kernels/clray_types.h",
      "float ambient, diffuse, specular, shininess;",
      "float diffuse, ambient, specular, shininess;",
      LAYOUT, RENDER),
    # the shapes' tests (kernels/shape.h, plane.h, sphere.h, cylinder.h, cone.h, triangle.h)
    m("intersect.press_root_sign", "kernels/shape.h",
      "REAL q = -(b + copysign(sqrt(disc), b));", "REAL q = -(b - copysign(sqrt(disc), b));",
      INTERSECT),
    m("intersect.plane_offset_sign", "kernels/plane.h",
      "REAL t = dot3(TO_REAL3(pl->point) - r->o, n) / dn;",
      "REAL t = dot3(r->o - TO_REAL3(pl->point), n) / dn;", INTERSECT),
    m("intersect.slab_not_widened", "kernels/shape.h",
      "        tf *= widen;\n", "", INTERSECT, HARD),
    # The nodes' slab test: the near plane by the reciprocal's sign, not by comparing the two t
    # (a -0 direction component on a face plane).
    m("intersect.node_near_plane_by_t", "kernels/bvh.h",
      "T near = select(tn, tf, SIGNS(inv));", "T near = tn > tf ? tf : tn;", INTERSECT),
    # The single-ray walks' triangle set-up, made at the first leaf (make_walk_ray).
    m("intersect.walk_ray_never_sheared", "kernels/bvh.h",
      "if (r->kz < 0) shear_walk_ray(r);", "", INTERSECT),
    m("intersect.cylinder_caps_swapped", "kernels/cylinder.h",
      "REAL tc = ((cap ? height : (REAL)0) - fa) / da;",
      "REAL tc = ((cap ? (REAL)0 : height) - fa) / da;", INTERSECT),
    m("intersect.cone_cap_radius", "kernels/cone.h",
      "REAL rb = height * tan_a;", "REAL rb = tan_a;", INTERSECT),
    m("intersect.side_unbounded_above", "kernels/shape.h",
      "if (s >= -tol && s <= height + tol) add_candidate", "if (s >= -tol) add_candidate",
      INTERSECT),
    m("intersect.triangle_hits_behind", "kernels/triangle.h",
      "M ahead = ((det < 0) & (t_scaled < 0)) | ((det > 0) & (t_scaled > 0));",
      "M ahead = (det != 0);", INTERSECT),
    m("intersect.triangle_backfaces_culled", "kernels/triangle.h",
      "M mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0));",
      "M mixed = (e0 < 0) | (e1 < 0) | (e2 < 0);", INTERSECT),
    m("intersect.sphere_packet_ignores_disc", "kernels/sphere.h",
      "MASK4 crossed = disc >= (REAL)0;", "MASK4 crossed = (MASK4)(-1);", INTERSECT),
    m("intersect.sphere_packet_stops_unless_all_crossed", "kernels/sphere.h",
      "if (!lane_bits4(convert_int4(crossed))) return 0;",
      "if (lane_bits4(convert_int4(crossed)) != 15) return 0;", INTERSECT),
    m("real.lane_bits8_upper_half_as_lower", "kernels/real.h",
      "(m.hi & (int4)(16, 32, 64, 128))", "(m.hi & (int4)(1, 2, 4, 8))", INTERSECT,
      "tests/test_lane_bits.py"),
    m("lanes.lane_mask_movmsk_drops_a_lane", "kernels/lanes.h",
      "HOT int lane_mask(MASKP m) { return lane_bits8(m); }",
      "HOT int lane_mask(MASKP m) { return lane_bits8(m) & 127; }", "tests/test_packets.py"),
    m("real.lane_bits8_movmsk_of_lower_half", "kernels/real.h",
      "__builtin_ia32_movmskps256(as_float8(m))", "__builtin_ia32_movmskps(as_float4(m.lo))",
      INTERSECT, "tests/test_lane_bits.py"),
    # kernels/bvh.h
    m("bvh.tie_to_larger_ref", "kernels/bvh.h",
      "return ref < hit->ref;", "return ref > hit->ref;",
      INTERSECT),
    m("bvh.first_crossing_only", "kernels/bvh.h",
      "int k = c->t[0] > (REAL)0 ? 0 : 1;", "int k = 0;", INTERSECT),
    m("bvh.flat_boxes_missed", "kernels/bvh.h",
      "MASK_TO_INTW(t0 <= t1) & used", "MASK_TO_INTW(t0 < t1) & used", INTERSECT),
    m("bvh.pop_prunes_the_wrong_side", "kernels/bvh.h",
      "while (sp > 0 && stack_t[sp - 1] > tie_reach(hit.t)) sp--;",
      "while (sp > 0 && stack_t[sp - 1] < tie_reach(hit.t)) sp--;", INTERSECT),
    m("bvh.shadow_ignores_segment_end", "kernels/bvh.h",
      "if (c->t[k] > (REAL)0 && c->t[k] < tmax) {", "if (c->t[k] > (REAL)0) {",
      *KERNEL_SCENES, SHADOW),
    m("bvh.shadow_filters_first_crossing_only", "kernels/bvh.h",
      "for (int k = 0; k < 2; ++k) {\n        if (c->t[k]",
      "for (int k = 0; k < 1; ++k) {\n        if (c->t[k]", *KERNEL_SCENES),
    m("bvh.opaque_triangle_beyond_light_blocks", "kernels/bvh.h",
      "lane_bits4(convert_int4((t > lo) & (t < hi)))", "lane_bits4(convert_int4(t > lo))",
      *KERNEL_SCENES),
    # kernels/texture.h
    m("texture.v_not_flipped", "kernels/texture.h",
      "REAL sy = ((REAL)1 - wrap01(tv)) * (REAL)h",
      "REAL sy = wrap01(tv) * (REAL)h", *KERNEL_SCENES, MESH),
    m("texture.bilinear_weight", "kernels/texture.h",
      "return mix(top, bottom, fy);", "return mix(top, bottom, fx);", *KERNEL_SCENES, MESH),
    m("texture.repeat_axes_swapped", "kernels/texture.h",
      "wrap01(uv.x * TO_REAL(tx->repeat_u))", "wrap01(uv.x * TO_REAL(tx->repeat_v))",
      *KERNEL_SCENES, MESH),
    m("texture.checker_pushed_towards_viewer", "kernels/texture.h",
      "(p - REAL_C(0.25) * size * n_f) / size", "(p + REAL_C(0.25) * size * n_f) / size",
      *KERNEL_SCENES),
    m("texture.checker_parity", "kernels/texture.h",
      "floor(cells * REAL_C(0.5)) == (REAL)1;",
      "floor(cells * REAL_C(0.5)) == (REAL)0;",
      *KERNEL_SCENES),
    m("texture.blend_reversed", "kernels/texture.h",
      "return blend * texel + ((REAL)1 - blend) * color;",
      "return ((REAL)1 - blend) * texel + blend * color;", *KERNEL_SCENES),
    # surfaces and shading (the shapes' headers, surface.h, lights.h, direct.h)
    m("shading.phong_power_skips_odd_bits", "kernels/lights.h",
      "r = (n & 1) != 0 ? r * x : r;", "r = (n & 2) != 0 ? r * x : r;", *KERNEL_SCENES),
    m("shading.phong_power_truncates_fractions", "kernels/lights.h",
      "s <= (REAL)4096 && s == floor(s)", "s <= (REAL)4096", *KERNEL_SCENES),
    m("shading.no_specular", "kernels/lights.h",
      "(diffuse * ndl * c + specular * spec)", "(diffuse * ndl * c)", *KERNEL_SCENES),
    m("shading.reflection_vector", "kernels/lights.h",
      "REAL3 refl = (REAL)2 * ndl * n - l;", "REAL3 refl = (REAL)2 * ndl * l - n;",
      *KERNEL_SCENES),
    m("shading.no_attenuation_clamp", "kernels/lights.h",
      "LESSER((T)(1), (REAL)1 / denom)", "(REAL)1 / denom", *KERNEL_SCENES),
    m("shading.linear_quadratic_term", "kernels/lights.h",
      "T denom = (T)(k.x) + k.y * dist + k.z * dist * dist;",
      "T denom = (T)(k.x) + k.y * dist + k.z * dist;", *KERNEL_SCENES),
    m("shading.shadow_ray_past_the_light", "kernels/lights.h",
      " tmax = span * ((REAL)1 - gamma_f32(ERR_ROUNDINGS));", " tmax = REAL_INF;",
      *KERNEL_SCENES, SHADOW),
    m("shading.no_scene_ambient", "kernels/direct.h",
      "TO_REAL(m->ambient) * c * ambient_light", "TO_REAL(m->ambient) * c", *KERNEL_SCENES),
    m("shading.shadow_filter_ignored", "kernels/lights.h",
      "phong_term(atten, TO_REAL3(light->color), filter,",
      "phong_term(atten, TO_REAL3(light->color), (REAL3)(1),",
      *KERNEL_SCENES),
    m("shading.offset_one_side", "kernels/surface.h",
      "return dot3(w, sf->n_g) > (REAL)0 ? sf->p + d * sf->n_g : sf->p - d * sf->n_g;",
      "return sf->p + d * sf->n_g;", *KERNEL_SCENES, HARD),
    m("shading.cone_cap_uv_radius", "kernels/cone.h",
      "axial_uv(q, axis, h / height, hit->part, height * tan_a)",
      "axial_uv(q, axis, h / height, hit->part, tan_a)", *KERNEL_SCENES),
    m("shading.cylinder_cap_uv_radius", "kernels/cylinder.h",
      "axial_uv(q, axis, h / height, hit->part, radius)",
      "axial_uv(q, axis, h / height, hit->part, height)", *KERNEL_SCENES),
    m("shading.plane_uv_anchor_dropped", "kernels/plane.h",
      "sf->uv = (REAL2)(dot(*p - q, e1) + TO_REAL(pl->point.w),",
      "sf->uv = (REAL2)(dot(*p - q, e1),", *KERNEL_SCENES),
    m("shading.sphere_u_axes", "kernels/sphere.h",
      "sf->uv = (REAL2)(angle_u(n.x, n.z),", "sf->uv = (REAL2)(angle_u(n.z, n.x),",
      *KERNEL_SCENES),
    m("shading.cone_normal_sign", "kernels/cone.h",
      "(radial - tan_a * axis) / sqrt", "(radial + tan_a * axis) / sqrt", INTERSECT, RENDER),
    m("shading.cylinder_bottom_cap_normal", "kernels/cylinder.h",
      "sf->n_g = hit->part == 2 ? axis : -axis;", "sf->n_g = axis;", INTERSECT, RENDER),
    m("shading.box_uv_axes", "kernels/box.h",
      "int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;",
      "int a1 = (axis + 2) % 3, a2 = (axis + 1) % 3;", *KERNEL_SCENES),
    m("shading.vertex_normal_index", "kernels/triangle.h",
      "b1 * TO_REAL3(s->normals[tri.v1])", "b1 * TO_REAL3(s->normals[tri.v2])", MESH),
    m("shading.vertex_uv_index", "kernels/triangle.h",
      "b2 * TO_REAL2(s->uvs[tri.v2])", "b2 * TO_REAL2(s->uvs[tri.v1])", MESH),
    # kernels/sampling.h and lights.h (area lights' samples, spot cones)
    m("lights.area_weight_without_cos", "kernels/lights.h",
      "fmin(TO_REAL(light->color.w) * cos_l / dist / dist",
      "fmin(TO_REAL(light->color.w) / dist / dist", LIGHTS),
    m("lights.two_sided", "kernels/lights.h",
      "if (!(cos_l > (REAL)0)) return false;", "cos_l = fabs(cos_l);", LIGHTS),
    m("lights.jitter_dimensions_swapped", "kernels/sampling.h",
      "r0 = light_uniform(key, k.sample, 0u), r1 = light_uniform(key, k.sample, 1u);",
      "r0 = light_uniform(key, k.sample, 1u), r1 = light_uniform(key, k.sample, 0u);", LIGHTS),
    m("lights.no_stratum_permutation", "kernels/sampling.h",
      "permute_stratum((uint)k.sample, (uint)k.spp, key)", "(uint)k.sample % (uint)k.spp",
      LIGHTS),
    m("lights.stratum_permutation_shared", "kernels/sampling.h",
      "int stratum = (int)permute_stratum((uint)k.sample, (uint)k.spp, key);",
      "int stratum = (int)permute_stratum((uint)k.sample, (uint)k.spp, k.seed);", LIGHTS),
    m("lights.sphere_solid_angle_halved", "kernels/lights.h",
      "*weight = (REAL)2 * PI_R * k;", "*weight = PI_R * k;", LIGHTS),
    m("lights.disc_not_concentric", "kernels/sampling.h",
      "phi = (PI_R / (REAL)4) * (b / a);", "phi = (PI_R / (REAL)2) * (b / a);", LIGHTS),
    m("lights.spot_linear_rim", "kernels/lights.h",
      "return t * t * ((REAL)3 - (REAL)2 * t);", "return t;", LIGHTS),
    m("pack.spot_inner_is_outer", "clray/lights/spot.py",
      "f4((0.0, 0.0, 0.0), versine(inner))",
      "f4((0.0, 0.0, 0.0), versine(light.angle))", LIGHTS),
    # kernels/ray_tree.h and background.h (sky)
    m("render.reflection_half", "kernels/ray_tree.h",
      "{ return d - (REAL)2 * dn * n; }", "{ return d - dn * n; }",
      *KERNEL_SCENES),
    m("render.tir_weight_lost", "kernels/ray_tree.h",
      "kr += kt;  // total internal reflection", "// total internal reflection", *KERNEL_SCENES,
      HARD),
    m("render.refraction_root_sign", "kernels/ray_tree.h",
      "(eta * cos_i - sqrt(k)) * n", "(eta * cos_i + sqrt(k)) * n", *KERNEL_SCENES),
    m("render.eta_inverted_on_entry", "kernels/ray_tree.h",
      "return n1 / ior_m;", "return ior_m / n1;", *KERNEL_SCENES),
    m("render.one_bounce_short", "kernels/ray_tree.h",
      "if (task->depth >= MAX_DEPTH) return 0;", "if (task->depth + 1 >= MAX_DEPTH) return 0;",
      *KERNEL_SCENES),
    m("render.reflection_unweighted", "kernels/ray_tree.h",
      "spawn(stack, sp, &next, &pt->sf, task->weight * kr,",
      "spawn(stack, sp, &next, &pt->sf, task->weight,", *KERNEL_SCENES),
    m("shading.normal_not_faced", "kernels/shading.h",
      "pt.n = dot(pt.sf.n_s, ray->d) < (REAL)0 ? pt.sf.n_s : -pt.sf.n_s;", "pt.n = pt.sf.n_s;",
      *KERNEL_SCENES),
    m("shading.checker_in_camera_frame", "kernels/shading.h",
      "pt.sf.p + TO_REAL3(camera->world)", "pt.sf.p", *KERNEL_SCENES),
    m("render.background_unweighted", "kernels/background.h",
      "return weight * TO_REAL3(params->background);", "return TO_REAL3(params->background);",
      *KERNEL_SCENES),
    m("group.pushed_entries_lost", "kernels/group.h",
      "st->own_t[at] = (bits >> far) & 1 ? tnear[far] : (REAL)-1;", "st->own_t[at] = (REAL)-1;",
      "tests/test_packets.py::test_group_packets_find_the_single_ray_hits"),
    # clray/device
    m("policy.native_width_ignored", "clray/device/policy.py",
      "return max(device.preferred_vector_width_float, device.native_vector_width_float)",
      "return device.preferred_vector_width_float",
      "tests/test_tuning.py::test_vector_width_is_the_preferred_or_the_native_one"),
    m("policy.packets_on_no_device", "clray/device/policy.py",
      '        return "sample_packet"\n    return "single"',
      '        return "single"\n    return "single"',
      "tests/test_tuning.py::test_each_device_has_its_own_traversal"),
    m("pack.plane_anchor_dropped", "clray/device/pack.py",
      'planes[i]["point"] = f4(nearest, np.dot(shift, e1))',
      'planes[i]["point"] = f4(nearest, 0.0)', *KERNEL_SCENES),
    m("pack.cone_bounds_radius", "clray/shapes/cone.py",
      'ext = disc_extent(axis, length * float(rec["apex_tan"][3]))',
      'ext = disc_extent(axis, float(rec["apex_tan"][3]))', INTERSECT),
    m("pack.cylinder_bounds_without_radius", "clray/shapes/cylinder.py",
      "lo.append(np.minimum(base, top) - ext)", "lo.append(np.minimum(base, top))", INTERSECT),
    m("pack.cone_half_angle_halved", "clray/shapes/cone.py",
      "np.tan(np.radians(o.angle))", "np.tan(np.radians(o.angle) / 2)", INTERSECT, RENDER),
    m("pack.attenuation_reversed", "clray/lights/point.py",
      'f4(light.attenuation)', 'f4(light.attenuation[::-1])', *KERNEL_SCENES),
    m("layout.texture_repeat_fields_swapped", "clray/device/layout.py",
      'TEXTURE = _struct([("color2", _F4), ("size", "<f4"), ("repeat_u", "<f4"), ("repeat_v",',
      'TEXTURE = _struct([("color2", _F4), ("size", "<f4"), ("repeat_v", "<f4"), ("repeat_u",',
      LAYOUT, INTERSECT),
    # clray/accel
    m("context.fp64_ignored", "clray/device/context.py",
      'if "cl_khr_fp64" in device.extensions.split():\n        return True\n'
      '    return opencl_version(device) >= (1, 2) and device.double_fp_config != 0',
      "return False", RENDER, HARD),
    m("bvh_device.bin_index_clamped_short", "kernels/bvh_build.cl",
      "return clamp((int)((c - cmin) * scale), 0, N_BINS - 1);",
      "return clamp((int)((c - cmin) * scale), 0, N_BINS - 2);", BVH),
    m("bvh_device.bins_not_the_hosts", "clray/device/bvh_builder.py",
      'f"-DN_BINS={N_BINS}"', '"-DN_BINS=8"', BVH),
    m("bvh_host.bounds_not_rounded_out", "clray/accel/bvh.py",
      "np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)", "hi32", BVH),
    m("bvh_host.sah_one_face", "clray/accel/bvh.py",
      "return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]",
      "return e[..., 0] * e[..., 1]", BVH),
    m("wide.refit_leaves_inner_boxes", "clray/accel/wide.py",
      "    for level in reversed(levels[:-1]):", "    for level in reversed(levels[:-2]):",
      WIDE, "tests/test_refit.py"),
    m("wide.refit_skips_instance_lanes", "clray/accel/wide.py",
      "    rows[node, lo, lane] = instance_lo[child[node, lane]]", "    pass", WIDE,
      "tests/test_refit.py"),
    m("wide.tree_cost_without_leaves", "clray/accel/wide.py",
      "_leaf_packets(count) + (count & LEAF_FIELD_MASK), traversal_cost)",
      "0, traversal_cost)", "tests/test_refit.py"),
    m("pack.move_ignores_instance_places", "clray/device/pack.py",
      "(np.array_equal(eye, geometry.eye) and np.array_equal(placements, geometry.placements)",
      "(np.array_equal(eye, geometry.eye)", "tests/test_refit.py"),
    m("pack.move_ignores_shape_values", "clray/device/pack.py",
      "and all(at.shapes[b].tobytes() == geometry.shapes[b].tobytes()",
      "and all(True", "tests/test_refit.py"),
    m("pack.move_skips_a_scene_packet", "clray/device/pack.py",
      "    first = geometry.group_packets\n", "    first = geometry.group_packets + 1\n",
      "tests/test_refit.py"),
    m("pack.refit_past_cost_limit_kept", "clray/device/pack.py",
      "if moved is None or moved.cost > REFIT_COST_LIMIT * (moved.built_cost or 0.0):",
      "if moved is None:",
      "tests/test_refit.py"),
    m("sequence.moved_objects_pack_each_frame", "clray/sequence.py",
      'track.path[0] in ("objects", "groups") and not moved_in_place(track.path)',
      'track.path[0] in ("objects", "groups")', "tests/test_sequence.py"),
    m("pack.move_to_other_primitives", "clray/device/pack.py",
      "    if not _same_primitives(geometry, at, sources):\n        return None\n", "",
      "tests/test_refit.py"),
    m("wide.stack_size_without_extra", "clray/accel/wide.py",
      "np.repeat(pushed[lo:hi] + extra[lo:hi], inner.sum(axis=1))",
      "np.repeat(pushed[lo:hi], inner.sum(axis=1))", WIDE, INTERSECT),
    # clray/scene
    m("model.camera_handedness", "clray/scene/model.py",
      "right = unit(np.cross(forward, unit(self.up)))",
      "right = unit(np.cross(unit(self.up), forward))",
      *KERNEL_SCENES, REFERENCE, HARD),
    m("values.directions_not_normalised", "clray/scene/values.py",
      "x, y, z = unit(v).tolist()", "x, y, z = v", LOAD, *KERNEL_SCENES),
    m("obj.indices_not_one_based", "clray/scene/obj.py", "index = raw - 1", "index = raw", OBJ),
    m("scale.ratio_limit", "clray/scene/scale.py", "RATIO_LIMIT = 1e4", "RATIO_LIMIT = 1e5",
      SCALE, HARD),
    # clray (top level)
    m("colour.srgb_threshold", "clray/scene/colour.py",
      "np.where(linear <= 0.0031308, 12.92 * linear,",
      "np.where(linear <= 0.04045, 12.92 * linear,",
      IMAGE_IO, SRGB),
    m("colour.srgb_decode_threshold", "clray/scene/colour.py",
      "np.where(encoded <= 0.04045, encoded / 12.92,",
      "np.where(encoded <= 0.0031308, encoded / 12.92,",
      SRGB, COLOUR),
    m("image_io.exposure_ignored", "clray/image_io.py",
      "values *= 2.0 ** encoding.exposure", "values *= 1.0", COLOUR),
    m("image_io.linear_png_tagged_srgb", "clray/image_io.py",
      "tag = (_png_chunk(b\"gAMA\", struct.pack(\">I\", 100000)) if linear",
      "tag = (_png_chunk(b\"gAMA\", struct.pack(\">I\", 100000)) if not linear",
      IMAGE_IO, COLOUR),
    m("materials.srgb_textures_not_decoded", "clray/scene/parse_materials.py",
      'if colorspace == "srgb":\n        texels = assets.decoded(texels)\n'
      '    return Texture(',
      'if colorspace == "linear":\n        texels = assets.decoded(texels)\n'
      '    return Texture(',
      LOAD, COLOUR),
    m("render.launch_rows_off_by_one", "clray/device/launch.py",
      "image[row0:row0 + band])\n            row0 += band\n",
      "image[row0:row0 + band])\n            row0 += band + 1\n",
      RENDER),
    m("metrics.count_over_inclusive", "clray/metrics.py",
      "close = (np.abs(_diff(a, b)) <= threshold) | (a == b)",
      "close = (np.abs(_diff(a, b)) < threshold) | (a == b)", METRICS),
    m("reference.no_attenuation_clamp", "clray/lights/point.py",
      "np.minimum(1.0, 1.0 / denom)", "1.0 / denom", REFERENCE, *KERNEL_SCENES),
    m("reference.specular_from_direction", "clray/reference/shading.py",
      "rv = dot(r, -d)", "rv = dot(r, d)", REFERENCE),
    # passes (kernels/passes.h, render.cl's render_passes, clray/passes.py, launch.py)
    m("passes.normal_facing_the_ray", "kernels/passes.h",
      "out.normal += pt.sf.n_s;", "out.normal += pt.n;", PASSES),
    m("passes.depth_over_every_sample", "kernels/render.cl",
      "(float)(p.depth / hits)", "(float)(p.depth / (REAL)params->spp)", PASSES),
    m("passes.position_camera_relative", "kernels/passes.h",
      "out.position += pt.sf.p + TO_REAL3(camera->world);", "out.position += pt.sf.p;",
      PASSES),
    m("passes.albedo_over_hits", "kernels/render.cl",
      "REAL3 colour = p.albedo / (REAL)params->spp;",
      "REAL3 colour = p.albedo / fmax(hits, (REAL)1);", PASSES),
    m("passes.instance_dropped", "kernels/passes.h",
      "out.instance = found ? hit.instance : -1;", "out.instance = -1;", PASSES),
    m("passes.object_not_the_instance", "clray/passes.py",
      "    objects[inside] = instance_objects(scene)[instances[inside]]\n", "", PASSES),
    m("passes.bands_at_the_first_row", "clray/device/launch.py",
      "kernel.set_args(*buffers, *band_buffers, np.int32(first + row0))",
      "kernel.set_args(*buffers, *band_buffers, np.int32(first))", PASSES),
    # mesh lights (kernels/lights.h, kernels/sampling.h, clray/lights/mesh.py, emitters.py)
    m("mesh_lights.pick_weight_dropped", "kernels/lights.h",
      "atten = fmin(atten * pick_weight, AREA_WEIGHT_MAX);",
      "atten = fmin(atten, AREA_WEIGHT_MAX);", EMISSION),
    m("mesh_lights.last_width_in_uint32", "kernels/lights.h",
      "ulong above = lo < mesh->pad1 - 1 ? (ulong)(uint)faces[lo].pad0 : 0x100000000ul;",
      "ulong above = (ulong)((uint)faces[lo].pad0 - (uint)below) + below;", EMISSION),
    m("mesh_lights.pick_on_a_threshold_takes_it", "kernels/lights.h",
      "if (pick < (uint)faces[mid].pad0) {", "if (pick <= (uint)faces[mid].pad0) {", EMISSION),
    m("mesh_lights.pick_shares_the_square_stream", "kernels/sampling.h",
      "uint pick_key = pcg_hash(light_key(k, light) ^ 0x40000000u);",
      "uint pick_key = light_key(k, light);", EMISSION),
    m("mesh_lights.picks_not_stratified", "kernels/sampling.h",
      "return (uint)((((ulong)stratum << 32) | (ulong)r) / (ulong)k.spp);", "return r;",
      EMISSION),
    m("mesh_lights.picks_uniform_not_by_area", "clray/lights/mesh.py",
      "share = np.cumsum(areas) / float(np.sum(areas))",
      "share = np.arange(1, len(areas) + 1) / len(areas)", EMISSION),
    m("mesh_lights.faces_at_the_limit_pooled", "clray/scene/emitters.py",
      "many = counts > EACH_FACE_UP_TO", "many = counts >= EACH_FACE_UP_TO", EMISSION),
)


@dataclass
class Outcome:
    name: str
    path: str
    status: str  # killed, survived, stale (the snippet no longer matches), error
    detail: str
    seconds: float
    tests: tuple[str, ...]


def _scratch_copy(dest: Path, rev: str | None) -> None:
    if rev is not None:
        archive = subprocess.run(["git", "archive", "--format=tar", rev], cwd=ROOT,
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
        return
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others",
                             "--exclude-standard"], cwd=ROOT, check=True,
                            capture_output=True).stdout.decode()
    for rel in filter(None, listed.split("\0")):
        src = ROOT / rel
        if src.is_file():  # a tracked file deleted in the working tree is left out
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def _check_imports(scratch: Path, env: dict[str, str]) -> None:
    """Exit unless the scratch copy's clray, and the kernels it builds, are the ones imported.
    The kernels ship as the package clray.kernels (pyproject.toml's package-dir), which an
    editable install maps to the shared checkout's kernels/: a link in the scratch copy's
    clray/ takes precedence, and a marker written into a scratch kernel must show up."""
    link = scratch / "clray" / "kernels"
    if (scratch / "kernels").is_dir() and not link.exists():
        link.symlink_to(Path("..") / "kernels", target_is_directory=True)
    marker = "// mutate.py: scratch kernel marker"
    header = scratch / "kernels" / "rng.h"
    original = header.read_text()
    header.write_text(original + marker + "\n")
    probe = ("import clray\nfrom clray.device.program import kernel_source\n"
             f"print(clray.__file__)\nprint({marker!r} in kernel_source())")
    try:
        out = subprocess.run([sys.executable, "-c", probe], cwd=scratch, env=env, check=True,
                             capture_output=True, text=True).stdout.split()
    finally:
        header.write_text(original)
    if not Path(out[0]).is_relative_to(scratch) or out[1] != "True":
        sys.exit(f"the scratch copy is not what runs: clray from {out[0]}, its kernels used: "
                 f"{out[1]}")


def _run_tests(scratch: Path, tests: tuple[str, ...], env: dict[str, str],
               timeout: float) -> tuple[int | None, str]:
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    try:
        done = subprocess.run(cmd, cwd=scratch, env=env, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {timeout:.0f} s"
    lines = (done.stdout + done.stderr).strip().splitlines()
    failed = [ln for ln in lines if ln.startswith(("FAILED", "ERROR"))]
    return done.returncode, (failed[0] if failed else lines[-1] if lines else "")[:200]


def _classify(code: int | None) -> str:
    # pytest: 1 tests failed; 2-5 interrupted, internal or usage errors, no tests collected.
    if code is None or code == 1 or code < 0:
        return "killed"
    return "survived" if code == 0 else "error"


def run(mutations: list[Mutation], rev: str | None, timeout: float, baseline: bool
        ) -> list[Outcome]:
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="clray-mutate-") as tmp:
        scratch = Path(tmp) / "repo"
        scratch.mkdir()
        _scratch_copy(scratch, rev)
        env = dict(os.environ, PYTHONPATH=str(scratch), CLRAY_REQUIRE_DEVICE="1",
                   POCL_CACHE_DIR=str(Path(tmp) / "pocl-cache"))
        _check_imports(scratch, env)
        if baseline:
            union = tuple(sorted({t for mu in mutations for t in mu.tests}))
            print(f"baseline: {len(union)} test files, unmutated", flush=True)
            code, detail = _run_tests(scratch, union, env, timeout * 4)
            if code != 0:
                sys.exit(f"the unmutated tests fail (exit {code}): {detail}")
        for i, mu in enumerate(mutations, start=1):
            target = scratch / mu.path
            original = target.read_text()
            start = time.monotonic()
            if original.count(mu.old) != 1:
                status, detail = "stale", f"snippet found {original.count(mu.old)} times"
            else:
                target.write_text(original.replace(mu.old, mu.new))
                try:
                    code, detail = _run_tests(scratch, mu.tests, env, timeout)
                finally:
                    target.write_text(original)
                status = _classify(code)
            seconds = time.monotonic() - start
            outcomes.append(Outcome(mu.name, mu.path, status, detail, seconds, mu.tests))
            print(f"[{i}/{len(mutations)}] {status:8} {mu.name} ({seconds:.0f} s)", flush=True)
    return outcomes


def table(outcomes: list[Outcome]) -> str:
    width = max(len(o.name) for o in outcomes)
    rows = [f"{'mutation':{width}}  {'status':8}  {'s':>5}  detail"]
    rows += [f"{o.name:{width}}  {o.status:8}  {o.seconds:5.0f}  {o.detail}" for o in outcomes]
    killed = sum(o.status == "killed" for o in outcomes)
    rows.append(f"score: {killed}/{len(outcomes)} killed")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.mutate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="+", metavar="NAME",
                        help="mutations whose name is, or starts with, one of these")
    parser.add_argument("--list", action="store_true", help="list the mutations and exit")
    parser.add_argument("--rev", help="test the files of this commit, not the working tree")
    parser.add_argument("--json", type=Path, help="write the report here (default: stdout)")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds per mutation's test run (default 900)")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip the unmutated run of every selected test file")
    args = parser.parse_args(argv)
    chosen = [mu for mu in MUTATIONS
              if not args.only or any(mu.name == o or mu.name.startswith(o) for o in args.only)]
    if args.list:
        for mu in chosen:
            print(f"{mu.name:44} {mu.path:24} {' '.join(mu.tests)}")
        return 0
    if not chosen:
        parser.error("no mutation matches --only")
    outcomes = run(chosen, args.rev, args.timeout, not args.no_baseline)
    print(table(outcomes))
    report = json.dumps({"killed": sum(o.status == "killed" for o in outcomes),
                         "total": len(outcomes),
                         "mutations": [asdict(o) for o in outcomes]}, indent=1)
    if args.json:
        args.json.write_text(report + "\n", encoding="utf-8")
    else:
        print(report)
    return 0 if all(o.status == "killed" for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
