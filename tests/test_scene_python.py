"""Scenes from Python (clray.scene_from_dict with numpy arrays, the model's dataclasses checked
by clray.scene.check) are untrusted input as scene files are: whatever a field or key holds,
a bad value is one SceneError naming where, never another exception, and a loaded scene keeps
no array its caller can still change."""

from __future__ import annotations

import dataclasses
import tracemalloc
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from clray.errors import SceneError, SettingsError
from clray.render import RenderSettings
from clray.scene import model as M
from clray.scene.check import check_scene
from clray.scene.load import load_scene, scene_from_dict

CAMERA = M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
SPHERE = M.Sphere((0.0, 0.0, 0.0), 1.0, 0)
DATA: dict[str, Any] = {
    "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
    "materials": {"m": {"color": [0.8, 0.3, 0.2]}},
    "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]}


def _scene(**fields: Any) -> M.Scene:
    base: dict[str, Any] = {"path": None, "render": M.RenderOptions(width=8, height=6),
                            "camera": CAMERA, "materials": (M.Material("m"),), "lights": (),
                            "objects": (SPHERE,)}
    return M.Scene(**(base | fields))


def _refused(scene: Any, message: str) -> None:
    with pytest.raises(SceneError) as info:
        check_scene(scene)
    assert str(info.value).startswith(message), str(info.value)


# -- the dataclasses: names -----------------------------------------------------------------

def test_a_nameless_material_does_not_take_the_place_of_one_named_like_its_fallback() -> None:
    red = M.Material("material 1", color=(1.0, 0.0, 0.0), ambient=1.0, diffuse=0.0)
    green = M.Material("", color=(0.0, 1.0, 0.0), ambient=1.0, diffuse=0.0)
    checked = check_scene(_scene(materials=(red, green)))
    assert [m.color for m in checked.materials] == [red.color, green.color]
    assert checked.objects[0].material == 0


def test_a_group_named_like_another_groups_fallback_is_kept() -> None:
    one = M.Group("group 1", (M.Sphere((0.0, 0.0, 0.0), 1.0, 0),))
    unnamed = M.Group("", (M.Sphere((0.0, 0.0, 0.0), 2.0, 0),))
    place = np.eye(3, 4)
    checked = check_scene(_scene(objects=(M.Instance(one, place), M.Instance(unnamed, place))))
    assert [obj.group.objects[0].radius for obj in checked.objects] == [1.0, 2.0]


# -- the dataclasses: fields of the wrong type ----------------------------------------------

def test_a_look_alike_of_a_checked_scene_is_not_one() -> None:
    _refused(types.SimpleNamespace(checked=True), "expected a clray Scene, got SimpleNamespace")


cyclic: list = [1.0]
cyclic.append(cyclic)
GROUP = M.Group("g", (SPHERE,))


@pytest.mark.parametrize(("scene", "message"), [
    (_scene(render=None), "render: expected a RenderOptions, got NoneType"),
    (_scene(render={"width": 8}), "render: expected a RenderOptions, got dict"),
    (_scene(path=5), "path: expected a path or None, got int"),
    (_scene(objects=None), "objects: expected a tuple, got NoneType"),
    (_scene(lights=None), "lights: expected a tuple, got NoneType"),
    (_scene(materials=None), "materials: expected a tuple, got NoneType"),
    (_scene(materials=(None,)), "materials[0]: expected a Material, got NoneType"),
    (_scene(objects=(None,)), "objects[0]: expected one of Sphere"),
    (_scene(lights=(None,)), "lights[0]: expected one of PointLight"),
    (_scene(objects=(M.Instance(M.Group("g", None), np.eye(3, 4)),)),
     "objects[0].group.objects: expected a tuple, got NoneType"),
    (_scene(objects=(M.Instance(M.Group("g", (None,)), np.eye(3, 4)),)),
     "groups.g.objects[0]: expected one of Sphere"),
    (_scene(objects=(M.Instance(None, np.eye(3, 4)),)),
     "objects[0].group: expected a Group, got NoneType"),
    (_scene(camera=M.Camera(np.array(1.0), (0.0, 0.0, 0.0))),
     "camera.position: expected 3 numbers, got 1.0"),
    (_scene(camera=M.Camera(cyclic, (0.0, 0.0, 0.0))), "camera.position: expected 3 numbers"),
    (_scene(camera=M.Camera(np.zeros(10**6), (0.0, 0.0, 0.0))),
     "camera.position: expected 3 numbers, got ndarray"),
    (_scene(render=M.RenderOptions(width=np.array(16.5))),
     "render.width: expected an integer, got 16.5"),
    (_scene(materials=(M.Material("m", texture=M.Texture(np.array(["a", "b"]))),)),
     "materials.m.texture.type: unknown type ndarray"),
    *[(_scene(objects=(M.Instance(GROUP, matrix),)),
       "objects[0].matrix: expected an array of 3x4 numbers")
      for matrix in (np.full((3, 4), "a"), [[1, 0, 0, 0], [0, 1], [0, 0, 1, 0]],
                     [["1", "0", "0", "0"], ["0", "1", "0", "0"], ["0", "0", "1", "0"]],
                     np.eye(3, 4, dtype=bool), np.eye(3, 4) * (1 + 1j),
                     np.eye(3, 4).astype(object), cyclic, None)],
])
def test_a_field_of_the_wrong_type_is_named(scene: M.Scene, message: str) -> None:
    _refused(scene, message)


def test_a_zero_dimensional_array_is_its_number() -> None:
    checked = check_scene(_scene(render=M.RenderOptions(width=np.array(16), height=6)))
    assert checked.render.width == 16 and type(checked.render.width) is int


# -- scene_from_dict: keys --------------------------------------------------------------------

SPHERE_SPEC = DATA["objects"][0]


@pytest.mark.parametrize(("data", "message"), [
    ({**DATA, 1: 2}, "keys must be strings, got 1"),
    ({**DATA, (1, 2): 2}, "keys must be strings, got [1, 2]"),
    ({**DATA, "render": {1: 2}}, "render: keys must be strings, got 1"),
    ({**DATA, "camera": {**DATA["camera"], None: 1}}, "camera: keys must be strings, got NoneType"),
    ({**DATA, "materials": {1: {}}}, "materials: keys must be strings, got 1"),
    ({**DATA, "materials": {"m": {2.5: 1}}}, "materials.m: keys must be strings, got 2.5"),
    ({**DATA, "objects": [{**SPHERE_SPEC, 0: 1}]}, "objects[0]: keys must be strings, got 0"),
    ({**DATA, "objects": [{**SPHERE_SPEC, "transform": {1: 2}}]},
     "objects[0].transform: keys must be strings, got 1"),
    ({**DATA, "groups": {3: {"objects": []}}}, "groups: keys must be strings, got 3"),
    ({**DATA, "animation": {"frames": 2, 1: 2}}, "animation: keys must be strings, got 1"),
    # With includes the tables are merged first, by include.py.
    ({**DATA, "include": [], 1: 2}, "keys must be strings, got 1"),
    ({**DATA, "include": [], "materials": {1: {}}}, "materials: keys must be strings, got 1"),
    ({**DATA, "include": [], "render": {1: {}}}, "render: keys must be strings, got 1"),
    ({**DATA, "include": [], "groups": {1: {}}}, "groups: keys must be strings, got 1"),
])
def test_a_key_that_is_not_a_string_is_named(data: dict, message: str) -> None:
    with pytest.raises(SceneError) as info:
        scene_from_dict(data)
    assert str(info.value) == message


# -- scene_from_dict: choices -----------------------------------------------------------------

ANIMATED = {**DATA, "animation": {"frames": 2, "tracks": [
    {"key": "objects[0].radius", "frames": [0, 1], "values": [1, 2]}]}}


@pytest.mark.parametrize("value", [np.array([8, 16]), np.array([16]), np.array(16), 16.0, True])
def test_png_bits_is_an_integer_not_an_array(value: Any) -> None:
    with pytest.raises(SceneError, match=r"^render\.png_bits: expected 8 or 16, got "):
        scene_from_dict({**DATA, "render": {"png_bits": value}})
    with pytest.raises(SettingsError, match=r"^RenderSettings\.png_bits: expected 8 or 16, "):
        RenderSettings(png_bits=value)


@pytest.mark.parametrize(("data", "message"), [
    ({**DATA, "camera": {**DATA["camera"], "type": np.array(["perspective", "orthographic"])}},
     'camera.type: expected "perspective" or "orthographic", got ndarray'),
    ({**DATA, "camera": {**DATA["camera"], "type": np.array(["orthographic"])}},
     'camera.type: expected "perspective" or "orthographic", got ndarray'),
    ({**ANIMATED, "animation": {**ANIMATED["animation"], "interpolation": np.array(["a", "b"])}},
     'animation.interpolation: expected "linear" or "catmull-rom", got ndarray'),
])
def test_a_choice_given_as_an_array_is_refused(data: dict, message: str) -> None:
    with pytest.raises(SceneError) as info:
        scene_from_dict(data)
    assert str(info.value) == message


def test_numpy_choices_are_taken_as_python_values() -> None:
    scene = scene_from_dict({**DATA, "render": {"png_bits": np.int64(16)},
                             "camera": {**DATA["camera"], "type": np.str_("orthographic"),
                                        "height": 2}})
    assert type(scene.render.png_bits) is int and scene.render.png_bits == 16
    assert type(scene.camera.type) is str and scene.camera.type == "orthographic"
    assert RenderSettings(png_bits=np.int64(16)).png_bits == 16


# -- animation key paths ----------------------------------------------------------------------

@pytest.mark.parametrize("index", ["9" * 5000, "9" * 10, "\u0660", "\uff11"])
def test_an_animation_index_of_too_many_or_non_ascii_digits_is_refused(
        tmp_path: Path, index: str) -> None:
    scene = tmp_path / "s.toml"
    scene.write_text(f"""
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
[animation]
frames = 2
tracks = [{{ key = "objects[{index}].radius", frames = [0], values = [2] }}]
""", encoding="utf-8")
    with pytest.raises(SceneError, match=r"^s\.toml: animation\.tracks\[0\]\.key: expected a "
                       "key path such as camera.position"):
        load_scene(scene)


# -- numpy scalars ----------------------------------------------------------------------------

def test_numpy_scalars_of_every_real_type_are_numbers() -> None:
    f32, i64 = np.float32, np.int64
    scene = scene_from_dict({
        "render": {"exposure": f32(1.5), "min_weight": np.float16(0.25), "width": i64(8),
                   "ambient": [f32(0.5), i64(1), np.uint8(0)]},
        "camera": {"position": [f32(0), i64(0), np.int32(5)], "look_at": [0, 0, 0],
                   "vfov": f32(30)},
        "materials": {"m": {"color": [f32(0.8), 0.3, 0.2], "reflect": f32(0.5)}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": f32(1.5),
                     "material": "m"}]})
    assert (scene.render.exposure, scene.render.min_weight) == (1.5, 0.25)
    assert scene.camera.position == (0.0, 0.0, 5.0) and scene.camera.vfov == 30.0
    assert scene.objects[0].radius == 1.5 and type(scene.objects[0].radius) is float
    checked = check_scene(_scene(objects=(M.Sphere((f32(0), i64(0), 0.0), f32(2), 0),)))
    assert checked.objects[0].radius == 2.0


