import json
import math
import os
import shutil
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene import limits
from clray.scene.load import load_scene, scene_from_dict
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
    Sphere,
    Texture,
    Triangle,
)

DATA = Path(__file__).parent / "data"
SCENE = Path("scene.toml")
CAMERA = {"position": [0, 0, 5], "look_at": [0, 0, 0]}

FULL_TOML = """\
[render]
width = 320
height = 200
spp = 4
max_depth = 2
background = [0.1, 0.2, 0.3]
ambient = [0.5, 0.5, 0.5]
seed = 7

[camera]
position = [0, 4.5, 11]
look_at = [0, 0.5, 0]
up = [0, 2, 0]
hfov = 60

[materials.glass]
color = [1, 1, 1]
transmit = 0.9
ior = 1.5
texture = { type = "checker", size = 0.5, color2 = [0, 0, 0] }

[materials.matte]
diffuse = 0.8

[[lights]]
type = "point"
position = [-6, 10, 6]
color = [0.7, 0.7, 0.7]
attenuation = [1, 0, 0.01]

[[lights]]
type = "directional"
direction = [0, -3, 0]

[[objects]]
type = "sphere"
center = [0, 1, 0]
radius = 1
material = "glass"

[[objects]]
type = "plane"
point = [0, 0, 0]
normal = [0, 0, 2]
material = { color = [1, 0, 0], reflect = 0.5 }

[[objects]]
type = "box"
min = [-1, -1, -1]
max = [1, 0, 1]
material = "matte"

[[objects]]
type = "triangle"
vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]

[[objects]]
type = "cylinder"
base = [0, 0, 0]
axis = [0, 5, 0]
radius = 0.5
height = 2
capped = false

[[objects]]
type = "cone"
apex = [0, 2, 0]
axis = [0, -1, 0]
angle = 30
height = 2
"""


def scene(**sections):
    """A scene dict with a valid camera, plus the given sections."""
    return {"camera": dict(CAMERA), **sections}


def anim(*tracks: dict) -> dict:
    """A scene of one sphere animated over 10 frames by `tracks`."""
    return scene(objects=[dict(SPHERE)], animation={"frames": 10, "tracks": list(tracks)})


def load_error(data) -> str:
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, SCENE)
    return str(info.value)


# -- valid scenes --------------------------------------------------------------------------


def test_minimal_scene_gets_every_default():
    s = scene_from_dict(scene())
    assert s.path is None
    assert s.render == RenderOptions()
    assert s.camera == Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, None)
    assert s.materials == () and s.lights == () and s.objects == ()
    # Only the empty scene's own warning: nothing of float accuracy.
    assert s.warnings == ("the scene has no objects: the image is the background alone",)


def test_full_toml_file(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(FULL_TOML)
    s = load_scene(path)
    assert s.path == path
    assert s.render == RenderOptions(320, 200, 4, 2, (0.1, 0.2, 0.3), (0.5, 0.5, 0.5), 7)
    assert s.camera.vfov is None and s.camera.hfov == 60.0
    assert s.camera.up == (0.0, 2.0, 0.0)
    assert [m.name for m in s.materials] == [
        "glass",
        "matte",
        "objects[1].material",
        "(default)",
    ]
    glass, matte, inline, default = s.materials
    assert glass == Material(
        "glass", transmit=0.9, ior=1.5, texture=Texture("checker", size=0.5, color2=(0, 0, 0))
    )
    assert matte == Material("matte", diffuse=0.8)
    assert inline == Material("objects[1].material", color=(1.0, 0.0, 0.0), reflect=0.5)
    assert default == Material("(default)")
    assert s.lights == (
        PointLight((-6.0, 10.0, 6.0), (0.7, 0.7, 0.7), (1.0, 0.0, 0.01)),
        DirectionalLight((0.0, -1.0, 0.0)),
    )
    assert s.objects == (
        Sphere((0.0, 1.0, 0.0), 1.0, 0),
        Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 2),
        Box((-1.0, -1.0, -1.0), (1.0, 0.0, 1.0), 1),
        Triangle(((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 3),
        Cylinder((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0.5, 2.0, 3, capped=False),
        Cone((0.0, 2.0, 0.0), (0.0, -1.0, 0.0), 30.0, 2.0, 3, capped=True),
    )
    # Every value in the model is a Python float, whatever the file wrote.
    assert all(type(x) is float for x in s.objects[0].center)


def test_json_with_the_same_keys_gives_the_same_scene(tmp_path):
    import tomllib

    toml_path = tmp_path / "scene.toml"
    toml_path.write_text(FULL_TOML)
    json_path = tmp_path / "scene.json"
    json_path.write_text(json.dumps(tomllib.loads(FULL_TOML)))
    a, b = load_scene(toml_path), load_scene(json_path)
    assert (a.render, a.camera, a.materials, a.lights, a.objects) == (
        b.render,
        b.camera,
        b.materials,
        b.lights,
        b.objects,
    )


def test_directions_are_normalised():
    s = scene_from_dict(
        scene(
            lights=[{"type": "directional", "direction": [3, 0, -4]}],
            objects=[
                {"type": "plane", "point": [0, 0, 0], "normal": [0, 3, 4]},
                {
                    "type": "cylinder",
                    "base": [0, 0, 0],
                    "axis": [2, 0, 0],
                    "radius": 1,
                    "height": 1,
                },
                {"type": "cone", "apex": [0, 0, 0], "axis": [1, 1, 0], "angle": 45, "height": 1},
            ],
        )
    )
    assert s.lights[0].direction == pytest.approx((0.6, 0.0, -0.8))
    assert s.objects[0].normal == pytest.approx((0.0, 0.6, 0.8))
    assert s.objects[1].axis == (1.0, 0.0, 0.0)
    assert s.objects[2].axis == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0))


def test_materials_shared_by_name_and_default_added_once():
    s = scene_from_dict(
        scene(
            materials={"red": {"color": [1, 0, 0]}, "unused": {}},
            objects=[
                {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "red"},
                {"type": "sphere", "center": [3, 0, 0], "radius": 1},
                {"type": "sphere", "center": [6, 0, 0], "radius": 1, "material": "red"},
                {"type": "sphere", "center": [9, 0, 0], "radius": 1},
            ],
        )
    )
    assert [m.name for m in s.materials] == ["red", "unused", "(default)"]
    assert [o.material for o in s.objects] == [0, 2, 0, 2]


def test_material_named_default_does_not_capture_objects_without_one():
    s = scene_from_dict(
        scene(
            materials={"(default)": {"color": [0, 0, 1]}},
            objects=[{"type": "sphere", "center": [0, 0, 0], "radius": 1}],
        )
    )
    assert s.materials[s.objects[0].material].color == (1.0, 1.0, 1.0)


def test_vfov_and_hfov():
    assert scene_from_dict(scene(camera={**CAMERA, "vfov": 30})).camera.vfov == 30.0
    cam = scene_from_dict(scene(camera={**CAMERA, "hfov": 90})).camera
    assert (cam.vfov, cam.hfov) == (None, 90.0)


def test_image_texture_decodes_srgb_texels_relative_to_the_scene(tmp_path):
    (tmp_path / "tex").mkdir()
    shutil.copy(DATA / "texels_3x2.png", tmp_path / "tex" / "t.png")
    data = scene(
        materials={"wood": {"texture": {"type": "image", "file": "tex/t.png", "repeat": [2, 3]}}}
    )
    tex = scene_from_dict(data, tmp_path / "scene.toml").materials[0].texture
    assert tex.kind == "image" and tex.repeat == (2.0, 3.0) and tex.blend == 1.0
    assert tex.file == tmp_path / "tex" / "t.png"
    assert tex.image.dtype == np.float32 and tex.image.shape == (2, 3, 3)
    assert tex.image.flags.c_contiguous
    np.testing.assert_array_equal(tex.image[0, 0], [1, 0, 0])  # row 0 is the top row
    np.testing.assert_array_equal(tex.image[0, 2], [0, 0, 1])
    # An 8-bit file is sRGB by default: 51, 102, 204 decode to these linear values.
    assert tex.colorspace == "srgb"
    np.testing.assert_allclose(tex.image[1, 2], [0.0331048, 0.1328683, 0.6038274], atol=1e-6)


def test_checker_texture_defaults():
    data = scene(materials={"m": {"texture": {"type": "checker", "blend": 0.25}}})
    tex = scene_from_dict(data).materials[0].texture
    assert tex == Texture("checker", size=1.0, color2=(0.0, 0.0, 0.0), blend=0.25)


def test_empty_scene_renders_background_only():
    s = scene_from_dict(scene(lights=[], objects=[], materials={}))
    assert s.objects == () and s.lights == ()


# -- meshes --------------------------------------------------------------------------------


def mesh_scene(**mesh):
    return scene(objects=[{"type": "mesh", **mesh}])


def test_mesh_from_file_is_relative_to_the_scene(tmp_path):
    shutil.copy(DATA / "cube.obj", tmp_path / "cube.obj")
    s = scene_from_dict(mesh_scene(file="cube.obj"), tmp_path / "scene.json")
    mesh = s.objects[0]
    assert isinstance(mesh, Mesh)
    assert mesh.faces.shape == (12, 3) and mesh.normals.shape == (24, 3)
    assert mesh.uvs.shape == (24, 2)
    assert s.materials[mesh.material].name == "(default)"


def test_inline_mesh_without_transform():
    s = scene_from_dict(
        mesh_scene(
            vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], faces=[[0, 1, 2], [1, 3, 2]]
        )
    )
    mesh = s.objects[0]
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])
    assert mesh.normals is None and mesh.uvs is None


