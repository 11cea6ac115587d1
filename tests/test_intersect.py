"""The intersection kernel (clray.device.launch.intersect_rays) against float64 numpy.

Every ray is rounded to float32 first and the float64 oracle is fed those same rounded values,
so the comparisons measure the kernel's arithmetic, not the input rounding. Scenes put the
camera at the origin, so the packed camera-relative frame is the world frame (one test moves
the camera to check the frame change itself). Expected values come from closed forms written
here, or for the random mixes from clray.reference.intersect_scene (brute force, float64).

Tolerances, relative in t unless stated: 1e-5 for generic hits (float32 carries 6e-8 per
rounding and the robust formulas keep errors within a few dozen of those); 1e-4 near
silhouettes and rims, where t depends on the ray with slope up to ~100; 1e-3 at a cone's apex
(a double root). For the random BVH mix the error is taken relative to t + |o|: a ray starting
near a surface cannot get t below the float32 resolution of its coordinates.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pytest
from conftest import check_unused_lanes, load_mesh_generator

from clray.device import layout as L
from clray.device.launch import intersect_rays
from clray.device.pack import pack_scene
from clray.reference import intersect_scene
from clray.scene import model as M
from clray.scene.scale import scene_warnings

RTOL = 1e-5
RTOL_GRAZING = 1e-4
# At a cone's apex the two roots coincide: the square root of a rounded-to-zero discriminant
# moves t by about sqrt(6e-8) = 2.4e-4.
RTOL_APEX = 1e-3

TYPE_CODE = {M.Plane: L.PRIM_PLANE, M.Sphere: L.PRIM_SPHERE, M.Box: L.PRIM_BOX,
             M.Cylinder: L.PRIM_CYLINDER, M.Cone: L.PRIM_CONE}
mesh_gen = load_mesh_generator()


def ref(kind: int, index: int) -> int:
    return (kind << L.PRIM_TYPE_SHIFT) | index


def make_scene(*objects: M.SceneObject, eye: tuple = (0.0, 0.0, 0.0)) -> M.Scene:
    camera = M.Camera(position=eye, look_at=(eye[0], eye[1], eye[2] - 1.0))
    return M.Scene(None, M.RenderOptions(), camera, (M.Material("m"),), (), objects)


def f32(a: np.ndarray) -> np.ndarray:
    """Round to float32 and back: the values the kernel will actually see."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def cast(device: cl.Device, scene: M.Scene, origins: np.ndarray, directions: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel closest hits of world-space rays: (t, n_g, ref) as float64 / int."""
    packed = pack_scene(scene, width=4, height=4, spp=1, max_depth=0, seed=0)
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    t, n, r = intersect_rays(packed, device, np.asarray(origins) - eye, directions)
    return t.astype(np.float64), n.astype(np.float64), r


def expected_refs(scene: M.Scene, obj: np.ndarray, face: np.ndarray) -> np.ndarray:
    """Map reference hits (object index, face) to the kernel's primitive references."""
    per_object = []
    counts: dict[type, int] = {}
    triangles = 0
    for ob in scene.objects:
        if isinstance(ob, M.Triangle | M.Mesh):
            per_object.append(ref(L.PRIM_TRIANGLE, triangles))
            triangles += 1 if isinstance(ob, M.Triangle) else len(ob.faces)
        else:
            k = counts.get(type(ob), 0)
            per_object.append(ref(TYPE_CODE[type(ob)], k))
            counts[type(ob)] = k + 1
    table = np.array(per_object, dtype=np.int64)
    out = np.full(len(obj), -1, dtype=np.int64)
    hit = obj >= 0
    out[hit] = table[obj[hit]] + np.maximum(face[hit], 0)
    return out


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_units(rng: np.random.Generator, n: int) -> np.ndarray:
    return unit(rng.normal(size=(n, 3)))


def perpendicular_units(rng: np.random.Generator, axes: np.ndarray) -> np.ndarray:
    """A random unit vector perpendicular to each (unit) row of `axes`."""
    v = rng.normal(size=axes.shape)
    v -= np.sum(v * axes, axis=1, keepdims=True) * axes
    return unit(v)


def assert_rel(actual: np.ndarray, expected: np.ndarray, rtol: float, what: str) -> None:
    err = np.abs(actual - expected) / np.abs(expected)
    worst = int(np.argmax(err))
    assert err[worst] <= rtol, (f"{what}: worst relative error {err[worst]:.3g} > {rtol} "
                                f"(got {actual[worst]!r}, want {expected[worst]!r})")


def assert_normals(actual: np.ndarray, expected: np.ndarray, atol: float, what: str) -> None:
    err = np.max(np.abs(actual - expected), axis=1)
    worst = int(np.argmax(err))
    assert err[worst] <= atol, (f"{what}: normal off by {err[worst]:.3g} > {atol} "
                                f"(got {actual[worst]}, want {expected[worst]})")


# ---------------------------------------------------------------------------------------------
# Spheres


def test_sphere_hits_match_closed_form(cl_device):
    rng = np.random.default_rng(1)
    center, radius = np.array([0.3, -0.2, -6.0]), 1.3
    scene = make_scene(M.Sphere(tuple(center), radius, 0))
    n = 2000
    # Origins from 2 to 50 radii away, aimed at random points well inside the disc it shows.
    o = f32(center + random_units(rng, n) * radius * rng.uniform(2.0, 50.0, (n, 1)))
    aim = center + random_units(rng, n) * radius * 0.5
    d = f32(aim - o)
    t, normal, r = cast(cl_device, scene, o, d)

    # Closest approach in float64: t = tca - sqrt(r^2 - b^2) along the unit direction.
    dn = np.linalg.norm(d, axis=1)
    u = d / dn[:, None]
    tca = np.sum((center - o) * u, axis=1)
    b2 = np.sum((center - o) ** 2, axis=1) - tca**2
    want = (tca - np.sqrt(radius**2 - b2)) / dn
    assert np.all(r == ref(L.PRIM_SPHERE, 0))
    assert_rel(t, want, RTOL, "sphere t")
    assert_normals(normal, (o + want[:, None] * d - center) / radius, 1e-5, "sphere normal")


@pytest.mark.parametrize("n", [1, 7, 97, 1009])
def test_every_ray_of_a_launch_is_walked(cl_device, n):
    # intersect_rays walks a work-group's rays in a loop where work-items run serially: ray
    # counts that no local size but 1 or n divides leave no ray unwalked, nor any walked twice
    # with another's result. Each ray its own distance: a ray left out keeps no right t.
    center, radius = np.array([0.0, 0.0, -5.0]), 1.0
    scene = make_scene(M.Sphere(tuple(center), radius, 0))
    distance = np.linspace(2.0, 40.0, n)
    o = f32(center + np.outer(distance, [0.0, 0.0, 1.0]))
    d = f32(np.tile([0.0, 0.0, -1.0], (n, 1)))
    t, _, r = cast(cl_device, scene, o, d)
    assert np.all(r == ref(L.PRIM_SPHERE, 0))
    assert_rel(t, (o[:, 2] - center[2]) - radius, RTOL, "sphere t")