@pytest.mark.parametrize(("value", "message"), [
    (np.float32("nan"), "objects[0].radius: must be finite, got nan"),
    (np.float32("inf"), "objects[0].radius: must be finite, got inf"),
    (np.bool_(True), "objects[0].radius: expected a number, got bool"),
    (np.complex64(1), "objects[0].radius: expected a number, got complex64"),
    (np.int64(-2), "objects[0].radius: must be > 0, got -2"),
])
def test_numpy_scalars_meet_the_number_rules(value: Any, message: str) -> None:
    with pytest.raises(SceneError) as info:
        scene_from_dict({**DATA, "objects": [{**SPHERE_SPEC, "radius": value}]})
    assert str(info.value) == message


def test_a_numpy_integer_out_of_range_is_shown_as_a_number() -> None:
    with pytest.raises(SceneError, match=r"^render\.width: must be an integer in \[1, 16384\], "
                       r"got 0$"):
        scene_from_dict({**DATA, "render": {"width": np.int64(0)}})


# -- arrays: copied, and read-only once checked -------------------------------------------------

def _all_arrays(scene: M.Scene) -> list[np.ndarray]:
    found = [m.texture.image for m in scene.materials if m.texture is not None]
    found.append(scene.render.background.image)
    for obj in scene.objects:
        if isinstance(obj, M.Instance):
            found.append(obj.matrix)
            obj = obj.group.objects[0]
        found += [getattr(obj, f.name) for f in dataclasses.fields(obj)]
    return [a for a in found if isinstance(a, np.ndarray)]