TRI = {"vertices": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "faces": [[0, 1, 2]]}


def test_transform_scale_then_rotate_then_translate():
    # (1,0,0) scaled by 2 -> (2,0,0), 90 degrees about z -> (0,2,0), translated -> (1,4,3).
    mesh = scene_from_dict(
        mesh_scene(**TRI, transform={"scale": 2, "rotate": [0, 0, 90], "translate": [1, 2, 3]})
    ).objects[0]
    np.testing.assert_allclose(mesh.vertices[0], [1, 4, 3], atol=1e-12)
    # (0,1,0) -> (0,2,0) -> (-2,0,0) -> (-1,2,3)
    np.testing.assert_allclose(mesh.vertices[1], [-1, 2, 3], atol=1e-12)


def test_rotation_order_is_x_then_y_then_z():
    # (0,1,0): x by 90 -> (0,0,1), then y by 90 -> (1,0,0). The other order gives (0,0,1).
    mesh = scene_from_dict(mesh_scene(**TRI, transform={"rotate": [90, 90, 0]})).objects[0]
    np.testing.assert_allclose(mesh.vertices[1], [1, 0, 0], atol=1e-12)
    # (0,0,1): x by 90 -> (0,-1,0), y leaves it, z by 90 -> (1,0,0).
    mesh = scene_from_dict(mesh_scene(**TRI, transform={"rotate": [90, 0, 90]})).objects[0]
    np.testing.assert_allclose(mesh.vertices[2], [1, 0, 0], atol=1e-12)


def test_per_axis_scale():
    mesh = scene_from_dict(mesh_scene(**TRI, transform={"scale": [2, 3, 4]})).objects[0]
    np.testing.assert_allclose(mesh.vertices, [[2, 0, 0], [0, 3, 0], [0, 0, 4]])


def test_normals_follow_the_inverse_transpose(tmp_path):
    # A face in the plane x + y = 1 with normal (1,1,0)/sqrt2; stretching x by 2 moves the
    # plane to x/2 + y = 1, whose unit normal is (1/2, 1, 0)/|...| = (1, 2, 0)/sqrt5.
    (tmp_path / "m.obj").write_text("v 1 0 0\nv 0 1 0\nv 1 0 1\nvn 1 1 0\nf 1//1 2//1 3//1\n")
    mesh = scene_from_dict(
        mesh_scene(file="m.obj", transform={"scale": [2, 1, 1], "rotate": [0, 0, 0]}),
        tmp_path / "scene.toml",
    ).objects[0]
    np.testing.assert_allclose(mesh.normals, np.tile([1, 2, 0], (3, 1)) / math.sqrt(5))
    tri = mesh.vertices[mesh.faces[0]]
    edge_1, edge_2 = tri[1] - tri[0], tri[2] - tri[0]
    np.testing.assert_allclose(mesh.normals[0] @ edge_1, 0, atol=1e-12)
    np.testing.assert_allclose(mesh.normals[0] @ edge_2, 0, atol=1e-12)


def test_normals_are_renormalised_even_without_transform(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 5\nf 1//1 2//1 3//1\n")
    mesh = scene_from_dict(mesh_scene(file="m.obj"), tmp_path / "scene.toml").objects[0]
    np.testing.assert_allclose(mesh.normals, np.tile([0, 0, 1], (3, 1)))


def test_mirroring_transform_keeps_faces_outward():
    mesh = scene_from_dict(mesh_scene(**TRI, transform={"scale": [-1, 1, 1]})).objects[0]
    tri = mesh.vertices[mesh.faces[0]]
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    # The unmirrored face's normal is (1,1,1); mirrored in x it must be (-1,1,1).
    np.testing.assert_allclose(normal, [-1, 1, 1])


def test_degenerate_faces_are_kept():
    mesh = scene_from_dict(
        mesh_scene(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2], [0, 0, 0]])
    ).objects[0]
    assert len(mesh.faces) == 2


# -- files -----------------------------------------------------------------------------------


