"""Scenes built in Python from the model's dataclasses, checked by the scene file's rules.

The rules live in one place, the loader (clray.scene.load). A Scene that the loader did not
make is written back into the file format's dict form (arrays stay arrays, so a large mesh is
checked at numpy speed) and loaded again: a hand-built scene meets the same checks, with the
same one-line messages naming the key (`objects[3].radius`), as a scene file, and comes back
normalised as a loaded scene is (unit directions and normals).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from clray.errors import SceneError, plural
from clray.lights import LIGHT_OF, LISTED
from clray.scene import model as M
from clray.scene.load import scene_from_dict
from clray.scene.values import Values
from clray.shapes import SHAPES

_OBJECT_TYPES: dict[type, str] = {
    **{shape.model: shape.kind for shape in SHAPES}, M.Plane: "plane", M.Triangle: "triangle",
    M.Mesh: "mesh", M.Spheres: "spheres",
}
_MESH_ARRAYS = ("vertices", "faces", "normals", "uvs", "colors")
# No field that _plain writes as a list holds more (a triangle's 3x3 vertices, a colour):
# a longer or deeper value goes to the loader as it is and is refused there, rather than
# copied element by element (a self-referencing list, or a large array, never ends or fills
# memory).
_PLAIN_ITEMS = 16
_PLAIN_DEPTH = 3


def check_scene(scene: M.Scene) -> M.Scene:
    """`scene` itself if the loader made it, else the same scene checked and normalised by the
    loader; SceneError (a one-line message naming the key) if something is wrong."""
    # The type first: any object may carry an attribute named `checked`.
    if not isinstance(scene, M.Scene):
        raise SceneError(None, None, f"expected a clray Scene, got {type(scene).__name__}")
    if scene.checked:
        return scene
    return scene_from_dict(scene_to_dict(scene), _path(scene.path))


def _path(path: Any) -> Path | None:
    if path is None:
        return None
    try:
        return Path(path)
    except TypeError:
        raise SceneError(None, "path", f"expected a path or None, got "
                         f"{type(path).__name__}") from None


def _expect(value: Any, kind: type | tuple[type, ...], key: str, what: str) -> None:
    """A Scene's (or Group's) field of the wrong type would fail in the conversion below with
    an AttributeError or TypeError: refused first, naming the field."""
    if not isinstance(value, kind):
        raise SceneError(None, key, f"expected {what}, got {type(value).__name__}")


def scene_to_dict(scene: M.Scene) -> dict:
    """The scene in the scene file's form (docs/scene_format.md), as scene_from_dict takes it."""
    _expect(scene.render, M.RenderOptions, "render", "a RenderOptions")
    for field in ("materials", "lights", "objects"):
        _expect(getattr(scene, field), tuple | list, field, "a tuple")
    names = _material_names(scene.materials)
    render = {f.name: _plain(getattr(scene.render, f.name))
              for f in dataclasses.fields(M.RenderOptions)}
    if isinstance(scene.render.background, M.Background):
        render["background"] = _background(scene.render.background)
    groups = _group_names(scene.objects)
    return {
        "render": render,
        "camera": _camera(scene.camera),
        "materials": {name: _material(m, f"materials[{i}]")
                      for i, (name, m) in enumerate(zip(names, scene.materials, strict=True))},
        "groups": {name: {"objects": [_object(obj, f"groups.{name}.objects[{j}]", names, {})
                                      for j, obj in enumerate(group.objects)]}
                   for name, group in groups.values()},
        "lights": [_light(light, i) for i, light in enumerate(scene.lights)],
        "objects": [_object(obj, f"objects[{i}]", names, groups)
                    for i, obj in enumerate(scene.objects)],
    }


def _group_names(objects: tuple) -> dict[int, tuple[str, M.Group]]:
    """A unique table key per group the instances use (by identity), its own name where that
    is unique."""
    groups: dict[int, M.Group] = {}
    for i, obj in enumerate(objects):
        if isinstance(obj, M.Instance):
            _expect(obj.group, M.Group, f"objects[{i}].group", "a Group")
            _expect(obj.group.objects, tuple | list, f"objects[{i}].group.objects", "a tuple")
            groups.setdefault(id(obj.group), obj.group)
    given = [g.name if isinstance(g.name, str) else "" for g in groups.values()]
    return dict(zip(groups, zip(_unique_names(given, "group"), groups.values(), strict=True),
                    strict=True))


def _unique_names(given: list[str], fallback: str) -> list[str]:
    """A table key for each item: its own name where that is given once, else a fallback
    (`material 3`) that is none of the names kept, nor another fallback: two items under one
    key would leave one of them out of the table, and objects would take the other."""
    counts = Counter(given)
    taken = {name for name in given if name and counts[name] == 1}
    names = []
    for i, name in enumerate(given):
        if not (name and counts[name] == 1):
            name, again = f"{fallback} {i}", 1
            while name in taken:
                again += 1
                name = f"{fallback} {i} ({again})"
            taken.add(name)
        names.append(name)
    return names


