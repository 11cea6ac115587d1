"""`spheres` objects: many spheres from arrays (.npy, .npz, inline, numpy from Python), packed
and intersected exactly as that many sphere objects; their errors name the file and key."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.reference import render_reference
from clray.render import render
from clray.scene import model as M
from clray.scene.load import load_scene, scene_from_dict

HEAD = """
[render]
width = 40
height = 30
[camera]
position = [0, 3, 9]
look_at = [0, 0.5, 0]
[materials.a]
color = [0.9, 0.3, 0.2]
[materials.b]
color = [0.2, 0.5, 0.9]
specular = 0.6
reflect = 0.3
[[lights]]
type = "point"
position = [4, 6, 5]
[[objects]]
type = "plane"
point = [0, 0, 0]
normal = [0, 1, 0]
material = "a"
"""

CENTERS = np.array([[-1.5, 0.6, 0.0], [0.0, 0.8, -0.5], [1.4, 0.5, 0.4], [0.3, 1.9, 0.8]])
RADII = np.array([0.6, 0.8, 0.5, 0.3])
INDEX = np.array([0, 1, 1, 0])


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def one_by_one(folder: Path) -> Path:
    spheres = "".join(
        f'[[objects]]\ntype = "sphere"\ncenter = {c.tolist()}\nradius = {r}\n'
        f'material = "{"ab"[m]}"\n' for c, r, m in zip(CENTERS, RADII, INDEX, strict=True))
    return write(folder, "one_by_one.toml", HEAD + spheres)


@pytest.mark.parametrize("form", ["npz", "npy", "inline"])
def test_array_spheres_render_as_sphere_objects(cl_device, tmp_path: Path, form: str) -> None:
    if form == "npz":
        np.savez(tmp_path / "s.npz", centers=CENTERS, radii=RADII, material_index=INDEX)
        spec = 'file = "s.npz"\nmaterials = ["a", "b"]\n'
    elif form == "npy":
        np.save(tmp_path / "s.npy", np.column_stack([CENTERS, RADII]))
        spec = f'file = "s.npy"\nmaterials = ["a", "b"]\nmaterial_index = {INDEX.tolist()}\n'
    else:
        spec = (f'centers = {CENTERS.tolist()}\nradii = {RADII.tolist()}\n'
                f'materials = ["a", {{ color = [0.2, 0.5, 0.9], specular = 0.6, reflect = 0.3 }}]'
                f'\nmaterial_index = {INDEX.tolist()}\n')
    bulk = load_scene(write(tmp_path, "bulk.toml", HEAD + '[[objects]]\ntype = "spheres"\n' + spec))
    single = load_scene(one_by_one(tmp_path))
    assert isinstance(bulk.objects[1], M.Spheres) and len(single.objects) == 5
    got, want = render(bulk), render(single)
    np.testing.assert_array_equal(got.image, want.image)
    assert got.stats["rays"] == want.stats["rays"]
    np.testing.assert_allclose(render_reference(bulk), render_reference(single), rtol=0, atol=0)


def test_one_material_and_one_radius(cl_device, tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", CENTERS)
    scene = load_scene(write(tmp_path, "s.toml", HEAD + '[[objects]]\ntype = "spheres"\n'
                             'file = "c.npy"\nradius = 0.4\nmaterial = "b"\n'))
    spheres = scene.objects[1]
    np.testing.assert_array_equal(spheres.radii, 0.4)
    np.testing.assert_array_equal(spheres.materials, 1)
    expected = render_reference(scene)
    image = render(scene).image
    # Measured on PoCL and Intel's CPU runtime alike: largest error 9.16e-6.
    assert np.abs(image - expected).max() < 3.7e-5


def test_numpy_arrays_from_python() -> None:
    data = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
            "materials": {"m": {}},
            "objects": [{"type": "spheres", "centers": CENTERS.astype(np.float32), "radius": 0.1,
                         "material": "m"}]}
    np.testing.assert_array_equal(scene_from_dict(data).objects[0].centers,
                                  CENTERS.astype(np.float32))


@pytest.mark.parametrize(("spec", "files", "message"), [
    ('centers = [[0, 0, 0]]\n', {}, "objects[1]: a spheres object needs radius or radii"),
    ('radius = 1\n', {}, "objects[1]: a spheres object needs centers"),
    ('centers = [[0, 0]]\nradius = 1\n', {}, "objects[1].centers: expected an array of Nx3"),
    ('centers = [[0, 0, nan]]\nradius = 1\n', {}, "objects[1].centers[0]: must be finite"),
    ('centers = [[0, 0, 0], [1, 1, 1]]\nradii = [1, 0]\n', {},
     "objects[1].radii[1]: must be >= 1e-30, got 0"),
    ('centers = [[0, 0, 0]]\nradii = [1, 2]\n', {},
     "objects[1].radii: expected an array of 1 number, got [1, 2]"),
    # true and false are no numbers: np.asarray took them among numbers for 1 and 0.
    ('centers = [[0, true, 0]]\nradius = 1\n', {},
     "objects[1].centers[0][1]: expected a number, got true"),
    ('centers = [[0, 0, 0], [1, 1, 1]]\nradii = [1, true]\n', {},
     "objects[1].radii[1]: expected a number, got true"),
    ('centers = [[0, 0, 0], [1, 1, 1]]\nradius = 1\nmaterials = ["a", "a"]\n'
     'material_index = [0, true]\n', {},
     "objects[1].material_index[1]: expected an integer, got true"),
    ('centers = [[0, 0, 0]]\nradius = 1\nradii = [1]\n', {},
     "objects[1]: give radius or radii, not both"),
    ('centers = [[0, 0, 0]]\nradius = 1\nmaterials = ["a"]\nmaterial_index = [1]\n', {},
     "objects[1].material_index[0]: index 1 out of range (0-based, 1 material)"),
    ('centers = [[0, 0, 0]]\nradius = 1\nmaterials = ["a", "zz"]\nmaterial_index = [0]\n', {},
     'objects[1].materials[1]: unknown material "zz"'),
    ('centers = [[0, 0, 0]]\nradius = 1\nmaterials = ["a"]\n', {},
     "objects[1]: materials needs material_index"),
    ('centers = [[0, 0, 0]]\nradius = 1\nmaterial = "a"\nmaterials = ["a"]\n', {},
     "objects[1]: give material or materials, not both"),
    ('file = "c.npy"\ncenters = [[0, 0, 0]]\n', {"c.npy": np.zeros((1, 3))},
     "objects[1]: centers is in the file: give it there or as a key, not both"),
    ('file = "s.txt"\nradius = 1\n', {}, "objects[1].file: expected a .npy or .npz file"),
    ('file = "missing.npy"\nradius = 1\n', {}, "objects[1].file: file not found: missing.npy"),
    ('file = "bad.npy"\nradius = 1\n', {"bad.npy": b"not an array"}, "objects[1].file: cannot "
     "read bad.npy"),
    ('file = "obj.npy"\nradius = 1\n', {"obj.npy": "object"}, "objects[1].file: cannot read "
     "obj.npy"),
    ('file = "flat.npy"\nradius = 1\n', {"flat.npy": np.zeros(6)},
     "objects[1].file: flat.npy: expected an (N, 3) or (N, 4) array, got shape (6,)"),
    ('file = "x.npz"\nradius = 1\n', {"x.npz": {"centres": np.zeros((1, 3))}},
     "objects[1].file: x.npz holds centres (expected centers, radii, material_index)"),
    # np.load goes by a file's first bytes, not its name: each kind named as the other.
    ('file = "a.npz"\nradius = 1\n', {"a.npz": np.zeros((1, 3))},
     "objects[1].file: cannot read a.npz: not a .npz file"),
    ('file = "z.npy"\nradius = 1\n', {"z.npy": {"centers": np.zeros((1, 3))}},
     "objects[1].file: cannot read z.npy: not a .npy file"),
])
def test_errors_name_the_key(tmp_path: Path, spec: str, files: dict, message: str) -> None:
    for name, content in files.items():
        if isinstance(content, bytes):
            (tmp_path / name).write_bytes(content)
        elif isinstance(content, dict):
            with (tmp_path / name).open("wb") as file:  # np.savez would add .npz to z.npy
                np.savez(file, **content)
        elif isinstance(content, str):  # a pickled object array: never unpickled
            np.save(tmp_path / name, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        else:
            with (tmp_path / name).open("wb") as file:  # np.save would add .npy to a.npz
                np.save(file, content)
    path = write(tmp_path, "s.toml", HEAD + '[[objects]]\ntype = "spheres"\n' + spec)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"s.toml: {message}"), str(info.value)


def test_mesh_from_npz_equals_the_obj(tmp_path: Path) -> None:
    from clray.scene.obj import parse_obj

    root = Path(__file__).resolve().parent.parent
    obj = parse_obj((root / "tests" / "data" / "cube.obj").read_bytes(), Path("cube.obj"))
    arrays = {"vertices": obj.vertices, "faces": obj.faces}
    arrays |= {k: v for k, v in (("normals", obj.normals), ("uvs", obj.uvs)) if v is not None}
    np.savez(tmp_path / "cube.npz", **arrays)
    text = HEAD + '[[objects]]\ntype = "mesh"\nfile = "{}"\ntransform = {{ scale = 0.5 }}\n'
    shutil.copy(root / "tests" / "data" / "cube.obj", tmp_path / "cube.obj")
    a = load_scene(write(tmp_path, "a.toml", text.format("cube.npz"))).objects[1]
    b = load_scene(write(tmp_path, "b.toml", text.format("cube.obj"))).objects[1]
    for name in ("vertices", "faces", "normals", "uvs"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None)
        if y is not None:
            np.testing.assert_array_equal(x, y)


def test_mesh_npz_errors_name_the_array(tmp_path: Path) -> None:
    np.savez(tmp_path / "m.npz", vertices=np.zeros((3, 3)), faces=np.array([[0, 1, 3]]))
    path = write(tmp_path, "s.toml", HEAD + '[[objects]]\ntype = "mesh"\nfile = "m.npz"\n')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value) == ("s.toml: objects[1].file: m.npz: faces[0]: index 3 out of range "
                               "(0-based, 3 vertices)")


def test_a_mesh_npy_named_npz_is_refused_in_one_line(tmp_path: Path) -> None:
    with (tmp_path / "m.npz").open("wb") as file:
        np.save(file, np.zeros((3, 3)))
    path = write(tmp_path, "s.toml", HEAD + '[[objects]]\ntype = "mesh"\nfile = "m.npz"\n')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith("s.toml: objects[1].file: cannot read m.npz: not a .npz "
                                      "file")


def test_a_compressed_npz_is_sized_before_it_is_inflated(tmp_path: Path, monkeypatch) -> None:
    """A few hundred kilobytes of zip hold a faces array over the triangle limit, and spheres
    over the byte limit: refused from the headers, with no array inflated."""
    from clray.scene import assets, limits

    faces = np.zeros((limits.MAX_TRIANGLES + 1, 3), np.int32)
    np.savez_compressed(tmp_path / "m.npz", vertices=np.zeros((3, 3)), faces=faces)
    np.savez_compressed(tmp_path / "s.npz",
                        centers=np.zeros((limits.MAX_ARRAY_BYTES // 24 + 1, 3)))
    del faces
    assert (tmp_path / "m.npz").stat().st_size < limits.MAX_ARRAY_BYTES // 100

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("an array was inflated")

    monkeypatch.setattr(assets, "npz_arrays", never)
    mesh = write(tmp_path, "m.toml", HEAD + '[[objects]]\ntype = "mesh"\nfile = "m.npz"\n')
    with pytest.raises(SceneError) as info:
        load_scene(mesh)
    assert f"{limits.MAX_TRIANGLES + 1} triangles is over what is left" in str(info.value)
    spheres = write(tmp_path, "s.toml",
                    HEAD + '[[objects]]\ntype = "spheres"\nfile = "s.npz"\nradius = 1\n')
    with pytest.raises(SceneError) as info:
        load_scene(spheres)
    assert str(info.value).startswith("s.toml: objects[1].file: cannot read s.npz: its arrays "
                                      f"take {(limits.MAX_ARRAY_BYTES // 24 + 1) * 24} bytes "
                                      f"inflated, over the limit of {limits.MAX_ARRAY_BYTES}")