def test_malformed_toml_names_line_and_column(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[render]\nwidth = 10\nheight = = 3\n")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith("bad.toml: invalid TOML: ")
    assert "line 3" in message and "column" in message


def test_malformed_json_names_line_and_column(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{\n  "camera": {"position": [0, 0, 1],}\n}\n')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith("bad.json: invalid JSON: ")
    assert "(at line 2, column" in str(info.value)


@pytest.mark.parametrize(("text", "where"), [
    ('{"camera": {"position": [0, 0, 5],\n "look_at": [0, 0, 0]},\n "objects": [{"type": '
     '"sphere", "center": [0, 0, 0], "radius": 1,\n   "radius": 2}]}', '"radius" (at line 4, '
     'column 4)'),
    # The same name in two objects is no duplicate; an escape spells the same key.
    ('{"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},\n"materials": {"a": {"ior": 1},'
     ' "b": {"ior": 1}},\n"\\u0063amera": {}}', '"camera" (at line 3, column 1)'),
])
def test_json_refuses_a_duplicate_key_as_toml_does(tmp_path, text, where):
    """json.loads kept the last value silently (the radius was 2)."""
    path = tmp_path / "dup.json"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value) == f"dup.json: invalid JSON: duplicate key {where}"


def test_unknown_suffix(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text("camera: {}")
    with pytest.raises(SceneError, match=r"^scene\.yaml: unknown scene file type '\.yaml'"):
        load_scene(path)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match=r"^nope\.toml: cannot read scene file"):
        load_scene(tmp_path / "nope.toml")


@pytest.mark.parametrize(("name", "raw", "where"), [
    # Columns count characters: "é" is two bytes and one column.
    ("scene.toml", b'[render]\nwidth = 64\n# caf\xc3\xa9 \xff\n', "line 3, column 8: not "
     "valid UTF-8 (byte 0xff)"),
    ("scene.json", b'{\n  "render": {"width": 64\xfe}}', "line 2, column 25: not valid UTF-8 "
     "(byte 0xfe)"),
    ("scene.toml", b"\xe2\x82", "line 1, column 1: not valid UTF-8 (bytes 0xe2 0x82)"),
])
def test_invalid_utf8_is_told_by_line_and_column(tmp_path, name, raw, where):
    (tmp_path / name).write_bytes(raw)
    with pytest.raises(SceneError) as info:
        load_scene(tmp_path / name)
    assert str(info.value) == f"{name}: {where}"


def test_json_top_level_must_be_a_table(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(SceneError, match=r"^list\.json: expected a table at the top level"):
        load_scene(path)


def test_obj_errors_name_the_obj_file_and_line(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(SceneError, match=r"^m\.obj: line 2: f: vertex index 2 out of range"):
        scene_from_dict(mesh_scene(file="m.obj"), tmp_path / "scene.toml")


def test_unreadable_image(tmp_path):
    (tmp_path / "t.png").write_text("not a png")
    data = scene(materials={"m": {"texture": {"type": "image", "file": "t.png"}}})
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, tmp_path / "scene.toml")
    assert str(info.value).startswith(
        "scene.toml: materials.m.texture.file: cannot read image t.png"
    )


def test_without_a_path_errors_have_no_file_prefix():
    with pytest.raises(SceneError) as info:
        scene_from_dict(scene(render={"width": 0}))
    assert str(info.value) == "render.width: must be an integer in [1, 16384], got 0"


# -- errors ----------------------------------------------------------------------------------

SPHERE = {"type": "sphere", "center": [0, 0, 0], "radius": 1}


def obj(**fields):
    return scene(objects=[dict(SPHERE), dict(SPHERE), {**fields}])


ERRORS = [
    # top level and render
    ({"camera": CAMERA, "rendr": {}}, "rendr: unknown key (expected one of: include, render, "),
    ({}, "camera: missing required key"),
    (scene(render={"widht": 3}), "render.widht: unknown key (expected one of: width, height,"),
    (scene(render=[1]), "render: expected a table, got [1]"),
    (scene(render={"width": 0}), "render.width: must be an integer in [1, 16384], got 0"),
    (scene(render={"height": 16385}), "render.height: must be an integer in [1, 16384], got 16385"),
    (scene(render={"width": 64.0}), "render.width: expected an integer, got 64.0"),
    (scene(render={"spp": True}), "render.spp: expected an integer, got true"),
    (scene(render={"spp": 5000}), "render.spp: must be an integer in [1, 4096]"),
    (scene(render={"max_depth": -1}), "render.max_depth: must be an integer in [0, 256], got -1"),
    (scene(render={"max_depth": 257}), "render.max_depth: must be an integer in [0, 256], got 257"),
    (scene(render={"seed": 2**32}), "render.seed: must be an integer in [0, 4294967295]"),
    (scene(render={"min_weight": 2}), "render.min_weight: must be in [0, 1], got 2"),
    (scene(render={"min_weight": -0.5}), "render.min_weight: must be in [0, 1], got -0.5"),
    (scene(render={"background": [0, 0]}), "render.background: expected 3 numbers, got [0, 0]"),
    (scene(render={"ambient": [1, -1, 0]}), "render.ambient: must be >= 0, got [1, -1, 0]"),
    (
        scene(render={"ambient": [1, math.inf, 0]}),
        "render.ambient: must be finite, got [1, inf, 0]",
    ),
    # camera
    (
        scene(camera={"position": "abc", "look_at": [0, 0, 0]}),
        'camera.position: expected 3 numbers, got "abc"',
    ),
    (
        scene(camera={"position": [0, True, 0], "look_at": [0, 0, 1]}),
        "camera.position: expected 3 numbers, got [0, true, 0]",
    ),
    (
        scene(camera={"position": [0, math.nan, 0], "look_at": [0, 0, 1]}),
        "camera.position: must be finite, got [0, nan, 0]",
    ),
    (scene(camera={"look_at": [0, 0, 0]}), "camera.position: missing required key"),
    (
        scene(camera={"position": [1, 2, 3], "look_at": [1, 2, 3]}),
        "camera.look_at: must differ from camera.position",
    ),
    (
        scene(camera={**CAMERA, "up": [0, 0, 0]}),
        "camera.up: must be a nonzero vector, got [0, 0, 0]",
    ),
    (
        scene(camera={**CAMERA, "up": [0, 0, -2]}),
        "camera.up: must not be parallel to the view direction",
    ),
    (scene(camera={**CAMERA, "vfov": 40, "hfov": 50}), "camera: give vfov or hfov, not both"),
    (scene(camera={**CAMERA, "vfov": 180}), "camera.vfov: must be in (0, 180), got 180"),
    (scene(camera={**CAMERA, "hfov": 0}), "camera.hfov: must be in (0, 180), got 0"),
    (scene(camera={**CAMERA, "fov": 40}), "camera.fov: unknown key (expected one of: position,"),
    (scene(camera={**CAMERA, "type": "fisheye"}),
     'camera.type: expected "perspective" or "orthographic", got "fisheye"'),
    (scene(camera={**CAMERA, "aperture": -0.1}), "camera.aperture: must be >= 0, got -0.1"),
    (scene(camera={**CAMERA, "aperture": math.nan}), "camera.aperture: must be finite, got nan"),
    (scene(camera={**CAMERA, "aperture": 1e31}), "camera.aperture: must be at most 1e+30"),
    (scene(camera={**CAMERA, "aperture": 3, "focus_distance": 1e-6}),
     "camera.aperture: must be at most 1e+06 times the focus distance (1e-06), got 3"),
    (scene(camera={**CAMERA, "aperture": 5.1e6}),
     "camera.aperture: must be at most 1e+06 times the focus distance (5), got 5.1e+06"),
    (scene(camera={**CAMERA, "aperture": 0.1, "focus_distance": 0}),
     "camera.focus_distance: must be > 0, got 0"),
    # Focused at look_at's distance by default: 1 / 1e-39 is inf in float32, NaN in every ray.
    (scene(camera={"position": [0, 0, 0], "look_at": [0, 0, -1e-39], "aperture": 1e-34}),
     "camera.look_at: with an aperture and no focus_distance, look_at's distance from "
     "position is the focus distance and must be >= 1e-30, got 1e-39"),
    (scene(camera={**CAMERA, "focus_distance": "far"}),
     'camera.focus_distance: expected a number, got "far"'),
    (scene(camera={**CAMERA, "width": 4}),
     'camera.width: only with type = "orthographic" (a perspective camera takes vfov or hfov)'),
    (scene(camera={**CAMERA, "type": "orthographic"}),
     "camera.height: missing required key (an orthographic camera needs width or height)"),
    (scene(camera={**CAMERA, "type": "orthographic", "width": 4, "height": 3}),
     "camera: give width or height, not both"),
    (scene(camera={**CAMERA, "type": "orthographic", "height": -3}),
     "camera.height: must be > 0, got -3"),
    (scene(camera={**CAMERA, "type": "orthographic", "height": 3, "vfov": 30}),
     "camera.vfov: an orthographic camera has no field of view: give width or height"),
    (scene(render={"background": {"type": "sky"}}),
     'render.background.type: unknown type "sky" (expected one of: gradient, image)'),
    (scene(render={"background": {"bottom": [0, 0, 0]}}),
     "render.background.type: missing required key (one of: gradient, image)"),
    (scene(render={"background": {"type": "gradient", "top": [1, 1, 1]}}),
     "render.background.bottom: missing required key"),
    (scene(render={"background": {"type": "gradient", "bottom": [0, 0, 0], "top": [1, -1, 1]}}),
     "render.background.top: must be >= 0, got [1, -1, 1]"),
    (scene(render={"background": {"type": "gradient", "bottom": [0, 0, 0], "top": [1, 1, 1],
                                  "file": "sky.png"}}),
     "render.background.file: unknown key (expected one of: type, bottom, top)"),
    (scene(render={"background": {"type": "image"}}),
     "render.background.file: missing required key"),
    (scene(render={"background": {"type": "image", "file": "nope.png"}}),
     "render.background.file: file not found: nope.png"),
    (scene(render={"background": {"type": "image", "file": 3}}),
     "render.background.file: expected a string, got 3"),
    (scene(render={"background": {"type": "image", "texels": [[[0, 0, 2]]]}}),
     "render.background.texels: must be linear values in [0, 1]"),
    (scene(render={"background": {"type": "image", "file": "a.png", "texels": [[[0, 0, 0]]]}}),
     "render.background: give file or texels, not both"),
    (scene(materials={"m": {"fresnel": 1}}), "materials.m.fresnel: expected true or false, got 1"),
    (scene(materials={"m": {"fresnel": True, "transmit": 0.9, "reflect": 0.2}}),
     "materials.m.fresnel: needs reflect + transmit <= 1, got 0.2 + 0.9"),
    # materials and textures
    (scene(materials={"glass": {"ior": 0}}), "materials.glass.ior: must be >= 0.01, got 0"),
    (
        scene(materials={"glass": {"ior": "1.5"}}),
        'materials.glass.ior: expected a number, got "1.5"',
    ),
    (scene(materials={"m": {"diffuse": -0.5}}), "materials.m.diffuse: must be >= 0, got -0.5"),
    (
        scene(materials={"m": {"transmit": math.nan}}),
        "materials.m.transmit: must be finite, got nan",
    ),
    (
        scene(materials={"m": {"colour": [1, 1, 1]}}),
        "materials.m.colour: unknown key (expected one of: color, ambient,",
    ),
    (scene(materials={"m": 3}), "materials.m: expected a table, got 3"),
    (
        scene(materials={"m": {"texture": {"size": 1}}}),
        "materials.m.texture.type: missing required key (one of: checker, image)",
    ),
    (
        scene(materials={"m": {"texture": {"type": "noise"}}}),
        'materials.m.texture.type: unknown type "noise" (expected one of: checker, image)',
    ),
    (
        scene(materials={"m": {"texture": {"type": "checker", "size": 0}}}),
        "materials.m.texture.size: must be > 0, got 0",
    ),
    (
        scene(materials={"m": {"texture": {"type": "checker", "blend": 1.5}}}),
        "materials.m.texture.blend: must be in [0, 1], got 1.5",
    ),
    (
        scene(materials={"m": {"texture": {"type": "checker", "file": "a.png"}}}),
        "materials.m.texture.file: unknown key (expected one of: type, size, color2, blend)",
    ),
    (
        scene(materials={"m": {"texture": {"type": "image"}}}),
        "materials.m.texture.file: missing required key",
    ),
    (
        scene(materials={"m": {"texture": {"type": "image", "file": "nope.png"}}}),
        "materials.m.texture.file: file not found: nope.png",
    ),
    (
        scene(materials={"m": {"texture": {"type": "image", "file": "x.png", "repeat": [1, 0]}}}),
        "materials.m.texture.repeat: must be > 0, got [1, 0]",
    ),
    (
        scene(materials={"m": {"texture": {"type": "image", "file": "x.png", "repeat": 2}}}),
        "materials.m.texture.repeat: expected 2 numbers, got 2",
    ),
    # lights
    (scene(lights={"type": "point"}), "lights: expected an array of tables, got a table"),
    (
        scene(lights=[{"type": "area"}]),
        'lights[0].type: unknown type "area" (expected one of: point, directional, spot, rect,'
        " disc, sphere)",
    ),
    (
        scene(lights=[{"type": "spot", "position": [0, 0, 0], "direction": [0, -1, 0]}]),
        "lights[0].angle: missing required key",
    ),
    (
        scene(lights=[{"type": "spot", "position": [0, 0, 0], "direction": [0, -1, 0],
                       "angle": 0}]),
        "lights[0].angle: must be in (0, 180), got 0",
    ),
    (
        scene(lights=[{"type": "spot", "position": [0, 0, 0], "direction": [0, -1, 0],
                       "angle": 30, "inner_angle": 40}]),
        "lights[0].inner_angle: must be in [0, 30], got 40",
    ),
    (
        scene(lights=[{"type": "spot", "position": [0, 0, 0], "direction": [0, 0, 0],
                       "angle": 30}]),
        "lights[0].direction: must be a nonzero vector, got [0, 0, 0]",
    ),
    (
        scene(lights=[{"type": "rect", "corner": [0, 0, 0], "u": [1, 0, 0]}]),
        "lights[0].v: missing required key",
    ),
    (
        scene(lights=[{"type": "rect", "corner": [0, 0, 0], "u": [1, 0, 0], "v": [2, 0, 0]}]),
        "lights[0].v: the light's area (|u x v|) must be in [1e-30, 1e+30], got 0",
    ),
    (
        # |u x v| = 3e-7 in float64, but v's z rounds to 3 in float32: the kernels' normal,
        # the float32 cross product, is zero and the light would emit nothing.
        scene(lights=[{"type": "rect", "corner": [0, 0, 0], "u": [3, 0, 3],
                       "v": [3, 0, 3.0000001]}]),
        "lights[0].v: u and v are parallel to float32 precision: the kernels' float32 "
        "|u x v| is within its rounding error",
    ),
    (
        scene(lights=[{"type": "rect", "corner": [0, 0, 0], "u": [1e20, 0, 0],
                       "v": [0, 1e20, 0]}]),
        "lights[0].v: the light's area (|u x v|) must be in [1e-30, 1e+30], got 1e+40",
    ),
    (
        scene(lights=[{"type": "rect", "corner": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0],
                       "radius": 1}]),
        "lights[0].radius: unknown key (expected one of: type, corner, u, v, color)",
    ),
    (
        scene(lights=[{"type": "disc", "center": [0, 0, 0], "normal": [0, 0, 0],
                       "radius": 1}]),
        "lights[0].normal: must be a nonzero vector, got [0, 0, 0]",
    ),
    (
        scene(lights=[{"type": "disc", "center": [0, 0, 0], "normal": [0, 1, 0],
                       "radius": -1}]),
        "lights[0].radius: must be > 0, got -1",
    ),
    (
        scene(lights=[{"type": "sphere", "center": [0, 0, 0], "radius": 1e16}]),
        "lights[0].radius: the light's area (pi radius^2) must be in [1e-30, 1e+30], got 3.14e+32",
    ),
    (
        scene(lights=[{"type": "sphere", "center": [0, 0, 0], "radius": 1, "color": [1, 1]}]),
        "lights[0].color: expected 3 numbers, got [1, 1]",
    ),
    (scene(lights=[{"position": [0, 0, 0]}]), "lights[0].type: missing required key"),
    (scene(lights=[{"type": "point"}]), "lights[0].position: missing required key"),
    (
        scene(lights=[{"type": "point", "position": [0, 0, 0], "attenuation": [0, 0, 0]}]),
        "lights[0].attenuation: must not be all zero",
    ),
    (
        scene(lights=[{"type": "point", "position": [0, 0, 0], "attenuation": [1, -1, 0]}]),
        "lights[0].attenuation: must be >= 0, got [1, -1, 0]",
    ),
    (
        scene(lights=[{"type": "point", "position": [0, 0, 0], "direction": [0, 0, 1]}]),
        "lights[0].direction: unknown key (expected one of: type, position, color, attenuation)",
    ),
    (
        scene(lights=[{"type": "directional", "direction": [0, 0, 0]}]),
        "lights[0].direction: must be a nonzero vector, got [0, 0, 0]",
    ),
    (
        scene(lights=[{"type": "directional", "direction": [0, -1, 0], "color": [-1, 0, 0]}]),
        "lights[0].color: must be >= 0, got [-1, 0, 0]",
    ),
    # objects
    (obj(type="sphere", center=[0, 0, 0], radius=-1), "objects[2].radius: must be > 0, got -1"),
    (obj(type="sphere", center=[0, 0, 0], radius=0), "objects[2].radius: must be > 0, got 0"),
    (obj(type="sphere", center=[0, 0, 0]), "objects[2].radius: missing required key"),
    (
        obj(type="sphere", center=[0, 0, 0], radius=1, radius2=2),
        "objects[2].radius2: unknown key (expected one of: type, material, center, radius, "
        "transform)",
    ),
    (obj(type="teapot"), 'objects[2].type: unknown type "teapot" (expected one of: sphere, box,'),
    (obj(type=3), "objects[2].type: unknown type 3"),
    (scene(objects=[3]), "objects[0]: expected a table, got 3"),
    (
        obj(type="plane", point=[0, 0, 0], normal=[0, 0, 0]),
        "objects[2].normal: must be a nonzero vector, got [0, 0, 0]",
    ),
    (
        obj(type="box", min=[0, 0, 0], max=[1, -1, 1]),
        "objects[2].max: must be >= min on every axis",
    ),
    (obj(type="box", min=[1, 1, 1], max=[1, 1, 1]), "objects[2].max: must differ from min"),
    (
        obj(type="triangle", vertices=[[0, 0, 0], [1, 0, 0]]),
        "objects[2].vertices: expected 3 points, got [[0, 0, 0], [1, 0, 0]]",
    ),
    (
        obj(type="triangle", vertices=[[0, 0, 0], [1, 0, 0], [0, "1", 0]]),
        'objects[2].vertices[2]: expected 3 numbers, got [0, "1", 0]',
    ),
    (
        obj(type="cylinder", base=[0, 0, 0], axis=[0, 0, 0], radius=1, height=1),
        "objects[2].axis: must be a nonzero vector",
    ),
    (
        obj(type="cylinder", base=[0, 0, 0], axis=[0, 1, 0], radius=1, height=-2),
        "objects[2].height: must be > 0, got -2",
    ),
    (
        obj(type="cylinder", base=[0, 0, 0], axis=[0, 1, 0], radius=1, height=1, capped=1),
        "objects[2].capped: expected true or false, got 1",
    ),
    (
        obj(type="cone", apex=[0, 0, 0], axis=[0, 1, 0], angle=90, height=1),
        "objects[2].angle: must be in (0, 90), got 90",
    ),
    (
        obj(type="cone", apex=[0, 0, 0], axis=[0, 1, 0], angle=30),
        "objects[2].height: missing required key",
    ),
    # object materials
    (
        obj(**SPHERE, material="glas"),
        'objects[2].material: unknown material "glas" (defined: none)',
    ),
    (obj(**SPHERE, material=1), "objects[2].material: expected a material name or an inline table"),
    (obj(**SPHERE, material={"ior": -1}), "objects[2].material.ior: must be >= 0.01, got -1"),
    (obj(**SPHERE, material={"shine": 3}), "objects[2].material.shine: unknown key"),
    # meshes
    (obj(type="mesh"), "objects[2]: a mesh needs file or vertices + faces"),
    (
        obj(type="mesh", file="a.obj", vertices=[]),
        "objects[2]: give file or vertices + faces, not both",
    ),
    (obj(type="mesh", file="missing.obj"), "objects[2].file: file not found: missing.obj"),
    # Refused by the suffix, before the file is opened: read as OBJ, an STL or an image gave
    # "mesh has no faces".
    (obj(type="mesh", file="m.stl"), 'objects[2].file: m.stl: unknown mesh file type ".stl" '
     "(use .obj, .ply, .npz, .gltf or .glb)"),
    (obj(type="mesh", file="mesh"), "objects[2].file: mesh: unknown mesh file type (no "
     "suffix)"),
    (obj(type="mesh", file=3), "objects[2].file: expected a string, got 3"),
    (obj(type="mesh", vertices=[[0, 0, 0]]), "objects[2].faces: missing required key"),
    (
        obj(type="mesh", vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[]),
        "objects[2]: mesh has no faces",
    ),
    (
        obj(type="mesh", vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 3]]),
        "objects[2].faces[0]: index 3 out of range (0-based, 3 vertices)",
    ),
    (
        obj(type="mesh", vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, -1]]),
        "objects[2].faces[0]: index -1 out of range",
    ),
    (
        obj(type="mesh", vertices=[[0, 0, 0]], faces=[[0, 0, 1]]),
        "objects[2].faces[0]: index 1 out of range (0-based, 1 vertex)",
    ),
    (
        obj(type="mesh", vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2, 0]]),
        "objects[2].faces[0]: expected 3 vertex indices, got [0, 1, 2, 0]",
    ),
    (
        obj(type="mesh", vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2.0]]),
        "objects[2].faces[0]: expected 3 vertex indices, got [0, 1, 2.0]",
    ),
    (
        obj(type="mesh", vertices=[[0, 0]], faces=[[0, 0, 0]]),
        "objects[2].vertices[0]: expected 3 numbers, got [0, 0]",
    ),
    (
        obj(type="mesh", **TRI, transform={"scale": 0}),
        "objects[2].transform.scale: must be nonzero, got 0",
    ),
    (
        obj(type="mesh", **TRI, transform={"scale": [1, 0, 1]}),
        "objects[2].transform.scale: must be nonzero, got [1, 0, 1]",
    ),
    (
        obj(type="mesh", **TRI, transform={"rotate": [0, 0]}),
        "objects[2].transform.rotate: expected 3 numbers, got [0, 0]",
    ),
    (
        obj(type="mesh", **TRI, transform={"shear": 1}),
        "objects[2].transform.shear: unknown key (expected one of: translate, rotate, scale, "
        "matrix)",
    ),
    (
        obj(type="mesh", **TRI, transform=[1, 2, 3]),
        "objects[2].transform: expected a table, got [1, 2, 3]",
    ),
    # animation: the table, its tracks, and each keyframe loaded into the scene
    (scene(animation=[]), "animation: expected a table, got []"),
    (scene(animation={}), "animation.frames: missing required key"),
    (scene(animation={"frames": 0}), "animation.frames: must be an integer in [1, 1000000], got 0"),
    (scene(animation={"frames": 10, "fps": 0}), "animation.fps: must be > 0, got 0"),
    (scene(animation={"frames": 10, "speed": 1}), "animation.speed: unknown key (expected one "
                                                  "of: frames, fps, interpolation, tracks)"),
    (scene(animation={"frames": 10, "interpolation": "cubic"}),
     'animation.interpolation: expected "linear" or "catmull-rom", got "cubic"'),
    (anim({"frames": [0, 9], "values": [1, 2]}), "animation.tracks[0].key: missing required key"),
    (anim({"key": "camera..position", "frames": [0], "values": [1]}),
     "animation.tracks[0].key: expected a key path such as camera.position"),
    (anim({"key": "camera.vfov", "frames": [0, 10], "values": [30, 40]}),
     "animation.tracks[0].frames[1]: must be an integer in [0, 9], got 10"),
    (anim({"key": "camera.vfov", "frames": [5, 5], "values": [30, 40]}),
     "animation.tracks[0].frames: must be strictly increasing"),
    (anim({"key": "camera.vfov", "frames": [0, 9], "values": [30]}),
     "animation.tracks[0].values: expected one value per keyframe (2)"),
    (anim({"key": "camera.vfov", "frames": [0, 9], "values": [30, [1, 2]]}),
     "animation.tracks[0].values[1]: expected the shape of values[0]"),
    (anim({"key": "camera.vfov", "frames": [0, 9], "values": [30, "wide"]}),
     'animation.tracks[0].values[1]: expected a number, got "wide"'),
    (anim({"key": "camera.vfov", "frames": [0], "values": [["wide"]]}),
     'animation.tracks[0].values[0]: expected 1 number, got ["wide"]'),
    (anim({"key": "objects[5].center", "frames": [0], "values": [[0, 0, 0]]}),
     "animation.tracks[0].key: objects[5] is not in the scene"),
    (anim({"key": "camera.positon", "frames": [0], "values": [[0, 0, 0]]}),
     "animation.tracks[0].values[0]: camera.positon: unknown key"),
    (anim({"key": "camera.vfov", "frames": [0, 9], "values": [30, 200]}),
     "animation.tracks[0].values[1]: camera.vfov: must be in (0, 180), got 200.0 (frame 9)"),
    (anim({"key": "objects[0].radius", "frames": [3], "values": [-1]}),
     "animation.tracks[0].values[0]: objects[0].radius: must be > 0, got -1.0 (frame 3)"),
    (anim({"key": "camera.vfov", "frames": [0], "values": [30], "interpolation": "step"}),
     'animation.tracks[0].interpolation: expected "linear" or "catmull-rom", got "step"'),
    # Integers: the values, read as real numbers, were refused as "expected an integer, got
    # 1.0 (frame 0)", as if the file had given 1.0.
    *((anim({"key": key, "frames": [0, 9], "values": values}),
       f"animation.tracks[0].key: {key} cannot be animated: it takes integers, and a track's "
       "values are real numbers")
      for key, values in (("render.spp", [1, 4]), ("render.png_bits", [8, 16]),
                          ("render.seed", [[0], [1]]),
                          ("objects[1].material_index", [[0, 1], [1, 0]]),
                          ("objects[1].material_index[0]", [0, 1]))),
]


