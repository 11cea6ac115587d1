"""Checks of the float64 reference renderer against closed forms computed here, independently.

Expected values come from hand-derived geometry (the ray-sphere hit by closest approach, the
ray-plane hit, Snell's law in a prism) and a pure-Python hash, never from the reference's own
code paths, so a wrong formula in clray/reference/ makes these fail.
"""

from __future__ import annotations

import ast
import importlib
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from clray.reference import (
    camera_rays,
    environment_texel,
    image_texel,
    intersect_scene,
    pcg_hash,
    render_reference,
    rng_uniform,
    sample_positions,
    trace,
    transmission,
)
from clray.reference.shading import offset_origin, surface_at
from clray.reference.texture import MaterialTable, surface_color
from clray.scene.model import (
    Box,
    Camera,
    Cone,
    Cylinder,
    DirectionalLight,
    Material,
    Mesh,
    Plane,
    PointLight,
    RenderOptions,
    Scene,
    Sphere,
    Texture,
    Triangle,
)

W, H = 48, 36


def make_scene(objects, materials, lights=(), camera=None, **render) -> Scene:
    camera = camera or Camera(position=(0.0, 0.0, 5.0), look_at=(0.0, 0.0, 0.0), vfov=40.0)
    options = RenderOptions(**{"width": W, "height": H, "max_depth": 4, **render})
    return Scene(None, options, camera, tuple(materials), tuple(lights), tuple(objects))


def pinhole(eye, look_at, up, vfov_deg, width, height):
    """Pixel-centre ray directions (H, W, 3), straight from the formula in docs/rendering.md."""
    eye, look_at, up = (np.array(v, dtype=float) for v in (eye, look_at, up))
    f = (look_at - eye) / np.linalg.norm(look_at - eye)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    half_h = math.tan(math.radians(vfov_deg) / 2)
    half_w = half_h * width / height
    d = np.empty((height, width, 3))
    for y in range(height):
        for x in range(width):
            px = 2 * (x + 0.5) / width - 1
            py = 1 - 2 * (y + 0.5) / height
            v = f + px * half_w * r + py * half_h * u
            d[y, x] = v / np.linalg.norm(v)
    return d


def sphere_hit(eye, d, center, radius):
    """(t, margin) of the nearer hit by closest approach; t = nan on a miss. margin = r^2 - b^2
    (b the ray's distance from the centre) says how far from the silhouette the ray is."""
    oc = np.asarray(center) - np.asarray(eye)
    tca = d @ oc
    b2 = oc @ oc - tca**2
    margin = radius**2 - b2
    with np.errstate(invalid="ignore"):
        t = np.where(margin >= 0, tca - np.sqrt(margin), np.nan)
    return t, margin


# ---------------------------------------------------------------------------------------------
# Hash and samples


def pcg_python(x: int) -> int:
    state = (x * 747796405 + 2891336453) & 0xFFFFFFFF
    word = (((state >> ((state >> 28) + 4)) ^ state) * 277803737) & 0xFFFFFFFF
    return (word >> 22) ^ word


def test_pcg_hash_matches_wrapping_uint32_arithmetic():
    xs = [0, 1, 2, 12345, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF]
    xs += np.random.default_rng(1).integers(0, 2**32, 200).tolist()
    got = pcg_hash(np.array(xs, dtype=np.uint64))
    assert got.dtype == np.uint32
    assert got.tolist() == [pcg_python(x) for x in xs]


def test_uniform_uses_the_documented_key():
    seed, pixels, samples = 7, [0, 5, 999, 123456], [0, 1, 3, 15]
    for dim in (0, 1):
        got = rng_uniform(seed, np.array(pixels), np.array(samples), dim)
        want = [
            (pcg_python(pcg_python(pcg_python(seed) ^ p) ^ (4 * s + dim)) >> 8) / 2**24
            for p, s in zip(pixels, samples, strict=True)
        ]
        assert got.tolist() == want


def test_uniform_values_are_in_unit_interval_and_look_uniform():
    r = rng_uniform(3, np.arange(100_000), np.zeros(100_000, dtype=int), 0)
    assert r.min() >= 0.0 and r.max() < 1.0
    assert np.all(r * 2**24 == np.floor(r * 2**24))  # 24-bit values
    counts = np.histogram(r, bins=10, range=(0, 1))[0]
    assert np.all(np.abs(counts - 10_000) < 500)


@pytest.mark.parametrize(("spp", "nx"), [(2, 2), (4, 2), (5, 3), (9, 3), (17, 5)])
def test_samples_are_stratified_one_per_cell(spp, nx):
    # Rows of nx cells nx/spp high, a last row of the m = spp mod nx cells left, 1/m wide and
    # m/spp high (docs/rendering.md): sample s in row s // nx, column s % nx.
    width, height = 5, 3
    sx, sy, pixel = sample_positions(width, height, spp, seed=11)
    assert len(sx) == width * height * spp
    sample = np.tile(np.arange(spp), width * height)
    x, y = pixel % width, pixel // width
    row = sample // nx
    cells = np.minimum(nx, spp - row * nx)
    assert np.array_equal(np.floor((sx - x) * cells), sample % nx)
    assert np.all((sy - y >= row * nx / spp) & (sy - y < (row * nx + cells) / spp))
    assert np.all((sx >= x) & (sx < x + 1) & (sy >= y) & (sy < y + 1))