def test_sphere_from_inside_hits_the_far_side(cl_device):
    rng = np.random.default_rng(2)
    center, radius = np.array([1.0, 2.0, -3.0]), 2.0
    scene = make_scene(M.Sphere(tuple(center), radius, 0))
    n = 500
    o = f32(center + random_units(rng, n) * radius * rng.uniform(0.0, 0.9, (n, 1)))
    d = f32(random_units(rng, n))
    t, normal, _ = cast(cl_device, scene, o, d)
    f = o - center
    dd = np.sum(d * d, axis=1)
    b = np.sum(f * d, axis=1)
    want = (-b + np.sqrt(b * b - dd * (np.sum(f * f, axis=1) - radius**2))) / dd
    assert_rel(t, want, RTOL, "sphere exit t")
    assert_normals(normal, (o + want[:, None] * d - center) / radius, 1e-5, "exit normal")


@pytest.mark.parametrize("distance", [3.0, 30.0, 300.0])
def test_sphere_silhouette(cl_device, distance):
    """Rays passing the centre at (1 -+ eps) radius: inside the limb they hit at the closed
    form t, clearly outside they miss."""
    rng = np.random.default_rng(int(distance))
    center, radius = np.array([0.0, 0.0, -distance]), 1.0
    scene = make_scene(M.Sphere(tuple(center), radius, 0))
    n = 1000
    o = np.zeros((n, 3))
    axis = unit(center - o)
    side = perpendicular_units(rng, axis)
    # The ray's distance from the centre is b; the input rounding of d moves b by about
    # distance * 6e-8, so "just inside" is 1e-4 radii and "clearly outside" 1e-3.
    results = {}
    for name, b in (("inside", radius * (1 - 1e-4)), ("outside", radius * (1 + 1e-3))):
        # Unit direction at angle asin(b / D) from the centre line: distance b from the centre.
        s = b / distance
        d = f32(np.sqrt(1 - s * s) * axis + s * side)
        results[name] = (d, cast(cl_device, scene, o, d))
    d, (t, _, r) = results["inside"]
    assert np.all(r == ref(L.PRIM_SPHERE, 0)), f"{np.sum(r < 0)} of {n} inside-limb rays missed"
    dn = np.linalg.norm(d, axis=1)
    tca = np.sum(center * d, axis=1) / dn
    b2 = distance**2 - tca**2
    assert_rel(t, (tca - np.sqrt(radius**2 - b2)) / dn, RTOL_GRAZING, "limb t")
    _, (t, _, r) = results["outside"]
    assert np.all(r == -1) and np.all(np.isinf(t)), f"{np.sum(r >= 0)} outside rays hit"


def test_sphere_behind_the_origin_is_missed(cl_device):
    scene = make_scene(M.Sphere((0.0, 0.0, 5.0), 1.0, 0))
    t, _, r = cast(cl_device, scene, np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]))
    assert r[0] == -1 and np.isinf(t[0])


# ---------------------------------------------------------------------------------------------
# Boxes


BOX_LO = np.array([-1.0, -0.5, -7.0])
BOX_HI = np.array([1.5, 0.75, -5.0])


def box_edge_points(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n: int
                    ) -> np.ndarray:
    """n random points on the box's 12 edges, rounded to float32."""
    pts = np.where(rng.random((n, 3)) < 0.5, lo, hi)
    free = rng.integers(0, 3, n)
    rows = np.arange(n)
    pts[rows, free] = lo[free] + rng.random(n) * (hi - lo)[free]
    return f32(pts)


def box_corner_points(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n: int
                      ) -> np.ndarray:
    return np.where(rng.random((n, 3)) < 0.5, lo, hi)


@pytest.mark.parametrize("targets", [box_edge_points, box_corner_points])
def test_box_rays_aimed_at_edges_and_corners_all_hit(cl_device, targets):
    rng = np.random.default_rng(3)
    scene = make_scene(M.Box(tuple(BOX_LO), tuple(BOX_HI), 0))
    n = 4000
    aim = targets(rng, BOX_LO, BOX_HI, n)
    center = (BOX_LO + BOX_HI) / 2
    o = f32(center + random_units(rng, n) * rng.uniform(4.0, 12.0, (n, 1)))
    d = f32(aim - o)
    t, _, r = cast(cl_device, scene, o, d)
    assert np.all(r == ref(L.PRIM_BOX, 0)), f"{np.sum(r < 0)} of {n} rays at the box missed"
    # The aimed point lies at t = 1 up to the rounding of d; the ray reaches the box there or
    # earlier (when the point is on the far side).
    want = intersect_scene(scene, o, d).t
    exact = np.isfinite(want)
    assert_rel(t[exact], want[exact], RTOL, "box t")
    # Where even float64 says "miss", the ray passes the edge by a rounding: it grazes at t=1.
    assert np.all(np.abs(t[~exact] - 1.0) <= RTOL)


def test_box_face_normals(cl_device):
    rng = np.random.default_rng(4)
    scene = make_scene(M.Box(tuple(BOX_LO), tuple(BOX_HI), 0))
    n = 2000
    center = (BOX_LO + BOX_HI) / 2
    o = f32(center + random_units(rng, n) * 8.0)
    d = f32(center + rng.uniform(-0.4, 0.4, (n, 3)) * (BOX_HI - BOX_LO) - o)
    t, normal, _ = cast(cl_device, scene, o, d)
    want = intersect_scene(scene, o, d)
    assert np.all(np.isfinite(want.t))
    assert_rel(t, want.t, RTOL, "box t")
    # Points within 1e-6 of an edge may report either face.
    p = o + want.t[:, None] * d
    clear = np.sum(np.minimum(np.abs(p - BOX_LO), np.abs(p - BOX_HI)) < 1e-6, axis=1) <= 1
    assert clear.sum() > n * 0.99
    assert_normals(normal[clear], want.normal[clear], 0.0, "box normal")


