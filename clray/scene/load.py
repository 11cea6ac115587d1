"""Scene files (.toml, .json) -> validated `clray.scene.model.Scene`.

Every problem becomes one `SceneError` naming the file and the key path
(`objects[3].radius`), so a user can find and fix it without reading a traceback.
The format itself, and the limits of clray.scene.limits, are documented in
docs/scene_format.md.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from clray.errors import SceneError
from clray.image_io import srgb_decode
from clray.scene import limits as L
from clray.scene.animation import Animation, parse_animation, put, show_path
from clray.scene.files import UnreadableFile, open_regular, read_at_most, read_regular
from clray.scene.model import (
    Box,
    Camera,
    Cone,
    Cylinder,
    DirectionalLight,
    Light,
    Material,
    Mesh,
    Plane,
    PointLight,
    RenderOptions,
    Scene,
    SceneObject,
    Sphere,
    Texture,
    Triangle,
    unit,
)
from clray.scene.obj import ObjMesh, parse_obj
from clray.scene.parse import parse_scene_text
from clray.scene.scale import scene_warnings
from clray.scene.texture import COLORSPACES, TextureError, read_texture

Vec3 = tuple[float, float, float]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_PLAIN_NAME = re.compile(r"[\w./+-]{1,100}")
_SHOW_ITEMS = 8  # array elements shown in a message
_SHOW_DEPTH = 3  # nested arrays shown in a message
_DECODE_SLICE = 1 << 20  # texel values decoded from sRGB at a time

_TOP_KEYS = ("render", "camera", "materials", "lights", "objects", "animation")
_RENDER_KEYS = (
    "width", "height", "spp", "max_depth", "background", "ambient", "seed", "min_weight",
    "linear", "exposure", "png_bits",
)
_CAMERA_KEYS = ("position", "look_at", "up", "vfov", "hfov")
_MATERIAL_KEYS = (
    "color",
    "ambient",
    "diffuse",
    "specular",
    "shininess",
    "reflect",
    "transmit",
    "ior",
    "texture",
)
_TEXTURE_KEYS = {
    "checker": ("type", "size", "color2", "blend"),
    "image": ("type", "file", "texels", "repeat", "blend", "colorspace"),
}
_LIGHT_KEYS = {
    "point": ("type", "position", "color", "attenuation"),
    "directional": ("type", "direction", "color"),
}
_TRANSFORM_KEYS = ("translate", "rotate", "scale")
# Per object type: (required keys, optional keys), besides `type` and `material`.
_OBJECT_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "sphere": (("center", "radius"), ()),
    "plane": (("point", "normal"), ()),
    "box": (("min", "max"), ()),
    "triangle": (("vertices",), ()),
    "mesh": ((), ("file", "vertices", "faces", "normals", "uvs", "transform")),
    "cylinder": (("base", "axis", "radius", "height"), ("capped",)),
    "cone": (("apex", "axis", "angle", "height"), ("capped",)),
}


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; the suffix (.toml or .json) picks the parser."""
    return scene_from_dict(read_scene_data(path), Path(path))


def read_scene_data(path: str | Path) -> dict:
    """A scene file parsed, not yet checked: what scene_from_dict takes."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise SceneError(
            path, None, f"unknown scene file type {path.suffix!r} (use .toml or .json)"
        )
    try:
        raw = read_regular(path, L.MAX_SCENE_BYTES)
    except UnreadableFile as exc:
        raise SceneError(path, None, f"cannot read scene file: {exc}") from None
    return parse_scene_text(raw, suffix, path)


def animation_from_dict(data: dict, path: Path | None = None) -> Animation | None:
    """The [animation] table of scene data that scene_from_dict has checked, or None."""
    if "animation" not in data:
        return None
    return parse_animation(data["animation"], _Loader(path))


def scene_from_dict(data: dict, path: Path | None = None) -> Scene:
    """Validate parsed scene data. `path` names the file in errors; texture and mesh files
    are relative to its folder (the working directory when there is no path)."""
    return _Loader(path).scene(data)


def _show(value: Any, depth: int = 0) -> str:
    """A value as the user wrote it, short enough for a one-line message."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value[:100], ensure_ascii=False)
    elif isinstance(value, int) and value.bit_length() > 200:
        # repr() of a huge integer is slow, and past 4300 digits refused.
        text = f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    elif isinstance(value, int | float):
        text = repr(value)
    elif isinstance(value, list | tuple):
        if depth >= _SHOW_DEPTH:
            text = "[...]"
        else:
            shown = [_show(v, depth + 1) for v in value[:_SHOW_ITEMS]]
            text = "[" + ", ".join(shown + ["..."] * (len(value) > _SHOW_ITEMS)) + "]"
    elif isinstance(value, dict):
        text = "a table"
    else:
        text = type(value).__name__
    return text if len(text) <= 60 else text[:57] + "..."


