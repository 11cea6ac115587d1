"""Rendering triangle meshes: closed meshes leak no ray, OBJ meshes (smooth normals, UVs, an
image texture) match the float64 reference, and mesh transforms match pre-transformed vertices.

Leak tests colour every surface pure red (material, light and highlights) and the background
pure green, so a single ray that escapes a closed mesh, primary or secondary, leaves green in
its pixel.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import load_mesh_generator

from clray.accel.prim_refs import PRIM_INDEX_MASK, PRIM_TRIANGLE, PRIM_TYPE_SHIFT
from clray.device.layout import TRIANGLE_COLOR, TRIANGLE_MATERIAL_MASK, TRIANGLE_SMOOTH
from clray.device.pack import pack_scene
from clray.metrics import count_over, max_abs, nonfinite_count, rmse
from clray.reference import camera_rays, render_reference
from clray.render import RenderSettings, render
from clray.scene import model as M
from clray.scene.load import load_scene
from clray.scene.obj import read_obj

DATA = Path(__file__).resolve().parent / "data"
W, H = 96, 72
# render() picks the default device: skip (via the fixture) where no OpenCL platform exists.
pytestmark = pytest.mark.usefixtures("cl_device")
mesh_gen = load_mesh_generator()

RED = M.Material("red", color=(1.0, 0.0, 0.0), ambient=0.3, diffuse=0.7, specular=0.5,
                 shininess=20.0)
MIRROR_RED = M.Material("mirror", color=(1.0, 0.0, 0.0), ambient=0.3, diffuse=0.5,
                        specular=0.5, shininess=20.0, reflect=0.5)
GREEN = (0.0, 1.0, 0.0)


def leak_scene(mesh: M.Mesh, camera: M.Camera, light: tuple, material: M.Material,
               width: int = W, height: int = H, max_depth: int = 0) -> M.Scene:
    options = M.RenderOptions(width=width, height=height, max_depth=max_depth, background=GREEN)
    return M.Scene(None, options, camera, (material,),
                   (M.PointLight(light, color=(1.0, 0.0, 0.0)),), (mesh,))


def assert_no_leak(scene: M.Scene) -> None:
    image = render(scene).image
    assert nonfinite_count(image) == 0
    leaks = np.argwhere(image[:, :, 1] != 0.0)
    assert len(leaks) == 0, f"{len(leaks)} pixels show the background, first at (y, x) {leaks[0]}"
    assert np.all(image[:, :, 0] > 0.0)  # every pixel shows the lit or ambient red surface


def bumpy_sphere(subdivisions: int = 4) -> M.Mesh:
    vertices, faces, normals = mesh_gen.bumpy_mesh(subdivisions)
    return M.Mesh(vertices=vertices, faces=faces, material=0, normals=normals)


def test_closed_mesh_from_outside_leaks_no_ray():
    # At distance 3 the sphere (radius 0.95 at its lowest bump) spans 18.5 degrees; a vfov of
    # 20 degrees at 4:3 reaches 16.4 degrees in the corners, so every pixel should see it.
    camera = M.Camera(position=(0.3, 0.2, 3.0), look_at=(0.0, 0.0, 0.0), vfov=20.0)
    assert_no_leak(leak_scene(bumpy_sphere(), camera, (2.0, 3.0, 4.0), RED))


def test_closed_mesh_from_inside_leaks_no_ray():
    """Camera and light inside; a mirror-red surface sends every hit's reflection back into
    the mesh, so reflected rays (depth up to 3) are checked too."""
    camera = M.Camera(position=(0.1, 0.05, -0.1), look_at=(1.0, 0.3, 0.2), vfov=90.0)
    scene = leak_scene(bumpy_sphere(), camera, (-0.2, 0.3, 0.1), MIRROR_RED, max_depth=3)
    assert_no_leak(scene)


@pytest.mark.parametrize("inside", [False, True])
def test_pixel_rays_exactly_on_a_shared_diagonal_hit(inside):
    """A cube mesh seen square-on with a square image of power-of-two size: the pixel rays
    (x, W - 1 - x) have equal y and z components exactly, so they meet the face x = -1 (or
    x = 1) precisely on the diagonal its two triangles share. Inside, one mirror bounce."""
    mesh = cube_mesh(2.0, (-1.0, -1.0, -1.0))
    if inside:
        camera = M.Camera(position=(0.0, 0.0, 0.0), look_at=(1.0, 0.0, 0.0), vfov=90.0)
        scene = leak_scene(mesh, camera, (0.3, 0.2, -0.1), MIRROR_RED, 64, 64, max_depth=1)
    else:
        # tan(25 deg) * 2 * 63/64 < 1: every pixel lands on the face x = -1.
        camera = M.Camera(position=(-3.0, 0.0, 0.0), look_at=(0.0, 0.0, 0.0), vfov=50.0)
        scene = leak_scene(mesh, camera, (-4.0, 1.0, 0.5), RED, 64, 64)
    assert_no_leak(scene)


def test_reflections_off_concave_cube_edges_stay_inside():
    """Inside the cube, the rays of the image's diagonal pixels, once reflected off the face
    x = 1, reach edges where two faces meet at a right angle exactly. A reflection spawned there
    must not start on the neighbouring face's plane and leave through it at t = 0."""
    camera = M.Camera(position=(0.0, 0.0, 0.0), look_at=(1.0, 0.0, 0.0), vfov=90.0)
    mesh = cube_mesh(2.0, (-1.0, -1.0, -1.0))
    assert_no_leak(leak_scene(mesh, camera, (0.3, 0.2, -0.1), MIRROR_RED, 64, 64,
                              max_depth=2))