@pytest.mark.parametrize(("data", "expected"), ERRORS, ids=[e[1].split(":")[0] for e in ERRORS])
def test_error_names_file_key_and_problem(data, expected):
    message = load_error(data)
    assert message.startswith(f"scene.toml: {expected}"), message
    assert "\n" not in message


def test_scene_error_carries_key_and_exit_code():
    with pytest.raises(SceneError) as info:
        scene_from_dict(obj(type="sphere", center=[0, 0, 0], radius=-1), SCENE)
    assert info.value.key == "objects[2].radius"
    assert info.value.file == SCENE
    assert info.value.exit_code == 3


# -- hostile input (issue 10): every crash class is a one-line scene error --------------------

LIMIT_ERRORS = [
    # Past float32: the BVH builder used to raise on these.
    (obj(type="sphere", center=[0, 0, 0], radius=1e39), "objects[2].radius: must be at most 1e+30"),
    (obj(type="sphere", center=[1e31, 0, 0], radius=1), "objects[2].center: must be at most 1e+30"),
    (obj(type="sphere", center=[0, 0, 0], radius=1e-31), "objects[2].radius: must be >= 1e-30"),
    (
        obj(type="mesh", **TRI, transform={"scale": 1e200}),
        "objects[2].transform.scale: must be at most 1e+30 in magnitude, got 1e+200",
    ),
    (
        obj(type="mesh", **TRI, transform={"scale": 1e20, "translate": [0, 0, 1e30]}),
        "objects[2].transform: moves vertices beyond 1e+30 in magnitude",
    ),
    (
        obj(type="mesh", **TRI, transform={"scale": [1, 1e-31, 1]}),
        "objects[2].transform.scale: must be at least 1e-30 in magnitude",
    ),
    # A cone's rim radius, height x tan(angle), is a length too: each within its own limit,
    # they made bounds of 5.7e38, past float32, and the BVH builder raised on them.
    (obj(type="cone", apex=[0, 0, -1], axis=[0, 0, -1], angle=89.9999999, height=1e30),
     "objects[2]: the cone's rim radius (height x tan(angle)) is 5.73e+38, beyond 1e+30 in "
     "magnitude"),
    (obj(type="cone", apex=[0, 0, -1], axis=[0, 0, -1], angle=89.9999999, height=1e20,
         transform={"scale": 1e10}),
     "objects[2].transform: makes the cone's rim radius (height x tan(angle)) 5.73e+38, beyond "
     "1e+30 in magnitude"),
    (scene(groups={"g": {"objects": [{"type": "cone", "apex": [0, 0, 0], "axis": [0, 0, 1],
                                      "angle": 89.9999999, "height": 1e30}]}}),
     "groups.g.objects[0]: the cone's rim radius (height x tan(angle)) is 5.73e+38"),
    # Integers beyond the double range used to raise OverflowError.
    (obj(type="sphere", center=[0, 0, 0], radius=10**400), "objects[2].radius: must be at most"),
    (scene(render={"width": 10**400}), "render.width: must be an integer in [1, 16384], got an "
                                       "integer of about 401 digits"),
    # Huge colours and weights gave infinite pixels.
    (scene(lights=[{"type": "directional", "direction": [0, -1, 0], "color": [1e7, 0, 0]}]),
     "lights[0].color: must be <= 1e+06, got [10000000.0, 0, 0]"),
    (scene(render={"ambient": [0, 2e6, 0]}), "render.ambient: must be <= 1e+06"),
    (scene(materials={"m": {"reflect": 1e20}}), "materials.m.reflect: must be <= 1, got 1e+20"),
    (scene(materials={"m": {"transmit": 1.5}}), "materials.m.transmit: must be <= 1, got 1.5"),
    (scene(materials={"m": {"specular": 1e300}}), "materials.m.specular: must be at most 1e+30"),
    (scene(materials={"m": {"ambient": 1e7}}), "materials.m.ambient: must be <= 1e+06"),
    (scene(materials={"m": {"shininess": 1e7}}), "materials.m.shininess: must be <= 1e+06"),
    (scene(materials={"m": {"ior": 101}}), "materials.m.ior: must be <= 100, got 101"),
    (scene(materials={"m": {"color": [0, 0, 1e39]}}), "materials.m.color: must be at most 1e+30"),
    # An empty key used to be shown as "objects[2].", naming nothing.
    (obj(**SPHERE, **{"": 1}), 'objects[2]."": unknown key'),
    (scene(materials={"a.b\nc": {"x": 1}}), 'materials."a.b\\nc".x: unknown key'),
    # Counts are bounded before anything is built.
    (scene(lights=[{}] * 10_001), "lights: 10001 entries is over the limit of 10000"),
]