def test_flat_box_normal_is_the_face_the_ray_enters_by(cl_device):
    """A box flat in z (lo.z == hi.z) has both z faces in one plane; the entry face, and so the
    normal, is the reference's: +z for a ray coming down, -z for one coming up. (Picking the
    near plane by comparing the two equal t kept the lo face, -z, for both.)"""
    scene = make_scene(M.Box((-1.0, -1.0, -5.0), (1.0, 1.0, -5.0), 0))
    o = np.array([[0.1, 0.2, 0.0], [0.1, 0.2, -9.0]])
    d = np.array([[0.0, 0.1, -1.0], [0.0, 0.1, 1.0]])
    t, normal, r = cast(cl_device, scene, o, d)
    want = intersect_scene(scene, o, d)
    assert np.all(r == ref(L.PRIM_BOX, 0))
    assert_rel(t, want.t, RTOL, "flat box t")
    assert_normals(normal, want.normal, 0.0, "flat box normal")
    assert want.normal[:, 2].tolist() == [1.0, -1.0]


def test_rays_along_box_edges_and_faces_hit(cl_device):
    """Axis-aligned rays: zero direction components with the origin exactly on slab planes
    give (bound - o) * inf = 0 * inf = NaN, which must not turn the hit into a miss; one ulp
    outside the slab they miss."""
    lo, hi = (-1.0, -1.0, -6.0), (1.0, 2.0, -4.0)
    scene = make_scene(M.Box(lo, hi, 0))
    below = float(np.nextafter(np.float32(-1.0), np.float32(-2.0)))
    rays = [
        # (origin, direction, expected t or None for a miss)
        ((-1.0, -1.0, 0.0), (0.0, 0.0, -1.0), 4.0),  # along an edge: two zero components
        ((1.0, 2.0, 0.0), (0.0, 0.0, -1.0), 4.0),  # along the opposite edge
        ((-1.0, 0.5, 0.0), (0.0, 0.0, -1.0), 4.0),  # in the plane of the x = -1 face
        ((0.5, 2.0, 0.0), (0.0, 0.0, -1.0), 4.0),  # in the plane of the y = 2 face
        ((-5.0, 2.0, -5.0), (1.0, 0.0, 0.0), 4.0),  # the numerics note's case, along x
        ((0.0, -5.0, -6.0), (0.0, 1.0, 0.0), 4.0),  # along y in the z = -6 face plane
        ((1.0, 2.0, -9.0), (0.0, 0.0, 1.0), 3.0),  # along an edge, from behind
        ((below, 0.5, 0.0), (0.0, 0.0, -1.0), None),  # one float32 ulp outside x = -1
        ((0.5, 2.0000002, 0.0), (0.0, 0.0, -1.0), None),  # one ulp above y = 2
    ]
    o = np.array([r[0] for r in rays])
    d = np.array([r[1] for r in rays])
    t, _, r = cast(cl_device, scene, o, d)
    for k, (origin, direction, want) in enumerate(rays):
        if want is None:
            assert r[k] == -1, f"ray {origin} {direction} should miss, got t={t[k]}"
        else:
            assert r[k] == ref(L.PRIM_BOX, 0), f"ray {origin} {direction} missed"
            assert t[k] == pytest.approx(want, rel=RTOL)


def test_axis_aligned_rays_on_bvh_slab_planes_reach_flat_primitives(cl_device):
    """The same NaN hazard in BVH node tests: a flat box and a triangle in the plane z = -5
    have node bounds with lo.z == hi.z, and rays with zero x / y components start on the
    nodes' x / y slab planes."""
    flat = M.Box((2.0, 0.0, -5.0), (3.0, 1.0, -5.0), 0)
    tri = M.Triangle(((0.0, 0.0, -5.0), (1.0, 0.0, -5.0), (0.0, 1.0, -5.0)), 0)
    scene = make_scene(flat, tri)
    o = np.array([
        [2.0, 0.0, 0.0], [3.0, 1.0, 0.0], [2.5, 0.5, 0.0],  # flat box: corner, corner, middle
        [0.0, 0.25, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0],  # triangle: edge, edge, vertex
        [-3.0, 0.5, -5.0],  # in the flat box's plane: enters the box through its x = 2 side
    ])
    d = np.array([[0.0, 0.0, -1.0]] * 6 + [[1.0, 0.0, 0.0]])
    t, _, r = cast(cl_device, scene, o, d)
    box, triangle = ref(L.PRIM_BOX, 0), ref(L.PRIM_TRIANGLE, 0)
    assert r.tolist() == [box, box, box, triangle, triangle, triangle, box]
    assert np.allclose(t, [5.0] * 6 + [5.0], rtol=RTOL)


@pytest.mark.parametrize("precision", ["float", "double"])
@pytest.mark.parametrize("traversal", ["single", "sample_packet"])
def test_negative_zero_direction_components_on_slab_planes_hit(cl_device, precision, traversal):
    """The rays of test_rays_along_box_edges_and_faces_hit with their zero components negative:
    1 / -0 = -inf, and a slab test that picks the near plane by comparing the two t (one NaN)
    kept (hi - o) * -inf = -inf as the far bound with the origin on lo (or +inf as the near one
    with it on hi), and missed. A -0 is what negating or scaling a zero gives (a reflected or
    flipped direction). Both the box's own test and the BVH nodes' (whose bounds are the
    box's) must ignore the NaN, as for +0. The oracle: clray.reference, which takes any zero
    component as parallel."""
    if precision == "double" and "cl_khr_fp64" not in cl_device.extensions:
        pytest.skip("no fp64")
    lo, hi = (-1.0, -1.0, -6.0), (1.0, 2.0, -4.0)
    scene = make_scene(M.Box(lo, hi, 0))
    z = -0.0
    rays = [
        ((-1.0, 0.5, 0.0), (z, z, -1.0)),  # in the plane of the x = lo face
        ((1.0, 0.5, 0.0), (z, z, -1.0)),  # in the plane of the x = hi face
        ((0.5, -1.0, 0.0), (z, z, -1.0)),  # y = lo
        ((0.5, 2.0, 0.0), (z, z, -1.0)),  # y = hi
        ((-1.0, -1.0, 0.0), (z, z, -1.0)),  # along an edge
        ((1.0, 2.0, -9.0), (z, z, 1.0)),  # along the opposite edge, from behind
        ((-5.0, 2.0, -6.0), (1.0, z, z)),  # along x, on the y = hi and z = lo planes
    ]
    o = np.array([r[0] for r in rays])
    d = np.array([r[1] for r in rays])
    assert np.all(np.signbit(d[d == 0.0]))
    packed = pack_scene(scene, width=4, height=4, spp=1, max_depth=0, seed=0,
                        precision=precision, traversal=traversal)
    t, _, r = intersect_rays(packed, cl_device, o, d)
    want = intersect_scene(scene, o, d)
    assert np.all(np.isfinite(want.t))
    assert r.tolist() == [ref(L.PRIM_BOX, 0)] * len(rays), f"t = {t}"
    assert_rel(t.astype(np.float64), want.t, RTOL, "t")