def _plain(value: Any, depth: int = 0) -> Any:
    """Numbers and small vectors as the parsers give them: Python scalars and lists (the
    loader refuses numpy scalars and tuples nowhere, but lists keep its messages alike)."""
    if isinstance(value, np.ndarray) and value.ndim == 0:  # not iterable
        value = value[()]
    if isinstance(value, np.bool_ | np.number | np.str_):
        return value.item()
    if isinstance(value, np.ndarray | tuple | list):
        if depth >= _PLAIN_DEPTH or len(value) > _PLAIN_ITEMS:
            return value
        return [_plain(v, depth + 1) for v in value]
    return value


def _material_names(materials: tuple[M.Material, ...]) -> list[str]:
    """A unique table key per material, its own name where that is unique."""
    return _unique_names([m.name if isinstance(m, M.Material) and isinstance(m.name, str)
                          else "" for m in materials], "material")


def _fields(obj: object, skip: tuple[str, ...] = ()) -> dict:
    return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)
            if f.name not in skip and getattr(obj, f.name) is not None}


def _camera(camera: M.Camera) -> dict:
    if not isinstance(camera, M.Camera):
        raise SceneError(None, "camera", f"expected a Camera, got {type(camera).__name__}")
    return _fields(camera)


def _material(material: M.Material, key: str) -> dict:
    if not isinstance(material, M.Material):
        raise SceneError(None, key, f"expected a Material, got {type(material).__name__}")
    spec = _fields(material, skip=("name", "texture"))
    texture = material.texture
    if texture is not None:
        if not isinstance(texture, M.Texture):
            raise SceneError(None, "texture", f"expected a Texture, got {type(texture).__name__}")
        spec["texture"] = _texture(texture)
    return spec


def _texture(texture: M.Texture) -> dict:
    # Any kind but a string goes to the loader as it is (an array's == would not be a bool).
    if isinstance(texture.kind, str) and texture.kind == "checker":
        return {"type": "checker", **_fields(texture, skip=(
            "kind", "file", "repeat", "colorspace", "image"))}
    return {"type": texture.kind, "repeat": _plain(texture.repeat), "blend": texture.blend,
            **_image_source(texture)}


def _image_source(image: M.Texture | M.Background) -> dict:
    """An image texture's or panorama's texels (already linear: what the file decoded to), or
    its file where it has no texels."""
    if image.image is not None:
        return {"texels": image.image}
    if image.file is None:
        return {}
    spec = {"file": str(image.file)}
    if image.colorspace is not None:
        spec["colorspace"] = image.colorspace
    return spec


def _background(background: M.Background) -> dict:
    if isinstance(background.kind, str) and background.kind == "gradient":
        return {"type": "gradient", "bottom": _plain(background.bottom),
                "top": _plain(background.top)}
    return {"type": background.kind, **_image_source(background)}


def _light(light: M.Light, i: int) -> dict:
    kind = LIGHT_OF.get(type(light))
    if kind is None or not kind.listed:
        shown = ", ".join(k.model.__name__ for k in LISTED.values())
        raise SceneError(None, f"lights[{i}]", f"expected one of {shown}, got "
                         f"{type(light).__name__}")
    return {"type": kind.kind, **_fields(light)}


def _instance(obj: M.Instance, key: str, names: list[str],
              groups: dict[int, tuple[str, M.Group]]) -> dict:
    # Numbers only, by the loader's array check: np.asarray(..., float64) would turn strings,
    # booleans and complex numbers into numbers, and fail on ragged or cyclic lists.
    matrix = Values(None).array(obj.matrix, f"{key}.matrix", (3, 4))
    spec = {"type": "instance", "group": groups[id(obj.group)][0],
            "transform": {"matrix": [*_plain(matrix), [0.0, 0.0, 0.0, 1.0]]}}
    if obj.material is not None:
        spec["material"] = names[_material_index(obj.material, key, names)]
    return spec


def _material_index(material: Any, key: str, names: list[str]) -> int:
    if (isinstance(material, bool) or not isinstance(material, int | np.integer)
            or not 0 <= material < len(names)):
        raise SceneError(None, f"{key}.material", f"expected the index of one of the scene's "
                         f"{plural(len(names), 'material')}, got {material!r}")
    return int(material)


def _object(obj: M.SceneObject, key: str, names: list[str],
            groups: dict[int, tuple[str, M.Group]]) -> dict:
    if isinstance(obj, M.Instance) and groups:
        return _instance(obj, key, names, groups)
    kind = _OBJECT_TYPES.get(type(obj))
    if kind is None:
        shown = ", ".join(t.__name__ for t in _OBJECT_TYPES)
        raise SceneError(None, key, f"expected one of {shown}, got {type(obj).__name__}")
    if kind == "spheres":
        return {"type": "spheres", "centers": obj.centers, "radii": obj.radii,
                "materials": names, "material_index": obj.materials}
    material = _material_index(obj.material, key, names)
    if kind == "mesh":
        spec = {name: getattr(obj, name) for name in _MESH_ARRAYS
                if getattr(obj, name) is not None}
        if obj.face_materials is not None:
            return {"type": kind, "materials": names, "material_index": obj.face_materials,
                    **spec}
    else:
        spec = _fields(obj, skip=("material",))
    return {"type": kind, "material": names[material], **spec}