def _key(prefix: str | None, name: str) -> str:
    """`prefix.name`, the name quoted unless it is a bare TOML key (an empty key, or one with
    dots or newlines, must stay visible and unambiguous)."""
    if _BARE_KEY.fullmatch(name) and len(name) <= 60:
        shown = name
    else:  # a long name is cut inside its quotes, so the quotes still close
        shown = json.dumps(name[:50], ensure_ascii=False) + "..." * (len(name) > 50)
    return f"{prefix}.{shown}" if prefix else shown


def _name(name: str) -> str:
    """A file name for a message: as written if plain, else quoted and escaped."""
    return name if _PLAIN_NAME.fullmatch(name) else _show(name)


def _is_number(value: Any) -> bool:
    # bool is an int subclass in Python, but `true` is not a number in a scene file.
    return isinstance(value, int | float) and not isinstance(value, bool)


def _out_of_range(value: int | float, limit: float) -> str | None:
    """Why a number is unusable, or None. Integers are compared exactly: float() of one
    beyond the double range raises OverflowError."""
    if isinstance(value, float) and not math.isfinite(value):
        return "must be finite"
    if abs(value) > limit:
        return f"must be at most {limit:g} in magnitude"
    return None


class _Loader:
    def __init__(self, path: Path | None) -> None:
        self.path = None if path is None else Path(path)
        self.base = Path.cwd() if path is None else Path(path).parent
        self.warnings: list[str] = []
        # Files read once per scene, by (device, inode): a scene naming one texture or mesh a
        # thousand times must not decode it a thousand times, nor count it against the
        # texel limit more than once.
        self.textures: dict[tuple[int, int], tuple[np.ndarray, bool]] = {}
        # By id() of the stored texels, which self.textures keeps alive for the loader's life.
        self.decoded_textures: dict[int, np.ndarray] = {}
        self.meshes: dict[tuple[int, int], ObjMesh] = {}
        self.texels_left = L.MAX_TEXELS
        self.triangles_left = L.MAX_TRIANGLES

    def error(self, key: str | None, message: str) -> SceneError:
        return SceneError(self.path, key, message)

    # -- generic checks ------------------------------------------------------------------

    def table(self, value: Any, key: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(key, f"expected a table, got {_show(value)}")
        return value

    def keys(
        self, table: dict, key: str | None, allowed: tuple[str, ...], required: tuple[str, ...]
    ) -> None:
        for name in table:
            if name not in allowed:
                expected = ", ".join(allowed)
                raise self.error(_key(key, name), f"unknown key (expected one of: {expected})")
        for name in required:
            if name not in table:
                raise self.error(_key(key, name), "missing required key")

    def number(self, value: Any, key: str, limit: float = L.MAX_MAGNITUDE) -> float:
        if not _is_number(value):
            raise self.error(key, f"expected a number, got {_show(value)}")
        problem = _out_of_range(value, limit)
        if problem:
            raise self.error(key, f"{problem}, got {_show(value)}")
        return float(value)

    def bounded(self, value: Any, key: str, low: float, high: float = L.MAX_MAGNITUDE) -> float:
        x = self.number(value, key)
        if x < low:
            raise self.error(key, f"must be >= {low:g}, got {_show(value)}")
        if x > high:
            raise self.error(key, f"must be <= {high:g}, got {_show(value)}")
        return x

    def length(self, value: Any, key: str) -> float:
        """A strictly positive length, within float32's normal range."""
        x = self.number(value, key)
        if x <= 0:
            raise self.error(key, f"must be > 0, got {_show(value)}")
        if x < L.MIN_LENGTH:
            raise self.error(key, f"must be >= {L.MIN_LENGTH:g}, got {_show(value)}")
        return x

    def open_range(self, value: Any, key: str, low: float, high: float) -> float:
        x = self.number(value, key)
        if not low < x < high:
            raise self.error(key, f"must be in ({low:g}, {high:g}), got {_show(value)}")
        return x

    def closed_range(self, value: Any, key: str, low: float, high: float) -> float:
        x = self.number(value, key)
        if not low <= x <= high:
            raise self.error(key, f"must be in [{low:g}, {high:g}], got {_show(value)}")
        return x

    def integer(self, value: Any, key: str, low: int, high: int) -> int:
        problem = L.integer_problem(value, low, high)
        if problem:
            raise self.error(key, f"{problem}, got {_show(value)}")
        return int(value)

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {_show(value)}")
        return value

    def choice(self, value: Any, key: str, allowed: tuple) -> Any:
        if isinstance(value, bool) or value not in allowed:
            expected = " or ".join(_show(v) for v in allowed)
            raise self.error(key, f"expected {expected}, got {_show(value)}")
        return value

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {_show(value)}")
        return value

    def numbers(
        self, value: Any, key: str, n: int, limit: float = L.MAX_MAGNITUDE
    ) -> tuple[float, ...]:
        if (
            not isinstance(value, list | tuple)
            or len(value) != n
            or not all(_is_number(v) for v in value)
        ):
            raise self.error(key, f"expected {n} numbers, got {_show(value)}")
        for v in value:
            problem = _out_of_range(v, limit)
            if problem:
                raise self.error(key, f"{problem}, got {_show(value)}")
        return tuple(float(v) for v in value)

    def vec3(self, value: Any, key: str) -> Vec3:
        x, y, z = self.numbers(value, key, 3)
        return (x, y, z)

    def non_negative(self, value: Any, key: str, limit: float = L.MAX_MAGNITUDE) -> Vec3:
        x, y, z = self.numbers(value, key, 3)
        if min(x, y, z) < 0:
            raise self.error(key, f"must be >= 0, got {_show(value)}")
        if max(x, y, z) > limit:
            raise self.error(key, f"must be <= {limit:g}, got {_show(value)}")
        return (x, y, z)

    def color(self, value: Any, key: str) -> Vec3:
        return self.non_negative(value, key, L.MAX_COLOR)

    def direction(self, value: Any, key: str) -> Vec3:
        v = self.vec3(value, key)
        if not any(v):
            raise self.error(key, f"must be a nonzero vector, got {_show(value)}")
        x, y, z = unit(v).tolist()
        return (x, y, z)

    def open_file(
        self, value: Any, key: str, max_bytes: int
    ) -> tuple[BinaryIO, tuple[int, int]]:
        """(open binary stream, (device, inode)) of a mesh or texture file."""
        name = self.string(value, key)
        try:
            stream, info = open_regular(self.base / name, max_bytes)
        except UnreadableFile as exc:
            raise self.error(key, f"{exc}: {_name(name)}") from None
        return stream, (info.st_dev, info.st_ino)

    def items(self, value: Any, key: str, limit: int) -> list[dict]:
        if not isinstance(value, list):
            raise self.error(key, f"expected an array of tables, got {_show(value)}")
        if len(value) > limit:
            raise self.error(key, f"{len(value)} entries is over the limit of {limit}")
        return [self.table(item, f"{key}[{i}]") for i, item in enumerate(value)]

    # -- sections ------------------------------------------------------------------------

    def scene(self, data: Any) -> Scene:
        if not isinstance(data, dict):
            raise self.error(None, f"expected a table at the top level, got {_show(data)}")
        self.keys(data, None, _TOP_KEYS, ("camera",))
        render = self.render(self.table(data.get("render", {}), "render"))
        camera = self.camera(self.table(data["camera"], "camera"))

        materials: list[Material] = []
        named: dict[str, int] = {}
        for name, spec in self.table(data.get("materials", {}), "materials").items():
            key = _key("materials", name)
            named[name] = len(materials)
            materials.append(self.material(self.table(spec, key), key, name))

        lights = tuple(
            self.light(spec, f"lights[{i}]")
            for i, spec in enumerate(self.items(data.get("lights", []), "lights", L.MAX_LIGHTS))
        )

        default_index: list[int] = []  # filled the first time an object needs it

        def material_for(spec: dict, key: str) -> int:
            if "material" not in spec:
                if not default_index:
                    default_index.append(len(materials))
                    materials.append(Material(name="(default)"))
                return default_index[0]
            value = spec["material"]
            mkey = f"{key}.material"
            if isinstance(value, str):
                if value not in named:
                    shown = [_show(n) for n in list(named)[:_SHOW_ITEMS]]
                    defined = ", ".join(shown + ["..."] * (len(named) > _SHOW_ITEMS)) or "none"
                    raise self.error(mkey, f"unknown material {_show(value)} (defined: {defined})")
                return named[value]
            if isinstance(value, dict):
                materials.append(self.material(value, mkey, mkey))
                return len(materials) - 1
            raise self.error(
                mkey, f"expected a material name or an inline table, got {_show(value)}"
            )

        objects = tuple(
            self.object(spec, f"objects[{i}]", material_for)
            for i, spec in enumerate(
                self.items(data.get("objects", []), "objects", L.MAX_OBJECTS)
            )
        )
        scene = Scene(
            path=self.path,
            render=render,
            camera=camera,
            materials=tuple(materials),
            lights=lights,
            objects=objects,
        )
        scene = dataclasses.replace(scene, warnings=(*self.warnings, *scene_warnings(scene)))
        object.__setattr__(scene, "checked", True)  # frozen: the one field the loader sets
        if "animation" in data:
            self.animation(data)
        return scene

    def animation(self, data: dict) -> Animation:
        """The [animation] table, each keyframe checked by loading the scene with its value put
        in: a key path or a value the scene cannot take is an error now, not at its frame."""
        animation = parse_animation(self.table(data["animation"], "animation"), self)
        base = {k: v for k, v in data.items() if k != "animation"}
        for i, track in enumerate(animation.tracks):
            key = f"animation.tracks[{i}]"
            for j, frame in enumerate(track.frames):
                keyed = copy.deepcopy(base)
                try:
                    put(keyed, track.path, track.values[j])
                except KeyError as missing:
                    raise self.error(f"{key}.key", f"{show_path(missing.args[0])} is not in the "
                                     "scene (give it a value there to animate it)") from None
                # Sharing the file caches: a keyframe does not read a mesh or texture again.
                loader = _Loader(self.path)
                loader.textures, loader.meshes = self.textures, self.meshes
                loader.decoded_textures = self.decoded_textures
                try:
                    loader.scene(keyed)
                except SceneError as err:
                    raise self.error(f"{key}.values[{j}]", f"{err.key}: {err.message} (frame "
                                     f"{frame})") from None
        return animation

    def render(self, spec: dict) -> RenderOptions:
        self.keys(spec, "render", _RENDER_KEYS, ())
        d = RenderOptions()

        def given(name: str) -> Any:
            return spec.get(name, getattr(d, name))

        # The tables RenderSettings and the command line check their overrides by, too.
        values = {name: self.integer(given(name), f"render.{name}", low, high)
                  for name, (low, high) in L.RENDER_INTEGERS.items()}
        values |= {name: self.closed_range(given(name), f"render.{name}", low, high)
                   for name, (low, high) in L.RENDER_NUMBERS.items()}
        values |= {name: self.choice(given(name), f"render.{name}", allowed)
                   for name, allowed in L.RENDER_CHOICES.items()}
        return RenderOptions(
            **values,
            background=self.color(given("background"), "render.background"),
            ambient=self.color(given("ambient"), "render.ambient"),
            linear=self.boolean(given("linear"), "render.linear"),
        )

    def camera(self, spec: dict) -> Camera:
        self.keys(spec, "camera", _CAMERA_KEYS, ("position", "look_at"))
        position = self.vec3(spec["position"], "camera.position")
        look_at = self.vec3(spec["look_at"], "camera.look_at")
        up = self.vec3(spec.get("up", (0.0, 1.0, 0.0)), "camera.up")
        if position == look_at:
            raise self.error("camera.look_at", "must differ from camera.position")
        if not any(up):
            raise self.error("camera.up", f"must be a nonzero vector, got {_show(spec['up'])}")
        # On unit vectors (scaled first, so that neither tiny nor huge lengths under- or
        # overflow) the test is relative: the right vector normalize(cross(forward, up)) only
        # needs the two directions not to be parallel, whatever their lengths.
        forward = unit(np.subtract(look_at, position))
        if np.linalg.norm(np.cross(forward, unit(up))) <= 1e-9:
            raise self.error("camera.up", "must not be parallel to the view direction")
        if "vfov" in spec and "hfov" in spec:
            raise self.error("camera", "give vfov or hfov, not both")
        if "hfov" in spec:
            return Camera(
                position,
                look_at,
                up,
                vfov=None,
                hfov=self.open_range(spec["hfov"], "camera.hfov", 0, 180),
            )
        vfov = self.open_range(spec.get("vfov", 40.0), "camera.vfov", 0, 180)
        return Camera(position, look_at, up, vfov=vfov, hfov=None)

    def material(self, spec: dict, key: str, name: str) -> Material:
        self.keys(spec, key, _MATERIAL_KEYS, ())
        d = Material(name=name)

        def coefficient(field: str, high: float) -> float:
            return self.bounded(spec.get(field, getattr(d, field)), f"{key}.{field}", 0, high)

        texture = None
        if "texture" in spec:
            tkey = f"{key}.texture"
            texture = self.texture(self.table(spec["texture"], tkey), tkey)
        low_ior, high_ior = L.IOR_RANGE
        return Material(
            name=name,
            color=self.color(spec.get("color", d.color), f"{key}.color"),
            ambient=coefficient("ambient", L.MAX_WEIGHT),
            diffuse=coefficient("diffuse", L.MAX_WEIGHT),
            specular=coefficient("specular", L.MAX_WEIGHT),
            shininess=coefficient("shininess", L.MAX_SHININESS),
            reflect=coefficient("reflect", L.MAX_BOUNCE_WEIGHT),
            transmit=coefficient("transmit", L.MAX_BOUNCE_WEIGHT),
            ior=self.bounded(spec.get("ior", d.ior), f"{key}.ior", low_ior, high_ior),
            texture=texture,
        )

    def texture(self, spec: dict, key: str) -> Texture:
        kind = self.kind(spec, key, _TEXTURE_KEYS)
        self.keys(spec, key, _TEXTURE_KEYS[kind], ("type",))
        d = Texture(kind=kind)
        blend = self.closed_range(spec.get("blend", d.blend), f"{key}.blend", 0, 1)
        if kind == "checker":
            return Texture(
                kind=kind,
                size=self.length(spec.get("size", d.size), f"{key}.size"),
                color2=self.color(spec.get("color2", d.color2), f"{key}.color2"),
                blend=blend,
            )
        rkey = f"{key}.repeat"
        j, k = self.numbers(spec.get("repeat", d.repeat), rkey, 2)
        if min(j, k) <= 0:
            raise self.error(rkey, f"must be > 0, got {_show(spec['repeat'])}")
        if min(j, k) < L.MIN_LENGTH:
            raise self.error(rkey, f"must be >= {L.MIN_LENGTH:g}, got {_show(spec['repeat'])}")
        if "file" in spec and "texels" in spec:
            raise self.error(key, "give file or texels, not both")
        if "file" not in spec and "texels" not in spec:
            raise self.error(f"{key}.file", "missing required key")
        if "texels" in spec:
            if "colorspace" in spec:
                raise self.error(f"{key}.colorspace", "texels are linear: give no colorspace")
            texels = self.texels(spec["texels"], f"{key}.texels")
            return Texture(kind=kind, repeat=(j, k), blend=blend, image=texels)
        fkey = f"{key}.file"
        file = self.base / self.string(spec["file"], fkey)
        texels, deep = self.image(spec["file"], fkey)
        # The file's values are sRGB-encoded unless it says otherwise: by default 8-bit images
        # are (as cameras and paint programs write them), 16-bit and float ones are linear.
        colorspace = self.choice(
            spec.get("colorspace", "linear" if deep else "srgb"), f"{key}.colorspace",
            COLORSPACES,
        )
        if colorspace == "srgb":
            texels = self.decoded(texels)
        return Texture(
            kind=kind, file=file, repeat=(j, k), blend=blend, colorspace=colorspace, image=texels
        )

    def image(self, name: str, key: str) -> tuple[np.ndarray, bool]:
        """(texels as stored, scaled to [0, 1]; whether the file has more than 8 bits)."""
        stream, identity = self.open_file(name, key, L.MAX_TEXTURE_BYTES)
        with stream:
            if identity in self.textures:
                return self.textures[identity]
            try:
                texels, deep, warned = read_texture(stream, self.texels_left)
            except TextureError as exc:
                raise self.error(key, f"cannot read image {_name(name)}: {exc}") from None
        self.texels_left -= texels.shape[0] * texels.shape[1]
        self.warnings.extend(f"{key}: image {_name(name)}: {w}" for w in warned)
        self.textures[identity] = (texels, deep)
        return texels, deep

    def texels(self, value: Any, key: str) -> np.ndarray:
        """Linear texels given as an (H, W, 3) array (from Python), within the texel limits."""
        texels = self.array(value, key, (None, None, 3))
        height, width, _ = texels.shape
        side = L.MAX_TEXTURE_SIDE
        if not 0 < min(height, width) <= max(height, width) <= side:
            raise self.error(key, f"must be at least 1 and at most {side} texels a side, "
                             f"got {width}x{height}")
        if width * height > self.texels_left:
            raise self.error(key, f"{width}x{height} texels is over what is left "
                             f"({self.texels_left}) of the limit of {L.MAX_TEXELS}")
        if not np.all((texels >= 0) & (texels <= 1)):
            raise self.error(key, "must be linear values in [0, 1]")
        self.texels_left -= width * height
        return np.ascontiguousarray(texels, dtype=np.float32)

    def array(self, value: Any, key: str, shape: tuple[int | None, ...],
              integer: bool = False) -> np.ndarray:
        """A numeric array (numpy, or nested lists) of `shape` (None: any length), with finite
        values within MAX_MAGNITUDE; the first bad row is named in the message."""
        try:
            a = np.asarray(value)
        except (ValueError, TypeError):
            a = np.asarray(None)
        kinds = "iu" if integer else "iuf"
        shown = "x".join("N" if n is None else str(n) for n in shape)
        if (a.dtype.kind not in kinds or a.ndim != len(shape)
                or any(n is not None and n != m for n, m in zip(shape, a.shape, strict=True))):
            what = "integers" if integer else "numbers"
            raise self.error(key, f"expected an array of {shown} {what}, got {_show(value)}")
        if not integer:
            bad = ~np.isfinite(a) | (np.abs(a) > L.MAX_MAGNITUDE)
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise self.error(f"{key}[{row}]", f"must be finite and at most "
                                 f"{L.MAX_MAGNITUDE:g} in magnitude, got {_show(a[row].tolist())}")
        return a

    def decoded(self, texels: np.ndarray) -> np.ndarray:
        """`texels` decoded from sRGB to linear, once per file however often it is named."""
        if id(texels) not in self.decoded_textures:
            # In float64, a slice at a time: the whole of a texture at the texel limit would
            # take several GiB of float64 temporaries.
            flat = texels.reshape(-1)
            linear = np.empty_like(flat)
            for start in range(0, flat.size, _DECODE_SLICE):
                part = flat[start : start + _DECODE_SLICE].astype(np.float64)
                linear[start : start + _DECODE_SLICE] = srgb_decode(part)
            self.decoded_textures[id(texels)] = linear.reshape(texels.shape)
        return self.decoded_textures[id(texels)]

    def kind(self, spec: dict, key: str, known: dict[str, tuple[str, ...]]) -> str:
        if "type" not in spec:
            raise self.error(f"{key}.type", f"missing required key (one of: {', '.join(known)})")
        kind = spec["type"]
        if not isinstance(kind, str) or kind not in known:
            raise self.error(
                f"{key}.type", f"unknown type {_show(kind)} (expected one of: {', '.join(known)})"
            )
        return kind

    def light(self, spec: dict, key: str) -> Light:
        kind = self.kind(spec, key, _LIGHT_KEYS)
        self.keys(spec, key, _LIGHT_KEYS[kind], _LIGHT_KEYS[kind][:2])
        color = self.color(spec.get("color", (1.0, 1.0, 1.0)), f"{key}.color")
        if kind == "directional":
            return DirectionalLight(self.direction(spec["direction"], f"{key}.direction"), color)
        akey = f"{key}.attenuation"
        attenuation = self.non_negative(spec.get("attenuation", (1.0, 0.0, 0.0)), akey)
        if not any(attenuation):
            raise self.error(akey, "must not be all zero")
        return PointLight(self.vec3(spec["position"], f"{key}.position"), color, attenuation)

    # -- objects -------------------------------------------------------------------------

    def object(self, spec: dict, key: str, material_for: Callable[[dict, str], int]) -> SceneObject:
        kind = self.kind(spec, key, _OBJECT_KEYS)
        allowed = ("type", "material", *_OBJECT_KEYS[kind][0], *_OBJECT_KEYS[kind][1])
        required = _OBJECT_KEYS[kind][0]
        self.keys(spec, key, allowed, required)
        material = material_for(spec, key)

        def k(name: str) -> str:
            return f"{key}.{name}"

        if kind == "sphere":
            radius = self.length(spec["radius"], k("radius"))
            return Sphere(self.vec3(spec["center"], k("center")), radius, material)
        if kind == "plane":
            normal = self.direction(spec["normal"], k("normal"))
            return Plane(self.vec3(spec["point"], k("point")), normal, material)
        if kind == "box":
            return self.box(spec, key, material)
        if kind == "triangle":
            return Triangle(self.points(spec["vertices"], k("vertices"), exactly=3), material)
        if kind == "mesh":
            return self.mesh(spec, key, material)
        capped = self.boolean(spec.get("capped", True), k("capped"))
        axis = self.direction(spec["axis"], k("axis"))
        height = self.length(spec["height"], k("height"))
        if kind == "cylinder":
            return Cylinder(
                base=self.vec3(spec["base"], k("base")),
                axis=axis,
                radius=self.length(spec["radius"], k("radius")),
                height=height,
                material=material,
                capped=capped,
            )
        return Cone(
            apex=self.vec3(spec["apex"], k("apex")),
            axis=axis,
            angle=self.open_range(spec["angle"], k("angle"), 0, 90),
            height=height,
            material=material,
            capped=capped,
        )

    def box(self, spec: dict, key: str, material: int) -> Box:
        lo = self.vec3(spec["min"], f"{key}.min")
        hi = self.vec3(spec["max"], f"{key}.max")
        if any(a > b for a, b in zip(lo, hi, strict=True)):
            raise self.error(
                f"{key}.max", f"must be >= min on every axis, got min {_show(lo)}, max {_show(hi)}"
            )
        # A box flat on one axis is a rectangle and still renders; one on all three is not.
        if lo == hi:
            raise self.error(f"{key}.max", f"must differ from min, got {_show(hi)} for both")
        return Box(lo, hi, material)

    def points(self, value: Any, key: str, exactly: int | None = None) -> tuple[Vec3, ...]:
        if not isinstance(value, list) or (exactly is not None and len(value) != exactly):
            what = f"{exactly} points" if exactly else "a list of points"
            raise self.error(key, f"expected {what}, got {_show(value)}")
        return tuple(self.vec3(p, f"{key}[{i}]") for i, p in enumerate(value))

    def obj(self, name: Any, key: str) -> ObjMesh:
        stream, identity = self.open_file(name, key, L.MAX_MESH_BYTES)
        with stream:
            if identity not in self.meshes:
                try:
                    data = read_at_most(stream, L.MAX_MESH_BYTES)
                except UnreadableFile as exc:
                    raise self.error(key, f"{exc}: {_name(name)}") from None
                self.meshes[identity] = parse_obj(data, self.base / name)
        return self.meshes[identity]

    def mesh(self, spec: dict, key: str, material: int) -> Mesh:
        inline = "vertices" in spec or "faces" in spec
        if "file" in spec and inline:
            raise self.error(key, "give file or vertices + faces, not both")
        for name in ("normals", "uvs"):
            if name in spec and not inline:
                raise self.error(f"{key}.{name}", "only with vertices + faces (an OBJ file "
                                 "gives its own)")
        if "file" in spec:
            obj = self.obj(spec["file"], f"{key}.file")
            vertices, faces, normals, uvs = obj.vertices, obj.faces, obj.normals, obj.uvs
        elif inline:
            for name in ("vertices", "faces"):
                if name not in spec:
                    raise self.error(f"{key}.{name}", "missing required key")
            vertices = self.vertex_values(spec["vertices"], f"{key}.vertices", None, 3)
            faces = self.faces(spec["faces"], f"{key}.faces", len(vertices))
            normals, uvs = (None if name not in spec else self.vertex_values(
                spec[name], f"{key}.{name}", len(vertices), size) for name, size in
                (("normals", 3), ("uvs", 2)))
            if normals is not None and not np.all(np.any(normals != 0, axis=1)):
                row = int(np.flatnonzero(~np.any(normals != 0, axis=1))[0])
                raise self.error(f"{key}.normals[{row}]", "must be a nonzero vector")
        else:
            raise self.error(key, "a mesh needs file or vertices + faces")
        if len(faces) == 0:
            raise self.error(key, "mesh has no faces")
        if len(faces) > self.triangles_left:
            raise self.error(
                key, f"{len(faces)} triangles is over what is left ({self.triangles_left}) of "
                f"the limit of {L.MAX_TRIANGLES} triangles for all meshes"
            )
        self.triangles_left -= len(faces)
        tkey = f"{key}.transform"
        rotation, scale, offset = self.transform(spec.get("transform", {}), tkey)
        # Without a transform the vertices are used as read: a 327k-triangle mesh spends a
        # fifth of its load time in the matrix product otherwise.
        identity = "transform" not in spec
        if not identity:
            vertices = (vertices.reshape(-1, 3) * scale) @ rotation.T + offset
        if not np.all(np.abs(vertices) <= L.MAX_MAGNITUDE):
            raise self.error(
                tkey, f"moves vertices beyond {L.MAX_MAGNITUDE:g} in magnitude "
                f"(largest {np.max(np.abs(vertices)):.3g})"
            )
        if normals is not None:
            # Normals follow the inverse transpose of R S, which is R S^-1: they stay
            # perpendicular to the surface under non-uniform scale. Unit normals over scales
            # of at least MIN_LENGTH stay finite.
            normals = unit(normals if identity else (normals / scale) @ rotation.T)
        if np.prod(np.sign(scale)) < 0:
            # A mirroring transform turns the winding inside out; swapping two corners keeps
            # (v1 - v0) x (v2 - v0) pointing outward, which refraction relies on.
            faces = faces[:, [0, 2, 1]]
        return Mesh(
            vertices=np.ascontiguousarray(vertices),
            faces=np.ascontiguousarray(faces, dtype=np.int64),
            material=material,
            normals=normals,
            uvs=uvs,
        )

    def vertex_values(self, value: Any, key: str, n_vertices: int | None, size: int
                      ) -> np.ndarray:
        """Per-vertex positions, normals or (u, v): a row of `size` numbers for each vertex,
        from a list of lists (scene files: each row checked as any other numbers) or an array
        (Python: checked at once)."""
        if isinstance(value, np.ndarray):
            a = self.array(value, key, (None, size)).astype(np.float64)
        elif isinstance(value, list):
            a = np.array([self.numbers(row, f"{key}[{i}]", size) for i, row in enumerate(value)],
                         dtype=np.float64).reshape(-1, size)
        else:
            raise self.error(key, f"expected a list of {size}-number rows, got {_show(value)}")
        if n_vertices is not None and len(a) != n_vertices:
            raise self.error(key, f"expected one row per vertex ({n_vertices}), got {len(a)}")
        return a

    def faces(self, value: Any, key: str, n_vertices: int) -> np.ndarray:
        if isinstance(value, np.ndarray):
            faces = self.array(value, key, (None, 3), integer=True)
        else:
            if not isinstance(value, list):
                raise self.error(key, f"expected a list of faces, got {_show(value)}")
            for i, face in enumerate(value):
                if (
                    not isinstance(face, list)
                    or len(face) != 3
                    or not all(isinstance(v, int) and not isinstance(v, bool) for v in face)
                ):
                    raise self.error(f"{key}[{i}]", f"expected 3 vertex indices, got {_show(face)}")
            faces = np.array(value, dtype=object).reshape(-1, 3)
        outside = np.any((faces < 0) | (faces >= n_vertices), axis=1)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            v = next(v for v in faces[i].tolist() if not 0 <= v < n_vertices)
            raise self.error(
                f"{key}[{i}]", f"index {_show(v)} out of range (0-based, {n_vertices} vertices)"
            )
        return faces.astype(np.int64)

    def transform(self, value: Any, key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(3x3 rotation, 3 scale factors, translation): scale, then rotate about x, y, z in
        turn, then translate."""
        spec = self.table(value, key)
        self.keys(spec, key, _TRANSFORM_KEYS, ())
        translate = np.array(self.vec3(spec.get("translate", (0, 0, 0)), f"{key}.translate"))
        rx, ry, rz = np.radians(self.vec3(spec.get("rotate", (0, 0, 0)), f"{key}.rotate"))
        skey = f"{key}.scale"
        scale_value = spec.get("scale", 1.0)
        if isinstance(scale_value, list):
            scale = np.array(self.vec3(scale_value, skey))
        else:
            scale = np.full(3, self.number(scale_value, skey))
        if not scale.all():
            raise self.error(skey, f"must be nonzero, got {_show(scale_value)}")
        if np.min(np.abs(scale)) < L.MIN_LENGTH:
            raise self.error(
                skey, f"must be at least {L.MIN_LENGTH:g} in magnitude, got {_show(scale_value)}"
            )
        cx, sx, cy, sy, cz, sz = (
            np.cos(rx),
            np.sin(rx),
            np.cos(ry),
            np.sin(ry),
            np.cos(rz),
            np.sin(rz),
        )
        rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return rot_z @ rot_y @ rot_x, scale, translate