def cube_mesh(scale: float, offset: tuple) -> M.Mesh:
    """tests/data/cube.obj (unit cube, each quad split along one diagonal), placed. Scale 2
    and integer offsets keep every vertex exact."""
    obj = read_obj(DATA / "cube.obj")
    return M.Mesh(vertices=obj.vertices * scale + np.asarray(offset), faces=obj.faces,
                  material=0)


# ---------------------------------------------------------------------------------------------
# OBJ meshes against the float64 reference


def write_ball_obj(path: Path) -> None:
    """An icosphere with unit vertex normals (smooth shading) and planar-projected UVs (no
    seam, so the texture lookup is continuous over the mesh)."""
    vertices, faces = mesh_gen.icosphere(2)
    uvs = 0.5 + 0.5 * vertices[:, :2]
    with path.open("w", encoding="ascii") as f:
        np.savetxt(f, vertices, fmt="v %.17g %.17g %.17g")
        np.savetxt(f, uvs, fmt="vt %.17g %.17g")
        np.savetxt(f, vertices, fmt="vn %.17g %.17g %.17g")
        np.savetxt(f, np.repeat(faces + 1, 3, axis=1), fmt="f %d/%d/%d %d/%d/%d %d/%d/%d")


MESH_SCENE = """
[render]
width = 64
height = 48
max_depth = 2
background = [0.1, 0.12, 0.2]

[camera]
position = [0.4, 1.3, 4.0]
look_at = [0.0, 0.1, 0.0]
vfov = 40

[materials.textured]
color = [0.9, 0.9, 0.9]
ambient = 0.15
diffuse = 0.8
specular = 0.4
shininess = 20
texture = {{ type = "image", file = "texels_3x2.png", repeat = [2, 1], blend = 0.8 }}

[materials.floor]
color = [0.6, 0.65, 0.7]
ambient = 0.1
reflect = 0.25

[[lights]]
type = "point"
position = [3.0, 4.0, 3.0]

[[objects]]
type = "plane"
point = [0, -1.05, 0]
normal = [0, 1, 0]
material = "floor"

[[objects]]
type = "mesh"
file = "ball.obj"
material = "textured"
transform = {{ {transform} }}
"""


def mesh_scene_file(folder: Path, transform: str = "") -> Path:
    shutil.copy(DATA / "texels_3x2.png", folder / "texels_3x2.png")
    if not (folder / "ball.obj").exists():
        write_ball_obj(folder / "ball.obj")
    path = folder / "ball.toml"
    path.write_text(MESH_SCENE.format(transform=transform), encoding="utf-8")
    return path


