"""The automatic scene of a mesh file frames the model whatever the image's shape, the model's
size or its place; refuses a model with no area; warns where the view sees a flat model
edge-on; and its ground plane leaves a flat model visible (clray/model_scene.py)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from clray.cli import main
from clray.model_scene import UP_ROTATIONS, VIEWS, load_model_scene, model_scene_data
from clray.render import render
from clray.scene import model as M
from clray.scene.load import load_scene, scene_from_dict

# An octahedron of radius 1 about the origin, and a box's triangles.
_OCTAHEDRON = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                       dtype=np.float64)
_OCTAHEDRON_FACES = [[1, 3, 5], [3, 2, 5], [2, 4, 5], [4, 1, 5], [3, 1, 6], [2, 3, 6],
                     [4, 2, 6], [1, 4, 6]]
_BOX = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
_BOX_FACES = [[1, 2, 4, 3], [5, 7, 8, 6], [1, 5, 6, 2], [3, 4, 8, 7], [1, 3, 7, 5],
              [2, 6, 8, 4]]


def _obj(path: Path, vertices: np.ndarray, faces: list[list[int]]) -> Path:
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                    + "".join("f " + " ".join(map(str, f)) + "\n" for f in faces))
    return path


def _seen(scene: M.Scene) -> np.ndarray:
    """Pixels that are not the background."""
    image = render(scene).image
    return np.any(image != np.asarray(scene.render.background, dtype=np.float32), axis=-1)


# Long along x, y and z in turn (the review's 10 x 1 x 0.5 model, cropped in portrait images).
SHAPES = {"long_x": (10.0, 1.0, 0.5), "long_y": (1.0, 10.0, 0.5), "long_z": (0.5, 1.0, 10.0)}


@pytest.mark.parametrize("size", [(100, 400), (60, 160), (400, 100), (640, 480), (100, 100)])
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_every_vertex_is_inside_the_image_for_every_view_and_up(tmp_path, monkeypatch, shape,
                                                                size):
    # The distance came from the 35-degree vertical angle: a portrait image, narrower than
    # that, cut off the model's sides (392 of the review's cases at 100 x 400).
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _BOX * SHAPES[shape] + [3.0, -2.0, 1.0], _BOX_FACES)
    width, height = size
    for view in VIEWS:
        for up in UP_ROTATIONS:
            scene = scene_from_dict(model_scene_data(Path("m.obj"), view, up=up, width=width,
                                                     height=height))
            assert (scene.render.width, scene.render.height) == size
            forward, right, true_up, half_w, half_h = scene.camera.basis(width, height)
            d = scene.objects[0].vertices - np.asarray(scene.camera.position)
            depth = d @ forward
            assert np.all(depth > 0)
            x, y = d @ right / depth, d @ true_up / depth
            assert np.all(np.abs(x) < half_w) and np.all(np.abs(y) < half_h), (view, up)


@pytest.mark.parametrize("scale", [1e-17, 1e-13, 1e14, 1e17])
def test_a_model_of_any_size_renders_and_its_written_scene_the_same(
        cl_device, tmp_path, monkeypatch, capsysbinary, scale):
    # The float32 triangle test multiplies three lengths: a 1e14 or 1e-16 model rendered only
    # the background, with no warning. The automatic scene scales it by a power of 2.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _OCTAHEDRON * scale + 3 * scale, _OCTAHEDRON_FACES)
    scene = load_model_scene(Path("m.obj"), width=32, height=24)
    assert scene.warnings == ()
    assert _seen(scene).mean() > 0.2
    assert main(["scene", "m.obj", "-W", "32", "-H", "24"]) == 0
    (tmp_path / "m.toml").write_bytes(capsysbinary.readouterr().out)
    np.testing.assert_array_equal(render(load_scene(tmp_path / "m.toml")).image,
                                  render(scene).image)


def test_a_model_too_small_for_float32_at_its_place_renders(cl_device, tmp_path, monkeypatch):
    # The review's unres.obj: a 1e-12 sphere at (1, 1, 1) rendered empty, with no warning.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _OCTAHEDRON * 1e-12 + 1.0, _OCTAHEDRON_FACES)
    scene = load_model_scene(Path("m.obj"), width=32, height=24)
    assert scene.warnings == ()
    assert _seen(scene).mean() > 0.2


def _ply(path: Path, vertices: np.ndarray) -> None:
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                     b"property float y\nproperty float z\nelement face 1\n"
                     b"property list uchar int vertex_indices\nend_header\n"
                     + "".join(f"{x} {y} {z}\n" for x, y, z in vertices.tolist()).encode()
                     + b"3 0 1 2\n")


@pytest.mark.parametrize(("name", "corners"), [
    ("same.obj", [[1, 2, 3]] * 3), ("zero.obj", [[0, 0, 0]] * 3),
    ("line.obj", [[0, 0, 0], [1, 0, 0], [2, 0, 0]]), ("same.ply", [[1, 2, 3]] * 3),
    ("same.npz", [[1, 2, 3]] * 3), ("slant.obj", [[0.1, 0.2, 0.3], [0.3, 0.6, 0.9],
                                                  [0.7, 1.4, 2.1]])])
def test_a_model_whose_triangles_have_no_area_is_refused_in_one_line(tmp_path, monkeypatch,
                                                                     capsys, name, corners):
    monkeypatch.chdir(tmp_path)
    vertices = np.array(corners, dtype=np.float64)
    if name.endswith(".obj"):
        _obj(tmp_path / name, vertices, [[1, 2, 3]])
    elif name.endswith(".ply"):
        _ply(tmp_path / name, vertices)
    else:
        np.savez(tmp_path / name, vertices=vertices.astype(np.float32),
                 faces=np.array([[0, 1, 2]], dtype=np.int32))
    for command in (["render", name, "-o", "m.png", "-q"], ["scene", name]):
        assert main(command) == 3
        err = capsys.readouterr().err
        assert err == f"clray: error: {name}: every triangle has zero area (its corners are " \
                      "one point or on one line): nothing to render\n"
    assert not (tmp_path / "m.png").exists()


# A flat square in the plane y = 0 (a terrain), and one in z = 0 (scenes/meshes/panel.obj).
_FLAT = {"y": np.array([[0, 0, 0], [4, 0, 0], [4, 0, 4], [0, 0, 4]], dtype=np.float64),
         "z": np.array([[-1, 0, 0], [1, 0, 0], [1, 1.5, 0], [-1, 1.5, 0]], dtype=np.float64)}


@pytest.mark.parametrize(("flat", "view", "facing"), [
    ("y", "front", "top"), ("y", "side", "top"), ("z", "side", "front"), ("z", "top", "front"),
    ("y", "top", None), ("y", "three-quarter", None), ("z", "front", None), ("z", "iso", None)])
def test_a_flat_model_seen_edge_on_is_warned_of(tmp_path, monkeypatch, capsys, flat, view,
                                                facing):
    # The review's terrain --view front and panel.obj --view side: an empty image, no word.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "flat.obj", _FLAT[flat], [[1, 2, 3, 4]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model_scene_data(Path("flat.obj"), view)
    said = [str(w.message) for w in caught]
    if facing is None:
        assert said == []
        return
    assert said == [f"flat.obj: the model is flat along {flat} and --view {view} sees it "
                    f"edge-on, as nothing; try --view {facing}"]
    for command in (["render", "flat.obj", "--view", view, "-W", "8", "-H", "6", "-o",
                     "m.png"], ["scene", "flat.obj", "--view", view]):
        assert main(command) == 0
        lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
        assert lines == [f"clray: warning: {said[0]}"]


def test_the_ground_leaves_a_model_in_its_plane_visible(cl_device, tmp_path, monkeypatch):
    # The review's terrain.obj (at y = 0) with --ground rendered the ground alone: the plane
    # stood at the model's lowest point and hid it.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "flat.obj", _FLAT["y"], [[1, 2, 3, 4]])
    data = model_scene_data(Path("flat.obj"), "three-quarter", ground=True, width=32,
                            height=24)
    ground_only = {**data, "objects": data["objects"][1:]}
    with_model, without = (render(scene_from_dict(d)).image for d in (data, ground_only))
    differs = np.any(with_model != without, axis=-1)
    assert differs.mean() > 0.05


def test_render_of_a_mesh_path_frames_it_for_the_settings_image_size(tmp_path, monkeypatch):
    # render() took a mesh file's path but framed it for the default 640 x 480, so a portrait
    # RenderSettings cut off a long model's sides as the command line no longer did.
    from clray.render import RenderSettings, scene_from

    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _BOX * SHAPES["long_x"], _BOX_FACES)
    settings = RenderSettings(width=60, height=160)
    framed = scene_from("m.obj", settings)
    direct = load_model_scene(Path("m.obj"), width=60, height=160)
    assert framed.camera == direct.camera
    assert (framed.render.width, framed.render.height) == (60, 160)
    assert framed.camera != scene_from("m.obj").camera


@pytest.mark.parametrize(("scale", "place"), [(1e-35, 0.0), (1e-38, 0.0), (1e30, 0.0),
                                              (1e-3, 1e29), (1e-10, 1e25)])
def test_a_model_at_the_edge_of_the_limits_renders_and_its_written_scene_loads(
        cl_device, tmp_path, monkeypatch, capsysbinary, scale, place):
    # The review's obj_tiny, obj_huge and obj_farsmall: the scale by 2^-round(log2(radius))
    # was beyond a transform's limits (1e35 for a 1e-35 model; 2^-100, under 1e-30, for
    # coordinates at 1e30; an offset of 1e32 for a small model at 1e29), and a valid model
    # failed naming objects[0].transform.matrix, a key the user never wrote.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _OCTAHEDRON * scale + [place, 0.0, 0.0], _OCTAHEDRON_FACES)
    scene = load_model_scene(Path("m.obj"), width=32, height=24)
    assert _seen(scene).mean() > 0.1
    assert main(["scene", "m.obj", "-W", "32", "-H", "24"]) == 0
    (tmp_path / "m.toml").write_bytes(capsysbinary.readouterr().out)
    np.testing.assert_array_equal(render(load_scene(tmp_path / "m.toml")).image,
                                  render(scene).image)


@pytest.mark.parametrize(("scale", "place"), [(1e-300, 0.0), (1e-300, 1e-299), (1e-28, 1e29)])
def test_a_model_too_small_to_frame_is_refused_naming_its_file(tmp_path, monkeypatch, capsys,
                                                               scale, place):
    # Scaled by the most a transform may (2^99), or moved by the most it may (1e30), the model
    # would still be under 2^-32 across, which the float32 triangle test renders as nothing.
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _OCTAHEDRON * scale + [place, 0.0, 0.0], _OCTAHEDRON_FACES)
    for command in (["render", "m.obj", "-o", "m.png", "-q"], ["scene", "m.obj"]):
        assert main(command) == 3
        out = capsys.readouterr()
        assert out.out == ""
        assert out.err.startswith("clray: error: m.obj: the automatic scene cannot frame a "
                                  "model this small (radius ")
        assert out.err.endswith("; scale the model up, or write a scene file\n")
        assert out.err.count("\n") == 1
    assert not (tmp_path / "m.png").exists()


def test_a_transform_beyond_the_limits_names_the_model_file(tmp_path, monkeypatch, capsys):
    # Whatever the framing computes, a transform the scene cannot take is said of the model
    # file, not of objects[0].transform, which the user never wrote.
    import clray.model_scene as model_scene

    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _OCTAHEDRON * 1e20, _OCTAHEDRON_FACES)
    monkeypatch.setattr(model_scene, "_shrink", lambda path, radius, reach: 2.0 ** -110)
    assert main(["scene", "m.obj"]) == 3
    err = capsys.readouterr().err
    assert err == ("clray: error: m.obj: the automatic scene cannot place this model (its "
                   "transform.matrix: is singular: it flattens space (its 3x3 part must be "
                   "invertible)); write a scene file\n")
