"""`clray render MODEL` and `clray scene MODEL`: every example mesh renders with the object
filling most of the frame, the written TOML renders the same image, and the views and ground
plane are where they should be."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from clray.cli import main
from clray.errors import SceneError
from clray.model_scene import VIEWS, load_model_scene, model_scene_data, to_toml
from clray.render import RenderSettings, render
from clray.scene import model as M
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted(p for p in (ROOT / "scenes" / "meshes").iterdir()
                  if p.suffix in (".obj", ".ply"))
W, H = 80, 60


def covered(scene: M.Scene) -> np.ndarray:
    """Pixels where the model (not the background) is seen."""
    scene = M.Scene(scene.path, M.RenderOptions(**{**scene.render.__dict__, "width": W,
                                                   "height": H}),
                    scene.camera, scene.materials, scene.lights, scene.objects)
    image = render(scene).image
    return np.any(image != np.asarray(scene.render.background, dtype=np.float32), axis=-1)


@pytest.mark.parametrize("mesh", EXAMPLES, ids=lambda p: p.name)
def test_each_example_mesh_fills_most_of_the_frame(cl_device, mesh, monkeypatch):
    monkeypatch.chdir(mesh.parent)
    seen = covered(load_model_scene(Path(mesh.name)))
    rows, cols = np.flatnonzero(seen.any(axis=1)), np.flatnonzero(seen.any(axis=0))
    # Framed by the bounding sphere: inside the frame, spanning most of its height or width.
    assert not (seen[0].any() or seen[-1].any() or seen[:, 0].any() or seen[:, -1].any())
    span = max((rows[-1] - rows[0] + 1) / H, (cols[-1] - cols[0] + 1) / W)
    assert span > 0.7, span
    assert seen.mean() > 0.2, seen.mean()


@pytest.mark.parametrize("mesh", EXAMPLES, ids=lambda p: p.name)
def test_render_command_takes_a_mesh_file(cl_device, mesh, tmp_path):
    out = tmp_path / "m.png"
    assert main(["render", str(mesh), "-o", str(out), "-W", "40", "-H", "30", "-q"]) == 0
    assert out.stat().st_size > 0


@pytest.mark.parametrize("name", ["cornell_box.obj", "scan.ply"])
def test_render_takes_a_mesh_file_as_the_command_does(cl_device, name):
    # Its automatic scene, as `clray render MODEL` frames it (was "unknown scene file type").
    path = ROOT / "scenes" / "meshes" / name
    settings = RenderSettings(width=24, height=18)
    np.testing.assert_array_equal(render(str(path), settings).image,
                                  render(load_model_scene(path), settings).image)


def test_written_scene_renders_identically(cl_device, tmp_path, monkeypatch, capsysbinary):
    shutil.copy(ROOT / "scenes" / "meshes" / "cornell_box.obj", tmp_path)
    shutil.copy(ROOT / "scenes" / "meshes" / "cornell_box.mtl", tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["scene", "cornell_box.obj", "--view", "iso", "--ground"]) == 0
    (tmp_path / "model.toml").write_bytes(capsysbinary.readouterr().out)
    from_toml = load_scene(tmp_path / "model.toml")
    direct = load_model_scene(Path("cornell_box.obj"), "iso", ground=True)
    assert from_toml.camera == direct.camera and from_toml.materials == direct.materials
    np.testing.assert_array_equal(render(from_toml).image, render(direct).image)


def test_file_materials_are_kept_and_a_plain_mesh_gets_grey():
    box = model_scene_data(ROOT / "scenes" / "meshes" / "cornell_box.obj")
    assert "material" not in box["objects"][0] and box["materials"] == {}
    scan = model_scene_data(ROOT / "scenes" / "meshes" / "scan.ply")
    assert scan["objects"][0]["material"] == "model"


@pytest.mark.parametrize("view", sorted(VIEWS))
def test_views_look_at_the_centre_from_their_side(view):
    mesh = ROOT / "scenes" / "meshes" / "cornell_box.obj"  # centre (278, 274.4, 279.6)
    data = model_scene_data(mesh, view, ground=True)
    eye = np.array(data["camera"]["position"]) - data["camera"]["look_at"]
    np.testing.assert_allclose(data["camera"]["look_at"], [278, 274.4, 279.6], atol=1e-3)
    toward = np.array(VIEWS[view][0])
    # Unit length, so that every view stands at the framing's distance.
    assert abs(np.linalg.norm(toward) - 1.0) < 1e-12
    np.testing.assert_allclose(eye / np.linalg.norm(eye), toward, atol=1e-5)
    plane = data["objects"][1]
    # Under the model's lowest point (y = 0) by GROUND_GAP of its radius.
    from clray.model_scene import GROUND_GAP

    assert plane["type"] == "plane"
    assert plane["point"][1] == pytest.approx(-GROUND_GAP * _framed_radius(data), rel=1e-9)


def test_scene_command_refuses_a_scene_file(capsys):
    assert main(["scene", "x.toml"]) != 0
    assert "expected a mesh file" in capsys.readouterr().err


def test_toml_strings_are_escaped():
    text = to_toml({"objects": [{"type": "mesh", "file": 'a "b"\\c.obj'}]})
    assert 'file = "a \\"b\\"\\\\c.obj"' in text


# Control characters and DEL (not TOML in a string or a comment unescaped), a character
# beyond U+FFFF (json.dumps wrote it as a surrogate pair of escapes, which TOML refuses), and
# characters TOML takes as they are.
_ODD_NAMES = ["del\x7f.obj", "ctl\x01\x1f.obj", "emoji\U0001F600.obj", "tab\tnl\ncr\r.obj",
              "nel\x85ls\u2028.obj", 'q"b\\.obj']


@pytest.mark.parametrize("name", _ODD_NAMES)
def test_toml_strings_and_comments_read_back(name):
    import tomllib

    text = to_toml({"objects": [{"type": "mesh", "file": name}]}, f"of {name}")
    assert tomllib.loads(text)["objects"][0]["file"] == name
    # A comment line for each of the header's lines ("\n" only: not at U+0085 or U+2028).
    assert text.count("# ") == name.count("\n") + 1


@pytest.mark.parametrize("name", ["del\x7f.obj", "ctl\x01.obj", "emoji\U0001F600.obj"])
def test_a_scene_written_for_an_odd_file_name_loads(tmp_path, monkeypatch, capsys, name):
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / name, _Y_UP)
    assert main(["scene", name]) == 0
    (tmp_path / "s.toml").write_text(capsys.readouterr().out, encoding="utf-8")
    written = load_scene(tmp_path / "s.toml")
    np.testing.assert_array_equal(written.objects[0].vertices,
                                  load_model_scene(Path(name)).objects[0].vertices)


def test_a_file_name_that_is_not_utf8_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    import os

    monkeypatch.chdir(tmp_path)
    name = os.fsdecode(b"bad\xff.obj")  # as Python has it from the command line
    _obj(tmp_path / name, _Y_UP)
    assert main(["scene", name]) == 3
    out, err = capsys.readouterr()
    assert out == ""
    assert err == ("clray: error: bad\\udcff.obj: the file name is not UTF-8, which a TOML "
                   "scene file cannot hold: rename the file\n")


def test_an_npz_mesh_renders_from_the_command_line(cl_device, tmp_path, monkeypatch):
    np.savez(tmp_path / "m.npz", vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                                                    [0, 0, 1.0]]),
             faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    monkeypatch.chdir(tmp_path)
    assert main(["render", "m.npz", "--view", "top", "-W", "40", "-H", "30", "-q"]) == 0
    assert (tmp_path / "m.png").stat().st_size > 0


def test_a_missing_mesh_file_is_named(tmp_path, capsys):
    assert main(["scene", str(tmp_path / "none.obj")]) == 3
    assert "none.obj: cannot read mesh file: file not found" in capsys.readouterr().err


# -- --up and models at the coordinate limit (issue 43) ----------------------------------------

_Y_UP = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [1, 2, 3]], dtype=float)
_FACES = [[1, 2, 3], [1, 3, 4], [2, 3, 4], [1, 2, 5]]


def _obj(path: Path, vertices: np.ndarray) -> Path:
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                    + "".join(f"f {a} {b} {c}\n" for a, b, c in _FACES))
    return path


@pytest.mark.parametrize("up", ["z", "-z", "x", "-x", "-y"])
def test_up_gives_the_scene_of_the_model_rotated_to_y_up(tmp_path, monkeypatch, up):
    from clray.model_scene import UP_ROTATIONS

    monkeypatch.chdir(tmp_path)
    rotation = np.array(UP_ROTATIONS[up], dtype=float)
    # The same model with `up` pointing up: rotated back (R^T) from the Y-up one.
    _obj(tmp_path / "yup.obj", _Y_UP)
    _obj(tmp_path / "other.obj", _Y_UP @ rotation)
    assert np.allclose((_Y_UP @ rotation) @ rotation.T, _Y_UP)
    for ground in (False, True):
        plain = model_scene_data(Path("yup.obj"), "front", ground)
        turned = model_scene_data(Path("other.obj"), "front", ground, up=up)
        assert "transform" not in plain["objects"][0]
        assert turned["objects"][0].pop("transform") == {"matrix": [
            *[[float(x) for x in row] + [0.0] for row in rotation], [0.0, 0.0, 0.0, 1.0]]}
        turned["objects"][0]["file"] = "yup.obj"
        assert turned == plain
        a, b = (load_model_scene(Path(n), "front", ground, u) for n, u in
                (("yup.obj", "y"), ("other.obj", up)))
        np.testing.assert_allclose(b.objects[0].vertices, a.objects[0].vertices, atol=1e-12)
        np.testing.assert_array_equal(b.objects[0].faces, a.objects[0].faces)


def test_up_with_a_scene_file_is_a_usage_error(capsys):
    assert main(["render", "scene.toml", "--up", "z"]) == 2
    assert "--up applies to a mesh file" in capsys.readouterr().err


def test_scene_command_writes_up(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _Y_UP)
    assert main(["scene", "m.obj", "--up", "z"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# The automatic scene of m.obj (clray scene --view three-quarter "
                          "--up=z).")
    assert "transform = {matrix = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, " \
        "0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]}" in out
    (tmp_path / "m.toml").write_text(out)
    written, direct = load_scene(tmp_path / "m.toml"), load_model_scene(Path("m.obj"), up="z")
    np.testing.assert_array_equal(written.objects[0].vertices, direct.objects[0].vertices)
    assert written.camera == direct.camera


def test_the_header_gives_a_command_that_writes_the_same_scene(tmp_path, monkeypatch, capsys):
    # It wrote `--up -x`, which the command line reads as --up without a value and a flag -x.
    import shlex

    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _Y_UP)
    assert main(["scene", "m.obj", "--up=-x", "--ground"]) == 0
    out = capsys.readouterr().out
    command = out.splitlines()[0].split("(", 1)[1].removesuffix(").")
    assert command == "clray scene --view three-quarter --ground --up=-x"
    assert main([*shlex.split(command)[1:], "m.obj"]) == 0
    assert capsys.readouterr().out == out


def test_a_negative_up_without_equals_is_told_how_to_write_it(capsys):
    assert main(["render", "m.obj", "--up", "-z"]) == 2
    assert "(a negative axis is written --up=-z)" in capsys.readouterr().err


@pytest.mark.parametrize("corner", [1e30, -1e30, "centred"])
def test_a_model_at_the_coordinate_limit_is_framed_within_it(tmp_path, monkeypatch, corner):
    # Valid vertices up to 1e30: the camera framing them from outside would stand beyond the
    # limit, which was refused as camera.position, a key the user never wrote.
    monkeypatch.chdir(tmp_path)
    if corner == "centred":
        # Centred on the origin: no offset to write, but the shrink was dropped with it.
        vertices = 3e29 * np.array([[-1, -1, -1], [1, 1, 1], [1, -1, 1], [-1, 1, 1],
                                    [1, 1, -1]])
    else:
        vertices = np.array([[0, 0, 0], [corner, 0, 0], [0, corner, 0], [0, 0, corner],
                             [corner, corner, corner]])
    _obj(tmp_path / "big.obj", vertices)
    scene = load_model_scene(Path("big.obj"), ground=True)
    mesh = scene.objects[0]
    assert np.max(np.abs(scene.camera.position)) <= 1e30
    assert np.max(np.abs(mesh.vertices)) <= 1e30
    # Still framed: the camera looks at the model's centre, from outside its sphere.
    centre = (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0)) / 2
    radius = np.linalg.norm(mesh.vertices - centre, axis=1).max()
    np.testing.assert_allclose(scene.camera.look_at, centre, atol=radius * 1e-5)
    assert np.linalg.norm(np.asarray(scene.camera.position) - centre) > radius



@pytest.mark.parametrize("name", ["scan.ply", "cornell_box.obj"])
def test_the_automatic_scene_reads_its_mesh_file_once(name, monkeypatch):
    # Framing the model and loading its scene share one read of the file (for a 5 M-triangle
    # PLY, half the load); each automatic scene, and a scene loaded after, reads it afresh.
    import clray.scene.assets as assets
    from clray.scene.load import scene_from_dict

    reads = []
    for reader in ("read_ply", "parse_obj"):
        real = getattr(assets, reader)
        monkeypatch.setattr(assets, reader,
                            lambda *a, real=real, **k: reads.append(1) or real(*a, **k))
    path = ROOT / "scenes" / "meshes" / name
    scene = load_model_scene(path)
    assert len(reads) == 1
    load_model_scene(path)
    assert len(reads) == 2
    again = scene_from_dict(model_scene_data(path))
    assert len(reads) == 4
    np.testing.assert_array_equal(again.objects[0].vertices, scene.objects[0].vertices)
    np.testing.assert_array_equal(again.objects[0].faces, scene.objects[0].faces)


# -- the automatic camera's numbers ---------------------------------------------------------


def _cube(path: Path, corner: tuple[float, float, float], side: float) -> np.ndarray:
    """An OBJ cube of `side` with its low corner at `corner`; its vertices as written."""
    vertices = np.array(corner) + side * np.array(
        [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    faces = [[1, 2, 4, 3], [5, 7, 8, 6], [1, 5, 6, 2], [3, 4, 8, 7], [1, 3, 7, 5], [2, 6, 8, 4]]
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                    + "".join("f " + " ".join(map(str, f)) + "\n" for f in faces))
    return vertices


def test_the_written_camera_keeps_every_digit(tmp_path, monkeypatch, capsys):
    # A 0.01-unit cube 4e6 from the origin (geographic coordinates): 6 significant digits
    # moved the camera and its look_at by half a unit, 50 times the model's size.
    monkeypatch.chdir(tmp_path)
    _cube(tmp_path / "geo.obj", (500000.0, 4000000.0, 100.0), 0.01)
    data = model_scene_data(Path("geo.obj"), "front")
    direct = load_model_scene(Path("geo.obj"), "front")
    vertices = direct.objects[0].vertices
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    assert data["camera"]["look_at"] == centre.tolist()
    eye = np.array(data["camera"]["position"])
    np.testing.assert_array_equal(eye[:2], centre[:2])  # the front view: along +z
    assert main(["scene", "geo.obj", "--view", "front"]) == 0
    (tmp_path / "geo.toml").write_text(capsys.readouterr().out)
    written = load_scene(tmp_path / "geo.toml")
    assert written.camera.position == tuple(data["camera"]["position"])
    assert written.camera.look_at == tuple(centre.tolist())
    assert written.camera == direct.camera and written.lights == direct.lights


def _framed_radius(data: dict) -> float:
    """The bounding radius the automatic camera frames (its distance over MARGIN / sin)."""
    from clray.model_scene import MARGIN, VFOV

    eye, at = np.array(data["camera"]["position"]), np.array(data["camera"]["look_at"])
    return float(np.linalg.norm(eye - at)) * np.sin(np.radians(VFOV) / 2) / MARGIN


@pytest.mark.parametrize(("corner", "side"), [((0.0, 0.0, 0.0), 2e-8),
                                              ((-1e-8, -1e-8, -1e-8), 2e-8),
                                              ((500000.0, 4000000.0, 100.0), 0.01),
                                              ((0.5, 0.5, 0.5), 1e-9)])
def test_a_small_model_is_framed_at_its_own_size(tmp_path, monkeypatch, corner, side):
    # The floor 1e-6 * max(|centre|, 1) framed a 2e-8 model at the origin as if 1e-6, and a
    # 0.01 one 4e6 from the origin as if 4 units.
    monkeypatch.chdir(tmp_path)
    vertices = _cube(tmp_path / "small.obj", corner, side)
    # The bounding sphere of the vertices as float64 has them (1e-9 at 0.5 is not exact).
    radius = np.linalg.norm(vertices - (vertices.min(axis=0) + vertices.max(axis=0)) / 2,
                            axis=1).max()
    np.testing.assert_allclose(_framed_radius(model_scene_data(Path("small.obj"), "front")), radius,
                               rtol=1e-6)


def test_a_model_below_what_float64_resolves_at_its_place_is_moved_to_the_origin(
        tmp_path, monkeypatch):
    # A 1e-5 cube 1e6 from the origin (below RESOLVED_RADIUS of its distance) was framed as
    # if 1e-4 in radius: a speck. Moved to the origin and scaled by a power of 2, it fills
    # the frame at a radius near 1.
    monkeypatch.chdir(tmp_path)
    vertices = _cube(tmp_path / "far.obj", (1e6, 0.0, 0.0), 1e-5)
    data = model_scene_data(Path("far.obj"), "front")
    matrix = np.array(data["objects"][0]["transform"]["matrix"])
    scale = matrix[0, 0]
    assert scale == 2.0 ** round(np.log2(scale))  # a power of 2: exact
    placed = vertices @ matrix[:3, :3].T + matrix[:3, 3]
    centre = (placed.min(axis=0) + placed.max(axis=0)) / 2
    radius = np.linalg.norm(placed - centre, axis=1).max()
    assert 0.5 < radius < 2 and np.all(np.abs(centre) < 1e-3)
    np.testing.assert_allclose(_framed_radius(data), radius, rtol=1e-6)


def test_the_camera_frames_only_the_vertices_faces_use(tmp_path, monkeypatch):
    # An `l` line's vertex (and a point's) draws nothing: the camera looked at (50, 50, 0).
    monkeypatch.chdir(tmp_path)
    (tmp_path / "l.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 100 100 0\nv -7 0 0\n"
                                    "f 1 2 3\nl 1 4\np 5\n")
    data = model_scene_data(Path("l.obj"), "front", ground=True)
    assert data["camera"]["look_at"] == [0.5, 0.5, 0.0]
    from clray.model_scene import GROUND_GAP

    assert data["objects"][1]["point"] == pytest.approx([0.5, -GROUND_GAP * 0.5 ** 0.5, 0.0])


@pytest.mark.parametrize(("arrays", "where"), [
    ({"faces": np.zeros((1, 3))}, "faces: expected an array of Nx3 integers"),
    ({"faces": np.array([[0, 1, 5]])}, "faces[0]: index 5 out of range"),
    ({"faces": np.array([[0, 1, 2]]), "uvs": np.zeros((3, 3))},
     "uvs: expected an array of Nx2 numbers")])
def test_an_npz_error_names_the_array(tmp_path, monkeypatch, capsys, arrays, where):
    # The array's name was dropped with the probe scene's key: "f.npz: expected an array of
    # Nx3 integers", of which array not said.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    np.savez(tmp_path / "sub" / "f.npz", vertices=np.zeros((3, 3)), **arrays)
    for command in ("scene", "render"):
        assert main([command, "sub/f.npz"]) == 3
        err = capsys.readouterr().err
        assert err.startswith(f"clray: error: sub/f.npz: {where}") and err.count("\n") == 1, err


def test_a_float16_npz_loads_without_numpy_warnings(tmp_path, monkeypatch):
    # The magnitude bound, 1e30, was cast to float16 (inf) with a RuntimeWarning printed.
    import warnings

    monkeypatch.chdir(tmp_path)
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float16)
    np.savez(tmp_path / "h.npz", vertices=vertices, faces=np.array([[0, 1, 2]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = load_model_scene(Path("h.npz")).objects[0]
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    # A value the writer overflowed to inf is refused in one line, as any other.
    vertices[1, 0] = np.inf
    np.savez(tmp_path / "h.npz", vertices=vertices, faces=np.array([[0, 1, 2]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(SceneError, match=r"h\.npz: vertices\[1\]: must be finite"):
            model_scene_data(Path("h.npz"))


def test_a_models_warnings_name_its_file_not_the_made_scenes_key(tmp_path, monkeypatch):
    """The automatic scene's warnings about the model began `objects[0].file: m.obj: `, a key
    of the scene clray made, which the user never wrote."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.mtl").write_text("newmtl m\nKd 1 0 0\nNi 0\nillum 2\n", encoding="utf-8")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\n"
                                    "f 1 2 3\n", encoding="utf-8")
    warnings = load_model_scene(Path("m.obj")).warnings
    ni = [w for w in warnings if "Ni 0" in w]
    assert len(ni) == 1 and ni[0].startswith("m.obj: line 1: m.mtl: line 3: "), warnings
    assert not any("objects[0]" in w for w in warnings), warnings
    # A scene file that names the mesh keeps the key it wrote.
    (tmp_path / "s.toml").write_text(
        '[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\n'
        '[[objects]]\ntype = "mesh"\nfile = "m.obj"\n', encoding="utf-8")
    assert any(w.startswith("objects[0].file: m.obj: line 1: m.mtl")
               for w in load_scene(Path("s.toml")).warnings)