def _array_scene() -> tuple[dict, dict[str, np.ndarray]]:
    given = {
        "texels": np.full((2, 2, 3), 0.5, dtype=np.float32),  # as stored: no conversion
        "sky": np.full((2, 4, 3), 0.25, dtype=np.float32),
        "vertices": np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
        "faces": np.array([[0, 1, 2]]),
        "normals": np.array([[0.0, 0, 1]] * 3),
        "uvs": np.zeros((3, 2)),
        "colors": np.full((3, 3), 0.5),
        "face_index": np.array([0]),
        "centers": np.zeros((2, 3)),
        "radii": np.ones(2),
        "sphere_index": np.array([0, 0]),
    }
    mesh = {"type": "mesh", "vertices": given["vertices"], "faces": given["faces"],
            "normals": given["normals"], "uvs": given["uvs"], "colors": given["colors"],
            "materials": ["t"], "material_index": given["face_index"]}
    data = {**DATA, "render": {"background": {"type": "image", "texels": given["sky"]}},
            "materials": {"t": {"texture": {"type": "image", "texels": given["texels"]}}},
            "groups": {"g": {"objects": [mesh]}},
            "objects": [mesh, {"type": "spheres", "centers": given["centers"],
                               "radii": given["radii"], "materials": ["t"],
                               "material_index": given["sphere_index"]},
                        {"type": "instance", "group": "g"}]}
    return data, given


