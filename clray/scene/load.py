"""Scene files (.toml, .json) -> validated `clray.scene.model.Scene`.

Every problem becomes one `SceneError` naming the file and the key path
(`objects[3].radius`), so a user can find and fix it without reading a traceback.
The format itself, and the limits of clray.scene.limits, are documented in
docs/scene_format.md.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from clray.errors import SceneError
from clray.image_io import srgb_decode
from clray.scene import limits as L
from clray.scene.animation import Animation, parse_animation, put, show_path
from clray.scene.files import UnreadableFile, open_regular, read_at_most, read_regular
from clray.scene.include import expand_includes
from clray.scene.model import (
    Background,
    Box,
    Camera,
    Cone,
    Cylinder,
    DirectionalLight,
    DiscLight,
    Group,
    Instance,
    Light,
    Material,
    Mesh,
    Plane,
    PointLight,
    RectLight,
    RenderOptions,
    Scene,
    SceneObject,
    Sphere,
    SphereLight,
    Spheres,
    SpotLight,
    Texture,
    Triangle,
    rect_area,
    unit,
)
from clray.scene.obj import ObjMesh, parse_obj
from clray.scene.parse import parse_scene_text
from clray.scene.scale import scene_warnings
from clray.scene.texture import COLORSPACES, TextureError, read_texture
from clray.scene.transform import place, rotation_matrix

Vec3 = tuple[float, float, float]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_PLAIN_NAME = re.compile(r"[\w./+-]{1,100}")
_SHOW_ITEMS = 8  # array elements shown in a message
_SHOW_DEPTH = 3  # nested arrays shown in a message
_DECODE_SLICE = 1 << 20  # texel values decoded from sRGB at a time

_TOP_KEYS = ("include", "render", "camera", "materials", "groups", "lights", "objects",
             "animation")
_RENDER_KEYS = (
    "width", "height", "spp", "max_depth", "background", "ambient", "seed", "min_weight",
    "linear", "exposure", "png_bits",
)
_CAMERA_KEYS = ("position", "look_at", "up", "vfov", "hfov", "type", "width", "height",
                "aperture", "focus_distance")
_CAMERA_TYPES = ("perspective", "orthographic")
_BACKGROUND_KEYS = {
    "gradient": ("type", "bottom", "top"),
    "image": ("type", "file", "texels", "colorspace"),
}
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
    "fresnel",
)
_TEXTURE_KEYS = {
    "checker": ("type", "size", "color2", "blend"),
    "image": ("type", "file", "texels", "repeat", "blend", "colorspace"),
}
_LIGHT_KEYS = {
    "point": ("type", "position", "color", "attenuation"),
    "directional": ("type", "direction", "color"),
    "spot": ("type", "position", "direction", "angle", "inner_angle", "color", "attenuation"),
    "rect": ("type", "corner", "u", "v", "color"),
    "disc": ("type", "center", "normal", "radius", "color"),
    "sphere": ("type", "center", "radius", "color"),
}
# Keys every light of the type must have, after `type`.
_LIGHT_REQUIRED = {"point": 1, "directional": 1, "spot": 3, "rect": 3, "disc": 3, "sphere": 2}
_TRANSFORM_KEYS = ("translate", "rotate", "scale", "matrix")
# Per object type: (required keys, optional keys), besides `type`, `material` and `transform`.
_OBJECT_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "sphere": (("center", "radius"), ()),
    "plane": (("point", "normal"), ()),
    "box": (("min", "max"), ()),
    "triangle": (("vertices",), ()),
    "mesh": ((), ("file", "vertices", "faces", "normals", "uvs")),
    "cylinder": (("base", "axis", "radius", "height"), ("capped",)),
    "cone": (("apex", "axis", "angle", "height"), ("capped",)),
    "spheres": ((), ("file", "centers", "radii", "radius", "materials", "material_index")),
    "instance": (("group",), ()),
}
# What a `spheres` object's .npz may hold (a .npy holds centers, or centers and radii).
_SPHERE_ARRAYS = ("centers", "radii", "material_index")


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


def animation_from_dict(data: dict, path: Path | None = None) -> Animation | None:
    """The [animation] table of scene data that scene_from_dict has checked, or None."""
    if "animation" not in data:
        return None
    return parse_animation(data["animation"], _Loader(path))


def scene_from_dict(data: dict, path: str | Path | None = None) -> Scene:
    """Validate parsed scene data. `path` names the file in errors; texture, mesh and included
    scene files are relative to its folder (the working directory when there is no path)."""
    path = None if path is None else Path(path)
    merged, origins = expand_includes(data, path, _read_scene_file)
    try:
        return _Loader(path).scene(merged)
    except SceneError as err:
        if origins is None:
            raise
        raise origins.locate(err, _key) from None


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
        self.spheres_left = L.MAX_BULK_SPHERES

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
            return material_ref(spec["material"], f"{key}.material")

        def material_ref(value: Any, mkey: str) -> int:
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

        self.material_ref = material_ref
        self.groups = {
            name: self.group(spec, _key("groups", name), name, material_for)
            for name, spec in self.table(data.get("groups", {}), "groups").items()
        }
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
            background=self.background(given("background"), "render.background"),
            ambient=self.color(given("ambient"), "render.ambient"),
            linear=self.boolean(given("linear"), "render.linear"),
        )

    def background(self, value: Any, key: str) -> Vec3 | Background:
        """A plain colour, or a gradient or environment image table."""
        if not isinstance(value, dict):
            return self.color(value, key)
        kind = self.kind(value, key, _BACKGROUND_KEYS)
        required = _BACKGROUND_KEYS[kind] if kind == "gradient" else ("type",)
        self.keys(value, key, _BACKGROUND_KEYS[kind], required)
        if kind == "gradient":
            return Background(kind, bottom=self.color(value["bottom"], f"{key}.bottom"),
                              top=self.color(value["top"], f"{key}.top"))
        if "file" in value and "texels" in value:
            raise self.error(key, "give file or texels, not both")
        if "texels" in value:
            if "colorspace" in value:
                raise self.error(f"{key}.colorspace", "texels are linear: give no colorspace")
            return Background(kind, image=self.texels(value["texels"], f"{key}.texels"))
        if "file" not in value:
            raise self.error(f"{key}.file", "missing required key")
        fkey = f"{key}.file"
        file = self.base / self.string(value["file"], fkey)
        texels, deep = self.image(value["file"], fkey)
        colorspace = self.choice(value.get("colorspace", "linear" if deep else "srgb"),
                                 f"{key}.colorspace", COLORSPACES)
        if colorspace == "srgb":
            texels = self.decoded(texels)
        return Background(kind, file=file, colorspace=colorspace, image=texels)

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
        kind = self.choice(spec.get("type", "perspective"), "camera.type", _CAMERA_TYPES)
        lens = {"aperture": self.bounded(spec.get("aperture", 0.0), "camera.aperture", 0)}
        if "focus_distance" in spec:
            lens["focus_distance"] = self.length(spec["focus_distance"], "camera.focus_distance")
        focus = lens.get("focus_distance", float(np.linalg.norm(np.subtract(look_at, position))))
        if lens["aperture"] > L.MAX_APERTURE_RATIO * focus:
            raise self.error("camera.aperture", f"must be at most {L.MAX_APERTURE_RATIO:g} "
                             f"times the focus distance ({focus:g}), got {lens['aperture']:g}")
        if kind == "orthographic":
            for name in ("vfov", "hfov"):
                if name in spec:
                    raise self.error(f"camera.{name}", "an orthographic camera has no field of "
                                     "view: give width or height")
            if "width" in spec and "height" in spec:
                raise self.error("camera", "give width or height, not both")
            if "width" not in spec and "height" not in spec:
                raise self.error("camera.height", "missing required key (an orthographic "
                                 "camera needs width or height)")
            extent = {name: self.length(spec[name], f"camera.{name}")
                      for name in ("width", "height") if name in spec}
            return Camera(position, look_at, up, vfov=None, hfov=None, type=kind, **extent,
                          **lens)
        for name in ("width", "height"):
            if name in spec:
                raise self.error(f"camera.{name}", 'only with type = "orthographic" (a '
                                 "perspective camera takes vfov or hfov)")
        if "vfov" in spec and "hfov" in spec:
            raise self.error("camera", "give vfov or hfov, not both")
        if "hfov" in spec:
            return Camera(
                position,
                look_at,
                up,
                vfov=None,
                hfov=self.open_range(spec["hfov"], "camera.hfov", 0, 180),
                **lens,
            )
        vfov = self.open_range(spec.get("vfov", 40.0), "camera.vfov", 0, 180)
        return Camera(position, look_at, up, vfov=vfov, hfov=None, **lens)

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
        fresnel = self.boolean(spec.get("fresnel", d.fresnel), f"{key}.fresnel")
        reflect = coefficient("reflect", L.MAX_BOUNCE_WEIGHT)
        transmit = coefficient("transmit", L.MAX_BOUNCE_WEIGHT)
        # With Fresnel, reflect + transmit leave the surface in all (docs/rendering.md).
        if fresnel and reflect + transmit > L.MAX_BOUNCE_WEIGHT:
            raise self.error(f"{key}.fresnel", f"needs reflect + transmit <= "
                             f"{L.MAX_BOUNCE_WEIGHT:g}, got {reflect:g} + {transmit:g}")
        return Material(
            name=name,
            color=self.color(spec.get("color", d.color), f"{key}.color"),
            ambient=coefficient("ambient", L.MAX_WEIGHT),
            diffuse=coefficient("diffuse", L.MAX_WEIGHT),
            specular=coefficient("specular", L.MAX_WEIGHT),
            shininess=coefficient("shininess", L.MAX_SHININESS),
            reflect=reflect,
            transmit=transmit,
            ior=self.bounded(spec.get("ior", d.ior), f"{key}.ior", low_ior, high_ior),
            texture=texture,
            fresnel=fresnel,
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
        self.keys(spec, key, _LIGHT_KEYS[kind], _LIGHT_KEYS[kind][1 : 1 + _LIGHT_REQUIRED[kind]])
        color = self.color(spec.get("color", (1.0, 1.0, 1.0)), f"{key}.color")
        if kind == "directional":
            return DirectionalLight(self.direction(spec["direction"], f"{key}.direction"), color)
        if kind in ("rect", "disc", "sphere"):
            return self.area_light(kind, spec, key, color)
        akey = f"{key}.attenuation"
        attenuation = self.non_negative(spec.get("attenuation", (1.0, 0.0, 0.0)), akey)
        if not any(attenuation):
            raise self.error(akey, "must not be all zero")
        position = self.vec3(spec["position"], f"{key}.position")
        if kind == "point":
            return PointLight(position, color, attenuation)
        angle = self.open_range(spec["angle"], f"{key}.angle", 0, L.MAX_SPOT_ANGLE)
        inner = self.closed_range(spec.get("inner_angle", angle), f"{key}.inner_angle", 0, angle)
        return SpotLight(position, self.direction(spec["direction"], f"{key}.direction"), angle,
                         color, attenuation, inner)

    def area_light(self, kind: str, spec: dict, key: str, color: Vec3) -> Light:
        if kind == "rect":
            corner = self.vec3(spec["corner"], f"{key}.corner")
            u, v = self.vec3(spec["u"], f"{key}.u"), self.vec3(spec["v"], f"{key}.v")
            self.light_area(rect_area(u, v), f"{key}.v", "|u x v|")
            return RectLight(corner, u, v, color)
        radius = self.length(spec["radius"], f"{key}.radius")
        center = self.vec3(spec["center"], f"{key}.center")
        self.light_area(math.pi * radius * radius, f"{key}.radius", "pi radius^2")
        if kind == "disc":
            return DiscLight(center, self.direction(spec["normal"], f"{key}.normal"), radius,
                             color)
        return SphereLight(center, radius, color)

    def light_area(self, area: float, key: str, what: str) -> None:
        """The kernels divide by and multiply with an emitting area: it must be a normal
        float32 number, far from overflow."""
        if not L.MIN_LENGTH <= area <= L.MAX_LIGHT_AREA:
            raise self.error(key, f"the light's area ({what}) must be in [{L.MIN_LENGTH:g}, "
                             f"{L.MAX_LIGHT_AREA:g}], got {area:.3g}")

    # -- objects -------------------------------------------------------------------------

    def group(self, value: Any, key: str, name: str,
              material_for: Callable[[dict, str], int]) -> Group:
        spec = self.table(value, key)
        self.keys(spec, key, ("objects",), ("objects",))
        items = self.items(spec["objects"], f"{key}.objects", L.MAX_OBJECTS)
        if not items:
            raise self.error(f"{key}.objects", "a group needs at least one object")
        return Group(name, tuple(self.object(item, f"{key}.objects[{i}]", material_for,
                                             in_group=True) for i, item in enumerate(items)))

    def object(self, spec: dict, key: str, material_for: Callable[[dict, str], int],
               in_group: bool = False) -> SceneObject:
        kind = self.kind(spec, key, _OBJECT_KEYS)
        allowed = ("type", "material", *_OBJECT_KEYS[kind][0], *_OBJECT_KEYS[kind][1],
                   "transform")
        required = _OBJECT_KEYS[kind][0]
        self.keys(spec, key, allowed, required)
        if in_group and kind in ("instance", "plane"):
            raise self.error(f"{key}.type", "a group holds bounded primitives: no planes "
                             "(unbounded) and no instances (groups do not nest)")
        if kind == "instance":
            return self.instance(spec, key)
        obj = self.unplaced(spec, key, kind, material_for)
        if kind == "mesh" or "transform" not in spec:
            return obj
        tkey = f"{key}.transform"
        a, offset = self.transform(spec["transform"], tkey)
        placed = place(obj, a, offset)
        if not isinstance(placed, str):
            return self.within_limits(placed, tkey)
        if in_group:
            raise self.error(tkey, f"{placed}, and inside a group that would need a group in a "
                             "group: place the instance by that transform instead")
        # A shape the transform does not keep (an ellipsoid, a box at an angle) is intersected
        # in its own frame, as a one-object group.
        return Instance(Group(key, (obj,)), self.placement(a, offset, tkey))

    def instance(self, spec: dict, key: str) -> Instance:
        name = self.string(spec["group"], f"{key}.group")
        if name not in self.groups:
            shown = [_show(n) for n in list(self.groups)[:_SHOW_ITEMS]]
            defined = ", ".join(shown + ["..."] * (len(self.groups) > _SHOW_ITEMS)) or "none"
            raise self.error(f"{key}.group", f"unknown group {_show(name)} (defined: {defined})")
        material = (self.material_ref(spec["material"], f"{key}.material")
                    if "material" in spec else None)
        tkey = f"{key}.transform"
        a, offset = self.transform(spec.get("transform", {}), tkey)
        return Instance(self.groups[name], self.placement(a, offset, tkey), material)

    def placement(self, a: np.ndarray, offset: np.ndarray, key: str) -> np.ndarray:
        """The (3, 4) matrix [A | t] of an instance, within the magnitudes the kernels take."""
        if not np.all(np.abs(offset) <= L.MAX_MAGNITUDE):
            raise self.error(key, f"moves the object beyond {L.MAX_MAGNITUDE:g} in magnitude")
        singular = np.linalg.svd(a, compute_uv=False)
        if singular.max() > L.MAX_MAGNITUDE or singular.min() < L.MIN_LENGTH:
            raise self.error(key, f"stretches or shrinks by more than {L.MAX_MAGNITUDE:g}")
        return np.hstack([a, offset[:, None]])

    def within_limits(self, obj: SceneObject, key: str) -> SceneObject:
        """A placed object's numbers still within what the kernels take."""
        values = [np.asarray(v, dtype=np.float64) for f in dataclasses.fields(obj)
                  if f.name != "material" and not isinstance(v := getattr(obj, f.name), bool)
                  and isinstance(v, float | tuple | np.ndarray)]
        if not all(np.all(np.abs(v) <= L.MAX_MAGNITUDE) for v in values):
            raise self.error(key, f"moves the object beyond {L.MAX_MAGNITUDE:g} in magnitude")
        lengths = [getattr(obj, n) for n in ("radius", "height", "radii") if hasattr(obj, n)]
        if any(np.any(np.asarray(v) < L.MIN_LENGTH) for v in lengths):
            raise self.error(key, f"shrinks the object below {L.MIN_LENGTH:g}")
        return obj

    def unplaced(self, spec: dict, key: str, kind: str,
                 material_for: Callable[[dict, str], int]) -> SceneObject:
        if kind == "spheres" and "materials" in spec:
            if "material" in spec:
                raise self.error(key, "give material or materials, not both")
            return self.spheres(spec, key, None)
        material = material_for(spec, key)
        if kind == "spheres":
            return self.spheres(spec, key, material)

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

    def spheres(self, spec: dict, key: str, material: int | None) -> Spheres:
        """A `spheres` object: arrays from a .npy/.npz file or given inline (lists, or numpy
        arrays from Python), one material or one per sphere through material_index."""
        arrays = self.sphere_arrays(spec, key)
        if "centers" not in arrays:
            raise self.error(key, "a spheres object needs centers (a file or the centers key)")
        centers = self.array(arrays["centers"], f"{key}.centers", (None, 3)).astype(np.float64)
        n = len(centers)
        if n > self.spheres_left:
            raise self.error(key, f"{n} spheres is over what is left ({self.spheres_left}) of the "
                             f"limit of {L.MAX_BULK_SPHERES} spheres for all spheres objects")
        self.spheres_left -= n
        if "radii" in arrays and "radius" in spec:
            raise self.error(key, "give radius or radii, not both")
        if "radius" in spec:
            radii = np.full(n, self.length(spec["radius"], f"{key}.radius"))
        elif "radii" in arrays:
            radii = self.array(arrays["radii"], f"{key}.radii", (n,)).astype(np.float64)
            small = ~(radii >= L.MIN_LENGTH)
            if small.any():
                i = int(np.flatnonzero(small)[0])
                raise self.error(f"{key}.radii[{i}]", f"must be >= {L.MIN_LENGTH:g}, "
                                 f"got {_show(radii[i].item())}")
        else:
            raise self.error(key, "a spheres object needs radius or radii")
        if material is not None:
            if "material_index" in arrays:
                raise self.error(f"{key}.material_index", "only with materials (a list)")
            return Spheres(centers, radii, np.full(n, material, dtype=np.int64))
        names = spec["materials"]
        if not isinstance(names, list) or not names:
            raise self.error(f"{key}.materials", f"expected a list of material names or inline "
                             f"tables, got {_show(names)}")
        refs = np.array([self.material_ref(v, f"{key}.materials[{j}]")
                         for j, v in enumerate(names)], dtype=np.int64)
        if "material_index" not in arrays:
            raise self.error(key, "materials needs material_index (in the file or as a key)")
        index = self.array(arrays["material_index"], f"{key}.material_index", (n,), integer=True)
        outside = (index < 0) | (index >= len(refs))
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise self.error(f"{key}.material_index[{i}]", f"index {index[i]} out of range "
                             f"(0-based, {len(refs)} materials)")
        return Spheres(centers, radii, refs[index])

    def sphere_arrays(self, spec: dict, key: str) -> dict[str, Any]:
        inline = {name: spec[name] for name in _SPHERE_ARRAYS if name in spec}
        if "file" not in spec:
            return inline
        from_file = self.sphere_file(spec["file"], f"{key}.file")
        both = [name for name in _SPHERE_ARRAYS if name in inline and name in from_file]
        if both:
            raise self.error(key, f"{both[0]} is in the file: give it there or as a key, "
                             "not both")
        return {**from_file, **inline}

    def sphere_file(self, value: Any, fkey: str) -> dict[str, Any]:
        name = self.string(value, fkey)
        suffix = Path(name).suffix.lower()
        if suffix not in (".npy", ".npz"):
            raise self.error(fkey, f"expected a .npy or .npz file, got {_name(name)}")
        stream, _ = self.open_file(name, fkey, L.MAX_ARRAY_BYTES)
        with stream:
            try:
                data = read_at_most(stream, L.MAX_ARRAY_BYTES)
                loaded = np.load(io.BytesIO(data), allow_pickle=False)
                if suffix == ".npy":
                    return self.npy_spheres(loaded, fkey, name)
                unknown = sorted(set(loaded.files) - set(_SPHERE_ARRAYS))
                if unknown:
                    raise self.error(fkey, f"{_name(name)} holds {', '.join(unknown)} (expected "
                                     f"{', '.join(_SPHERE_ARRAYS)})")
                return {n: loaded[n] for n in loaded.files}
            except (UnreadableFile, OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                raise self.error(fkey, f"cannot read {_name(name)}: {exc}") from None

    def npy_spheres(self, array: np.ndarray, key: str, name: str) -> dict[str, Any]:
        """A .npy of spheres: (N, 3) centers, or (N, 4) centers and radii."""
        if array.ndim != 2 or array.shape[1] not in (3, 4):
            raise self.error(key, f"{_name(name)}: expected an (N, 3) or (N, 4) array, got shape "
                             f"{array.shape}")
        if array.shape[1] == 3:
            return {"centers": array}
        return {"centers": array[:, :3], "radii": array[:, 3]}

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
                if Path(str(name)).suffix.lower() == ".npz":
                    self.meshes[identity] = self.npz_mesh(data, key, name)
                else:
                    self.meshes[identity] = parse_obj(data, self.base / name)
        return self.meshes[identity]

    def npz_mesh(self, data: bytes, key: str, name: str) -> ObjMesh:
        """A mesh from a .npz of arrays: vertices (V, 3), faces (F, 3, 0-based), and optionally
        normals (V, 3) and uvs (V, 2); checked as inline arrays are."""
        try:
            loaded = np.load(io.BytesIO(data), allow_pickle=False)
            arrays = {n: loaded[n] for n in loaded.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise self.error(key, f"cannot read {_name(name)}: {exc}") from None
        known = ("vertices", "faces", "normals", "uvs")
        unknown = sorted(set(arrays) - set(known))
        if unknown or "vertices" not in arrays or "faces" not in arrays:
            raise self.error(key, f"{_name(name)} holds {', '.join(sorted(arrays)) or 'nothing'} "
                             f"(expected vertices, faces and optionally normals, uvs)")
        return self.mesh_arrays(arrays, f"{key}: {_name(name)}: ")  # errors name the array

    def mesh_arrays(self, source: dict, prefix: str) -> ObjMesh:
        """Vertices, faces and the optional per-vertex normals (made unit) and uvs of `source`,
        numpy arrays or lists; errors name the array as `prefix` + its name."""
        vertices = self.vertex_values(source["vertices"], f"{prefix}vertices", None, 3)
        faces = self.faces(source["faces"], f"{prefix}faces", len(vertices))
        normals, uvs = (None if n not in source else self.vertex_values(
            source[n], f"{prefix}{n}", len(vertices), size) for n, size in (("normals", 3),
                                                                            ("uvs", 2)))
        if normals is not None:
            zero = ~np.any(normals != 0, axis=1)
            if zero.any():
                raise self.error(f"{prefix}normals[{int(np.flatnonzero(zero)[0])}]",
                                 "must be a nonzero vector")
            normals = unit(normals)
        return ObjMesh(vertices, faces, normals, uvs)

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
            obj = self.mesh_arrays(spec, f"{key}.")
            vertices, faces, normals, uvs = obj.vertices, obj.faces, obj.normals, obj.uvs
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
        a, offset = self.transform(spec.get("transform", {}), tkey)
        # Without a transform the vertices are used as read: a 327k-triangle mesh spends a
        # fifth of its load time in the matrix product otherwise.
        identity = "transform" not in spec
        if not identity:
            vertices = vertices.reshape(-1, 3) @ a.T + offset
        if not np.all(np.abs(vertices) <= L.MAX_MAGNITUDE):
            raise self.error(
                tkey, f"moves vertices beyond {L.MAX_MAGNITUDE:g} in magnitude "
                f"(largest {np.max(np.abs(vertices)):.3g})"
            )
        if normals is not None and not identity:
            # Normals follow the inverse transpose of A (n @ A^-1 as rows): they stay
            # perpendicular to the surface under non-uniform scale and shear. Unit normals
            # under a matrix whose singular values are at least MIN_LENGTH stay finite. They
            # arrive unit (the OBJ reader and mesh_arrays normalise them).
            normals = unit(normals @ np.linalg.inv(a))
        if np.linalg.det(a) < 0:
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

    def transform(self, value: Any, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(A, t) of x -> A x + t, in float64: scale, then rotate about x, y, z in turn, then
        translate; or a 4x4 `matrix` (row-major, last row 0 0 0 1)."""
        spec = self.table(value, key)
        self.keys(spec, key, _TRANSFORM_KEYS, ())
        if "matrix" in spec:
            others = [k for k in ("translate", "rotate", "scale") if k in spec]
            if others:
                raise self.error(key, f"give matrix or {', '.join(others)}, not both")
            return self.matrix(spec["matrix"], f"{key}.matrix")
        translate = np.array(self.vec3(spec.get("translate", (0, 0, 0)), f"{key}.translate"))
        rotation = rotation_matrix(self.vec3(spec.get("rotate", (0, 0, 0)), f"{key}.rotate"))
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
        return rotation * scale, translate

    def matrix(self, value: Any, key: str) -> tuple[np.ndarray, np.ndarray]:
        rows = value if isinstance(value, list) and len(value) == 4 else None
        if rows is None:
            raise self.error(key, f"expected 4 rows of 4 numbers, got {_show(value)}")
        m = np.array([self.numbers(row, f"{key}[{i}]", 4) for i, row in enumerate(rows)])
        if m[3].tolist() != [0.0, 0.0, 0.0, 1.0]:
            raise self.error(f"{key}[3]", f"must be [0, 0, 0, 1] (an affine transform), got "
                             f"{_show(rows[3])}")
        if np.linalg.svd(m[:3, :3], compute_uv=False).min() < L.MIN_LENGTH:
            raise self.error(key, "is singular: it flattens space (its 3x3 part must be "
                             "invertible)")
        return m[:3, :3], m[:3, 3]