def _placed_vertices(scene: M.Scene) -> np.ndarray:
    """The turntable's model as the frame places it: its group's mesh by its instance."""
    instance = scene.objects[0]
    return instance.group.objects[0].vertices @ instance.matrix[:, :3].T + instance.matrix[:, 3]


@pytest.mark.parametrize("up", ["y", "z"])
def test_a_turntable_turns_the_model_once_about_its_vertical_axis(tmp_path, monkeypatch,
                                                                  capsys, up):
    """`clray scene MODEL --turntable N` writes the still's scene with the model turned
    360 k / N degrees about the vertical through its centre in frame k, the rest still, and
    frames that share one packing (the model's BVH built once: docs/distributed.md)."""
    from clray.scene.transform import rotation_matrix
    from clray.sequence import load_sequence

    monkeypatch.chdir(tmp_path)
    _obj(tmp_path / "m.obj", _Y_UP)
    assert main(["scene", "m.obj", f"--up={up}", "--ground", "--turntable", "6"]) == 0
    out = capsys.readouterr().out
    assert "--ground --up=" in out.splitlines()[0] and "--turntable 6)." in out.splitlines()[0]
    (tmp_path / "turn.toml").write_text(out)
    sequence = load_sequence(tmp_path / "turn.toml")
    assert sequence.animation.frames == 6 and not sequence.packs_each_frame()
    still = load_model_scene(Path("m.obj"), up=up, ground=True)
    model = still.objects[0].vertices
    center = (model.min(axis=0) + model.max(axis=0)) / 2
    for k in range(6):
        frame = sequence.scene(k)
        assert (frame.camera, frame.lights, frame.objects[1]) == (still.camera, still.lights,
                                                                  still.objects[1])
        turned = (model - center) @ rotation_matrix((0.0, 60.0 * k, 0.0)).T + center
        np.testing.assert_allclose(_placed_vertices(frame), turned, rtol=0, atol=1e-12)