@pytest.mark.parametrize("precision", ["float", "double"])
@pytest.mark.parametrize("traversal", ["single", "sample_packet"])
def test_unused_node_lanes_are_missed_by_rays_with_zero_direction_components(
        cl_device, precision, traversal):
    """A wide node's unused lanes (child -1) hold NaN boxes, which the slab test's
    compare-select passes over (a NaN never narrows the interval), so node_children masks them
    by child >= 0: a crossed one would send the walk to node -1. Rays with every sign of zero
    in their zero components (reciprocals of +-inf), from origins at 0 and on the boxes'
    planes, through a tree whose nodes have unused lanes, against clray.reference."""
    if precision == "double" and "cl_khr_fp64" not in cl_device.extensions:
        pytest.skip("no fp64")
    # A grid of boxes, of sizes that leave the tree's lower nodes part full, one at the
    # origin's planes (x = 0, y = 0).
    boxes = [M.Box((3.0 * i, 3.0 * j, -6.0 - (i + j) % 4),
                   (3.0 * i + 1.0, 3.0 * j + 1.0 + i % 3, -5.0), 0)
             for i in range(11) for j in range(11)]
    scene = make_scene(*boxes)
    packed = pack_scene(scene, width=4, height=4, spp=1, max_depth=0, seed=0,
                        precision=precision, traversal=traversal)
    nodes = packed.nodes
    unused = nodes["child"] < 0
    assert unused.any() and ((nodes["count"] == 0) & ~unused).any()  # inner nodes, not full
    check_unused_lanes(nodes)
    o, d = [], []
    for a in (0.0, -0.0):
        for b in (0.0, -0.0):
            for x in (0.0, 1e-30, 0.5, 1.0, 2.0, 3.0, 4.0, 15.0, 31.0):
                for y in (0.0, 0.5, 1.0, 2.0, 3.0, 30.5):
                    o += [(x, y, 0.0), (x, y, -20.0)]  # down the z axis, and from behind
                    d += [(a, b, -1.0), (a, b, 1.0)]
            for u in (0.0, 1.0, 3.0, 3.5, 4.0):
                for z in (-5.0, -6.0, -8.0, 0.0):
                    # Along x and along y, on the boxes' planes and between them.
                    o += [(-4.0, u, z), (40.0, u, z), (u, -4.0, z), (u, 40.0, z)]
                    d += [(1.0, a, b), (-1.0, a, b), (a, 1.0, b), (a, -1.0, b)]
    o, d = np.array(o), np.array(d)
    t, _, r = intersect_rays(packed, cl_device, o, d)
    want = intersect_scene(scene, o, d)
    hit = np.isfinite(want.t)
    assert hit.sum() > len(o) // 4 and (~hit).sum() > len(o) // 8
    assert np.array_equal(r >= 0, hit), f"rays {np.flatnonzero((r >= 0) != hit)}"
    assert np.all(r[hit] >> L.PRIM_TYPE_SHIFT == L.PRIM_BOX)
    assert_rel(t[hit].astype(np.float64), want.t[hit], RTOL, "t")


# ---------------------------------------------------------------------------------------------
# Planes


def test_plane_hits_from_both_sides(cl_device):
    rng = np.random.default_rng(5)
    normal = unit(np.array([0.2, 1.0, -0.3]))
    point = np.array([0.5, -1.0, 2.0])
    scene = make_scene(M.Plane(tuple(point), tuple(normal), 0))
    n = 2000
    o = f32(rng.uniform(-10, 10, (n, 3)))
    d = f32(random_units(rng, n))
    t, got_n, r = cast(cl_device, scene, o, d)
    with np.errstate(divide="ignore"):
        want = np.sum((point - o) * normal, axis=1) / (d @ normal)
    ahead = want > 0
    assert ahead.sum() > n // 3 and (~ahead).sum() > n // 3
    assert np.all(r[~ahead] == -1)
    assert np.all(r[ahead] == ref(L.PRIM_PLANE, 0))
    # t is ill-conditioned for rays nearly parallel to the plane; there the hit point's
    # distance from the plane, relative to the distance travelled, is the fair measure.
    p = o[ahead] + t[ahead, None] * d[ahead]
    off = np.abs((p - point) @ normal) / np.linalg.norm(p - o[ahead] + 1.0, axis=1)
    assert off.max() <= RTOL
    steep = ahead & (np.abs(d @ normal) > 0.1)
    assert_rel(t[steep], want[steep], RTOL, "plane t")
    # n_g is the plane's normal as given, on either side.
    assert_normals(got_n[ahead], np.broadcast_to(normal, (ahead.sum(), 3)), 1e-6, "plane n")


def test_ray_parallel_to_a_plane_misses(cl_device):
    scene = make_scene(M.Plane((0.0, -1.0, 0.0), (0.0, 1.0, 0.0), 0))
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.6, 0.0, 0.8]])
    t, _, r = cast(cl_device, scene, np.zeros((3, 3)), d)
    assert np.all(r == -1) and np.all(np.isinf(t))


# ---------------------------------------------------------------------------------------------
# Cylinders and cones (a tilted axis, so no component is special)

AXIS = unit(np.array([0.3, 1.0, 0.2]))


def cylinder(capped: bool = True) -> M.Cylinder:
    return M.Cylinder(base=(0.5, -1.0, -6.0), axis=tuple(AXIS), radius=0.8, height=2.0,
                      material=0, capped=capped)


def cone(capped: bool = True) -> M.Cone:
    return M.Cone(apex=(-0.5, 1.0, -5.0), axis=tuple(-AXIS), angle=25.0, height=2.0,
                  material=0, capped=capped)


def f32_shape(shape: M.Cylinder | M.Cone) -> M.Cylinder | M.Cone:
    """The shape as the kernel stores it: positions, axis and sizes rounded to float32. (The
    cone keeps its exact angle: the stored tan's rounding moves the surface by ~1e-7.)"""
    axis = tuple(f32(shape.axis))
    if isinstance(shape, M.Cylinder):
        return M.Cylinder(base=tuple(f32(shape.base)), axis=axis, radius=float(f32(shape.radius)),
                          height=float(f32(shape.height)), material=0, capped=shape.capped)
    return M.Cone(apex=tuple(f32(shape.apex)), axis=axis, angle=shape.angle,
                  height=float(f32(shape.height)), material=0, capped=shape.capped)


