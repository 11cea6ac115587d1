"""One set of rules however a value arrives: the scene file's [render] table, the command line's
flags and RenderSettings refuse the same values in the same words; scenes built in Python meet
the scene file's checks before they render."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from clray import cli
from clray.errors import EXIT_USAGE, SceneError, SettingsError
from clray.render import RenderSettings, render
from clray.scene import limits as L
from clray.scene import model as M
from clray.scene.check import check_scene, scene_to_dict
from clray.scene.load import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parent.parent
SCENE_PATH = ROOT / "scenes" / "spheres.toml"
SCENE = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
         "materials": {"m": {"color": [0.8, 0.3, 0.2]}},
         "lights": [{"type": "point", "position": [2, 3, 4]}],
         "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]}

FLAGS = {"width": "--width", "height": "--height", "spp": "--spp", "max_depth": "--max-depth",
         "seed": "--seed", "min_weight": "--min-weight", "exposure": "--exposure",
         "png_bits": "--png-bits"}

# (field, value as Python and the file give it, as the command line gives it, the problem)
BAD = [
    ("width", 0, "0", "must be an integer in [1, 16384]"),
    ("width", 16385, "16385", "must be an integer in [1, 16384]"),
    ("width", 64.5, "64.5", "expected an integer"),
    ("height", 0, "0", "must be an integer in [1, 16384]"),
    ("height", 20000, "20000", "must be an integer in [1, 16384]"),
    ("spp", 0, "0", "must be an integer in [1, 4096]"),
    ("spp", -3, "-3", "must be an integer in [1, 4096]"),
    ("spp", 5000, "5000", "must be an integer in [1, 4096]"),
    ("max_depth", -1, "-1", "must be an integer in [0, 256]"),
    ("max_depth", 257, "257", "must be an integer in [0, 256]"),
    ("seed", -1, "-1", "must be an integer in [0, 4294967295]"),
    ("seed", 2**32, str(2**32), "must be an integer in [0, 4294967295]"),
    ("min_weight", -0.5, "-0.5", "must be in [0, 1]"),
    ("min_weight", 1.5, "1.5", "must be in [0, 1]"),
    ("min_weight", math.nan, "nan", "must be finite"),
    ("exposure", 33.0, "33", "must be in [-32, 32]"),
    ("exposure", -math.inf, "-inf", "must be finite"),
    ("png_bits", 12, "12", "expected 8 or 16"),
]
# The largest and smallest values each way accepts.
GOOD = [("width", 1, "1"), ("width", 16384, "16384"), ("spp", 4096, "4096"),
        ("max_depth", 0, "0"), ("max_depth", 256, "256"), ("seed", 2**32 - 1, str(2**32 - 1)),
        ("min_weight", 0.0, "0"), ("min_weight", 1.0, "1"), ("exposure", -32.0, "-32"),
        ("png_bits", 16, "16")]


def test_every_overridable_field_has_cases() -> None:
    fields = {*L.RENDER_INTEGERS, *L.RENDER_NUMBERS, *L.RENDER_CHOICES}
    assert fields == set(FLAGS) == {case[0] for case in BAD}


def _file_problem(name: str, value: object) -> str:
    with pytest.raises(SceneError) as info:
        scene_from_dict({**SCENE, "render": {name: value}})
    prefix, got = f"render.{name}: ", ", got "
    message = str(info.value)
    assert message.startswith(prefix) and got in message, message
    return message[len(prefix):message.rindex(got)]


@pytest.mark.parametrize(("name", "value", "text", "problem"), BAD,
                         ids=[f"{c[0]}={c[2]}" for c in BAD])
def test_file_flag_and_api_refuse_alike(name: str, value: object, text: str, problem: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert _file_problem(name, value) == problem

    with pytest.raises(SystemExit) as exited:
        cli._parse(["render", "scene.toml", f"{FLAGS[name]}={text}"])
    assert exited.value.code == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith("clray: error: ") and err.count("\n") == 1
    assert f"{FLAGS[name]}: {problem}, got {text!r}" in err

    with pytest.raises(SettingsError) as info:
        RenderSettings(**{name: value})
    assert str(info.value) == f"RenderSettings.{name}: {problem}, got {value!r}"
    assert isinstance(info.value, ValueError) and info.value.exit_code == EXIT_USAGE


@pytest.mark.parametrize(("name", "value", "text"), GOOD, ids=[f"{c[0]}={c[2]}" for c in GOOD])
def test_file_flag_and_api_accept_alike(name: str, value: object, text: str) -> None:
    assert getattr(scene_from_dict({**SCENE, "render": {name: value}}).render, name) == value
    assert getattr(cli._parse(["render", "s.toml", FLAGS[name], text]), name) == value
    assert getattr(RenderSettings(**{name: value}), name) == value


@pytest.mark.parametrize(("settings", "message"), [
    ({"precision": "half"}, "RenderSettings.precision: expected float or double, got 'half'"),
    ({"linear": "yes"}, "RenderSettings.linear: expected True or False, got 'yes'"),
    ({"device": 3}, "RenderSettings.device: expected a string, got 3"),
    ({"spp": True}, "RenderSettings.spp: expected an integer, got True"),
    ({"progress": 5}, "RenderSettings.progress: expected a callable, got 5"),
    # Fields whose default is not None take no None (it failed later, in the render).
    ({"aovs": None}, "RenderSettings.aovs: expected a tuple of pass names, got None"),
    ({"precision": None}, "RenderSettings.precision: expected float or double, got None"),
    ({"denoise": None}, "RenderSettings.denoise: expected True or False, got None"),
])
def test_settings_only_the_api_has(settings: dict, message: str) -> None:
    with pytest.raises(SettingsError) as info:
        RenderSettings(**settings)
    assert str(info.value) == message


@pytest.mark.parametrize(("variants", "message"), [
    (5, "expected a tuple of (KernelConfig field name, value) pairs, got 5"),
    ((("nope", 1),), "'nope' is not a KernelConfig field, got (('nope', 1),)"),
    ((("fresnel_schlick", 1),), "'fresnel_schlick' takes True or False, not 1"),
    ((("build_options", "-cl-mad-enable"),), "'build_options' takes a tuple of strings"),
    # A knob's None means "the device's"; a variant names a value, and None is no integer.
    ((("bvh_width", 3),), "'bvh_width' takes one of 4, 8, not 3"),
    ((("bvh_width", None),), "'bvh_width' takes an integer, not None"),
    # None for the tuple itself too: not "the scene's", which variants has no use for.
    (None, "expected a tuple of (KernelConfig field name, value) pairs, got None"),
    ((("traversal", "nope"),), "'traversal' takes one of single, sample_packet, group_packet, not"),
    # Set from the scene: pack_scene got the field twice, a TypeError.
    ((("has_planes", True),), "'has_planes' is set by the render from the scene and settings"),
    ((("max_depth", 2),), "'max_depth' is set by the render"),
])
def test_variants_are_checked_on_creation(variants: object, message: str) -> None:
    with pytest.raises(SettingsError) as info:
        RenderSettings(variants=variants)
    assert str(info.value).startswith(f"RenderSettings.variants: {message}")


def test_the_study_variants_are_accepted() -> None:
    from clray.study import VARIANTS

    for variant in VARIANTS:
        assert RenderSettings(variants=variant.switches).variants == variant.switches


@pytest.mark.parametrize("settings", [{"width": 4}, {}, 4])
def test_render_refuses_settings_that_are_not_render_settings(settings: object) -> None:
    # An empty dict too, which `settings or RenderSettings()` took for the defaults.
    with pytest.raises(SettingsError) as info:
        render(SCENE_PATH, settings)  # type: ignore[arg-type]
    assert str(info.value) == ("settings: expected a clray.RenderSettings or None, got "
                               f"{type(settings).__name__}")


def test_numpy_integers_are_integers() -> None:
    assert RenderSettings(width=np.int64(32)).width == 32


def test_numpy_numbers_become_pythons_own() -> None:
    # Accepted as numbers, kept as Python's int and float: the render's stats hold them, and
    # json.dumps refuses numpy's scalars.
    settings = RenderSettings(width=np.int64(8), height=np.int32(6), spp=np.uint8(2),
                              max_depth=np.int16(1), seed=np.int64(3),
                              min_weight=np.float32(0.25), exposure=np.float64(-1.5),
                              png_bits=np.int64(16),
                              variants=(("packet_lanes", np.int64(4)),))
    values = {name: getattr(settings, name) for name in
              ("width", "height", "spp", "max_depth", "seed", "min_weight", "exposure",
               "png_bits")}
    assert values == {"width": 8, "height": 6, "spp": 2, "max_depth": 1, "seed": 3,
                      "min_weight": 0.25, "exposure": -1.5, "png_bits": 16}
    assert {name: type(value) for name, value in values.items()} == {
        **dict.fromkeys(("width", "height", "spp", "max_depth", "seed", "png_bits"), int),
        "min_weight": float, "exposure": float}
    assert type(settings.variants[0][1]) is int
    json.dumps({**values, "variants": settings.variants})
    assert RenderSettings(min_weight=0).min_weight == 0  # Python's numbers as they are
    assert type(RenderSettings(min_weight=0).min_weight) is int


def test_render_stats_are_json_with_numpy_settings(cl_device) -> None:
    result = render(SCENE_PATH, RenderSettings(width=np.int64(8), height=np.int64(6),
                                               min_weight=np.float32(0.5)))
    assert json.loads(json.dumps(result.stats))["width"] == 8


# -- scenes built in Python --------------------------------------------------------------------

def _scene(objects: tuple, *, camera: M.Camera | None = None, **render: object) -> M.Scene:
    camera = camera or M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
    return M.Scene(None, M.RenderOptions(width=16, height=12, **render), camera,
                   (M.Material("m", (0.8, 0.3, 0.2)),), (M.PointLight((2.0, 3.0, 4.0)),),
                   objects)


@pytest.mark.parametrize(("scene", "message"), [
    (_scene((M.Sphere((0, 0, 0), 1.0, 5),)),
     "objects[0].material: expected the index of one of the scene's 1 material, got 5"),
    (_scene((M.Sphere((0, 0, 0), 1.0, 0),), camera=M.Camera((0, 0, 5), (0, 0, 0), up=(0, 0, 1))),
     "camera.up: must not be parallel to the view direction"),
    (_scene((M.Sphere((0, 0, 0), -1.0, 0),)), "objects[0].radius: must be > 0, got -1.0"),
    (_scene((M.Sphere((0, 0, math.nan), 1.0, 0),)), "objects[0].center: must be finite"),
    (_scene((M.Plane((0, 0, 0), (0, 0, 0), 0),)), "objects[0].normal: must be a nonzero vector"),
    (_scene((M.Sphere((0, 0, 0), 1.0, 0),), spp=0),
     "render.spp: must be an integer in [1, 4096], got 0"),
    (_scene((M.Mesh(np.zeros((3, 3)), np.array([[0, 1, 9]]), 0),)),
     "objects[0].faces[0]: index 9 out of range (0-based, 3 vertices)"),
    (_scene((M.Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]]), np.array([[0, 1, 2]]),
                    0),)),
     "objects[0].vertices[2]: must be finite"),
    (_scene(("sphere",)), "objects[0]: expected one of Sphere"),
    (dataclasses.replace(_scene((M.Sphere((0, 0, 0), 1.0, 0),)),
                         lights=(M.RectLight((0, 3, 0), (1, 0, 0), (-2, 0, 0)),)),
     "lights[0].v: the light's area (|u x v|) must be in"),
    (dataclasses.replace(_scene((M.Sphere((0, 0, 0), 1.0, 0),)),
                         lights=(M.PointLight((0, 3, 0)), "spot")),
     "lights[1]: expected one of PointLight, DirectionalLight, SpotLight, RectLight"),
])
def test_scene_built_in_python_meets_the_file_rules(scene: M.Scene, message: str) -> None:
    with pytest.raises(SceneError) as info:
        check_scene(scene)
    assert str(info.value).startswith(message)


def test_render_checks_a_scene_before_any_device_work() -> None:
    # No cl_device fixture: the check must refuse before a device is even chosen.
    with pytest.raises(SceneError, match=r"objects\[0\]\.material"):
        render(_scene((M.Sphere((0, 0, 0), 1.0, 1),)))


def test_changed_loaded_scene_is_checked_again() -> None:
    loaded = scene_from_dict(SCENE)
    assert loaded.checked and check_scene(loaded) is loaded
    changed = dataclasses.replace(loaded, render=M.RenderOptions(spp=0))
    assert not changed.checked
    with pytest.raises(SceneError, match=r"render\.spp"):
        check_scene(changed)


def test_check_normalises_as_the_loader_does() -> None:
    mesh = M.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), 0,
                  normals=np.array([[0.0, 0, 2], [0, 0, 3], [0, 0, 0.5]]))
    checked = check_scene(_scene((M.Plane((0, -1, 0), (0, 3, 0), 0), mesh)))
    assert checked.objects[0].normal == (0.0, 1.0, 0.0)
    np.testing.assert_array_equal(checked.objects[1].normals, [[0, 0, 1]] * 3)


@pytest.mark.parametrize("path", sorted((ROOT / "scenes").glob("*.toml")), ids=lambda p: p.stem)
def test_round_trip_keeps_every_example_scene(path: Path) -> None:
    scene = load_scene(path)
    again = scene_from_dict(scene_to_dict(scene), path)
    background = scene.render.background
    if isinstance(background, M.Background) and background.image is not None:
        # As for textures: the texels travel, already linear; where they came from does not.
        np.testing.assert_array_equal(again.render.background.image, background.image)
        scene = dataclasses.replace(scene, render=dataclasses.replace(
            scene.render, background=dataclasses.replace(background, file=None,
                                                          colorspace=None)))
    assert (again.render, again.camera) == (scene.render, scene.camera)
    assert [type(light) for light in again.lights] == [type(light) for light in scene.lights]
    for a, b in zip(again.lights, scene.lights, strict=True):
        for f in dataclasses.fields(b):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if f.name in ("direction", "normal"):
                # Loaded directions are unit already: normalising again may move one ulp.
                np.testing.assert_allclose(x, y, rtol=0, atol=4e-16)
            else:
                assert x == y, f.name
    for a, b in zip(again.materials, scene.materials, strict=True):
        if b.texture is not None and b.texture.image is not None:
            # The texels travel, already linear; where they came from does not.
            np.testing.assert_array_equal(a.texture.image, b.texture.image)
            assert (a.texture.file, a.texture.colorspace) == (None, None)
            b = dataclasses.replace(b, texture=dataclasses.replace(b.texture, file=None,
                                                                   colorspace=None))
        assert a == b  # textures compare without their texels
    assert len(again.objects) == len(scene.objects)
    for a, b in zip(again.objects, scene.objects, strict=True):
        assert_same_object(a, b)


def assert_same_object(a: M.SceneObject, b: M.SceneObject) -> None:
    assert type(a) is type(b)
    if isinstance(b, M.Spheres):
        for name in ("centers", "radii", "materials"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    elif isinstance(b, M.Mesh):
        for name in ("vertices", "faces", "normals", "uvs"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None)
            if y is not None:
                # Loaded normals are unit already: normalising again may move one ulp.
                np.testing.assert_allclose(x, y, rtol=0, atol=4e-16)
    elif isinstance(b, M.Instance):
        np.testing.assert_array_equal(a.matrix, b.matrix)
        assert (a.material, a.group.name) == (b.material, b.group.name)
        assert len(a.group.objects) == len(b.group.objects)
        for x, y in zip(a.group.objects, b.group.objects, strict=True):
            assert_same_object(x, y)
    else:
        assert a == b


def test_render_takes_a_path(cl_device) -> None:
    settings = RenderSettings(width=16, height=12)
    path = ROOT / "scenes" / "spheres.toml"
    by_path = render(str(path), settings).image
    np.testing.assert_array_equal(by_path, render(load_scene(path), settings).image)
