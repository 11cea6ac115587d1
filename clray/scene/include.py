"""Scene files that include others: `include = ["materials.toml", ...]`, merged into one scene.

Rules (docs/scene_format.md, Includes): included files are read in order, each after its own
includes, and the including file comes last. `materials` and `groups` are merged by name, and a
name defined in two files is an error naming both; `lights` and `objects` are appended in that
order; `render` keys are merged one by one, a later file's value replacing an earlier one's (so
the including file overrides its libraries); `camera` may be given by one file only. Relative
file names inside an included file (textures, meshes, a background image) are relative to that
file's folder, as they are in the file itself. A file included more than once (two files
sharing a material library) is merged once, where it is first included. A file that includes
itself, directly or through others, is an error showing the chain. The merged data keeps where
each entry came from, so that an error the loader finds in it names the file and the key as
they are written there (`lib.toml: materials.glass.ior: ...`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clray.errors import SceneError
from clray.scene import limits as L
from clray.scene.files import UnreadableFile
from clray.scene.values import key_path, show, string_keys

_KEYS = ("include", "render", "camera", "materials", "groups", "lights", "objects", "animation")
_NAMED = ("materials", "groups")  # tables merged by name
_INDEXED = re.compile(r"(objects|lights)\[(\d+)\](.*)", re.S)
_RENDER_KEY = re.compile(r"[^.\[]*")


@dataclass
class Origins:
    """The file (and index there) each merged entry came from."""

    materials: dict[str, Path] = field(default_factory=dict)
    groups: dict[str, Path] = field(default_factory=dict)
    lights: list[tuple[Path, int]] = field(default_factory=list)
    objects: list[tuple[Path, int]] = field(default_factory=list)
    render: dict[str, Path] = field(default_factory=dict)
    camera: Path | None = None
    merged_files: set[Path] = field(default_factory=set)
    folder: Path = Path()  # the top scene's, which the other files' names are relative to

    def named(self, file: Path) -> str:
        """`file` as a message names another file: relative to the top scene's folder, as the
        scene names its files (its base name alone may be another library's too)."""
        try:
            return file.relative_to(self.folder).as_posix()
        except ValueError:  # an absolute include
            return file.as_posix()

    def locate(self, error: SceneError, key_of: Callable[[str, str], str]) -> SceneError:
        """`error` (found in the merged data) re-addressed to the file and key it came from."""
        key = error.key or ""
        found = _INDEXED.fullmatch(key)
        if found:
            table, index, rest = found.group(1), int(found.group(2)), found.group(3)
            entries = self.objects if table == "objects" else self.lights
            if index < len(entries):
                file, local = entries[index]
                return SceneError(file, f"{table}[{local}]{rest}", error.message)
        for table in _NAMED:
            for name, file in getattr(self, table).items():
                prefix = key_of(table, name)
                if key == prefix or key.startswith((prefix + ".", prefix + "[")):
                    return SceneError(file, key, error.message)
        head = key.split(".", 1)
        # render.KEY, or a value inside it (render.background.file): KEY's file gave it all.
        name = _RENDER_KEY.match(head[1]).group() if len(head) == 2 else ""
        if head[0] == "render" and name in self.render:
            return SceneError(self.render[name], key, error.message)
        if head[0] == "camera" and self.camera is not None:
            return SceneError(self.camera, key, error.message)
        return error


def expand_includes(data: Any, path: Path | None, read: Callable[[Path], Any]
                    ) -> tuple[Any, Origins | None]:
    """`data` with its includes merged in, and where each entry came from (None when `data`
    includes nothing). `read(path)` parses a scene file: its syntax errors name that file, and
    UnreadableFile becomes an error of the include naming it. `path` names the file `data`
    came from (None: relative names are relative to the working directory)."""
    if not isinstance(data, dict) or "include" not in data:
        return data, None
    origins = Origins(folder=(path or Path("scene")).parent)
    merged: dict[str, Any] = {"materials": {}, "groups": {}, "lights": [], "objects": [],
                              "render": {}}
    top = path or Path("scene")
    _merge(data, path, ((top.resolve(), top),), merged, origins, Path(), read)
    return merged, origins


def _merge(data: Any, path: Path | None, chain: tuple[tuple[Path, Path], ...], merged: dict,
           origins: Origins, folder: Path, read: Callable[[Path], Any]) -> None:
    """Merges `data`, read from `path`, after its includes. `folder`: the folder of `path`
    relative to the top scene's (Path() for the top scene itself). Names are joined, never
    resolved or normalised: a relative name is then relative to the folder of the file as
    it was named, through any symbolic link, as the system opens it and as the loader reads
    the top scene's textures and meshes (clray.scene.load._base); `chain` holds the files
    including it, each resolved (a cycle repeats those however they are named) and joined (as
    the cycle's message names them, not by where a symbolic link points)."""
    if not isinstance(data, dict):
        raise SceneError(path, None, f"expected a table at the top level, got {show(data)}")
    for key in string_keys(data, path, None):
        if key not in _KEYS:
            raise SceneError(path, key, f"unknown key (expected one of: {', '.join(_KEYS)})")
    names = data.get("include", [])
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise SceneError(path, "include", "expected a list of file names")
    for i, name in enumerate(names):
        target = (path or Path("scene")).parent / name
        resolved = target.resolve()
        if resolved in (file for file, _ in chain):
            # Lexically, from the top scene's folder: where a link points is not what was named.
            top = chain[0][1].parent
            shown = " -> ".join(Path(os.path.relpath(joined, top)).as_posix()
                                for _, joined in (*chain, (resolved, target)))
            raise SceneError(path, f"include[{i}]", f"includes itself: {shown}")
        if len(chain) > L.MAX_INCLUDE_DEPTH:
            raise SceneError(path, f"include[{i}]", f"includes nested more than "
                             f"{L.MAX_INCLUDE_DEPTH} deep")
        if resolved in origins.merged_files:
            continue
        origins.merged_files.add(resolved)
        try:
            included = read(target)
        except UnreadableFile as exc:
            raise SceneError(path, f"include[{i}]", f"cannot read {name!r}: {exc}") from None
        _merge(included, target, (*chain, (resolved, target)), merged, origins,
               folder / Path(name).parent, read)
    own = {k: _relocated(v, folder) for k, v in data.items()
           if k in ("materials", "groups", "lights", "objects", "render")}
    _merge_tables(data, own, path, merged, origins)
    if "animation" in data:
        # Its tracks name values by the scene file's own key paths (clray.scene.animation).
        if len(chain) > 1:
            raise SceneError(path, "animation", "only the scene file itself may animate")
        merged["animation"] = data["animation"]


def _merge_tables(data: dict, own: dict, path: Path | None, merged: dict,
                  origins: Origins) -> None:
    file = path or Path("scene")
    for table in (*_NAMED, "render"):
        value = data.get(table, {})
        if not isinstance(value, dict):
            raise SceneError(path, table, f"expected a table, got {show(value)}")
        string_keys(value, path, table)  # materials' and groups' names key the origins
    for table in _NAMED:
        defined = getattr(origins, table)
        for name, spec in own.get(table, {}).items():
            if name in merged[table]:
                raise SceneError(path, key_path(table, name),
                                 f"already defined in {origins.named(defined[name])}")
            merged[table][name] = spec
            defined[name] = file
    for table in ("lights", "objects"):
        items = own.get(table, [])
        if not isinstance(items, list):
            raise SceneError(path, table, f"expected an array of tables, got {show(items)}")
        merged[table].extend(items)
        getattr(origins, table).extend((file, i) for i in range(len(items)))
    for key, value in own.get("render", {}).items():
        merged["render"][key] = value
        origins.render[key] = file
    if "camera" in data:
        if origins.camera is not None:
            raise SceneError(path, "camera",
                             f"already given in {origins.named(origins.camera)}")
        merged["camera"] = data["camera"]
        origins.camera = file


def _relocated(value: Any, folder: Path) -> Any:
    """`value` with every relative `file` name prefixed by `folder` (its file's folder
    relative to the top scene's, where the loader reads them), so it still names the same
    file."""
    if folder == Path():
        return value
    if isinstance(value, dict):
        return {k: (str(folder / v)
                    if k == "file" and isinstance(v, str) and not Path(v).is_absolute()
                    else _relocated(v, folder)) for k, v in value.items()}
    if isinstance(value, list):
        return [_relocated(v, folder) for v in value]
    return value