def test_a_turntable_renders_its_frames_with_one_bvh_build(cl_device, tmp_path, monkeypatch,
                                                           capsys, bvh_builds):
    from clray.sequence import load_sequence, render_frames

    monkeypatch.chdir(tmp_path)
    shutil.copy(ROOT / "scenes" / "meshes" / "bumpy_ico2.obj", tmp_path / "m.obj")
    assert main(["scene", "m.obj", "--turntable", "4"]) == 0
    (tmp_path / "turn.toml").write_text(capsys.readouterr().out)
    settings = RenderSettings(width=40, height=30, spp=1)
    sequence = load_sequence(tmp_path / "turn.toml")
    images: dict[int, np.ndarray] = {}
    render_frames(sequence, range(4), settings,
                  lambda frame, result: images.update({frame: result.image}))
    assert len(bvh_builds) == 1
    for k in range(4):
        np.testing.assert_array_equal(images[k], render(sequence.scene(k), settings).image)
    assert not np.array_equal(images[0], images[1])  # the bumps turned


def test_a_turntable_of_a_model_with_emissive_faces_is_refused_in_one_line(tmp_path,
                                                                           monkeypatch, capsys):
    # In the turntable's group its lamp would glow and light nothing (clray.scene.emitters).
    monkeypatch.chdir(tmp_path)
    for name in ("cornell_box.obj", "cornell_box.mtl"):
        shutil.copy(ROOT / "scenes" / "meshes" / name, tmp_path / name)
    assert main(["scene", "cornell_box.obj", "--turntable", "4"]) == 3
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "cornell_box.obj" in captured.err
    assert "emissive faces" in captured.err