@pytest.mark.parametrize(("data", "expected"), LIMIT_ERRORS,
                         ids=[e[1].split(":")[0] for e in LIMIT_ERRORS])
def test_limits_are_checked_at_load_with_the_key_named(data, expected):
    message = load_error(data)
    assert message.startswith(f"scene.toml: {expected}"), message
    assert "\n" not in message


def test_values_at_the_limits_load():
    s = scene_from_dict(scene(
        render={"ambient": [1e6, 0, 0]},
        materials={"m": {"reflect": 1, "transmit": 1, "specular": 1e6, "ior": 100}},
        objects=[{"type": "sphere", "center": [-1e30, 0, 0], "radius": 1e30, "material": "m"}],
    ))
    assert s.objects[0].radius == 1e30
    assert s.materials[0].ior == 100


def test_tiny_up_vector_is_a_direction_not_parallel():
    # Its squared length underflows to 0: the parallel test used to reject it, wrongly.
    s = scene_from_dict(scene(camera={**CAMERA, "up": [0, 1e-200, 1e-200]}))
    _, right, up, *_ = s.camera.basis(4, 3)
    assert np.allclose(right, [1, 0, 0])
    assert np.all(np.isfinite(up))


def test_tiny_direction_normalises_to_unit_length():
    s = scene_from_dict(obj(type="plane", point=[0, 0, 0], normal=[1e-170, 1e-170, 0]))
    assert np.allclose(s.objects[2].normal, [0.5**0.5, 0.5**0.5, 0])


