"""Scene files (.toml, .json) -> validated `clray.scene.model.Scene`.

Every problem becomes one `SceneError` naming the file and the key path
(`objects[3].radius`), so a user can find and fix it without reading a traceback.
The format itself, and the limits of clray.scene.limits, are documented in
docs/scene_format.md. This module reads the file and walks its sections in order; the
generic checks are clray.scene.values, the files a scene names clray.scene.assets, and each
section has its parser (clray.scene.parse_*).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from clray.errors import SceneError, plural
from clray.host_memory import small_pages
from clray.scene import limits as L
from clray.scene.animation import Animation, parse_animation, put, show_path
from clray.scene.assets import Assets
from clray.scene.emitters import emissive_lights
from clray.scene.files import UnreadableFile, read_regular
from clray.scene.include import expand_includes
from clray.scene.model import Background, Instance, Mesh, Scene, Spheres
from clray.scene.parse import parse_scene_text
from clray.scene.parse_camera import parse_camera
from clray.scene.parse_lights import parse_light
from clray.scene.parse_materials import MaterialTable
from clray.scene.parse_objects import ObjectParser
from clray.scene.parse_render import parse_render
from clray.scene.scale import scene_warnings
from clray.scene.values import Values, key_path, show

_TOP_KEYS = ("include", "render", "camera", "materials", "groups", "lights", "objects",
             "animation")


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; the suffix (.toml or .json) picks the parser."""
    return scene_from_dict(read_scene_data(path), Path(path))


def read_scene_data(path: str | Path) -> dict:
    """A scene file parsed, not yet checked (nor its includes merged): what scene_from_dict
    takes."""
    path = Path(path)
    try:
        return _read_scene_file(path)
    except UnreadableFile as exc:
        raise SceneError(path, None, f"cannot read scene file: {exc}") from None


def _read_scene_file(path: Path) -> Any:
    """A scene file parsed: SceneError naming it for a bad type or syntax, UnreadableFile for
    a file that cannot be read."""
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise SceneError(
            path, None, f"unknown scene file type {path.suffix!r} (use .toml or .json)"
        )
    return parse_scene_text(read_regular(path, L.MAX_SCENE_BYTES), suffix, path)


@small_pages
def scene_from_dict(data: dict, path: str | Path | None = None) -> Scene:
    """Validate parsed scene data. `path` names the file in errors; texture, mesh and included
    scene files are relative to its folder (the working directory when there is no path)."""
    return scene_and_animation(data, path)[0]


def scene_and_animation(data: dict, path: str | Path | None = None
                        ) -> tuple[Scene, Animation | None]:
    """scene_from_dict, and the [animation] table (None without one), each keyframe checked."""
    path = None if path is None else Path(path)
    values = Values(path)
    assets = Assets(values, _base(path))
    scene = _merged_scene(data, values, assets, _read_scene_file)
    animation = (_animation(data, values, assets) if isinstance(data, dict)
                 and "animation" in data else None)
    return scene, animation


def _merged_scene(data: Any, v: Values, assets: Assets, read: Callable[[Path], Any]) -> Scene:
    """The scene of a file's data, its includes (read by `read`) merged in; an error found in
    the merged data names the file and key it came from."""
    merged, origins = expand_includes(data, v.path, read)
    try:
        return _scene(merged, v, assets)
    except SceneError as err:
        if origins is None:
            raise
        raise origins.locate(err, key_path) from None


def _base(path: Path | None) -> Path:
    """The folder that file names in the scene are relative to."""
    return Path.cwd() if path is None else path.parent


