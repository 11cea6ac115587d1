"""Tori. The ray-torus crossings of kernels/torus.h, built alone and checked against the float64
reference's (clray.reference.intersect_torus: the textbook quartic's companion eigenvalues,
polished on the distance form) and a closed form, in the float and double builds: thick and thin
tori (minor/major 1 to 1e-4), far from the origin (1e4), rays parallel to the axis. Every
crossing found must lie within two roundings (of the ray origin's scale) of the surface, and none
may be lost but on rays whose chord through the tube is shorter than the build's resolution can
decide (near-tangent). Then whole renders against the reference renderer, and the scene format's
checks. The hard cases (tests/hard_cases) see tori head-on, thin, far and lit."""

from __future__ import annotations

import copy

import numpy as np
import pyopencl as cl
import pytest

from clray import metrics
from clray.device.context import context_for, queue_for
from clray.device.program import device_build_options, kernel_source
from clray.errors import SceneError
from clray.reference import camera_rays, render_reference
from clray.reference.bvh import intersect_scene
from clray.render import RenderSettings, render
from clray.scene.load import scene_from_dict
from clray.scene.model import Instance, Torus
from clray.shapes.torus import TORUS, intersect_torus

PROBE = r"""
__kernel void probe(__global const float* o, __global const float* d, __global const Torus* tr,
                    __global REAL* out, __global int* count) {
    int i = get_global_id(0);
    Ray r = make_ray((REAL3)(o[3 * i], o[3 * i + 1], o[3 * i + 2]),
                     (REAL3)(d[3 * i], d[3 * i + 1], d[3 * i + 2]));
    REAL t[TORUS_ROOTS];
    count[i] = torus_crossings(tr, &r, t);
    for (int k = 0; k < TORUS_ROOTS; ++k) out[TORUS_ROOTS * i + k] = t[k];
}
"""


def device_crossings(device: cl.Device, o: np.ndarray, d: np.ndarray, torus: Torus,
                     double: bool) -> tuple[np.ndarray, np.ndarray]:
    """(t (N, 4), count (N,)) of torus_crossings for float32 rays, the torus as the packer
    stores it."""
    ctx = context_for(device)
    options = ["-DHAS_TORI=1", "-DBVH_WIDTH=8", *device_build_options(device)]
    if double:
        options.append("-DUSE_DOUBLE")
    source = kernel_source("torus.h") + PROBE
    program = cl.Program(ctx, source).build(options=options)
    record = np.zeros(1, dtype=TORUS.record)
    record["centre_major"][0] = (*torus.center, torus.major_radius)
    record["axis_minor"][0] = (*torus.axis, torus.minor_radius)
    mf = cl.mem_flags
    buffers = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in
               (np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32), record)]
    t = np.empty((len(o), 4), np.float64 if double else np.float32)
    count = np.empty(len(o), np.int32)
    out = [cl.Buffer(ctx, mf.WRITE_ONLY, a.nbytes) for a in (t, count)]
    queue = queue_for(device)
    program.probe(queue, (len(o),), None, *buffers, *out)
    cl.enqueue_copy(queue, t, out[0])
    cl.enqueue_copy(queue, count, out[1])
    return t.astype(np.float64), count


def stored(torus: Torus) -> Torus:
    """The torus as the device holds it: float32 numbers, the axis renormalised in float64."""
    def f32(v: object) -> np.ndarray:
        return np.asarray(v, np.float32).astype(np.float64)

    axis = f32(torus.axis)
    return Torus(tuple(f32(torus.center)), tuple(axis / np.linalg.norm(axis)),
                 float(f32(torus.major_radius)), float(f32(torus.minor_radius)), 0)