@pytest.mark.parametrize(("suffix", "text", "line"), [
    (".toml", "[camera]\nposition = [0, 0, 1]\nx = " + "[" * 3000 + "]" * 3000 + "\n", 3),
    (".json", '{\n"camera":\n' + "[" * 100_000 + "]" * 100_000 + "}", 3),
])
def test_deep_nesting_is_an_error_naming_the_line(tmp_path, suffix, text, line):
    path = tmp_path / f"deep{suffix}"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    kind = suffix[1:].upper()
    assert str(info.value) == (f"deep{suffix}: invalid {kind}: arrays or tables nested more "
                               f"than 64 levels deep (at line {line})")


def test_deeply_nested_value_is_shown_briefly():
    value = [[[[[[[[1]]]]]]]]
    for _ in range(500):
        value = [value]
    message = load_error(scene(camera={**CAMERA, "position": value}))
    assert message == "scene.toml: camera.position: expected 3 numbers, got [[[[...]]]]"


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_integer_literal_past_the_digit_limit(tmp_path, suffix):
    digits = "9" * 5000
    path = tmp_path / f"big{suffix}"
    path.write_text(f'[render]\nseed = {digits}\n' if suffix == ".toml"
                    else f'{{\n"render": {{"seed": {digits}}}}}')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"big{suffix}: invalid {suffix[1:].upper()}: an integer "
                                      "literal has more than 4300 digits (at line 2)")