def _scene(data: Any, v: Values, assets: Assets) -> Scene:
    """The sections in order: render, camera, materials, lights, groups, objects (the
    [animation] table's keyframes are checked by the caller, against the file's own data)."""
    if not isinstance(data, dict):
        raise v.error(None, f"expected a table at the top level, got {show(data)}")
    v.keys(data, None, _TOP_KEYS, ("camera",))
    render = parse_render(v.table(data.get("render", {}), "render"), v, assets)
    camera = parse_camera(v.table(data["camera"], "camera"), v)
    materials = MaterialTable(v.table(data.get("materials", {}), "materials"), v, assets)
    lights = tuple(
        parse_light(spec, f"lights[{i}]", v)
        for i, spec in enumerate(v.items(data.get("lights", []), "lights", L.MAX_LIGHTS))
    )
    objects = ObjectParser(v, assets, materials)
    objects.groups = {
        name: objects.group(spec, key_path("groups", name), name)
        for name, spec in v.table(data.get("groups", {}), "groups").items()
    }
    placed = tuple(
        obj
        for i, spec in enumerate(v.items(data.get("objects", []), "objects", L.MAX_OBJECTS))
        for obj in objects.objects(spec, f"objects[{i}]")
    )
    scene = Scene(
        path=v.path,
        render=render,
        camera=camera,
        materials=tuple(materials.materials),
        lights=lights,
        objects=placed,
    )
    glowing = len(emissive_lights(scene))
    if glowing and len(lights) + glowing > L.MAX_LIGHTS:
        raise v.error("objects", f"{plural(glowing, 'light')} of emissive faces and "
                      f"{plural(len(lights), 'light')} are over the limit of {L.MAX_LIGHTS} lights")
    scene = dataclasses.replace(scene, warnings=(*assets.warnings, *content_warnings(scene),
                                                 *scene_warnings(scene)))
    object.__setattr__(scene, "checked", True)  # frozen: the one field the loader sets
    # A checked scene is not checked again, so its arrays must not change after this check:
    # none is the caller's own (each is a copy, or a file's), and none can be written.
    for array in _arrays(scene):
        array.setflags(write=False)
    return scene


def _arrays(scene: Scene) -> Iterator[np.ndarray]:
    """Every numpy array a scene holds: texels, mesh, spheres and instance arrays (a group's
    once, however many instances place it)."""
    images = [m.texture.image for m in scene.materials if m.texture is not None]
    if isinstance(scene.render.background, Background):
        images.append(scene.render.background.image)
    yield from (image for image in images if image is not None)
    objects = list(scene.objects)
    seen: set[int] = set()  # groups, by identity
    while objects:
        obj = objects.pop()
        if isinstance(obj, Mesh | Spheres):
            yield from (value for value in vars(obj).values() if isinstance(value, np.ndarray))
        elif isinstance(obj, Instance):
            yield obj.matrix
            if id(obj.group) not in seen:
                seen.add(id(obj.group))
                objects.extend(obj.group.objects)


def content_warnings(scene: Scene) -> tuple[str, ...]:
    """What makes a valid scene render black or empty, said before the render rather than
    left for the user to find in the image: no objects, or nothing to light them."""
    if not scene.objects:
        return ("the scene has no objects: the image is the background alone",)
    # Without lights, ambient terms and emission still show the objects (the hard cases light
    # scenes so on purpose): only a scene that must render black is told.
    if scene.lights or any(m.ambient > 0 or any(m.emission) for m in scene.materials):
        return ()
    return ("the scene has no lights and no material with ambient or emission: every object "
            "renders black",)


def _animation(data: dict, v: Values, assets: Assets) -> Animation:
    """The [animation] table, each keyframe checked by loading the scene with its value put
    in: a key path or a value the scene cannot take is an error now, not at its frame. The
    value is put where clray.sequence puts it, into the file's own data before its includes
    are merged: key paths name the file's own tables (docs/scene_format.md, Animation)."""
    animation = parse_animation(v.table(data["animation"], "animation"), v)
    base = {k: value for k, value in data.items() if k != "animation"}
    # Each included file is read once for all keyframes: merging copies nothing it changes.
    files: dict[Path, Any] = {}

    def read(file: Path) -> Any:
        if file not in files:
            files[file] = _read_scene_file(file)
        return files[file]

    for i, track in enumerate(animation.tracks):
        key = f"animation.tracks[{i}]"
        for j, frame in enumerate(track.frames):
            keyed = copy.deepcopy(base)
            try:
                put(keyed, track.path, track.values[j])
            except KeyError as missing:
                raise v.error(f"{key}.key", f"{show_path(missing.args[0])} is not in the "
                              "scene (give it a value there to animate it)") from None
            try:
                _merged_scene(keyed, v, assets.sharing_files(), read)
            except SceneError as err:
                # An error located in an included file names it (the value put in may be
                # checked against that file's entries).
                where = f"{err.file.name}: " if err.file not in (None, v.path) else ""
                raise v.error(f"{key}.values[{j}]", f"{where}{err.key}: {err.message} (frame "
                              f"{frame})") from None
    return animation