def test_obj_mesh_with_normals_uvs_and_texture_matches_reference(tmp_path):
    """Smooth shading, an image texture through vertex UVs, a shadow on a mirror floor and
    its reflection: the kernel against the float64 reference at 64 x 48. Tolerances: 4x
    what the scene measured on PoCL (RMSE 2.36e-7, largest error 3.72e-6, no outlier pixel),
    so a wrong normal or texture lookup on a handful of pixels fails."""
    scene = load_scene(mesh_scene_file(tmp_path))
    mesh = scene.objects[1]
    assert isinstance(mesh, M.Mesh) and mesh.normals is not None and mesh.uvs is not None
    got = render(scene).image
    want = render_reference(scene)
    assert nonfinite_count(got) == 0
    # The texture shows: the ball is not one flat colour.
    assert np.ptp(got[20:30, 28:36].reshape(-1, 3), axis=0).max() > 0.1
    assert rmse(got, want) < 9.5e-7
    assert max_abs(got, want) < 1.5e-5


def test_a_shading_normal_along_the_ray_faces_away_as_in_the_kernel():
    """A square in z = 0 whose vertex normals all lie in it, (1, 0, 0), seen head-on at 3 x 3:
    the middle column's rays have d . n_s = 0 exactly (x = 0 in float32 and float64). The
    kernel (shade_point) flips n_s there, n = (-1, 0, 0), away from the light at
    l = (1, 0, 1) / sqrt(2), so those pixels get the ambient term only; the reference kept n_s
    at d . n_s = 0 and lit them."""
    vertices = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    mesh = M.Mesh(vertices=vertices, faces=np.array([[0, 1, 2], [0, 2, 3]]), material=0,
                  normals=np.tile([1.0, 0.0, 0.0], (4, 1)))
    light = M.DirectionalLight(tuple(np.array([-1.0, 0.0, -1.0]) / np.sqrt(2.0)))
    scene = M.Scene(None, M.RenderOptions(3, 3, 1, 0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
                    M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), vfov=10.0),
                    (M.Material("m", ambient=0.2, diffuse=0.7),), (light,), (mesh,))
    _, d, _ = camera_rays(scene, 3, 3, 1, 0)
    assert np.all(d.reshape(3, 3, 3)[:, 1, 0] == 0.0)
    got = render(scene).image.astype(np.float64)
    want = render_reference(scene)
    lit = 0.2 + 0.7 / np.sqrt(2.0)
    np.testing.assert_allclose(want[:, :, 0], [[lit, 0.2, 0.2]] * 3, rtol=0, atol=1e-12)
    assert max_abs(got, want) < 1e-6


def test_mesh_transform_renders_like_pretransformed_vertices(tmp_path):
    """transform = scale, rotate x then y then z, translate (docs/scene_format.md), against
    the same OBJ with its vertices and normals transformed here."""
    scale = np.array([0.8, 1.1, 0.9])
    angles = np.radians([20.0, -35.0, 10.0])
    translate = np.array([0.3, 0.1, -0.4])
    transform = "scale = [0.8, 1.1, 0.9], rotate = [20, -35, 10], translate = [0.3, 0.1, -0.4]"
    plain = load_scene(mesh_scene_file(tmp_path))
    moved = load_scene(mesh_scene_file(tmp_path, transform))
    (cx, cy, cz), (sx, sy, sz) = np.cos(angles), np.sin(angles)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    matrix = rot_z @ rot_y @ rot_x @ np.diag(scale)
    folder = tmp_path / "baked"
    folder.mkdir()
    vertices, faces = mesh_gen.icosphere(2)
    with (folder / "ball.obj").open("w", encoding="ascii") as f:
        normals = vertices @ np.linalg.inv(matrix)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        np.savetxt(f, vertices @ matrix.T + translate, fmt="v %.17g %.17g %.17g")
        np.savetxt(f, 0.5 + 0.5 * vertices[:, :2], fmt="vt %.17g %.17g")
        np.savetxt(f, normals, fmt="vn %.17g %.17g %.17g")
        np.savetxt(f, np.repeat(faces + 1, 3, axis=1), fmt="f %d/%d/%d %d/%d/%d %d/%d/%d")
    baked = load_scene(mesh_scene_file(folder))

    a, b = render(moved).image, render(baked).image
    untransformed = render(plain).image
    # The transform matters: without it the image differs widely.
    assert count_over(untransformed, b, 2 / 255) > 100
    assert rmse(a, b) < 1e-4
    assert count_over(a, b, 2 / 255) <= 2