def test_scene_file_that_is_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    with pytest.raises(SceneError, match=r"^pipe\.toml: cannot read scene file: not a regular"):
        load_scene(fifo)


def test_scene_directory_is_refused(tmp_path):
    (tmp_path / "dir.toml").mkdir()
    with pytest.raises(SceneError, match=r"^dir\.toml: cannot read scene file: not a regular"):
        load_scene(tmp_path / "dir.toml")


def test_scene_file_size_is_limited(tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "MAX_SCENE_BYTES", 100)
    path = tmp_path / "big.toml"
    path.write_text("#" * 101)
    with pytest.raises(SceneError, match=r"^big\.toml: cannot read scene file: 101 bytes is "
                                         r"over the limit of 100 bytes$"):
        load_scene(path)


@pytest.mark.parametrize(("make", "expected"), [
    (lambda d: os.mkfifo(d / "m.obj"), "not a regular file: m.obj"),
    (lambda d: (d / "m.obj").mkdir(), "not a regular file: m.obj"),
    (lambda d: os.symlink("m.obj", d / "m.obj"), "Too many levels of symbolic links: m.obj"),
])
def test_mesh_file_that_is_not_a_regular_file(tmp_path, make, expected):
    make(tmp_path)
    with pytest.raises(SceneError) as info:
        scene_from_dict(mesh_scene(file="m.obj"), tmp_path / "scene.toml")
    assert str(info.value) == f"scene.toml: objects[0].file: {expected}"


def test_over_long_file_name(tmp_path):
    name = "a" * 300 + ".obj"
    with pytest.raises(SceneError) as info:
        scene_from_dict(mesh_scene(file=name), tmp_path / "scene.toml")
    assert str(info.value).startswith('scene.toml: objects[0].file: File name too long: "aaa')