def check_against_reference(device: cl.Device, shape: M.SceneObject, o: np.ndarray,
                            d: np.ndarray, rtol: float, what: str) -> np.ndarray:
    """All rays must hit; t and n_g must match the float64 reference. Returns t."""
    scene = make_scene(shape)
    t, normal, r = cast(device, scene, o, d)
    want = intersect_scene(make_scene(f32_shape(shape)), o, d)
    assert np.all(np.isfinite(want.t)), "test rays must all hit in float64"
    assert np.all(r >= 0), f"{what}: {np.sum(r < 0)} of {len(o)} rays missed"
    assert_rel(t, want.t, rtol, f"{what} t")
    assert_normals(normal, want.normal, 1e-4, f"{what} normal")
    return t


def test_cylinder_side(cl_device):
    rng = np.random.default_rng(6)
    c = cylinder()
    base = np.array(c.base)
    n = 2000
    # Aim at points on the axis between 5 % and 95 % of the height, from outside the tube.
    aim = base + rng.uniform(0.1, 1.9, (n, 1)) * AXIS
    o = f32(aim + perpendicular_units(rng, np.broadcast_to(AXIS, (n, 3))) * 5.0
            + rng.uniform(-0.5, 0.5, (n, 1)) * AXIS)
    d = f32(aim - o)
    check_against_reference(cl_device, c, o, d, RTOL, "cylinder side")


@pytest.mark.parametrize("shape", ["cylinder", "cone"])
def test_side_from_just_inside_reaches_the_far_side(cl_device, shape):
    """Origins 1e-4 radii inside the side, as a refracted ray starts: the near root is tiny
    and negative, and the far one must not inherit its cancellation (the Press pair computes
    each root from the sum of two same-signed numbers)."""
    rng = np.random.default_rng(16)
    n = 2000
    perp = perpendicular_units(rng, np.broadcast_to(AXIS, (n, 3)))
    if shape == "cylinder":
        c = cylinder(capped=False)
        along = rng.uniform(0.8, 1.2, (n, 1))
        o = f32(np.array(c.base) + along * AXIS + perp * c.radius * 0.9999)
    else:
        c = cone(capped=False)
        along = rng.uniform(0.8, 1.2, (n, 1))
        radius = along * math.tan(math.radians(c.angle))
        o = f32(np.array(c.apex) - along * AXIS + perp * radius * 0.9999)
    # Inwards and across, nearly perpendicular to the axis, so the far crossing is on the side.
    tangent = np.cross(AXIS, perp)
    d = f32(unit(-perp + 0.9 * rng.uniform(-1, 1, (n, 1)) * tangent
                 + 0.02 * rng.uniform(-1, 1, (n, 1)) * AXIS))
    t = check_against_reference(cl_device, c, o, d, RTOL, f"{shape} from inside")
    assert np.all(t > 0.1 * c.radius if shape == "cylinder" else t > 0.05)


def test_cylinder_caps(cl_device):
    rng = np.random.default_rng(7)
    c = cylinder()
    base = np.array(c.base)
    n = 2000
    perp = perpendicular_units(rng, np.broadcast_to(AXIS, (n, 3)))
    top = rng.random(n) < 0.5
    # From beyond either cap, nearly along the axis, at points within 90 % of the radius.
    cap_center = base + np.where(top, c.height, 0.0)[:, None] * AXIS
    aim = cap_center + perp * rng.uniform(0, 0.9 * c.radius, (n, 1))
    out = np.where(top, 1.0, -1.0)[:, None] * AXIS
    o = f32(aim + 4.0 * out + 0.3 * random_units(rng, n))
    d = f32(aim - o)
    t = check_against_reference(cl_device, c, o, d, RTOL, "cylinder cap")
    assert np.all(np.abs(t - 1.0) < 1e-5)


def test_cylinder_rims_hit(cl_device):
    """Rays aimed exactly at points of the two rim circles, crossing from the cap into the
    side or back: none may miss. (Rays that only touch the rim from outside, meeting one
    surface from the front and the other from behind, are left out: after rounding they may
    truly miss.)"""
    rng = np.random.default_rng(8)
    c = cylinder()
    base = np.array(c.base)
    n = 4000
    perp = perpendicular_units(rng, np.broadcast_to(AXIS, (n, 3)))
    top = rng.random(n) < 0.5
    aim = f32(base + np.where(top, c.height, 0.0)[:, None] * AXIS + c.radius * perp)
    o = f32(aim + random_units(rng, n) * 6.0)
    d = f32(aim - o)
    cap_normal = np.where(top, 1.0, -1.0)[:, None] * AXIS
    keep = crossing(np.stack([perp, cap_normal], axis=1), d)
    assert keep.mean() > 0.3
    o, d = o[keep], d[keep]
    t, _, r = cast(cl_device, make_scene(c), o, d)
    assert np.all(r >= 0), f"{np.sum(r < 0)} of {len(o)} rays at the rims missed"
    want = intersect_scene(make_scene(f32_shape(c)), o, d).t
    exact = np.isfinite(want)
    assert exact.mean() > 0.9
    assert_rel(t[exact], want[exact], RTOL_GRAZING, "rim t")
    # Where float64 misses, the ray grazes the rim by a rounding, at the aimed point.
    assert np.all(np.abs(t[~exact] - 1.0) <= RTOL_GRAZING)


def test_uncapped_cylinder_inside_is_visible_and_the_bore_is_empty(cl_device):
    c = cylinder(capped=False)
    base = np.array(c.base)
    rng = np.random.default_rng(9)
    n = 500
    # Along the axis through the open ends: nothing to hit.
    o_axis = f32(base - 3.0 * AXIS + 0.3 * perpendicular_units(
        rng, np.broadcast_to(AXIS, (n, 3))))
    _, _, r = cast(cl_device, make_scene(c), o_axis, np.broadcast_to(f32(AXIS), (n, 3)))
    assert np.all(r == -1)
    # From inside the tube, sideways: the inner wall, with the outward normal.
    o_in = f32(base + 1.0 * AXIS)
    d = f32(perpendicular_units(rng, np.broadcast_to(AXIS, (n, 3))))
    t = check_against_reference(cl_device, c, np.broadcast_to(o_in, (n, 3)), d, RTOL,
                                "tube inside")
    assert np.allclose(t, c.radius, rtol=RTOL)


def test_cone_side_and_cap(cl_device):
    rng = np.random.default_rng(10)
    k = cone()
    apex, axis = np.array(k.apex), -AXIS
    n = 2000
    perp = perpendicular_units(rng, np.broadcast_to(axis, (n, 3)))
    # Side: sideways rays aimed at axis points between 10 % and 90 % of the height.
    aim = apex + rng.uniform(0.2, 1.8, (n, 1)) * axis
    o = f32(aim + 5.0 * perp)
    check_against_reference(cl_device, k, o, f32(aim - o), RTOL, "cone side")
    # Cap: from beyond the base, at points within 90 % of the base radius.
    radius = k.height * np.tan(np.radians(k.angle))
    aim = apex + k.height * axis + perp * rng.uniform(0, 0.9 * radius, (n, 1))
    o = f32(aim + 4.0 * axis + 0.3 * random_units(rng, n))
    t = check_against_reference(cl_device, k, o, f32(aim - o), RTOL, "cone cap")
    assert np.all(np.abs(t - 1.0) < 1e-5)


