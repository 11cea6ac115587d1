"""OBJ materials: `mtllib`/`usemtl` give each face its material, the MTL table of
docs/scene_format.md maps every illum model, problems are warnings or errors naming file and
line, and the kernels render each illum model and per-face materials as the float64 reference
renderer does."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene import model as M
from clray.scene.load import scene_from_dict
from clray.scene.mtl import MtlMaterial, to_material
from clray.scene.values import file_name
from tests.reference_check import Tolerance, assert_kernel_matches_reference

CAMERA = {"position": [0, 1.5, 5], "look_at": [0, 0.5, 0], "vfov": 40}

# A back wall (x in [-2, 2], y in [-1, 3] at z = -1) and a panel in front of it, tilted so that
# it reflects the floor side of the scene and refracts the wall.
WALL_AND_PANEL = """mtllib m.mtl
v -2 -1 -1
v 2 -1 -1
v 2 3 -1
v -2 3 -1
v -1 -0.5 0.5
v 1 -0.5 0.8
v 1 1.5 0.2
v -1 1.5 -0.1
usemtl wall
f 1 2 3 4
usemtl panel
f 5 6 7 8
"""
WALL = "newmtl wall\nKd 0.9 0.5 0.2\nKa 0.3 0.3 0.3\nillum 1\n"


def write(tmp_path: Path, obj: str, mtl: str | None, name: str = "m.obj") -> Path:
    (tmp_path / name).write_text(obj)
    if mtl is not None:
        (tmp_path / "m.mtl").write_text(mtl)
    return tmp_path / name


def scene_of(tmp_path: Path, mesh: dict | None = None, **render: object) -> M.Scene:
    data = {
        "render": {"width": 48, "height": 36, "background": [0.2, 0.3, 0.5], **render},
        "camera": CAMERA,
        "lights": [{"type": "point", "position": [2, 4, 4], "color": [1, 1, 1]}],
        "objects": [{"type": "mesh", "file": "m.obj", **(mesh or {})}],
    }
    return scene_from_dict(data, tmp_path / "s.toml")


def test_usemtl_gives_each_face_its_material(tmp_path):
    write(tmp_path, WALL_AND_PANEL, WALL + "newmtl panel\nKd 0 0 1\n")
    scene = scene_of(tmp_path)
    mesh = scene.objects[0]
    names = [scene.materials[i].name for i in mesh.face_materials]
    assert names == ["wall", "wall", "panel", "panel"]
    wall = scene.materials[mesh.face_materials[0]]
    assert wall.color == (0.9, 0.5, 0.2) and wall.ambient == pytest.approx(0.3)
    assert wall.specular == 0.0  # illum 1: no highlight
    assert scene.warnings == ()


def test_scene_material_overrides_the_files(tmp_path):
    write(tmp_path, WALL_AND_PANEL, "newmtl wall\nKd nonsense\n")  # not even read
    scene = scene_from_dict({"camera": CAMERA, "materials": {"red": {"color": [1, 0, 0]}},
                             "objects": [{"type": "mesh", "file": "m.obj",
                                          "material": "red"}]}, tmp_path / "s.toml")
    mesh = scene.objects[0]
    assert mesh.face_materials is None and scene.materials[mesh.material].name == "red"


def test_faces_before_usemtl_and_unknown_names_take_the_default(tmp_path):
    obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl nowhere\nf 1 2 3\n" \
          "usemtl wall\nf 1 2 3\n"
    write(tmp_path, obj, WALL)
    scene = scene_of(tmp_path)
    names = [scene.materials[i].name for i in scene.objects[0].face_materials]
    assert names == ["(default)", "(default)", "wall"]
    assert any("usemtl \"nowhere\"" in w and "m.obj" in w for w in scene.warnings)


def test_missing_library_is_a_warning_naming_file_and_line(tmp_path):
    write(tmp_path, "# comment\n" + WALL_AND_PANEL, None)
    scene = scene_of(tmp_path)
    assert any("m.obj: line 2: cannot read material library m.mtl: file not found" in w
               for w in scene.warnings), scene.warnings
    assert {scene.materials[i].name for i in scene.objects[0].face_materials} == {"(default)"}


@pytest.mark.parametrize("library", ["../m.mtl", "/nowhere/m.mtl", "http://x.test/m.mtl",
                                     "libs/m.mtl"])
def test_a_library_that_cannot_be_read_is_named_as_the_file_writes_it(tmp_path, library):
    # Its base name alone named another file: m.mtl beside the OBJ here, which can be read.
    write(tmp_path, f"mtllib {library}\n" + WALL_AND_PANEL.split("\n", 1)[1], WALL)
    scene = scene_of(tmp_path)
    shown = [w for w in scene.warnings if "cannot read material library" in w]
    assert len(shown) == 1 and "\n" not in shown[0], scene.warnings
    assert f"m.obj: line 1: cannot read material library {file_name(library)}: " in shown[0], \
        shown


@pytest.mark.parametrize("line, message", [
    ("Kd 1 x 1", "Kd: expected numbers"),
    ("Kd 1 1", "Kd: expected 1 or 3 numbers"),
    ("Ks -1 0 0", "Ks: components must be in"),
    ("Ni 0\nillum 4", "Ni: must be in [0.01, 100] (illum 4 refracts by it), got 0"),
    ("d 1.5", "d: must be in [0, 1]"),
    ("illum 11", "illum: expected an integer 0-10"),
    ("illum \u00b9", "illum: expected an integer 0-10, got '\u00b9'"),  # isdigit() takes it
    ("illum " + "9" * 5000, "illum: expected an integer 0-10, got '9999"),  # int() limit
    ("illum 1 2", "illum: expected an integer 0-10"),
    ("Kd spectral file.rfl", "the spectral form is not supported"),
])
def test_malformed_values_are_errors_naming_file_and_line(tmp_path, line, message):
    write(tmp_path, WALL_AND_PANEL, WALL + f"newmtl panel\n{line}\n")
    with pytest.raises(SceneError) as info:
        scene_of(tmp_path)
    assert "m.mtl: line 6:" in str(info.value) and message in str(info.value)


def test_illum_leading_zeros_are_read(tmp_path):
    write(tmp_path, WALL_AND_PANEL, WALL.replace("illum 1", "illum " + "0" * 5000 + "1"))
    mesh = scene_of(tmp_path).objects[0]
    assert mesh is not None


def test_unmodelled_keys_warn_once_per_key_and_file(tmp_path):
    mtl = WALL + "bump b.png\nPr 0.5\nnewmtl panel\nbump c.png\nmap_Ns n.png\n"
    write(tmp_path, WALL_AND_PANEL, mtl)
    warnings = [w for w in scene_of(tmp_path).warnings if "not modelled" in w]
    assert len(warnings) == 3
    assert all("m.mtl" in w for w in warnings)
    assert any("line 5: bump" in w for w in warnings)


def test_two_meshes_share_one_library_material(tmp_path):
    write(tmp_path, WALL_AND_PANEL, WALL + "newmtl panel\nKd 0 0 1\n")
    data = {"camera": CAMERA, "objects": [{"type": "mesh", "file": "m.obj"},
                                          {"type": "mesh", "file": "m.obj"}]}
    scene = scene_from_dict(data, tmp_path / "s.toml")
    assert len(scene.materials) == 3  # wall, panel, (default)
    np.testing.assert_array_equal(scene.objects[0].face_materials,
                                  scene.objects[1].face_materials)


# The table of docs/scene_format.md, model by model: (reflect, transmit, ior, fresnel, specular,
# diffuse) for Ks 0.4, Ni 1.3, Tf 0.6, d 1.
ILLUM_TABLE = {
    0: (0.0, 0.0, 1.0, False, 0.0, 0.0),
    1: (0.0, 0.0, 1.0, False, 0.0, 1.0),
    2: (0.0, 0.0, 1.0, False, 0.4, 1.0),
    3: (0.4, 0.0, 1.0, False, 0.4, 1.0),
    4: (0.4, 0.6, 1.3, False, 0.4, 1.0),
    5: (0.4, 0.0, 1.0, False, 0.4, 1.0),
    6: (0.4, 0.6, 1.3, False, 0.4, 1.0),
    7: (0.4, 0.6, 1.3, True, 0.4, 1.0),
    8: (0.4, 0.0, 1.0, False, 0.4, 1.0),
    9: (0.0, 0.6, 1.3, False, 0.4, 1.0),
    10: (0.0, 0.0, 1.0, False, 0.4, 1.0),
}


@pytest.mark.parametrize("illum", sorted(ILLUM_TABLE))
def test_illum_table(illum):
    mtl = MtlMaterial("m", 1, colors={"Kd": (0.5, 0.5, 0.5), "Ks": (0.4, 0.4, 0.4),
                                      "Tf": (0.6, 0.6, 0.6)},
                      numbers={"Ni": 1.3, "Ns": 50.0}, illum=illum)
    m = to_material(mtl)
    got = (m.reflect, m.transmit, m.ior, m.fresnel, m.specular, m.diffuse)
    assert got == pytest.approx(ILLUM_TABLE[illum])


def test_dissolve_sees_through_without_bending():
    m = to_material(MtlMaterial("m", 1, numbers={"d": 0.25, "Ni": 1.5}, illum=2))
    assert (m.transmit, m.ior) == (0.75, 1.0)
    assert to_material(MtlMaterial("m", 1, numbers={"Tr": 0.25})).transmit == 0.25


@pytest.mark.parametrize("illum", [0, 1, 2, 3, 5, 8, 10])
def test_dissolve_applies_to_every_model_without_glass(illum):
    # "Dissolve works on all illumination models" (the MTL spec), constant colour included.
    m = to_material(MtlMaterial("m", 1, numbers={"d": 0.5, "Ni": 1.5}, illum=illum))
    assert (m.transmit, m.ior) == (0.5, 1.0)


# Four times the worst measured over the illum models (rmse 6.4e-7, largest error 5.3e-6 in a
# channel; PoCL 3.1, AMD EPYC).
TOLERANCE = Tolerance(rmse=2.6e-6, err=2.2e-5)

PANELS = {
    0: "Kd 0.2 0.8 0.3\nd 0.6",
    1: "Kd 0.2 0.8 0.3\nKa 0.2 0.2 0.2",
    2: "Kd 0.2 0.8 0.3\nKs 0.5 0.5 0.5\nNs 40",
    3: "Kd 0.2 0.3 0.3\nKs 0.6 0.6 0.6\nNs 40",
    4: "Kd 0.1 0.1 0.1\nKs 0.2 0.2 0.2\nTf 0.7 0.7 0.7\nNi 1.4",
    5: "Kd 0.2 0.3 0.3\nKs 0.6 0.6 0.6\nNs 40",
    6: "Kd 0.1 0.1 0.1\nKs 0.2 0.2 0.2\nTf 0.7 0.7 0.7\nNi 1.4",
    7: "Kd 0.1 0.1 0.1\nKs 0.1 0.1 0.1\nTf 0.8 0.8 0.8\nNi 1.5",
    8: "Kd 0.2 0.3 0.3\nKs 0.6 0.6 0.6\nNs 40",
    9: "Kd 0.1 0.1 0.1\nTf 0.7 0.7 0.7\nNi 1.4\nd 0.5",
    10: "Kd 0.2 0.8 0.3\nKs 0.5 0.5 0.5",
}


@pytest.mark.parametrize("illum", sorted(PANELS))
def test_each_illum_model_matches_the_reference(cl_device, tmp_path, illum):
    write(tmp_path, WALL_AND_PANEL, WALL + f"newmtl panel\n{PANELS[illum]}\nillum {illum}\n")
    scene = scene_of(tmp_path, max_depth=4)
    assert_kernel_matches_reference(scene, TOLERANCE)


def test_alternating_face_materials_match_the_reference(cl_device, tmp_path):
    # A 6 x 6 grid of quads, checkered by usemtl.
    n = 6
    lines = ["mtllib m.mtl"]
    lines += [f"v {x - n / 2} {y - n / 2 + 0.5} 0" for y in range(n + 1) for x in range(n + 1)]
    for y in range(n):
        for x in range(n):
            a = y * (n + 1) + x + 1
            lines += [f"usemtl {'red' if (x + y) % 2 else 'blue'}",
                      f"f {a} {a + 1} {a + n + 2} {a + n + 1}"]
    write(tmp_path, "\n".join(lines) + "\n",
          "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\nKs 0.5 0.5 0.5\nillum 2\n")
    scene = scene_of(tmp_path)
    names = [scene.materials[i].name for i in scene.objects[0].face_materials]
    assert names == [("red" if (k // 2 % n + k // 2 // n) % 2 else "blue")
                     for k in range(2 * n * n)]
    assert_kernel_matches_reference(scene, TOLERANCE)


QUAD_UV = """mtllib mats/m.mtl
v -1 -1 0
v 1 -1 0
v 1 1 0
v -1 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl tex
f 1/1 2/2 3/3 4/4
"""
DATA = Path(__file__).resolve().parent / "data"


def textured_quad(tmp_path: Path, map_kd: str) -> None:
    (tmp_path / "mats").mkdir()
    (tmp_path / "m.obj").write_text(QUAD_UV)
    (tmp_path / "mats" / "m.mtl").write_text(f"newmtl tex\nKd 1 1 1\nKs 0.3 0.3 0.3\n"
                                             f"illum 2\n{map_kd}\n")
    (tmp_path / "mats" / "tex").mkdir()
    (tmp_path / "mats" / "tex" / "t.png").write_bytes((DATA / "texels_3x2.png").read_bytes())


def test_map_kd_on_a_quad_equals_the_same_texture_in_the_scene(cl_device, tmp_path):
    from clray.render import render

    textured_quad(tmp_path, "map_Kd -s 2 1 1 tex/t.png")  # relative to the MTL file
    from_mtl = scene_of(tmp_path)
    material = from_mtl.materials[from_mtl.objects[0].face_materials[0]]
    assert material.texture is not None and material.texture.repeat == (2.0, 1.0)
    in_scene = scene_of(tmp_path, {"material": {
        "color": [1, 1, 1], "specular": 0.3, "texture": {
            "type": "image", "file": "mats/tex/t.png", "repeat": [2, 1]}}})
    assert in_scene.objects[0].face_materials is None
    image = render(from_mtl).image
    np.testing.assert_array_equal(image, render(in_scene).image)
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 6  # the texels show


def test_missing_texture_is_a_warning_and_the_material_keeps_kd(tmp_path):
    textured_quad(tmp_path, "map_Kd -o 0.5 0 0 -bm 2 tex/none.png")
    scene = scene_of(tmp_path)
    material = scene.materials[scene.objects[0].face_materials[0]]
    assert material.texture is None and material.color == (1.0, 1.0, 1.0)
    text = "\n".join(scene.warnings)
    assert "m.mtl: line 5: map_Kd" in text and "file not found" in text
    assert "option -o is not modelled" in text and "option -bm is not modelled" in text


@pytest.mark.parametrize("written, message", [
    # Joined to the MTL file's folder, the URL read "mats/http:/x.test/t.png".
    ("http://x.test/t.png", "file not found: {}"),
    ("tex//none.png", "file not found: {}"),
    ("./tex/bad.png", "cannot read image {}: not an image"),
])
def test_a_texture_that_cannot_be_read_is_named_as_the_mtl_file_writes_it(tmp_path, written,
                                                                         message):
    textured_quad(tmp_path, f"map_Kd {written}")
    (tmp_path / "mats" / "tex" / "bad.png").write_bytes(b"not an image")
    scene = scene_of(tmp_path)
    assert scene.materials[scene.objects[0].face_materials[0]].texture is None
    shown = [w for w in scene.warnings if "keeps Kd" in w]
    assert len(shown) == 1, scene.warnings
    where = "objects[0].file: m.obj: line 1: mats/m.mtl: line 5: map_Kd: "
    assert shown[0].startswith(where + message.format(file_name(written))), shown


@pytest.mark.parametrize("line, message", [
    ("map_Kd", "expected an image file name"),
    ("map_Kd -s x t.png", "-s: expected numbers"),
    ("map_Kd -s 0 1 t.png", "-s: scales must be > 0"),
    ("map_Kd -t x t.png", "-t: expected numbers"),
])
def test_malformed_map_kd_is_an_error(tmp_path, line, message):
    textured_quad(tmp_path, line)
    with pytest.raises(SceneError) as info:
        scene_of(tmp_path)
    assert "m.mtl: line 5:" in str(info.value) and message in str(info.value)


def test_a_python_built_mesh_with_face_materials_is_checked_and_kept():
    from clray.scene.check import check_scene

    red, blue = M.Material("red", color=(1, 0, 0)), M.Material("blue", color=(0, 0, 1))
    mesh = M.Mesh(vertices=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]),
                  faces=np.array([[0, 1, 2], [0, 2, 3]]), material=0,
                  face_materials=np.array([1, 0]))
    scene = M.Scene(None, M.RenderOptions(width=8, height=6),
                    M.Camera((0.5, 0.5, 3), (0.5, 0.5, 0)), (red, blue), (), (mesh,))
    checked = check_scene(scene)
    picked = [checked.materials[i].name for i in checked.objects[0].face_materials]
    assert picked == ["blue", "red"]
    bad = M.Scene(None, scene.render, scene.camera, (red, blue), (),
                  (M.Mesh(mesh.vertices, mesh.faces, 0, face_materials=np.array([0, 2])),))
    with pytest.raises(SceneError, match=r"objects\[0\]\.material_index\[1\]: index 2 out of"):
        check_scene(bad)


def test_a_mesh_material_index_takes_no_booleans(tmp_path):
    # np.asarray took true among the integers for 1: the second face took material b.
    data = {"camera": CAMERA, "materials": {"a": {}, "b": {}},
            "objects": [{"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                         "faces": [[0, 1, 2], [0, 2, 1]], "materials": ["a", "b"],
                         "material_index": [0, True]}]}
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, tmp_path / "s.toml")
    assert str(info.value) == "s.toml: objects[0].material_index[1]: expected an integer, got true"


def test_inline_mesh_materials_need_an_index_per_triangle(tmp_path):
    base = {"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]}
    for extra, message in [({"materials": ["a"]}, "materials needs material_index"),
                           ({"material_index": [0]}, "only with materials"),
                           ({"materials": ["a"], "material_index": [0, 0]}, "expected an array"),
                           ({"materials": ["a"], "material": "a", "material_index": [0]},
                            "give material or materials, not both")]:
        data = {"camera": CAMERA, "materials": {"a": {}}, "objects": [{**base, **extra}]}
        with pytest.raises(SceneError, match=message):
            scene_from_dict(data, tmp_path / "s.toml")


def test_a_byte_order_mark_is_not_part_of_the_first_key():
    from clray.scene.mtl import parse_mtl

    library = parse_mtl(b"\xef\xbb\xbfnewmtl a\nKd 0 0 1\n", Path("m.mtl"), "m.mtl")
    assert library.materials["a"].colors == {"Kd": (0.0, 0.0, 1.0)}
    assert library.warnings == []


@pytest.mark.parametrize("line, file, scale, ignored", [
    # -s, -o and -t take u and optionally v and w: only the numbers after them are theirs.
    ("map_Kd -t 0.1 wood.png", "wood.png", (1.0, 1.0), ("-t",)),
    ("map_Kd -t 0.1 0.2 -s 2 wood.png", "wood.png", (2.0, 1.0), ("-t",)),
    ("map_Kd -t 0 0 0 -o 0 -s 2 3 1 my wood.png", "my wood.png", (2.0, 3.0), ()),
    ("map_Kd -o 0.5 -clamp on -t 0 0.5 wood.png", "wood.png", (1.0, 1.0), ("-o", "-clamp", "-t")),
])
def test_map_options_take_the_numbers_that_follow(line, file, scale, ignored):
    from clray.scene.mtl import parse_mtl

    texture = parse_mtl(f"newmtl a\n{line}\n".encode(), Path("m.mtl"), "m.mtl") \
        .materials["a"].map_kd
    assert (texture.file, texture.scale, texture.ignored) == (file, scale, ignored)


@pytest.mark.parametrize("first", ["root:x:0:0:root:/root:/bin/bash",
                                   "\x1b[31mSECRET\x1b[0m" + "A" * 200, "\u00ff\u00fe binary"])
def test_a_file_that_is_not_a_material_library_is_said_so_without_its_text(tmp_path, first):
    # The review's `mtllib ../../etc/passwd`: the error echoed the file's first word, whole.
    (tmp_path / "sub").mkdir()
    (tmp_path / "notes.txt").write_text(f"# a comment\n\n{first}\nnewmtl m\n")
    write(tmp_path, "# header\nmtllib ../notes.txt\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
          "f 1 2 3\n", None, "sub/m.obj")
    data = {"camera": CAMERA, "objects": [{"type": "mesh", "file": "sub/m.obj"}]}
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, tmp_path / "s.toml")
    assert str(info.value) == ("notes.txt: line 3: not a material library: its first "
                               "statement is not an MTL one (expected newmtl) (sub/m.obj line "
                               "2 names it in mtllib)")


def test_a_key_before_newmtl_names_the_objs_mtllib_line(tmp_path):
    # Which reference is wrong: the OBJ file and its mtllib line, with the library's line.
    write(tmp_path, WALL_AND_PANEL, "Kd 1 0 0\nnewmtl wall\n")
    with pytest.raises(SceneError) as info:
        scene_of(tmp_path)
    assert str(info.value) == ("m.mtl: line 1: Kd before the first newmtl (m.obj line 1 "
                               "names it in mtllib)")


@pytest.mark.parametrize(("line", "message"), [
    ("Kd 1 " + "x" * 200, "Kd: expected numbers, got '1 " + "x" * 38 + "...'"),
    ("illum " + "\x1b" * 100, "illum: expected an integer 0-10, got '" + "\\x1b" * 40 + "...'"),
])
def test_text_a_value_error_echoes_is_cut(tmp_path, line, message):
    write(tmp_path, WALL_AND_PANEL, WALL + f"newmtl panel\n{line}\n")
    with pytest.raises(SceneError) as info:
        scene_of(tmp_path)
    assert str(info.value).endswith(f"m.mtl: line 6: {message} (m.obj line 1 names it in "
                                    "mtllib)")


def test_a_long_unmodelled_key_is_cut_in_its_warning(tmp_path):
    write(tmp_path, WALL_AND_PANEL, WALL + "P" * 300 + " 1\n")
    said = [w for w in scene_of(tmp_path).warnings if "not modelled" in w]
    assert len(said) == 1 and "line 5: " + "P" * 40 + "... is not modelled" in said[0]
    assert "P" * 41 not in said[0]


@pytest.mark.parametrize("illum", [None, 0, 1, 2, 3, 5, 8, 10])
def test_ni_outside_its_range_is_unset_with_a_warning_where_nothing_refracts(tmp_path, illum):
    # Blender 2.62 writes `Ni 0.000000` for every material: the whole model was refused.
    block = "newmtl panel\nKd 0 0 1\nNi 0.000000\n" + (f"illum {illum}\n" if illum is not None
                                                      else "")
    write(tmp_path, WALL_AND_PANEL, WALL + block)
    scene = scene_of(tmp_path)
    panel = scene.materials[scene.objects[0].face_materials[2]]
    assert panel.name == "panel" and panel.ior == 1.0
    assert [w for w in scene.warnings if "Ni" in w] == [
        "objects[0].file: m.obj: line 1: m.mtl: line 7: Ni 0 is outside [0.01, 100]: read as "
        "unset (material 'panel' does not refract)"]


@pytest.mark.parametrize("illum", [4, 6, 7, 9])
def test_ni_outside_its_range_is_refused_where_the_material_refracts(tmp_path, illum):
    # illum after Ni, as exporters write it: the block's illum decides.
    write(tmp_path, WALL_AND_PANEL, WALL + f"newmtl panel\nNi 0\nTf 1 1 1\nillum {illum}\n"
          "newmtl other\nKd 1 1 1\n")
    with pytest.raises(SceneError) as info:
        scene_of(tmp_path)
    assert str(info.value) == (f"m.mtl: line 6: Ni: must be in [0.01, 100] (illum {illum} "
                               "refracts by it), got 0 (m.obj line 1 names it in mtllib)")


def test_a_later_ni_in_range_replaces_one_outside(tmp_path):
    write(tmp_path, WALL_AND_PANEL, WALL + "newmtl panel\nNi 0\nNi 1.5\nillum 4\n")
    scene = scene_of(tmp_path)
    assert scene.materials[scene.objects[0].face_materials[2]].ior == 1.5
    assert not [w for w in scene.warnings if "Ni" in w]


def test_cr_only_line_ends_are_read_as_lf_ones(tmp_path):
    # Classic Mac OS text: the OBJ reader saw one line ("line 1: expected a number, got 'v'"),
    # and the MTL one a single statement.
    lf_obj, lf_mtl = WALL_AND_PANEL, WALL + "newmtl panel\nKd 0 0 1\nillum 3\n"
    write(tmp_path, lf_obj, lf_mtl)
    want = scene_of(tmp_path)
    write(tmp_path, lf_obj.replace("\n", "\r"), lf_mtl.replace("\n", "\r"))
    got = scene_of(tmp_path)
    assert got.warnings == want.warnings == ()
    np.testing.assert_array_equal(got.objects[0].vertices, want.objects[0].vertices)
    np.testing.assert_array_equal(got.objects[0].faces, want.objects[0].faces)
    assert [got.materials[i] for i in got.objects[0].face_materials] == \
        [want.materials[i] for i in want.objects[0].face_materials]


def test_cr_only_line_ends_keep_line_numbers_in_errors(tmp_path):
    write(tmp_path, WALL_AND_PANEL.replace("\n", "\r"),
          (WALL + "newmtl panel\nKd 1 x 1\n").replace("\n", "\r"))
    with pytest.raises(SceneError, match=r"m\.mtl: line 6: Kd: expected numbers"):
        scene_of(tmp_path)
    write(tmp_path, "v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 9\r", None)
    with pytest.raises(SceneError, match=r"m\.obj: line 4: f: vertex index 9 out of range"):
        scene_of(tmp_path)