def test_triangle_records_are_the_slots_triangles_with_their_vertex_data():
    """The device's Triangle records are one a slot of prim_refs (a hit's part is its slot)
    and its vertex arrays are renumbered in the slots' order: every slot's record must still
    name its triangle's material, flags and, through the new numbering, its corners' normals,
    uvs and colours. Two meshes (one with per-face materials) make the offsets and flags
    differ between triangles."""
    vertices, faces, normals = mesh_gen.bumpy_mesh(2)
    rng = np.random.default_rng(7)
    uvs = rng.random((len(vertices), 2))
    colors = rng.random((len(vertices), 3))
    face_materials = rng.integers(0, 2, len(faces))
    smooth = M.Mesh(vertices=vertices, faces=faces, material=0, normals=normals, uvs=uvs,
                    face_materials=face_materials)
    tinted = M.Mesh(vertices=vertices + 3.0, faces=faces[::-1].copy(), material=1,
                    colors=colors)
    scene = leak_scene(smooth, M.Camera(position=(0, 0, 6), look_at=(0, 0, 0), vfov=40),
                       (0, 5, 5), M.Material("red", color=(1, 0, 0)))
    scene = replace(scene, objects=(smooth, tinted),
                    materials=(*scene.materials, M.Material("green", color=(0, 1, 0))))
    packed = pack_scene(scene, width=8, height=8, spp=1, max_depth=0, seed=0)
    refs = packed.prim_refs[:len(packed.triangles)]
    slots = np.flatnonzero((refs >= 0) & ((refs >> PRIM_TYPE_SHIFT) == PRIM_TRIANGLE))
    assert len(slots) == 2 * len(faces)
    records = packed.triangles.view(np.int32).reshape(-1, 4)[slots]
    index = refs[slots] & PRIM_INDEX_MASK  # the scene's triangle: smooth's, then tinted's
    mine = index < len(faces)
    face = np.where(mine[:, None], faces[index % len(faces)], faces[::-1][index % len(faces)])
    material = records[:, 3]
    assert np.array_equal(material & TRIANGLE_MATERIAL_MASK,
                          np.where(mine, face_materials[index % len(faces)], 1))
    assert np.array_equal((material & TRIANGLE_SMOOTH) != 0, mine)
    assert np.array_equal((material & TRIANGLE_COLOR) != 0, ~mine)
    for k in range(3):
        corner = records[:, k]
        assert np.array_equal(packed.normals[corner[mine], :3],
                              normals[face[mine, k]].astype(np.float32))
        assert np.array_equal(packed.uvs[corner[mine]], uvs[face[mine, k]].astype(np.float32))
        assert np.array_equal(packed.colors[corner[~mine], :3],
                              colors[face[~mine, k]].astype(np.float32))


# The two layouts of a triangle slot's record (clray.device.layout.SCENE_BUFFERS, kernels/scene.h:
# HAS_VERTEX_ATTRIBUTES): the whole Triangle record where some triangle has vertex normals, uvs
# or colours, the material word alone where none has.

FACE_MATERIALS = (M.Material("red", color=(0.9, 0.1, 0.1), ambient=0.2, diffuse=0.8),
                  M.Material("green", color=(0.1, 0.9, 0.1), ambient=0.2, diffuse=0.8),
                  M.Material("blue", color=(0.1, 0.1, 0.9), ambient=0.2, diffuse=0.8))


def face_material_scene(**attributes: np.ndarray) -> M.Scene:
    """The bumpy sphere with one of three materials a face (at random, so that neighbouring
    slots differ), and the vertex attributes given (normals, uvs, colors)."""
    vertices, faces, _ = mesh_gen.bumpy_mesh(2)
    face_materials = np.random.default_rng(3).integers(0, 3, len(faces))
    mesh = M.Mesh(vertices=vertices, faces=faces, material=0, face_materials=face_materials,
                  **attributes)
    camera = M.Camera(position=(0.3, 0.4, 3.2), look_at=(0, 0, 0), vfov=45)
    options = M.RenderOptions(width=64, height=48, max_depth=0, background=(0.0, 0.0, 0.0))
    return M.Scene(None, options, camera, FACE_MATERIALS,
                   (M.PointLight((2.0, 3.0, 4.0), color=(1.0, 1.0, 1.0)),), (mesh,))