def test_one_sample_is_the_pixel_centre_and_seed_matters_only_for_jitter():
    sx, sy, _ = sample_positions(4, 2, 1, seed=5)
    assert sx.tolist() == [0.5, 1.5, 2.5, 3.5] * 2
    assert sy.tolist() == [0.5] * 4 + [1.5] * 4
    a = sample_positions(4, 2, 4, seed=1)[0]
    b = sample_positions(4, 2, 4, seed=2)[0]
    assert not np.array_equal(a, b)
    assert np.array_equal(a, sample_positions(4, 2, 4, seed=1)[0])


def test_camera_rays_follow_the_pinhole_formula():
    cam = Camera(position=(1.0, 2.0, 3.0), look_at=(0.0, 0.5, -1.0), vfov=35.0)
    scene = make_scene([], [Material("m")], camera=cam)
    origins, dirs, pixel = camera_rays(scene, W, H, 1, 0)
    want = pinhole(cam.position, cam.look_at, cam.up, 35.0, W, H).reshape(-1, 3)
    assert np.array_equal(pixel, np.arange(W * H))
    assert np.allclose(origins, cam.position)
    assert np.allclose(dirs, want, atol=1e-14)


def test_hfov_fixes_the_horizontal_extent():
    cam = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0), vfov=None, hfov=90.0)
    scene = make_scene([], [Material("m")], camera=cam)
    _, dirs, _ = camera_rays(scene, 2, 1, 1, 0)
    # Pixel centres at px = -1/2 and +1/2, tan(45 deg) = 1, half_h = 1/2: py = 0.
    want = np.array([[-0.5, 0.0, -1.0], [0.5, 0.0, -1.0]]) / math.sqrt(1.25)
    assert np.allclose(dirs, want, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Intersection


def test_intersections_of_every_primitive():
    objects = [
        Box((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 0),
        Cylinder((10.0, 0.0, 0.0), (0.0, 1.0, 0.0), 1.0, 2.0, 0),
        Cylinder((20.0, 0.0, 0.0), (0.0, 1.0, 0.0), 1.0, 2.0, 0, capped=False),
        Cone((30.0, 2.0, 0.0), (0.0, -1.0, 0.0), 45.0, 2.0, 0),
        Cone((40.0, 2.0, 0.0), (0.0, -1.0, 0.0), 45.0, 2.0, 0, capped=False),
        Triangle(((50.0, 0.0, 0.0), (51.0, 0.0, 0.0), (50.0, 1.0, 0.0)), 0),
        Sphere((60.0, 0.0, 0.0), 2.0, 0),
    ]
    scene = make_scene(objects, [Material("m")])
    s = 1 / math.sqrt(2)
    cases = [  # origin, direction, t, outward normal
        ((-5, 0.2, 0.3), (1, 0, 0), 4.0, (-1, 0, 0)),  # box, entering
        ((0, 0, 0), (0, 1, 0), 1.0, (0, 1, 0)),  # box, from inside
        ((10, 5, 0.5), (0, -1, 0), 3.0, (0, 1, 0)),  # cylinder top cap
        ((15, 1, 0), (-1, 0, 0), 4.0, (1, 0, 0)),  # cylinder side
        ((10, -3, 0.2), (0, 1, 0), 3.0, (0, -1, 0)),  # cylinder bottom cap
        ((20, 5, 0), (0, -1, 0), np.inf, (0, 0, 0)),  # open tube, down the axis
        ((20, 1, 0), (1, 0, 0), 1.0, (1, 0, 0)),  # open tube, from inside
        ((35, 1, 0), (-1, 0, 0), 4.0, (s, s, 0)),  # cone side at radius 1
        ((30, -5, 0.5), (0, 1, 0), 5.0, (0, -1, 0)),  # cone base disc
        ((40, -5, 0.5), (0, 1, 0), 6.5, (0, s, s)),  # uncapped: inside of the nappe
        ((40, 5, 0.5), (0, -1, 0), 3.5, (0, s, s)),  # other nappe is absent
        ((50.2, 0.3, 5), (0, 0, -1), 5.0, (0, 0, 1)),  # triangle
        ((50.2, 0.3, -5), (0, 0, 1), 5.0, (0, 0, 1)),  # triangle back side, normal not flipped
        ((60, 0, 0), (0, 0, 1), 2.0, (0, 0, 1)),  # sphere from inside
    ]
    o = np.array([c[0] for c in cases], dtype=float)
    d = np.array([c[1] for c in cases], dtype=float)
    hit = intersect_scene(scene, o, d)
    assert np.allclose(hit.t, [c[2] for c in cases], rtol=1e-13, atol=0)
    assert np.allclose(hit.normal, [c[3] for c in cases], atol=1e-13)


def test_texture_coordinates():
    objects = [
        Sphere((0.0, 0.0, 0.0), 2.0, 0),
        Cylinder((10.0, 0.0, 0.0), (0.0, 1.0, 0.0), 1.0, 2.0, 0),
        Box((20.0, 0.0, 0.0), (22.0, 4.0, 8.0), 0),
        Plane((0.0, -10.0, 0.0), (0.0, 1.0, 0.0), 0),
        Triangle(((50.0, 0.0, 0.0), (51.0, 0.0, 0.0), (50.0, 1.0, 0.0)), 0),
    ]
    scene = make_scene(objects, [Material("m")])
    cases = [
        ((0, 0, 5), (0, 0, -1), (0.5, 0.5)),  # sphere, q = +z
        ((5, 0, 0), (-1, 0, 0), (0.75, 0.5)),  # sphere, q = +x: atan2(1, 0) = pi / 2
        ((0, 5, 0), (0, -1, 0), (0.5, 1.0)),  # sphere pole
        # frame(+y) = (e1, e2) = (-z, -x); cap q = (0, 2, 0.5): u = 0.5 + 0.5 * (-0.5)
        ((10, 5, 0.5), (0, -1, 0), (0.25, 0.5)),
        # side at q = (1, 0.5, 0): atan2(q.e2, q.e1) = atan2(-1, 0) = -pi/2, v = 0.5 / 2
        ((15, 0.5, 0), (-1, 0, 0), (0.25, 0.25)),
        # box face x = 20: u along y, v along z
        ((15, 1, 2), (1, 0, 0), (0.25, 0.25)),
        # box face z = 8: u along x, v along y
        ((21.5, 3, 20), (0, 0, -1), (0.75, 0.75)),
        # plane: frame(+y) = (-z, -x), q = (3, 0, 2)
        ((3, -5, 2), (0, -1, 0), (-2.0, -3.0)),
        ((50.2, 0.3, 5), (0, 0, -1), (0.2, 0.3)),  # triangle: barycentrics
    ]
    hit = intersect_scene(scene, [c[0] for c in cases], [c[1] for c in cases])
    assert np.allclose(hit.uv, [c[2] for c in cases], atol=1e-13)


def test_a_flat_box_face_has_texture_coordinate_zero_across_it():
    # A box flat along y (a rectangle) struck on its x face by a ray in its plane: the face's
    # u runs along y, where the box has no extent, so u is 0 (kernels/box.h), not 0 / 0; v
    # runs along z as on any box.
    scene = make_scene([Box((0.0, 0.0, 0.0), (1.0, 0.0, 2.0), 0)], [Material("m")])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        hit = intersect_scene(scene, [[-1.0, 0.0, 0.5], [3.0, 0.0, 1.5]],
                              [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    assert hit.t.tolist() == [1.0, 2.0]
    np.testing.assert_array_equal(hit.normal, [[-1, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(hit.uv, [[0.0, 0.25], [0.0, 0.75]])


def test_mesh_blends_vertex_normals_and_uvs():
    verts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]])
    mesh = Mesh(verts, np.array([[0, 1, 2]]), 0, normals=normals, uvs=uvs)
    hit = intersect_scene(make_scene([mesh], [Material("m")]), [[0.2, 0.3, 1.0]], [[0, 0, -1]])
    b = np.array([0.5, 0.2, 0.3])
    want_n = b @ normals / np.linalg.norm(b @ normals)
    assert np.allclose(hit.normal, [[0, 0, 1]])
    assert np.allclose(hit.shading_normal, [want_n], atol=1e-14)
    assert np.allclose(hit.uv, [b @ uvs], atol=1e-14)
    assert hit.face.tolist() == [0] and hit.obj.tolist() == [0]


def test_a_degenerate_triangle_faces_the_ray():
    # Collinear corners, the third twice the second: each component of the cross product is
    # a y z - z y of the same rounded products, exactly 0, so the triangle has no normal. The
    # crossing test's determinant is rounding noise, not always 0, so some rays still hit it;
    # there it faces the ray, n_g = -d, as kernels/triangle.h has it (no zero normal).
    v1 = np.array([0.1, 0.3, 0.7])
    assert not np.cross(v1, 2 * v1).any()
    tri = Triangle(((0.0, 0.0, 0.0), tuple(v1), tuple(2 * v1)), 0)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = rng.uniform(0.0, 2.0, (2000, 1)) * v1 - rng.uniform(0.1, 1.0, (2000, 1)) * d
    hit = intersect_scene(make_scene([tri], [Material("m")]), o, d)
    struck = np.isfinite(hit.t)
    assert struck.sum() >= 10
    np.testing.assert_array_equal(hit.normal[struck], -d[struck])
    np.testing.assert_array_equal(hit.shading_normal[struck], -d[struck])


def test_ties_go_to_type_order_then_scene_order():
    objects = [
        Sphere((0.0, 0.0, 0.0), 1.0, 0),
        Sphere((0.0, 0.0, 0.0), 1.0, 1),
        Plane((0.0, 1.0, 0.0), (0.0, 1.0, 0.0), 2),  # tangent to the spheres' top
        Triangle(((-1.0, 1.0, -1.0), (1.0, 1.0, -1.0), (0.0, 1.0, 2.0)), 3),
    ]
    mats = [Material(f"m{i}") for i in range(4)]
    hit = intersect_scene(
        make_scene(objects, mats), [[0, 5, 0], [0, 0, 5]], [[0, -1, 0], [0, 0, -1]]
    )
    assert hit.t.tolist() == [4.0, 4.0]
    assert hit.obj.tolist() == [2, 0]  # the plane beats sphere and triangle; sphere 0 beats 1


def test_shadow_segments_filter_once_per_crossing():
    glass = Material("g", color=(1.0, 0.5, 0.25), transmit=0.5)
    objects = [
        Sphere((0.0, 0.0, 0.0), 1.0, 0),
        Cylinder((10.0, -1.0, 0.0), (0.0, 1.0, 0.0), 1.0, 2.0, 0, capped=False),
        Plane((20.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0),
    ]
    scene = make_scene(objects, [glass])
    f = 0.5 * np.array([1.0, 0.5, 0.25])
    o = [[-5, 0, 0], [-5, 0, 0], [10, -5, 0], [10, 0, -5], [15, 0, 0], [-0.5, 0, 0]]
    d = [[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], [1, 0, 0]]
    tmax = [8.0, 5.0, 20.0, 20.0, 10.0, 1.0]
    got = transmission(scene, o, d, tmax)
    want = [
        f**2,  # through the sphere, not reaching the tube
        f,  # segment ends inside the sphere
        np.ones(3),  # along the open tube's axis: no crossing
        f**2,  # across the open tube
        f,  # the plane
        np.ones(3),  # ends before leaving the sphere, starts inside it: no crossing
    ]
    assert np.allclose(got, want, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Shading


def test_a_ray_spawned_along_the_surface_starts_inside_from_either_side():
    # kernels/surface.h, offset_origin: p moves err along the outward n_g where w . n_g > 0,
    # else against it; a w along the surface (w . n_g = 0) starts inside, whether the ray that
    # hit came from outside or inside. The reference went by the normal facing the ray, with
    # >= 0: outside for a ray that came from outside.
    normal = np.array([[0.0, 0.0, 1.0]] * 2)
    o = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])  # from outside, from inside
    sf = surface_at(o, d, np.ones(2), normal, normal, np.zeros((2, 2)), np.zeros(2, int))
    np.testing.assert_array_equal(sf.n_g, [[0, 0, 1], [0, 0, -1]])
    err = 1e-6
    for w, z in (((1.0, 0.0, 0.0), -err), ((0.0, 0.0, 1.0), err), ((0.0, 0.0, -1.0), -err)):
        got = offset_origin(sf.p, sf.n_out, np.array([w, w]), np.full(2, err))
        np.testing.assert_array_equal(got, [[0.0, 0.0, z]] * 2)


def test_a_tangent_ray_sees_both_normals_flipped():
    # kernels/shading.h, shade_point: entering = d . n_g < 0, n_f = entering ? n_g : -n_g,
    # n = d . n_s < 0 ? n_s : -n_s; so where d . n is exactly 0 the normal is flipped. The
    # reference kept it there (it flipped only where d . n > 0).
    normal = np.array([[0.0, 1.0, 0.0]] * 3)
    shading = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0], [1.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    o = np.zeros((3, 3))
    sf = surface_at(o, d, np.zeros(3), normal, shading, np.zeros((3, 2)), np.zeros(3, int))

    def kernel_facing(n: np.ndarray) -> np.ndarray:
        return np.array([m if np.dot(w, m) < 0 else -m for w, m in zip(d, n, strict=True)])

    assert np.sum(d * normal, axis=-1).tolist() == [0.0, 0.0, -1.0]
    assert np.sum(d * shading, axis=-1).tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_array_equal(sf.entering, [False, False, True])
    np.testing.assert_array_equal(sf.n_g, kernel_facing(normal))
    np.testing.assert_array_equal(sf.n_g, [[0, -1, 0], [0, -1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(sf.n, kernel_facing(shading))
    np.testing.assert_array_equal(sf.n, -shading)
    # The checker's quarter-cell push goes by n_f: at p = 0, on a cell corner, the tangent
    # rays' q = (0, 0.25, 0) is in cell 0 (even: the material colour); the ray arriving from
    # above gets q = (0, -0.25, 0), cell -1 (odd: color2).
    c1, c2 = (0.9, 0.8, 0.7), (0.1, 0.2, 0.3)
    checker = Texture("checker", size=1.0, color2=c2)
    mats = MaterialTable((Material("chk", color=c1, texture=checker),))
    got = surface_color(mats, sf.material, sf.p, sf.uv, sf.n_g, np.zeros(3, bool))
    np.testing.assert_array_equal(got, [c1, c1, c2])


def test_background_on_miss():
    scene = make_scene(
        [Sphere((100.0, 0.0, 0.0), 1.0, 0)],
        [Material("m", ambient=1.0)],
        [DirectionalLight((0.0, -1.0, 0.0))],
        background=(0.2, 0.4, 0.6),
    )
    img = render_reference(scene)
    assert img.shape == (H, W, 3)
    assert np.array_equal(img, np.broadcast_to([0.2, 0.4, 0.6], img.shape))


@pytest.mark.parametrize("spp", [1, 4])
def test_plane_under_directional_light_is_uniform(spp):
    c = np.array([0.9, 0.6, 0.3])
    mat = Material("m", color=tuple(c), ambient=0.15, diffuse=0.7)
    light_dir = np.array([-0.3, -1.0, -0.2]) / np.linalg.norm([-0.3, -1.0, -0.2])
    light = DirectionalLight(tuple(light_dir), color=(0.8, 1.0, 0.5))
    scene_ambient = np.array([0.5, 0.25, 1.0])
    cam = Camera(position=(0.0, 6.0, 1.0), look_at=(0.0, 0.0, 0.0), vfov=40.0)
    scene = make_scene(
        [Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0)],
        [mat],
        [light],
        camera=cam,
        ambient=tuple(scene_ambient),
        spp=spp,
    )
    n_dot_l = -light_dir[1]
    want = 0.15 * c * scene_ambient + 0.7 * c * n_dot_l * np.array([0.8, 1.0, 0.5])
    img = render_reference(scene)
    assert np.allclose(img, np.broadcast_to(want, img.shape), rtol=0, atol=1e-13)


def test_a_python_scene_is_normalised_as_render_takes_it():
    # render() checks and normalises a scene built in Python (clray.scene.check); the reference
    # must take it the same way, or a direction of length 3 triples n . l.
    light_dir = np.array([-0.3, -1.0, -0.2]) / np.linalg.norm([-0.3, -1.0, -0.2])
    mat = Material("m", color=(1.0, 1.0, 1.0), diffuse=0.7)
    scene = make_scene([Plane((0.0, 0.0, 0.0), (0.0, 2.5, 0.0), 0)], [mat],
                       [DirectionalLight(tuple(3.0 * light_dir))],
                       camera=Camera(position=(0.0, 6.0, 1.0), look_at=(0.0, 0.0, 0.0)),
                       ambient=(0.0, 0.0, 0.0))
    img = render_reference(scene)
    assert np.allclose(img, 0.7 * -light_dir[1], rtol=0, atol=1e-13)


# The last: a denominator below 1 on the near side (0.1 + 0.05 d + 0.01 d^2 at d ~ 4), where
# min(1, 1 / denominator) clamps.
@pytest.mark.parametrize("attenuation", [(1.0, 0.0, 0.0), (0.2, 0.1, 0.05), (0.1, 0.05, 0.01)])
@pytest.mark.parametrize("specular", [0.0, 0.6])
def test_lone_sphere_follows_lambert_and_phong(attenuation, specular):
    center, radius = np.array([0.3, -0.2, 0.0]), 1.2
    c = np.array([0.2, 0.7, 0.9])
    light_pos = np.array([3.0, 4.0, 2.5])
    light_col = np.array([1.0, 0.9, 0.8])
    eye = np.array([0.0, 0.0, 5.0])
    mat = Material("m", color=tuple(c), ambient=0.1, diffuse=0.8, specular=specular, shininess=12)
    scene = make_scene(
        [Sphere(tuple(center), radius, 0)],
        [mat],
        [PointLight(tuple(light_pos), tuple(light_col), attenuation)],
        background=(0.05, 0.0, 0.1),
    )
    dirs = pinhole(eye, (0, 0, 0), (0, 1, 0), 40.0, W, H)
    img = render_reference(scene)
    n_checked = 0
    for y in range(H):
        for x in range(W):
            d = dirs[y, x]
            t, margin = sphere_hit(eye, d, center, radius)
            if abs(margin) < 1e-6:
                continue  # silhouette: either answer is fine
            if np.isnan(t):
                assert np.allclose(img[y, x], [0.05, 0.0, 0.1], atol=0)
                continue
            p = eye + t * d
            n = (p - center) / radius
            to_l = light_pos - p
            dist = np.linalg.norm(to_l)
            ldir = to_l / dist
            want = 0.1 * c
            ndl = n @ ldir
            if ndl > 0:
                kc, kl, kq = attenuation
                atten = min(1.0, 1.0 / (kc + kl * dist + kq * dist**2))
                rv = (2 * ndl * n - ldir) @ -d
                spec = rv**12 if rv > 0 else 0.0
                want = want + atten * light_col * (0.8 * c * ndl + specular * spec)
                n_checked += 1
            assert np.allclose(img[y, x], want, rtol=0, atol=1e-12), (x, y)
    assert n_checked > 100


@pytest.mark.parametrize("transmit", [0.0, 0.5])
def test_sphere_shadows_exactly_the_pixels_whose_shadow_ray_it_blocks(transmit):
    center, radius = np.array([0.0, 1.0, 0.0]), 0.6
    light_pos = np.array([0.5, 4.0, 0.3])
    c = np.array([0.8, 0.8, 0.7])
    blocker_color = np.array([1.0, 0.6, 0.2])
    floor = Material("floor", color=tuple(c), ambient=0.2, diffuse=0.8)
    blocker = Material("ball", color=tuple(blocker_color), transmit=transmit, diffuse=0.5)
    cam = Camera(position=(0.0, 4.0, 5.0), look_at=(0.0, 0.3, 0.0), vfov=40.0)
    scene = make_scene(
        [Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0), Sphere(tuple(center), radius, 1)],
        [floor, blocker],
        [PointLight(tuple(light_pos))],
        camera=cam,
        max_depth=0,
    )
    eye = np.array(cam.position)
    dirs = pinhole(eye, cam.look_at, cam.up, 40.0, W, H)
    img = render_reference(scene)
    filt = (transmit * blocker_color) ** 2  # in and out of the ball
    shadowed = 0
    for y in range(H):
        for x in range(W):
            d = dirs[y, x]
            t_ball, margin = sphere_hit(eye, d, center, radius)
            if not np.isnan(t_ball) or abs(margin) < 1e-6:
                continue  # the ball itself is seen here
            if d[1] >= 0:
                continue
            p = eye + (-eye[1] / d[1]) * d
            seg = light_pos - p
            s = np.clip((center - p) @ seg / (seg @ seg), 0, 1)
            miss_by = np.linalg.norm(p + s * seg - center) - radius
            if abs(miss_by) < 1e-6:
                continue
            ndl = seg[1] / np.linalg.norm(seg)
            lit = c * 0.8 * ndl * (filt if miss_by < 0 else 1.0)
            shadowed += miss_by < 0
            assert np.allclose(img[y, x], 0.2 * c + lit, rtol=0, atol=1e-12), (x, y)
    assert shadowed > 20


# ---------------------------------------------------------------------------------------------
# Secondary rays


def checker_floor_scene(extra_objects, extra_materials, **render):
    floor = Material(
        "floor",
        ambient=0.3,
        diffuse=0.7,
        texture=Texture("checker", size=0.4, color2=(0.1, 0.3, 0.9)),
    )
    cam = Camera(position=(0.0, 2.0, 6.0), look_at=(0.0, 0.0, 0.0), vfov=40.0)
    return make_scene(
        [Plane((0.0, -1.0, 0.0), (0.0, 1.0, 0.0), 0), *extra_objects],
        [floor, *extra_materials],
        [PointLight((2.0, 5.0, 3.0))],
        camera=cam,
        **render,
    )


def test_glass_slab_of_ior_one_does_not_bend_rays():
    def slab(ior):
        glass = Material("glass", diffuse=0.0, transmit=1.0, ior=ior)
        return checker_floor_scene([Box((-1.5, -0.5, -0.5), (1.5, 0.8, 1.5), 1)], [glass])

    bare = render_reference(checker_floor_scene([], []), max_depth=2)
    through = render_reference(slab(1.0), max_depth=2)
    assert np.allclose(through, bare, rtol=0, atol=1e-9)
    # The same slab with a real IOR bends the view: the comparison can fail.
    assert np.abs(render_reference(slab(1.5), max_depth=2) - bare).max() > 0.1


def outward_prism(ior):
    """A right prism: cross-section A = (0, 0), B = (1, 0), C = (0, 1) in xy, z in [-1, 1];
    faces wound so that (v1 - v0) x (v2 - v0) points out of the solid."""
    xy = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]
    verts = np.array([(x, y, z) for z in (-1.0, 1.0) for x, y in xy])
    quads = [(0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)]
    faces = [(0, 2, 1), (3, 4, 5)]
    for a, b, c, d in quads:
        faces += [(a, b, c), (a, c, d)]
    faces = np.array(faces)
    centroid = verts.mean(axis=0)
    for f in faces:
        v0, v1, v2 = verts[f]
        if np.cross(v1 - v0, v2 - v0) @ ((v0 + v1 + v2) / 3 - centroid) < 0:
            f[1], f[2] = f[2], f[1]
    return Mesh(verts, faces, 0), Material("glass", diffuse=0.0, transmit=1.0, ior=ior)


@pytest.mark.parametrize("ior", [1.5, 1.2])
def test_total_internal_reflection_sends_transmit_weight_to_the_reflection(ior):
    # A ray along +x enters the leg x = 0 head on, meets the hypotenuse x + y = 1 at 45 degrees
    # (beyond the critical angle asin(1/1.5) = 41.8 but not asin(1/1.2) = 56.4), and after a
    # total internal reflection leaves through the leg y = 0, heading -y into a lit target box.
    prism, glass = outward_prism(ior)
    target = Material("target", color=(0.2, 0.5, 0.8), ambient=1.0, diffuse=0.0)
    scene = make_scene(
        [prism, Box((0.5, -3.0, -1.0), (0.9, -2.0, 1.0), 1)],
        [glass, target],
        background=(0.05, 0.05, 0.05),
    )
    got = trace(scene, [[-1.0, 0.3, 0.0]], [[1.0, 0.0, 0.0]], max_depth=3)[0]
    if ior == 1.5:
        assert np.allclose(got, [0.2, 0.5, 0.8], rtol=0, atol=1e-12)
        # Cut one bounce short, the path ends inside the prism with nothing.
        assert np.array_equal(trace(scene, [[-1.0, 0.3, 0.0]], [[1.0, 0.0, 0.0]], 2)[0], [0, 0, 0])
    else:
        # Refracted out of the hypotenuse at asin(1.2 sin 45) = 58 deg, over the target.
        assert np.allclose(got, [0.05, 0.05, 0.05], rtol=0, atol=1e-12)


def test_nested_media_of_equal_ior_do_not_bend_at_the_inner_surface():
    def ball(inner):
        glass = Material("glass", diffuse=0.0, transmit=1.0, ior=1.5)
        objects = [Sphere((0.0, 0.2, 0.0), 1.0, 1)]
        if inner:
            objects.append(Sphere((0.0, 0.2, 0.0), 0.5, 1))
        return checker_floor_scene(objects, [glass])

    eye = np.array([0.0, 2.0, 6.0])
    d = pinhole(eye, (0, 0, 0), (0, 1, 0), 40.0, W, H).reshape(-1, 3)
    o = np.broadcast_to(eye, d.shape)
    single = trace(ball(False), o, d, max_depth=8)
    nested = trace(ball(True), o, d, max_depth=8)
    assert np.allclose(nested, single, rtol=0, atol=1e-9)


@pytest.mark.parametrize("reflect", [1.0, 0.5])
def test_mirror_needs_a_bounce(reflect):
    sky = np.array([0.3, 0.6, 0.9])
    mats = [
        Material("mirror", diffuse=0.0, reflect=reflect),
        Material("ceiling", color=tuple(sky), ambient=1.0, diffuse=0.0),
    ]
    eye = (0.0, 1.0, 0.0)
    cam = Camera(position=eye, look_at=(0.0, 0.5, -5.0), vfov=60.0)
    scene = make_scene(
        [Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0), Plane((0.0, 3.0, 0.0), (0.0, -1.0, 0.0), 1)],
        mats,
        camera=cam,
    )
    dy = pinhole(eye, cam.look_at, cam.up, 60.0, W, H)[:, :, 1]
    down = dy < 0
    assert down.any() and (~down).any()
    want = np.where(down[:, :, None], 0.0, sky)
    assert np.allclose(render_reference(scene, max_depth=0), want, rtol=0, atol=1e-12)
    want = np.where(down[:, :, None], reflect * sky, sky)
    assert np.allclose(render_reference(scene, max_depth=1), want, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Textures


@pytest.mark.parametrize(("eye_y", "normal_y", "blend"), [(5, 1, 1.0), (5, -1, 1.0), (-5, 1, 0.5)])
def test_checker_parity(eye_y, normal_y, blend):
    size = 0.7
    c1, c2 = np.array([0.9, 0.8, 0.7]), np.array([0.1, 0.2, 0.3])
    mat = Material(
        "chk",
        color=tuple(c1),
        ambient=1.0,
        diffuse=0.0,
        texture=Texture("checker", size=size, color2=tuple(c2), blend=blend),
    )
    eye = np.array([0.3, float(eye_y), 4.1])
    cam = Camera(position=tuple(eye), look_at=(0.0, 0.0, 0.0), vfov=50.0)
    scene = make_scene([Plane((0.0, 0.0, 0.0), (0.0, float(normal_y), 0.0), 0)], [mat], camera=cam)
    dirs = pinhole(eye, cam.look_at, cam.up, 50.0, W, H)
    img = render_reference(scene)
    # The plane is y = 0 and the viewer's side is sign(eye_y): the quarter-cell push away from
    # the viewer lands in the cell row floor(-sign(eye_y) / 4) = -1 above, 0 below.
    row = -1 if eye_y > 0 else 0
    seen = set()
    for y in range(H):
        for x in range(W):
            d = dirs[y, x]
            if d[1] * eye_y >= 0:
                continue
            p = eye - eye[1] / d[1] * d
            gx, gz = p[0] / size, p[2] / size
            if min(abs(gx - round(gx)), abs(gz - round(gz))) < 1e-6:
                continue
            even = (math.floor(gx) + math.floor(gz) + row) % 2 == 0
            texel = c1 if even else c2
            seen.add(even)
            assert np.allclose(img[y, x], blend * texel + (1 - blend) * c1, atol=1e-12), (x, y)
    assert seen == {True, False}


def test_image_sampling_is_bilinear_and_wraps():
    rng = np.random.default_rng(4)
    img = rng.random((2, 4, 3)).astype(np.float32)
    tex = img.astype(np.float64)
    h, w = 2, 4

    def uv_of(col, row):  # (u, v) landing exactly on texel (col, row) centre
        return (col + 0.5) / w, 1 - (row + 0.5) / h

    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    u, v = uv_of(cols.ravel(), rows.ravel())
    got = image_texel(img, u, v, (1.0, 1.0))
    assert np.allclose(got, tex[rows.ravel(), cols.ravel()], atol=1e-15)
    # Half way between columns 1 and 2 of the top row.
    got = image_texel(img, np.array([0.5]), np.array([uv_of(0, 0)[1]]), (1.0, 1.0))
    assert np.allclose(got, [(tex[0, 1] + tex[0, 2]) / 2], atol=1e-15)
    # u = 0 sits half way between the last column and the first.
    got = image_texel(img, np.array([0.0]), np.array([uv_of(0, 1)[1]]), (1.0, 1.0))
    assert np.allclose(got, [(tex[1, 3] + tex[1, 0]) / 2], atol=1e-15)
    # repeat = (2, 1): u and u + 1/2 sample the same place.
    a = image_texel(img, np.array([0.1]), np.array([0.3]), (2.0, 1.0))
    b = image_texel(img, np.array([0.6]), np.array([0.3]), (2.0, 1.0))
    assert np.allclose(a, b, atol=1e-15)


def test_a_non_finite_texture_coordinate_wraps_as_zero():
    # kernels/texture.h, wrap01: a non-finite u j or v k (a degenerate (u, v)) wraps to 0
    # before the half-texel shift, as u = 0 or v = 0 does: s = -0.5 blends the last column with
    # the first, t = H - 0.5 the last row with the first; not texel (0, 0) alone.
    rng = np.random.default_rng(5)
    tex = rng.random((2, 4, 3))
    h, w = tex.shape[:2]
    row_1 = np.array([1 - 1.5 / h])  # v at row 1's centre
    col_2 = np.array([2.5 / w])  # u at column 2's centre
    for bad in (np.nan, np.inf, -np.inf):
        got = image_texel(tex, np.array([bad]), row_1, (1.0, 1.0))
        np.testing.assert_allclose(got, [(tex[1, w - 1] + tex[1, 0]) / 2], atol=1e-15)
        got = image_texel(tex, col_2, np.array([bad]), (1.0, 1.0))
        np.testing.assert_allclose(got, [(tex[h - 1, 2] + tex[0, 2]) / 2], atol=1e-15)
        np.testing.assert_array_equal(
            image_texel(tex, np.array([bad]), np.array([bad]), (1.0, 1.0)),
            image_texel(tex, np.array([0.0]), np.array([0.0]), (1.0, 1.0)))


def test_image_texture_on_a_sphere_facing_the_camera():
    # The ray along -z hits the sphere at q = +z: (u, v) = (0.5, 0.5), the centre of a 2 x 2
    # image, where all four texels weigh a quarter.
    img = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], dtype=np.float32)
    mat = Material("tex", ambient=1.0, diffuse=0.0, texture=Texture("image", image=img))
    scene = make_scene([Sphere((0.0, 0.0, 0.0), 1.0, 0)], [mat])
    got = trace(scene, [[0.0, 0.0, 5.0]], [[0.0, 0.0, -1.0]])[0]
    assert np.allclose(got, [0.5, 0.5, 0.5], atol=1e-12)


# Functions that do the same in both carry the same name (clray/reference/__init__.py): the
# kernel header and the reference module of each pair below.
SHARED_NAMES = [
    ("background.h", "background", "environment_texel"),
    ("background.h", "background", "environment_bilinear"),
    ("rng.h", "sampling", "rng_uniform"),
    ("sampling.h", "sampling", "lens_sample"),
    ("ray_tree.h", "render", "spawn_secondary"),
    ("texture.h", "texture", "wrap01"),
]


@pytest.mark.parametrize(("header", "module", "name"), SHARED_NAMES)
def test_kernel_and_reference_share_the_functions_name(header: str, module: str,
                                                       name: str) -> None:
    source = (Path(__file__).resolve().parent.parent / "kernels" / header).read_text()
    assert re.search(rf"\b{name}\(", source), f"no {name} in kernels/{header}"
    assert callable(getattr(importlib.import_module(f"clray.reference.{module}"), name, None))


def test_environment_texel_is_one_texel() -> None:
    texels = np.arange(24, dtype=np.float64).reshape(2, 4, 3)
    got = environment_texel(texels, np.array([3, 0]), np.array([1, 0]))
    np.testing.assert_array_equal(got, [texels[1, 3], texels[0, 0]])


def test_the_reference_docstring_names_what_it_shares_and_mirrors() -> None:
    # clray/reference/__init__.py says what the oracle shares with the packer: every clray
    # module outside clray.reference that it imports, or a package above it, is named there;
    # and each module it pairs with a kernel header ("bvh (bvh.h") is one of its own.
    import clray.reference as reference

    doc = reference.__doc__
    # Each dotted name and its prefixes: clray.scene.check.check_scene names clray.scene.check.
    named = {".".join(name.split(".")[:k]) for name in re.findall(r"\bclray(?:\.\w+)+", doc)
             for k in range(2, name.count(".") + 2)}
    package = Path(reference.__file__).parent
    for path in sorted(package.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("clray."):
                module = node.module
                if module.startswith("clray.reference"):
                    continue
                parts = module.split(".")
                above = {".".join(parts[:k]) for k in range(2, len(parts) + 1)}
                assert above & named, f"{path.name} imports {module}, not named in the docstring"
    paired = re.findall(r"\b(\w+)\s+\((?:kernels/)?\w+\.h\b", doc)
    assert len(paired) >= 8
    for module in paired:
        assert (package / f"{module}.py").is_file(), f"no clray/reference/{module}.py"