def test_newline_in_a_file_name_stays_on_one_line(tmp_path):
    name = "a\nclray: error: b.png"
    data = scene(materials={"m": {"texture": {"type": "image", "file": name}}})
    message = load_error(data)
    assert message == ('scene.toml: materials.m.texture.file: file not found: '
                       '"a\\nclray: error: b.png"')
    bad = tmp_path / "x\u2028y.toml"
    with pytest.raises(SceneError) as info:
        load_scene(bad)
    assert str(info.value).startswith("x\\u2028y.toml: cannot read scene file")


def test_mesh_triangle_limit_counts_every_instance(monkeypatch):
    monkeypatch.setattr(limits, "MAX_TRIANGLES", 2)
    mesh = {"type": "mesh", **TRI}
    message = load_error(scene(objects=[mesh, mesh, mesh]))
    assert message == ("scene.toml: objects[2]: 1 triangle is over what is left (0) of the "
                       "limit of 2 triangles for all meshes")


def test_counts_of_one_take_the_singular(monkeypatch, tmp_path):
    from PIL import Image

    monkeypatch.setattr(limits, "MAX_LIGHTS", 2)
    glow = {"type": "mesh", **TRI, "material": {"emission": [1, 1, 1]}}
    point = {"type": "point", "position": [0, 5, 0]}
    assert load_error(scene(objects=[glow], lights=[point, point])) == (
        "scene.toml: objects: 1 light of emissive faces and 2 lights are over the limit of 2 "
        "lights")
    monkeypatch.setattr(limits, "MAX_BULK_SPHERES", 1)
    spheres = {"type": "spheres", "centers": [[0, 0, 0]], "radius": 1}
    assert load_error(scene(objects=[spheres, spheres])) == (
        "scene.toml: objects[1]: 1 sphere is over what is left (0) of the limit of 1 spheres "
        "for all spheres objects")
    monkeypatch.setattr(limits, "MAX_TEXELS", 1)
    for name in ("a.png", "b.png"):
        Image.new("RGB", (1, 1)).save(tmp_path / name)
    assert load_error_at(texture_scene("a.png", "b.png"), tmp_path) == (
        "scene.toml: materials.m1.texture.file: cannot read image b.png: image is 1x1 = 1 texel, "
        "over what is left (0) of the limit of 1 texels for all textures")


def png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG that declares its size but holds no pixel data: what a decompression bomb
    looks like to a reader that trusts the header."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                     + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def texture_scene(*files: str) -> dict:
    return scene(materials={f"m{i}": {"texture": {"type": "image", "file": f}}
                            for i, f in enumerate(files)})


@pytest.mark.parametrize(("width", "height", "expected"), [
    (100_000, 100_000, "image is over the limits of 16384 pixels a side and 67108864 texels"),
    (20_000, 1, "image is 20000x1, over the limit of 16384 pixels a side"),
    (16_384, 6_000, "image is 16384x6000 = 98304000 texels, over what is left (67108864)"),
])
def test_texture_size_is_checked_before_decoding(tmp_path, width, height, expected):
    png_header_only(tmp_path / "bomb.png", width, height)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Pillow's own bomb warning must not get out either
        with pytest.raises(SceneError) as info:
            scene_from_dict(texture_scene("bomb.png"), tmp_path / "scene.toml")
    assert str(info.value).startswith(
        f"scene.toml: materials.m0.texture.file: cannot read image bomb.png: {expected}")


def test_texel_limit_covers_all_textures_and_counts_a_file_once(tmp_path, monkeypatch):
    from PIL import Image

    monkeypatch.setattr(limits, "MAX_TEXELS", 10)
    Image.new("RGB", (3, 2)).save(tmp_path / "a.png")
    Image.new("RGB", (5, 1)).save(tmp_path / "b.png")
    s = scene_from_dict(texture_scene("a.png", "a.png", "a.png"), tmp_path / "scene.toml")
    assert s.materials[0].texture.image is s.materials[2].texture.image
    message = load_error_at(texture_scene("a.png", "b.png"), tmp_path)
    assert message.endswith("image is 5x1 = 5 texels, over what is left (4) of the limit of "
                            "10 texels for all textures")


def load_error_at(data: dict, folder: Path) -> str:
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, folder / "scene.toml")
    return str(info.value)


@pytest.mark.parametrize(("array", "expected"), [
    (np.full((2, 3), 32768, dtype=np.uint16), 32768 / 65535),  # 16-bit grey: was clipped to 1
    (np.full((2, 3), 0.25, dtype=np.float32), 0.25),  # float: was rounded to 0
    (np.full((2, 3), 7.0, dtype=np.float32), 1.0),
])
def test_texture_modes_keep_their_scale(tmp_path, array, expected):
    from PIL import Image

    name = "t.png" if array.dtype == np.uint16 else "t.tiff"
    Image.fromarray(array).save(tmp_path / name)
    s = scene_from_dict(texture_scene(name), tmp_path / "scene.toml")
    image = s.materials[0].texture.image
    assert image.shape == (2, 3, 3) and image.dtype == np.float32
    assert np.allclose(image, expected, atol=1e-7)


@pytest.mark.parametrize("name", ["t.png", "t.jpg", "t.bmp"])
def test_truncated_texture_is_a_scene_error_that_says_so(tmp_path, name):
    from PIL import Image

    pixels = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / name)
    data = (tmp_path / name).read_bytes()
    (tmp_path / name).write_bytes(data[: len(data) // 2])
    message = load_error_at(texture_scene(name), tmp_path)
    # Pillow's "OSError: image file is truncated" named a Python class, not the problem.
    assert message == (f"scene.toml: materials.m0.texture.file: cannot read image {name}: "
                       "the file is truncated (it ends before its image data does)")


def test_texture_in_no_known_format_says_so_without_naming_a_stream(tmp_path):
    (tmp_path / "t.png").write_bytes(b"\x89PNG\r\n\x1a\n but no chunks")
    message = load_error_at(texture_scene("t.png"), tmp_path)
    assert message == ("scene.toml: materials.m0.texture.file: cannot read image t.png: not an "
                       "image in a format Pillow reads, or its header is damaged")


def test_damaged_texture_data_is_told_in_pillows_words_without_its_class(tmp_path):
    from PIL import Image

    pixels = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "t.jpg")
    data = bytearray((tmp_path / "t.jpg").read_bytes())
    data[len(data) // 2 : len(data) // 2 + 20] = b"\xff" * 20
    (tmp_path / "t.jpg").write_bytes(bytes(data))
    message = load_error_at(texture_scene("t.jpg"), tmp_path)
    # Pillow's own words in the brackets, e.g. "broken data stream when reading image file".
    assert message.startswith("scene.toml: materials.m0.texture.file: cannot read image t.jpg: "
                              "the image data is damaged or unsupported (")
    assert "Error" not in message


def test_c_library_messages_while_decoding_become_warning_text(capfd):
    from clray.scene.texture import _c_stderr

    with _c_stderr() as lines:
        os.write(2, b"tempfile.tif: Using code not yet in table.\n")
    assert lines == ["tempfile.tif: Using code not yet in table."]
    assert capfd.readouterr().err == ""


def test_long_quoted_key_is_cut_inside_its_quotes():
    message = load_error(obj(**SPHERE, **{"r" + "9" * 80: 1}))
    assert message.startswith('scene.toml: objects[2]."r' + "9" * 49 + '"...: unknown key')
