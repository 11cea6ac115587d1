"""Load-time scale analysis: which primitives get a warning or the fp64 sphere path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clray.device.pack import pack_scene
from clray.scene.load import load_scene, scene_from_dict
from clray.scene.scale import _median, analyze

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def _scene(objects: list, eye: tuple = (0.0, 1.0, 4.0)) -> dict:
    look = [eye[0], eye[1], eye[2] - 1]
    return {"camera": {"position": list(eye), "look_at": look}, "objects": objects}


def _sphere(centre: list, radius: float) -> dict:
    return {"type": "sphere", "center": centre, "radius": radius}


def test_shipped_scenes_need_no_warning() -> None:
    for path in sorted(SCENES.glob("*.toml")):
        assert load_scene(path).warnings == (), path.name


def test_huge_ground_sphere_is_flagged_for_fp64() -> None:
    scene = scene_from_dict(_scene([_sphere([0, -1e5, 0], 1e5), _sphere([0, 0.5, 0], 0.5)]))
    report = analyze(scene)
    assert report.fp64_spheres == (0,)
    assert "objects[0] (sphere)" in report.warnings[0]
    packed = pack_scene(scene, width=4, height=3, spp=1, max_depth=0, seed=0)
    assert packed.config.fp64_spheres


def test_far_small_sphere_threshold() -> None:
    near = scene_from_dict(_scene([_sphere([0, 0, -1e3], 1.0)], eye=(0, 0, 0)))
    far = scene_from_dict(_scene([_sphere([0, 0, -1e5], 1.0)], eye=(0, 0, 0)))
    assert analyze(near).fp64_spheres == ()
    assert analyze(far).fp64_spheres == (0,)
    assert not pack_scene(near, width=4, height=3, spp=1, max_depth=0, seed=0).config.fp64_spheres


def test_camera_just_under_a_surface_is_flagged() -> None:
    scene = scene_from_dict(_scene([_sphere([0, 0, 0], 1.0)], eye=(0, 0, 1 - 1e-6)))
    assert analyze(scene).fp64_spheres == (0,)


def test_other_primitives_only_warn() -> None:
    box = {"type": "box", "min": [0, 0, -1e6], "max": [1e-3, 1e-3, -1e6 + 1e-3]}
    report = analyze(scene_from_dict(_scene([box])))
    assert report.fp64_spheres == ()
    assert "cannot resolve" in report.warnings[0]


def _cone(angle: float, height: float) -> dict:
    return {"type": "cone", "apex": [0, 0.5, 0], "axis": [0, 1, 0.2], "angle": angle,
            "height": height}


def test_near_flat_cone_warns() -> None:
    # Rim radius 57.3 over a height of 1e-3: the float kernel's side quadratic (tan^2 = 3.3e9)
    # cancels; seen from 8 away, 10 of 768 pixels went astray against the reference, though
    # the distance over the height (8e3) raises no warning.
    report = analyze(scene_from_dict(_scene([_cone(89.999, 1e-3)])))
    assert report.fp64_spheres == ()
    assert len(report.warnings) == 1
    assert report.warnings[0].startswith("objects[0] (cone): its rim radius 57.3 is 5.73e+04 "
                                         "times its height 0.001")


@pytest.mark.parametrize(("angle", "height"), [(30, 1.5), (89.99, 1e-2), (0.01, 1.5)])
def test_ordinary_and_rendered_alike_cones_do_not_warn(angle: float, height: float) -> None:
    # 89.99 degrees (rim radius 5.7e3 heights) still matches the reference in float32.
    assert analyze(scene_from_dict(_scene([_cone(angle, height)]))).warnings == ()


def test_lengths_outside_float32_squares_warn() -> None:
    tiny = scene_from_dict(_scene([_sphere([0, 0, 0], 1e-20)], eye=(0, 0, 1e-19)))
    assert "float32 can hold" in analyze(tiny).warnings[0]
    assert analyze(tiny).fp64_spheres == ()


def test_explicit_variant_overrides_the_flag() -> None:
    scene = scene_from_dict(_scene([_sphere([0, -1e5, 0], 1e5)]))
    packed = pack_scene(scene, width=4, height=3, spp=1, max_depth=0, seed=0, fp64_spheres=False)
    assert not packed.config.fp64_spheres


def test_median_of_sizes_is_numpys() -> None:
    # The scale analysis takes its median without np.median (whose import of numpy.ma costs the
    # command 10 ms): the same value for odd and even counts, repeated values included.
    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 4, 7, 10, 1001):
        sizes = np.round(rng.lognormal(size=n) * 10, 1)
        assert _median(sizes) == float(np.median(sizes))


_OCTAHEDRON = ("v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\nf 1 3 5\nf 3 2 5\n"
               "f 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n")


@pytest.mark.parametrize(("scale", "warned"), [(1e11, False), (1e-11, False), (1e13, True),
                                                (1e-16, True)])
def test_triangles_warn_where_products_of_three_lengths_leave_float32(
        cl_device, tmp_path, scale: float, warned: bool) -> None:
    # The watertight test's t scaled by det is a product of three lengths: a 1e13 or a 1e-16
    # mesh rendered nothing in float32, while the limits of squares (1e+-18) said nothing.
    from clray.render import render

    (tmp_path / "oct.obj").write_text(_OCTAHEDRON)
    size = [[scale, 0, 0, 0], [0, scale, 0, 0], [0, 0, scale, 0], [0, 0, 0, 1]]
    objects = [{"type": "mesh", "file": "oct.obj", "transform": {"matrix": size}},
               {"type": "triangle", "vertices": [[scale, 0, 0], [0, scale, 0], [0, 0, scale]]}]
    for i, obj in enumerate(objects):
        scene = scene_from_dict({
            "render": {"width": 16, "height": 12, "background": [0, 0, 0]},
            "camera": {"position": [3 * scale] * 3, "look_at": [0, 0, 0], "vfov": 40},
            "lights": [{"type": "directional", "direction": [-1, -1, -1]}],
            "objects": [obj]}, tmp_path / "s.toml")
        seen = int(np.any(render(scene).image != 0, axis=-1).sum())
        if warned:
            assert len(scene.warnings) == 1
            assert "whose products of three lengths float32 can hold" in scene.warnings[0]
            assert seen == 0  # the warned range is where the pixels go
        else:
            assert scene.warnings == ()
            assert seen == (16, 8)[i]  # as at scale 1
