"""Scene files including others: merge rules, relative paths, cycles, and errors that name the
file and key where the problem is written."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clray.errors import SceneError
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent
CAMERA = '[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n'
GLASS = '[materials.glass]\ntransmit = 0.9\nior = 1.5\n'
SPHERE = '[[objects]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "{}"\n'


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def load_error(path: Path) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(path)
    return str(info.value)


def test_included_library_is_the_same_as_inline(tmp_path: Path) -> None:
    write(tmp_path, "lib/materials.toml", GLASS)
    with_include = write(tmp_path, "scene.toml",
                         'include = ["lib/materials.toml"]\n' + CAMERA + SPHERE.format("glass"))
    inline = write(tmp_path, "inline.toml", CAMERA + GLASS + SPHERE.format("glass"))
    a, b = load_scene(with_include), load_scene(inline)
    assert (a.materials, a.objects, a.camera, a.render) == (b.materials, b.objects, b.camera,
                                                          b.render)


def test_order_objects_lights_and_render_overrides(tmp_path: Path) -> None:
    write(tmp_path, "a.toml", '[render]\nwidth = 100\nspp = 4\n[[lights]]\ntype = "point"\n'
          'position = [1, 0, 0]\n' + SPHERE.format("m").replace("radius = 1", "radius = 0.5"))
    write(tmp_path, "b.toml", '[render]\nwidth = 200\n[[lights]]\ntype = "point"\n'
          'position = [2, 0, 0]\n[materials.m]\ndiffuse = 0.5\n')
    scene = load_scene(write(tmp_path, "scene.toml", 'include = ["a.toml", "b.toml"]\n'
                             '[render]\nheight = 50\n' + CAMERA + SPHERE.format("m")))
    # Included files in order, then the including file; later render values win, key by key.
    assert [light.position[0] for light in scene.lights] == [1.0, 2.0]
    assert [obj.radius for obj in scene.objects] == [0.5, 1.0]
    assert (scene.render.width, scene.render.height, scene.render.spp) == (200, 50, 4)


def test_relative_files_are_relative_to_the_including_file(tmp_path: Path) -> None:
    shutil.copy(ROOT / "tests" / "data" / "texels_3x2.png", tmp_path / "texels.png")
    write(tmp_path, "lib/deeper/m.toml",
          '[materials.t]\ntexture = { type = "image", file = "../../texels.png" }\n')
    scene = load_scene(write(tmp_path, "scenes/s.toml", 'include = ["../lib/deeper/m.toml"]\n'
                             + CAMERA + SPHERE.format("t")))
    direct = load_scene(write(tmp_path, "d.toml", CAMERA + SPHERE.format("t") +
                              '[materials.t]\ntexture = { type = "image", file = "texels.png" }\n'))
    np.testing.assert_array_equal(scene.materials[0].texture.image,
                                  direct.materials[0].texture.image)


def test_a_background_image_is_relative_to_the_file_that_gives_it(tmp_path: Path) -> None:
    # A sky.png beside the including file too, which the included file's name must not reach.
    shutil.copy(ROOT / "tests" / "data" / "texels_3x2.png", tmp_path / "sky.png")
    (tmp_path / "sub").mkdir()
    Image.fromarray(255 - np.array(Image.open(tmp_path / "sky.png"))).save(
        tmp_path / "sub" / "sky.png")
    write(tmp_path, "sub/env.toml", '[render]\nbackground = { type = "image", file = "sky.png" }\n')
    scene = load_scene(write(tmp_path, "s.toml", 'include = ["sub/env.toml"]\n' + CAMERA))
    direct = load_scene(write(tmp_path, "sub/d.toml", CAMERA + '[render]\n'
                              'background = { type = "image", file = "sky.png" }\n'))
    assert scene.render.background.file == tmp_path / "sub" / "sky.png"
    np.testing.assert_array_equal(scene.render.background.image,
                                  direct.render.background.image)


def test_a_linked_scene_reads_every_relative_name_beside_the_link(tmp_path: Path) -> None:
    """Includes were read beside the link's target, textures beside the link; now both
    beside the link, as a shell opens them. Each folder has its own library and image."""
    texels = np.array(Image.open(ROOT / "tests" / "data" / "texels_3x2.png"))
    for folder, ior, image in (("real", 1.5, texels), ("linked", 2.0, 255 - texels)):
        write(tmp_path, f"{folder}/lib.toml", f'[materials.t]\nior = {ior}\n'
              'texture = { type = "image", file = "t.png" }\n')
        Image.fromarray(image).save(tmp_path / folder / "t.png")
    write(tmp_path, "real/s.toml", 'include = ["lib.toml"]\n' + CAMERA + SPHERE.format("t")
          + '[render]\nbackground = { type = "image", file = "t.png" }\n')
    (tmp_path / "linked" / "s.toml").symlink_to(tmp_path / "real" / "s.toml")
    scene = load_scene(tmp_path / "linked" / "s.toml")
    assert scene.materials[0].ior == 2.0
    np.testing.assert_array_equal(scene.materials[0].texture.image,
                                  scene.render.background.image)
    assert scene.render.background.file == tmp_path / "linked" / "t.png"


def test_library_shared_by_two_includes_is_merged_once(tmp_path: Path) -> None:
    write(tmp_path, "lib.toml", GLASS)
    write(tmp_path, "a.toml", 'include = ["lib.toml"]\n')
    write(tmp_path, "b.toml", 'include = ["lib.toml"]\n')
    scene = load_scene(write(tmp_path, "s.toml", 'include = ["a.toml", "b.toml"]\n' + CAMERA +
                             SPHERE.format("glass")))
    assert [m.name for m in scene.materials] == ["glass"]


def test_json_includes_toml(tmp_path: Path) -> None:
    write(tmp_path, "lib.toml", GLASS)
    path = write(tmp_path, "s.json", '{"include": ["lib.toml"], "camera": {"position": [0, 0, 5],'
                 ' "look_at": [0, 0, 0]}, "objects": [{"type": "sphere", "center": [0, 0, 0], '
                 '"radius": 1, "material": "glass"}]}')
    assert load_scene(path).materials[0].transmit == 0.9


def test_cycle_shows_the_chain(tmp_path: Path) -> None:
    write(tmp_path, "a.toml", 'include = ["b.toml"]\n')
    write(tmp_path, "b.toml", 'include = ["a.toml"]\n')
    message = load_error(write(tmp_path, "s.toml", 'include = ["a.toml"]\n' + CAMERA))
    assert message == "b.toml: include[0]: includes itself: s.toml -> a.toml -> b.toml -> a.toml"


def test_files_in_other_folders_are_named_from_the_scenes_folder(tmp_path: Path) -> None:
    # Two libraries named lib.toml: "already defined in lib.toml" did not say which, nor did
    # a chain of files named a.toml.
    write(tmp_path, "wood/lib.toml", GLASS)
    write(tmp_path, "metal/lib.toml", GLASS)
    message = load_error(write(tmp_path, "s.toml",
                               'include = ["wood/lib.toml", "metal/lib.toml"]\n' + CAMERA))
    assert message == "lib.toml: materials.glass: already defined in wood/lib.toml"
    write(tmp_path, "x/a.toml", 'include = ["../y/a.toml"]\n')
    write(tmp_path, "y/a.toml", 'include = ["../x/a.toml"]\n' + CAMERA)
    message = load_error(write(tmp_path, "s.toml", 'include = ["x/a.toml"]\n' + CAMERA))
    assert message == ("a.toml: include[0]: includes itself: s.toml -> x/a.toml -> y/a.toml -> "
                       "x/a.toml")
    write(tmp_path, "x/a.toml", CAMERA)
    message = load_error(write(tmp_path, "s.toml", 'include = ["x/a.toml"]\n' + CAMERA))
    assert message == "s.toml: camera: already given in x/a.toml"


def test_a_cycle_through_a_link_is_shown_by_the_names_given(tmp_path: Path) -> None:
    # The chain names the files as the scenes name them: not where a symbolic link points
    # (../elsewhere/a.toml), which no scene wrote.
    write(tmp_path, "elsewhere/a.toml", 'include = ["a.toml"]\n')
    (tmp_path / "top").mkdir()
    (tmp_path / "top" / "lib").symlink_to(tmp_path / "elsewhere")
    message = load_error(write(tmp_path, "top/s.toml", 'include = ["lib/a.toml"]\n' + CAMERA))
    assert message == "a.toml: include[0]: includes itself: s.toml -> lib/a.toml -> lib/a.toml"


def test_self_include(tmp_path: Path) -> None:
    message = load_error(write(tmp_path, "s.toml", 'include = ["s.toml"]\n' + CAMERA))
    assert message == "s.toml: include[0]: includes itself: s.toml -> s.toml"


@pytest.mark.parametrize(("files", "message"), [
    ({"lib.toml": GLASS, "s.toml": 'include = ["lib.toml"]\n' + CAMERA + GLASS},
     "s.toml: materials.glass: already defined in lib.toml"),
    # Quoted as every key path is (values.key_path), not as Python's repr: 'my glass'.
    ({"lib.toml": '[materials."my glass"]\n', "s.toml": 'include = ["lib.toml"]\n' + CAMERA
      + '[materials."my glass"]\n'}, 's.toml: materials."my glass": already defined in lib.toml'),
    ({"lib.toml": CAMERA, "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "s.toml: camera: already given in lib.toml"),
    ({"lib.toml": '[materials.bad]\nior = 0\n', "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: materials.bad.ior: must be >= 0.01, got 0"),
    ({"lib.toml": SPHERE.format("m") + SPHERE.format("m").replace("radius = 1", "radius = -2"),
      "s.toml": 'include = ["lib.toml"]\n' + CAMERA + '[materials.m]\n' + SPHERE.format("m")},
     "lib.toml: objects[1].radius: must be > 0, got -2"),
    ({"lib.toml": SPHERE.format("nope"), "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     'lib.toml: objects[0].material: unknown material "nope" (defined: none)'),
    ({"lib.toml": '[render]\nspp = 0\n', "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: render.spp: must be an integer in [1, 4096], got 0"),
    # A value inside a render table is the file's that gave the table.
    ({"lib.toml": '[render]\nbackground = { type = "gradient", bottom = [2e6, 0, 0], '
                  'top = [1, 1, 1] }\n', "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: render.background.bottom: must be <= 1e+06"),
    ({"sub/env.toml": '[render]\nbackground = { type = "image", file = "sky.png" }\n',
      "s.toml": 'include = ["sub/env.toml"]\n' + CAMERA},
     "env.toml: render.background.file: file not found: sub/sky.png"),
    ({"s.toml": 'include = ["missing.toml"]\n' + CAMERA},
     "s.toml: include[0]: cannot read 'missing.toml': file not found"),
    ({"lib.toml": "[camera\n", "s.toml": 'include = ["lib.toml"]\n'},
     "lib.toml: invalid TOML"),
    ({"lib.yaml": "", "s.toml": 'include = ["lib.yaml"]\n'},
     "lib.yaml: unknown scene file type '.yaml'"),
    ({"lib.toml": "[objectz]\n", "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: objectz: unknown key"),
    ({"s.toml": 'include = "lib.toml"\n' + CAMERA},
     "s.toml: include: expected a list of file names"),
    # The value as written, not its Python type ("got list", "got int", "got dict").
    ({"lib.json": "[1, 2]", "s.toml": 'include = ["lib.json"]\n' + CAMERA},
     "lib.json: expected a table at the top level, got [1, 2]"),
    ({"lib.toml": "render = 5\n", "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: render: expected a table, got 5"),
    ({"lib.toml": "objects = { a = 1 }\n", "s.toml": 'include = ["lib.toml"]\n' + CAMERA},
     "lib.toml: objects: expected an array of tables, got a table"),
])
def test_errors_name_the_file_and_key_where_written(tmp_path: Path, files: dict,
                                                    message: str) -> None:
    for name, text in files.items():
        write(tmp_path, name, text)
    assert load_error(tmp_path / "s.toml").startswith(message)


def test_nesting_deeper_than_the_limit_is_refused(tmp_path: Path) -> None:
    for i in range(20):
        write(tmp_path, f"f{i}.toml", f'include = ["f{i + 1}.toml"]\n')
    write(tmp_path, "f20.toml", GLASS)
    assert "includes nested more than 16 deep" in load_error(tmp_path / "f0.toml")