def test_triangle_slots_keep_only_the_material_word_without_vertex_attributes():
    """4 bytes a slot (the material word) for a mesh without vertex attributes, the 16-byte
    Triangle record with them; the same words either way, in the same slots."""
    vertices = mesh_gen.bumpy_mesh(2)[0]
    bare, smooth = (pack_scene(face_material_scene(**attributes), width=8, height=8, spp=1,
                               max_depth=0, seed=0)
                    for attributes in ({}, {"normals": vertices}))
    slots = 4 * len(bare.triangle_packets)
    assert bare.device_bytes()["triangles"] == 0
    assert bare.device_bytes()["triangle_materials"] == 4 * slots
    assert smooth.device_bytes()["triangles"] == 16 * slots
    assert smooth.device_bytes()["triangle_materials"] == 0
    # The kernels read the layout that the vertex switches pick (HAS_VERTEX_ATTRIBUTES).
    assert not (bare.config.has_vertex_normals or bare.config.has_vertex_uvs
                or bare.config.has_vertex_colors)
    assert smooth.config.has_vertex_normals
    assert np.array_equal(bare.prim_refs, smooth.prim_refs)
    words = smooth.triangles["material"]
    assert np.array_equal(bare.triangle_materials, words & TRIANGLE_MATERIAL_MASK)
    refs = bare.prim_refs[:slots]
    is_tri = (refs >= 0) & ((refs >> PRIM_TYPE_SHIFT) == PRIM_TRIANGLE)
    face_materials = bare.triangle_materials[is_tri]
    assert np.array_equal(np.bincount(face_materials, minlength=3),
                          np.bincount(face_material_scene().objects[0].face_materials))


@pytest.mark.parametrize("precision, traversal", [("float", "single"), ("double", "single"),
                                                  ("float", "sample_packet"),
                                                  ("float", "group_packet")])
def test_face_materials_render_alike_from_either_record_layout(precision, traversal):
    """Three materials a face at random: the kernel must find each hit's word in the layout it
    was packed in (the material word alone, or the Triangle record of a mesh with vertex uvs,
    which an untextured material does not use). Both against the float64 reference, with the
    tolerances of the textured mesh above; a word read from the wrong place or slot gives a
    face the wrong one of three far-apart colours."""
    scene = face_material_scene()
    uvs = np.random.default_rng(5).random((len(scene.objects[0].vertices), 2))
    settings = RenderSettings(spp=4, precision=precision, traversal=traversal)
    bare = render(scene, settings).image
    with_uvs = render(face_material_scene(uvs=uvs), settings).image
    want = render_reference(scene, spp=4)
    # Every material shows: the faces' colours are in the image, off the black background.
    lit = bare.max(axis=2) > 0.05
    for channel in range(3):
        assert np.count_nonzero(lit & (np.argmax(bare, axis=2) == channel)) > 100
    for got in (bare, with_uvs):
        assert nonfinite_count(got) == 0
        assert rmse(got, want) < 9.5e-7
        assert max_abs(got, want) < 1.5e-5


@pytest.mark.parametrize("precision", ["float", "double"])
def test_a_mesh_of_one_material_keeps_one_word(precision):
    """Every face of material 1 (not the first, so a word read from a padding slot's zeros
    shows as red): the device keeps the one word (4 bytes in all) and the kernels read it for
    every hit (HAS_ONE_TRIANGLE_MATERIAL), against the float64 reference; three materials
    keep a word a slot."""
    scene = face_material_scene()
    mesh = scene.objects[0]
    one = replace(scene, objects=(replace(
        mesh, face_materials=np.ones(len(mesh.faces), dtype=np.int64)),))
    packed = pack_scene(one, width=8, height=8, spp=1, max_depth=0, seed=0)
    assert packed.config.has_one_triangle_material
    assert packed.device_bytes()["triangle_materials"] == 4
    assert not pack_scene(scene, width=8, height=8, spp=1, max_depth=0,
                          seed=0).config.has_one_triangle_material
    got = render(one, RenderSettings(spp=4, precision=precision)).image
    want = render_reference(one, spp=4)
    lit = got.max(axis=2) > 0.05
    assert np.count_nonzero(lit) > 500
    assert np.all(np.argmax(got[lit], axis=1) == 1)  # green, material 1, everywhere
    assert nonfinite_count(got) == 0
    assert rmse(got, want) < 9.5e-7
    assert max_abs(got, want) < 1.5e-5