def test_a_turntable_of_a_gltf_file_turns_its_nodes_meshes_and_repeats_its_header(
        tmp_path, monkeypatch, capsys):
    """A glTF file's nodes placed in the group (its instanced mesh copied for each node), the
    frames turning its triangles about the still's centre; the header's command writes the
    same file again."""
    import shlex

    from gltf_files import instanced_cubes

    from clray.sequence import load_sequence

    monkeypatch.chdir(tmp_path)
    instanced_cubes().save(tmp_path / "cubes.glb")
    assert main(["scene", "cubes.glb", "--turntable", "4", "-W", "80"]) == 0
    out = capsys.readouterr().out
    command = out.splitlines()[0].split("(", 1)[1].removesuffix(").")
    assert main([*shlex.split(command)[1:], "cubes.glb"]) == 0
    assert capsys.readouterr().out == out
    (tmp_path / "turn.toml").write_text(out)
    sequence = load_sequence(tmp_path / "turn.toml")
    still = load_model_scene(Path("cubes.glb"), width=80)
    count = sum(len(obj.faces) if isinstance(obj, M.Mesh) else len(obj.group.objects[0].faces)
                for obj in still.objects)
    for k in (0, 1):
        group = sequence.scene(k).objects[0].group
        assert sum(len(obj.faces) for obj in group.objects) == count
    assert sequence.scene(0).camera == still.camera


@pytest.mark.parametrize("frames", ["1", "0", "x"])
def test_a_turntable_needs_two_frames_or_more(capsys, frames):
    assert main(["scene", "m.obj", "--turntable", frames]) == 2
    assert "--turntable" in capsys.readouterr().err