@pytest.mark.parametrize("distance", [100.0, 2000.0])
def test_far_cone_side_hits_match_reference(cl_device, distance):
    """Sideways rays from `distance` away (the cone is 2 high: well under the loader's 1e4
    ratio, so no warning) aimed at axis points between 10 % and 90 % of the height: every ray
    crosses the cone through its axis, with a chord of its own size. The discriminant
    b^2 - a c from the far origin is the difference of two terms of order distance^2, whose
    float32 roundings swamp it: ragged or missing sides, as the textbook sphere gives. Taken
    from the line's point nearest the apex (as the sphere's and cylinder's Hearn-Baker form)
    it keeps float32 accuracy. Normals are not compared: at this distance the hit point's own
    float32 rounding moves them by more than the 1e-4 the near tests allow."""
    rng = np.random.default_rng(17)
    k = cone()
    apex, axis = np.array(k.apex), -AXIS
    n = 2000
    perp = perpendicular_units(rng, np.broadcast_to(axis, (n, 3)))
    aim = apex + rng.uniform(0.2, 1.8, (n, 1)) * axis
    o = f32(aim + distance * perp + rng.uniform(-0.2, 0.2, (n, 1)) * distance * axis)
    d = f32(aim - o)
    scene = make_scene(k)
    assert scene_warnings(scene) == ()
    t, normal, r = cast(cl_device, scene, o, d)
    want = intersect_scene(make_scene(f32_shape(k)), o, d)
    assert np.all(np.isfinite(want.t)), "test rays must all hit in float64"
    assert np.all(r >= 0), f"{np.sum(r < 0)} of {n} rays at the far cone missed"
    assert_rel(t, want.t, RTOL, "far cone t")
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-5)


def test_cone_apex(cl_device):
    """Along the axis into the apex, from outside and (uncapped) from inside the cone: a hit at
    the apex. Rays aimed at the apex from any direction: a hit there or a miss (a tangency),
    never a NaN normal."""
    apex = np.array([0.0, 1.0, -5.0])
    k = M.Cone(apex=tuple(apex), axis=(0.0, -1.0, 0.0), angle=30.0, height=2.0, material=0,
               capped=False)
    o = apex + np.array([[0.0, 3.0, 0.0], [0.0, -4.0, 0.0]])
    d = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    t, normal, r = cast(cl_device, make_scene(k), o, d)
    assert r.tolist() == [ref(L.PRIM_CONE, 0)] * 2
    assert np.allclose(t, [3.0, 4.0], rtol=RTOL_APEX)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-5)

    rng = np.random.default_rng(11)
    n = 2000
    o = f32(apex + random_units(rng, n) * 4.0)
    d = f32(apex - o)
    t, normal, r = cast(cl_device, make_scene(k), o, d)
    hit = r >= 0
    assert np.all(np.isfinite(normal))
    assert np.allclose(np.linalg.norm(normal[hit], axis=1), 1.0, atol=1e-5)
    # A line through the apex meets the (double) cone only there: at the aimed point, t = 1.
    assert np.all(np.abs(t[hit] - 1.0) <= RTOL_APEX)


def test_ray_parallel_to_a_cone_generator_meets_the_side_once(cl_device):
    """A 45-degree cone and directions along its side's slope, (1, -1, 0) exactly: the side's
    quadratic has a = 0 exactly in float32 (tan 45 stores as 1), and its linear root is the
    closed form's. From the apex's height, (-c, 0, z) off the axis, the line meets the cone
    where (s - c)^2 + z^2 = s^2: s = (c^2 + z^2) / (2 c) down the axis, at t = s."""
    apex = np.array([0.0, 1.0, -5.0])
    k = M.Cone(apex=tuple(apex), axis=(0.0, -1.0, 0.0), angle=45.0, height=2.0, material=0,
               capped=False)
    c = np.array([2.0, 1.0, 3.0, 0.5, 1.5, 4.0])
    z = np.array([0.5, 0.25, -1.0, 0.1, 1.0, 2.0])
    o = apex + np.stack([-c, np.zeros_like(c), z], axis=1)
    d = np.tile([1.0, -1.0, 0.0], (len(c), 1))
    s = (c * c + z * z) / (2.0 * c)
    want = np.where(s <= 2.0, s, np.inf)  # the last, 2.5 down, is past the cone's height
    assert np.isinf(want[-1]) and np.all(np.isfinite(want[:-1]))
    reference = intersect_scene(make_scene(k), o, d)
    assert np.allclose(reference.t, want, rtol=1e-12)
    t, normal, r = cast(cl_device, make_scene(k), o, d)
    assert r.tolist() == [ref(L.PRIM_CONE, 0)] * (len(c) - 1) + [-1]
    assert_rel(t[:-1], want[:-1], RTOL, "cone side along a generator t")
    assert_normals(normal[:-1], reference.normal[:-1], 1e-4, "cone side along a generator")
    # Unit directions along the slope: float32's rounding leaves a a hair off 0.
    du = np.tile(f32(np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)), (len(c), 1))
    t, _, r = cast(cl_device, make_scene(k), o, du)
    assert r.tolist() == [ref(L.PRIM_CONE, 0)] * (len(c) - 1) + [-1]
    assert_rel(t[:-1], intersect_scene(make_scene(k), o, du).t[:-1], RTOL, "unit slope t")


# ---------------------------------------------------------------------------------------------
# Triangles and closed meshes


def test_triangles_match_reference(cl_device):
    rng = np.random.default_rng(12)
    depth = np.array([0.0, 0.0, -6.0])
    tris = [f32(rng.uniform(-2, 2, (3, 3)) + depth) for _ in range(5)]
    scene = make_scene(*(M.Triangle(tuple(map(tuple, v)), 0) for v in tris))
    n = 4000
    o = f32(rng.uniform(-3, 3, (n, 3)))
    d = f32(rng.uniform(-2.5, 2.5, (n, 3)) + depth - o)
    t, normal, r = cast(cl_device, scene, o, d)
    want = intersect_scene(scene, o, d)
    want_ref = expected_refs(scene, want.obj, want.face)
    hit = want_ref >= 0
    assert 0.2 * n < hit.sum() < 0.9 * n
    # A ray may pass within rounding of an edge: hit/miss there may differ. None of these
    # seeded rays does, so demand agreement everywhere.
    assert np.array_equal(r, want_ref)
    assert_rel(t[hit], want.t[hit], RTOL, "triangle t")
    assert_normals(normal[hit], want.normal[hit], 1e-5, "triangle n_g")