def aimed(rng: np.random.Generator, torus: Torus, n: int, dist: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """Rays from `dist` away, each aimed at a point within 1.5 minor radii of the circle, with
    directions of lengths 0.5 to 2 (t is not a distance), as float32."""
    axis = np.asarray(torus.axis)
    e1 = np.cross(axis, [1, 0, 0] if abs(axis[0]) < 0.9 else [0, 1, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi, theta = rng.uniform(0, 2 * np.pi, (2, n))
    off = 1.5 * torus.minor_radius * np.sqrt(rng.uniform(0, 1, n))
    ring = torus.major_radius + off * np.cos(theta)
    target = (np.asarray(torus.center) + (ring * np.cos(phi))[:, None] * e1
              + (ring * np.sin(phi))[:, None] * e2 + (off * np.sin(theta))[:, None] * axis)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    o = (target - dist * dirs).astype(np.float32).astype(np.float64)
    d = (dirs * rng.uniform(0.5, 2, n)[:, None]).astype(np.float32).astype(np.float64)
    return o, d


def tube_distance(torus: Torus, p: np.ndarray) -> np.ndarray:
    q = p - np.asarray(torus.center)
    z = q @ np.asarray(torus.axis)
    rho = np.linalg.norm(q - z[:, None] * np.asarray(torus.axis), axis=1)
    return np.abs(np.hypot(rho - torus.major_radius, z) - torus.minor_radius)


def _axis(v: tuple) -> tuple:
    return tuple(np.asarray(v) / np.linalg.norm(v))


RING_CASES = [((0.0, 0.0, 0.0), _axis((0.3, 1, 0.2)), major, minor, 3 * (major + minor))
              for major, minor in [(1, 0.25), (1, 1), (1, 0.5), (1, 1e-2), (1, 1e-3), (1, 1e-4),
                                   (100, 1e-2)]]
RING_CASES += [((1e4, -1e4, 1e4), (0.0, 0.0, 1.0), 1, minor, 5.0) for minor in (0.25, 1e-2)]


@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
@pytest.mark.parametrize(("centre", "axis", "major", "minor", "dist"), RING_CASES)
def test_crossings_lie_on_the_torus_and_none_is_lost(cl_device, centre, axis, major, minor,
                                                     dist, double):
    if double and not cl_device.double_fp_config:
        pytest.skip("no fp64 on this device")
    torus = stored(Torus(centre, axis, major, minor, 0))
    o, d = aimed(np.random.default_rng(1), torus, 1500, dist)
    t, count = device_crossings(cl_device, o, d, torus, double)
    ref = np.stack([tk for tk, _ in intersect_torus(torus, o, d)], axis=1)
    ref = np.where(ref > 0, ref, np.inf)
    ref = np.sort(ref, axis=1)
    ref_count = np.isfinite(ref).sum(axis=1)
    eps = np.finfo(np.float64 if double else np.float32).eps
    length = np.linalg.norm(d, axis=1)
    scale = np.max(np.abs(o - np.asarray(centre)), axis=1) + major + minor
    with np.errstate(invalid="ignore"):
        chord = np.nanmin(np.where(np.isfinite(np.diff(ref, axis=1)), np.diff(ref, axis=1),
                                   np.inf), axis=1) * length
    decidable = chord >= np.sqrt(8 * minor * 16 * eps * scale)
    lost = np.nonzero((count != ref_count) & decidable)[0]
    assert lost.size == 0, (f"{lost.size} rays lost or gained crossings, e.g. ray {lost[0]}: "
                            f"{t[lost[0]]} against {ref[lost[0]]}")
    assert (count > 0).mean() > 0.5  # aimed at the tube: most rays cross it
    hits = np.nonzero(count > 0)[0]
    k = np.concatenate([np.arange(c) for c in count[hits]])
    rays = np.repeat(hits, count[hits])
    p = o[rays] + t[rays, k, None] * d[rays]
    roundings = tube_distance(torus, p) / (eps * (np.max(np.abs(o[rays]), axis=1)
                                                  + major + minor))
    assert roundings.max() <= 2.0, f"a crossing {roundings.max():.1f} roundings off the tube"


@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
def test_rays_parallel_to_the_axis_match_the_closed_form(cl_device, double):
    """At rho0 from the axis a ray along it crosses the tube at z = +-sqrt(r^2 - (rho0 - R)^2),
    or passes through the hole or outside without a crossing."""
    if double and not cl_device.double_fp_config:
        pytest.skip("no fp64 on this device")
    major, minor = 1.0, 0.25
    rho0 = np.linspace(0, 1.3, 2001).astype(np.float32).astype(np.float64)
    o = np.stack([rho0, np.zeros_like(rho0), np.full_like(rho0, -3)], 1)
    d = np.tile([0, 0, 1.0], (len(rho0), 1))
    t, count = device_crossings(cl_device, o, d, Torus((0, 0, 0), (0, 0, 1), major, minor, 0),
                                double)
    w2 = minor**2 - (rho0 - major) ** 2
    decided = np.abs(w2) > 1e-5  # the tube's rim: tangent
    assert np.array_equal(count[decided], np.where(w2 > 0, 2, 0)[decided])
    hit = decided & (w2 > 0)
    w = np.sqrt(w2[hit])
    # The crossing's rounding, magnified where the ray meets the tube at a glancing angle.
    tol = 16 * np.finfo(np.float64 if double else np.float32).eps * 3 * minor / w
    assert np.all(np.abs(t[hit, 0] - (3 - w)) <= tol)
    assert np.all(np.abs(t[hit, 1] - (3 + w)) <= tol)


def torus_scene(objects: list, **render: object) -> dict:
    return {
        "camera": {"position": [0, 2.5, -4], "look_at": [0, 0, 0], "vfov": 50},
        "render": {"width": 64, "height": 48, "max_depth": 3, "ambient": [0.1, 0.1, 0.1],
                   **render},
        "materials": {
            "red": {"color": [0.9, 0.2, 0.2], "diffuse": 0.8, "specular": 0.3,
                    "shininess": 30},
            "glass": {"color": [0.9, 0.9, 1.0], "diffuse": 0.1, "transmit": 0.8, "ior": 1.5},
            "checks": {"color": [1, 1, 1], "diffuse": 0.9,
                       "texture": {"type": "checker", "color2": [0.1, 0.2, 0.8], "size": 0.25}},
            "floor": {"color": [0.8, 0.8, 0.8], "diffuse": 0.9}},
        "lights": [{"type": "point", "position": [3, 5, -3], "color": [1, 1, 1]}],
        "objects": [*objects,
                    {"type": "plane", "point": [0, -1, 0], "normal": [0, 1, 0],
                     "material": "floor"}],
    }


TORI = [
    {"type": "torus", "center": [-0.8, 0, 0], "axis": [0, 1, 0.3], "major_radius": 1.0,
     "minor_radius": 0.3, "material": "red"},
    # Glass: shadow rays through it cross the tube up to four times, each filtering the light.
    {"type": "torus", "center": [1.2, 0.2, 0.5], "axis": [1, 0.2, 0], "major_radius": 0.7,
     "minor_radius": 0.25, "material": "glass"},
    {"type": "torus", "center": [0, -0.5, -1.5], "axis": [0, 1, 0], "major_radius": 0.5,
     "minor_radius": 1e-3, "material": "red"},
    # Unevenly scaled: an instance, intersected in its own frame.
    {"type": "torus", "center": [0, 0, 0], "axis": [0, 0, 1], "major_radius": 0.4,
     "minor_radius": 0.15, "material": "checks",
     "transform": {"scale": [1, 1.5, 1], "translate": [0.2, 1.0, 1.5]}},
]


@pytest.mark.parametrize("traversal", ["single", "sample_packet"])
@pytest.mark.parametrize("precision", ["float", "double"])
def test_tori_render_as_the_reference_does(cl_device, precision, traversal):
    if precision == "double" and not cl_device.double_fp_config:
        pytest.skip("no fp64 on this device")
    scene = scene_from_dict(torus_scene(TORI, spp=2))
    assert isinstance(scene.objects[3], Instance)
    image = render(scene, RenderSettings(precision=precision, traversal=traversal)).image
    reference = render_reference(scene)
    assert metrics.nonfinite_count(image) == 0
    # Measured on PoCL and Intel's CPU runtime, either traversal: largest error 1.12e-4 and
    # 1.15e-4 in float, 1.07e-4 in double (which reads the same float32 scene records), RMSE
    # 3.9e-6 in float, 3.5e-6 in double.
    assert np.abs(image - reference).max() < 4.6e-4
    assert metrics.rmse(image, reference) < 1.6e-5


def scaled_scene(data: dict, scale: float) -> dict:
    """torus_scene's dict with every position and length (camera, lights, objects) times
    scale: the same picture, since the default attenuation does not depend on distance."""
    data = copy.deepcopy(data)
    for key in ("position", "look_at"):
        data["camera"][key] = [x * scale for x in data["camera"][key]]
    for light in data["lights"]:
        light["position"] = [x * scale for x in light["position"]]
    for obj in data["objects"]:
        for key in ("center", "point"):
            if key in obj:
                obj[key] = [x * scale for x in obj[key]]
        for key in ("major_radius", "minor_radius"):
            if key in obj:
                obj[key] *= scale
    return data


@pytest.mark.parametrize("scale", [1e12, 1e-11])
def test_a_scaled_torus_scene_renders_as_at_unit_scale(cl_device, scale):
    """Thick, glass and thin rings, camera and light scaled together. The local quartic's
    coefficients reach r^4 / R^2, which in world units overflows float32 at 1e12 (the rings
    vanish: 732 of 3,072 pixels off by over 2/255) and goes denormal at 1e-11 (375 pixels off);
    the kernel solves it in units of the ring. Against the unit-scale image and the reference,
    within test_tori_render_as_the_reference_does's bounds. At 1e-11 the reference is the
    unit-scale one: the reference's hit-point bound (clray/reference/shading.py) has an
    absolute floor of 1e-9, a hundred times this scene, which moves its shadow rays off it."""
    data = torus_scene(TORI[:3], spp=2)
    base = scene_from_dict(data)
    unit = render(base).image
    scene = scene_from_dict(scaled_scene(data, scale))
    # Nothing to warn of: the scene is inside float32's range, and the tori render right.
    assert scene.warnings == ()
    image = render(scene).image
    reference = render_reference(scene if scale > 1 else base)
    assert metrics.nonfinite_count(image) == 0
    # Measured on PoCL: against unit scale, largest error 7.6e-6 (1e12) and 1.7e-5 (1e-11);
    # against the reference 1.2e-4, RMSE 3.2e-6.
    for want in (unit, reference):
        assert np.abs(image - want).max() < 4.6e-4
        assert metrics.rmse(image, want) < 1.6e-5


def test_a_torus_shadow_through_glass_filters_at_every_crossing(cl_device):
    """A light seen along a line that crosses a glass tube twice (four surfaces): the floor
    under it gets transmit^4 of the light, which is what the reference counts; two of the four
    would leave it brighter."""
    glass = {"type": "torus", "center": [0, 0, 0], "axis": [0, 0, 1], "major_radius": 1.0,
             "minor_radius": 0.3, "material": "glass"}
    data = torus_scene([glass])
    data["lights"] = [{"type": "point", "position": [-3, 0, 0], "color": [1, 1, 1]}]
    data["objects"][-1] = {"type": "plane", "point": [3, 0, 0], "normal": [-1, 0, 0],
                           "material": "floor"}
    data["camera"] = {"position": [2.9, 0.0, -0.5], "look_at": [3, 0, 0], "vfov": 20}
    data["render"]["max_depth"] = 0
    scene = scene_from_dict(data)
    image = render(scene, RenderSettings(width=16, height=12)).image
    reference = render_reference(scene, width=16, height=12)
    assert metrics.max_abs(image, reference) < 2 / 255
    # The floor (colour 0.8, diffuse 0.9, no ambient) at the image's centre faces the light.
    lit = 0.8 * 0.9 * 0.8**4 * np.array([0.9, 0.9, 1.0]) ** 4
    assert np.allclose(image[6, 8], lit, atol=0.005)


@pytest.mark.parametrize(("change", "message"), [
    ({"minor_radius": 2.0}, "objects[0].minor_radius: must be at most major_radius (1.0), got 2.0"),
    ({"minor_radius": 0}, "objects[0].minor_radius: must be"),
    ({"axis": [0, 0, 0]}, "objects[0].axis:"),
])
def test_bad_tori_are_one_line_scene_errors(change, message):
    torus = {"type": "torus", "center": [0, 0, 0], "axis": [0, 1, 0], "major_radius": 1.0,
             "minor_radius": 0.25, "material": "red", **change}
    with pytest.raises(SceneError) as info:
        scene_from_dict(torus_scene([torus]))
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


def test_a_similarity_moves_the_torus_itself():
    torus = {"type": "torus", "center": [1, 0, 0], "axis": [0, 1, 0], "major_radius": 1.0,
             "minor_radius": 0.25, "material": "red",
             "transform": {"rotate": [90, 0, 0], "scale": 2, "translate": [0, 1, 0]}}
    placed = scene_from_dict(torus_scene([torus])).objects[0]
    assert isinstance(placed, Torus)
    assert np.allclose(placed.center, (2, 1, 0))
    assert np.allclose(np.abs(placed.axis), (0, 0, 1))
    assert (placed.major_radius, placed.minor_radius) == (2.0, 0.5)


def test_passes_of_tori_follow_the_reference(cl_device):
    """The depth, normal and object passes of the tori (an instance among them) against the
    float64 reference's closest hits, pixel-centre rays."""
    scene = scene_from_dict(torus_scene(TORI, spp=1))
    result = render(scene, RenderSettings(aovs=("depth", "normal", "object")))
    o, d, _ = camera_rays(scene)
    ref = intersect_scene(scene, o, d)
    h, w = result.image.shape[:2]
    want_object = ref.obj.reshape(h, w)
    assert {0, 1, 2, 3, 4} <= set(np.unique(want_object))
    # Silhouette pixels, where a ray grazes a tube within rounding, may go either way.
    same = result.aovs["object"] == want_object
    assert same.mean() > 0.995
    hit = same & (want_object >= 0)
    depth = ref.t.reshape(h, w) * np.linalg.norm(d, axis=1).reshape(h, w)
    assert np.allclose(result.aovs["depth"][hit], depth[hit], rtol=1e-4)
    normal = ref.shading_normal.reshape(h, w, 3)
    assert np.abs(result.aovs["normal"][hit] - normal[hit]).max() < 1e-3