def test_a_loaded_scene_keeps_no_array_of_its_caller_and_none_can_be_written() -> None:
    data, given = _array_scene()
    scene = scene_from_dict(data)
    held = _all_arrays(scene)
    assert len(held) == 18  # 2 images, 2 meshes of 6, 3 spheres arrays, the matrix
    kept = [a.copy() for a in held]
    for array in given.values():
        array[...] = 7  # the caller changes its arrays after loading
    for array, before in zip(held, kept, strict=True):
        np.testing.assert_array_equal(array, before)
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array.flat[0] = 0


def test_a_checked_scene_keeps_no_array_of_its_caller() -> None:
    texels = np.full((2, 2, 3), 0.5, dtype=np.float32)
    faces = np.array([[0, 1, 2]])
    mesh = M.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), faces, 0)
    material = M.Material("t", texture=M.Texture("image", image=texels))
    checked = check_scene(_scene(materials=(material,), objects=(mesh,)))
    texels[...] = np.nan
    faces[0, 2] = 10**6
    assert np.all(checked.materials[0].texture.image == 0.5)
    np.testing.assert_array_equal(checked.objects[0].faces, [[0, 1, 2]])
    assert not checked.objects[0].faces.flags.writeable


# -- limits before memory -----------------------------------------------------------------------

def _huge(shape: tuple[int, ...], dtype: type = np.float64) -> np.ndarray:
    """An array of any size that takes no memory: one row, broadcast."""
    return np.broadcast_to(np.zeros(shape[-1], dtype), shape)


MESH = {"type": "mesh", "vertices": np.zeros((3, 3)), "faces": np.array([[0, 1, 2]]),
        "material": "m"}


@pytest.mark.parametrize(("data", "message"), [
    ({**DATA, "objects": [{**MESH, "faces": _huge((2**28, 3), np.uint8)}]},
     "objects[0]: 268435456 triangles is over what is left (33554432) of the limit"),
    ({**DATA, "objects": [{**MESH, "vertices": _huge((2**27, 3))}]},
     "objects[0].vertices: 134217728 vertices is over the limit of 100663296 for a mesh"),
    ({**DATA, "objects": [{**MESH, "normals": _huge((2**27, 3))}]},
     "objects[0].normals: expected one row per vertex (3), got 134217728"),
    ({**DATA, "objects": [{"type": "spheres", "centers": _huge((2**26, 3)), "radius": 1,
                           "material": "m"}]},
     "objects[0]: 67108864 spheres is over what is left (16777216) of the limit"),
    ({**DATA, "render": {"background": {"type": "image",
                                        "texels": _huge((20000, 20000, 3), np.float32)}}},
     "render.background.texels: must be at least 1 and at most 16384 texels a side"),
    ({**DATA, "materials": {"m": {"texture": {"type": "image",
                                              "texels": _huge((16384, 16384, 3))}}}},
     "materials.m.texture.texels: 16384x16384 texels is over what is left (67108864)"),
])
def test_arrays_over_a_limit_are_refused_before_they_are_converted(data: dict,
                                                                   message: str) -> None:
    tracemalloc.start()
    try:
        with pytest.raises(SceneError) as info:
            scene_from_dict(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(info.value).startswith(message), str(info.value)
    assert peak < 2**20, peak