def closed_icosphere(subdivisions: int, center: np.ndarray, radius: float) -> M.Mesh:
    """The bumpy benchmark mesh with its vertices rounded to float32, so targets computed in
    float64 from them are exactly the kernel's edges and vertices."""
    vertices, faces, _ = mesh_gen.bumpy_mesh(subdivisions, tuple(center), radius)
    return M.Mesh(vertices=f32(vertices), faces=faces, material=0)


def face_normals(mesh: M.Mesh) -> np.ndarray:
    v = mesh.vertices[mesh.faces]
    return unit(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))


def shared_edges(mesh: M.Mesh) -> tuple[np.ndarray, np.ndarray]:
    """(E, 2) vertex pairs and (E, 2) the two faces of each edge of a closed mesh."""
    f = mesh.faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    face = np.tile(np.arange(len(f)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, face = e[order], face[order]
    # Closed and manifold: every edge comes exactly twice, the copies adjacent after sorting.
    assert np.array_equal(e[0::2], e[1::2])
    return e[0::2], face.reshape(-1, 2)


def vertex_fans(mesh: M.Mesh) -> np.ndarray:
    """(V, 6) the faces around each vertex (an icosphere's valence is 5 or 6), padded by
    repeating the first."""
    corner_face = np.repeat(np.arange(len(mesh.faces)), 3)
    order = np.argsort(mesh.faces.ravel(), kind="stable")
    counts = np.bincount(mesh.faces.ravel(), minlength=len(mesh.vertices))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.minimum(np.arange(6)[None, :], counts[:, None] - 1)
    return corner_face[order][starts[:, None] + slot]


def crossing(normals: np.ndarray, d: np.ndarray) -> np.ndarray:
    """True where the ray meets every given face from the same side, clear of tangency: it
    crosses the surface there, so it cannot pass by on a silhouette."""
    cos = np.einsum("nkc,nc->nk", normals, unit(d))
    return (np.all(cos > 1e-3, axis=1)) | (np.all(cos < -1e-3, axis=1))


@pytest.mark.parametrize(("where", "distance"), [("outside", 5.0), ("outside", 1000.0),
                                                 ("inside", 0.0)])
def test_closed_mesh_is_watertight_at_edges_and_vertices(cl_device, where, distance):
    """Rays aimed exactly at shared edges and shared vertices of a closed mesh, from outside
    (near and far) and from inside it: none may slip between the triangles. Rays at silhouette
    edges, which only touch the mesh, are left out: after rounding they may truly miss."""
    rng = np.random.default_rng(13)
    center, radius = np.array([0.2, -0.1, -4.0]), 1.0
    mesh = closed_icosphere(4, center, radius)
    scene = make_scene(mesh)
    normals = face_normals(mesh)
    edges, edge_faces = shared_edges(mesh)
    fans = vertex_fans(mesh)
    n = 4000
    if where == "inside":
        o = f32(center + random_units(rng, n) * rng.uniform(0, 0.5, (n, 1)))
    else:
        o = f32(center + random_units(rng, n) * distance)
    pick = rng.integers(0, len(edges), n)
    a, b = mesh.vertices[edges[pick, 0]], mesh.vertices[edges[pick, 1]]
    # Targets in float64, not rounded: a point rounded to float32 would leave the edge.
    edge_aim = a + rng.random((n, 1)) * (b - a)
    vertex = rng.integers(0, len(mesh.vertices), n)
    targets = {"edge": (edge_aim, normals[edge_faces[pick]]),
               "vertex": (mesh.vertices[vertex], normals[fans[vertex]])}
    for name, (aim, adjacent) in targets.items():
        # The direction is rounded to float32 like any ray; the ray then passes within a
        # rounding of the target, where two (or more) triangles meet.
        d = f32(aim - o)
        keep = crossing(adjacent, d)
        assert keep.mean() > 0.8
        t, _, r = cast(cl_device, scene, o[keep], d[keep])
        miss = r < 0
        assert not miss.any(), (f"{miss.sum()} of {keep.sum()} rays at shared {name}s leaked "
                                f"({where}, distance {distance}); first origin "
                                f"{o[keep][miss][0]}, direction {d[keep][miss][0]}")
        # Reaching the mesh at or before the aimed point (t = 1 up to rounding).
        assert np.all(t <= 1.0 + RTOL_GRAZING)
        if where == "inside":
            assert np.all(t >= 1.0 - RTOL_GRAZING)


def test_rays_exactly_on_a_shared_diagonal_with_inexact_products_hit(cl_device):
    """Axis-aligned rays through points exactly on the diagonal a quad's two triangles share,
    where the edge function's two products are equal but not representable in float32. The
    compensated a*b - c*d (difference_of_products) gives exactly 0 for both triangles, so the
    edge counts as inside; an uncompensated one gives both the same rounding residue, which
    one triangle reads as inside and the other as outside, or both as outside: a leak."""
    rng = np.random.default_rng(15)
    leaks = []
    for _ in range(40):
        # 22-bit mantissas in [1, 2): a s and a - a s are exact for s in {1/4, 1/2, 3/4},
        # while products of two such numbers need about 44 bits.
        a, b = rng.integers(2**21, 2**22, 2) / 2.0**21
        quad = M.Mesh(vertices=np.array([[0, 0, -5], [a, 0, -5], [a, b, -5], [0, b, -5]]),
                      faces=np.array([[0, 1, 2], [0, 2, 3]]), material=0)
        s = np.array([0.25, 0.5, 0.75])
        points = np.stack([a * s, b * s], axis=1)
        o = np.concatenate([np.column_stack([points, np.zeros(3)]),
                            np.column_stack([points, np.full(3, -10.0)])])
        d = np.array([[0.0, 0.0, -1.0]] * 3 + [[0.0, 0.0, 1.0]] * 3)
        t, _, r = cast(cl_device, make_scene(quad), o, d)
        assert np.all(f32(o) == o) and np.all((r < 0) | (np.abs(t - 5.0) <= RTOL * 5))
        leaks += [(a, b, tuple(o[k])) for k in np.flatnonzero(r < 0)]
    assert not leaks, f"{len(leaks)} of 240 rays slipped between the triangles: {leaks[:3]}"


# ---------------------------------------------------------------------------------------------
# The BVH: closest hit over a random mix, against brute force


def random_mix(rng: np.random.Generator, eye: tuple = (0.0, 0.0, 0.0)) -> M.Scene:
    """About 250 primitives of every type in a 20-unit cube, some overlapping."""
    objects: list[M.SceneObject] = [
        M.Plane((0.0, -12.0, 0.0), (0.0, 1.0, 0.0), 0),
        M.Plane((0.0, 0.0, -14.0), tuple(unit(np.array([0.1, 0.2, 1.0]))), 0),
    ]

    def pos() -> tuple:
        return tuple(rng.uniform(-10, 10, 3))

    for _ in range(40):
        objects.append(M.Sphere(pos(), float(rng.uniform(0.2, 1.5)), 0))
    for _ in range(40):
        lo = np.array(pos())
        objects.append(M.Box(tuple(lo), tuple(lo + rng.uniform(0.2, 2.0, 3)), 0))
    for _ in range(30):
        objects.append(M.Cylinder(pos(), tuple(random_units(rng, 1)[0]),
                                  float(rng.uniform(0.2, 1.0)), float(rng.uniform(0.5, 3.0)),
                                  0, capped=bool(rng.random() < 0.7)))
    for _ in range(30):
        objects.append(M.Cone(pos(), tuple(random_units(rng, 1)[0]),
                              float(rng.uniform(10, 60)), float(rng.uniform(0.5, 3.0)), 0,
                              capped=bool(rng.random() < 0.7)))
    for _ in range(30):
        objects.append(M.Triangle(tuple(map(tuple, np.array(pos()) + rng.uniform(
            -1.5, 1.5, (3, 3)))), 0))
    sphere_mesh = mesh_gen.bumpy_mesh(2, pos(), 1.5)
    objects.append(M.Mesh(vertices=sphere_mesh[0], faces=sphere_mesh[1], material=0))
    order = rng.permutation(len(objects))  # interleave the types in scene order
    return make_scene(*(objects[i] for i in order), eye=eye)


@pytest.mark.parametrize("eye", [(0.0, 0.0, 0.0), (3.5, -2.25, 7.0)])
def test_bvh_closest_hit_matches_brute_force(cl_device, eye):
    rng = np.random.default_rng(14)
    scene = random_mix(rng, eye)
    n = 5000
    o = f32(rng.uniform(-12, 12, (n, 3)))
    d = f32(random_units(rng, n))
    t, _, r = cast(cl_device, scene, o, d)
    want = intersect_scene(scene, o, d)
    want_ref = expected_refs(scene, want.obj, want.face)
    hit = np.isfinite(want.t)
    assert hit.mean() > 0.5
    # Same hit or miss everywhere (these seeded rays graze no silhouette within rounding).
    assert np.array_equal(r >= 0, hit), f"{np.sum((r >= 0) != hit)} hit/miss disagreements"
    # d is unit: t + |o| is the size of the coordinates the hit is computed from.
    rel = np.abs(t[hit] - want.t[hit]) / (want.t[hit] + np.linalg.norm(o[hit], axis=1))
    same = r[hit] == want_ref[hit]
    # A different primitive is allowed only as a near-tie: its t within 1e-5 of the closest.
    assert np.all(rel[~same] <= RTOL), f"non-tie differences: {rel[~same].max():.3g}"
    assert same.mean() > 0.995
    # Grazing rays (silhouettes, rims, cone apexes) get the wider tolerance.
    assert np.quantile(rel, 0.999) <= RTOL
    assert rel.max() <= RTOL_GRAZING


def test_coincident_primitives_report_the_lowest_reference(cl_device):
    """Exact ties in t: the type order plane < sphere < box < ... < triangle decides, then the
    scene order within a type. Many copies spread the ties over several BVH leaves."""
    tri = M.Triangle(((-1.0, -1.0, -5.0), (1.0, -1.0, -5.0), (-1.0, 1.0, -5.0)), 0)
    box = M.Box((-2.0, -2.0, -6.0), (2.0, 2.0, -5.0), 0)
    plane = M.Plane((0.0, 0.0, -5.0), (0.0, 0.0, 1.0), 0)
    sphere = M.Sphere((0.0, 0.0, -6.0), 1.0, 0)
    # Rays straight down -z, at points where every surface above lies at exactly t = 5.
    o = np.array([[-0.5, -0.5, 0.0], [-0.25, 0.25, 0.0]])
    d = np.array([[0.0, 0.0, -1.0]] * 2)
    cases = [
        ((tri, box, plane), ref(L.PRIM_PLANE, 0)),
        ((tri, box), ref(L.PRIM_BOX, 0)),
        ((tri,) * 40 + (box,) * 40, ref(L.PRIM_BOX, 0)),
        ((tri,) * 40, ref(L.PRIM_TRIANGLE, 0)),
        ((sphere, box), ref(L.PRIM_BOX, 0)),  # not a tie: the box face is nearer
        ((sphere,) * 40, ref(L.PRIM_SPHERE, 0)),
    ]
    for objects, want in cases:
        _, _, r = cast(cl_device, make_scene(*objects), o, d)
        names = [type(ob).__name__ for ob in objects]
        assert r.tolist() == [want] * 2, f"{names[:3]}...: got refs {r.tolist()}"
    # The 40 triangles also as one mesh: the first face in file order wins.
    mesh = M.Mesh(vertices=np.array(tri.vertices * 40), faces=np.arange(120).reshape(40, 3),
                  material=0)
    _, _, r = cast(cl_device, make_scene(mesh), o, d)
    assert r.tolist() == [ref(L.PRIM_TRIANGLE, 0)] * 2


def test_tie_goes_to_the_lowest_reference_in_a_later_leaf(cl_device):
    """400 coplanar triangles all under the rays, shifted left in scene order: the builder
    puts the later (higher) references in the first children, so the first hit found at t = 5
    is not the winner, and the winner's subtree is opened only after that. Its boxes are
    entered at exactly t = 5 (flat in z) and must still be searched."""
    # Shifts in 1/512ths keep every edge function exact, so all 400 hits are at t = 5 exactly.
    shifts = -np.arange(400) / 512
    tris = [M.Triangle(((-3.0 + s, -3.0, -5.0), (3.0 + s, -3.0, -5.0), (s, 3.0, -5.0)), 0)
            for s in shifts]
    o = np.array([[0.0, 0.0, 0.0], [0.25, -0.5, 0.0]])
    d = np.array([[0.0, 0.0, -1.0]] * 2)
    t, _, r = cast(cl_device, make_scene(*tris), o, d)
    assert t.tolist() == [5.0, 5.0]
    assert r.tolist() == [ref(L.PRIM_TRIANGLE, 0)] * 2
