"""Wavefront MTL material libraries -> clray materials.

MTL is the Phong model clray shades with, plus illumination models (`illum` 0-10) that switch
ray-traced reflection and refraction on. docs/scene_format.md (OBJ materials) has the table
this module implements; keys clray does not model give one warning per key and file, values
it cannot read are errors naming the file and line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from clray.errors import SceneError
from clray.scene import limits as L
from clray.scene.files import lf_line_ends
from clray.scene.model import Material

Vec3 = tuple[float, float, float]

# Keys clray reads besides illum and map_Kd; every other key gives a warning.
_COLORS = ("Ka", "Kd", "Ks", "Tf", "Ke")
_NUMBERS = ("Ns", "Ni", "d", "Tr")
# Texture map options and how many values follow each: -s, -o and -t (scale, offset,
# turbulence) take u and optionally v and w, so up to 3 numbers; the others a fixed count.
_MAP_OPTIONS = {"-s": 3, "-o": 3, "-t": 3, "-mm": 2, "-bm": 1, "-boost": 1, "-texres": 1,
                "-blendu": 1, "-blendv": 1, "-clamp": 1, "-cc": 1, "-imfchan": 1}
_UVW_OPTIONS = ("-s", "-o", "-t")
# The MTL statements clray does not model (warned of): with the keys above, illum and the
# map_ statements, what a material library's first statement may be. Any other word before
# the first newmtl says the file is not a material library (an `mtllib` naming the wrong
# file), and is not shown: it may be any file's first word.
_UNMODELLED = ("bump", "disp", "decal", "refl", "norm", "sharpness", "Pr", "Pm", "Ps", "Pc",
               "Pcr", "aniso", "anisor")
# Text of the file shown in a message is cut to this many characters.
ECHO_CHARS = 40
# Illumination models with ray-traced reflection, and those that transmit.
REFLECTING = (3, 4, 5, 6, 7, 8)
TRANSMITTING = (4, 6, 7, 9)


@dataclass
class MtlMaterial:
    """One `newmtl` block as read: only the keys the file gives."""

    name: str
    line: int
    colors: dict[str, Vec3] = field(default_factory=dict)
    numbers: dict[str, float] = field(default_factory=dict)
    illum: int | None = None
    map_kd: TextureMap | None = None
    # An Ni outside IOR_RANGE (exporters write `Ni 0`) and its line: unset where the
    # material does not refract (a warning), an error where it does (_check_ni).
    outside_ni: tuple[int, float] | None = None


@dataclass(frozen=True)
class TextureMap:
    """A `map_Kd` statement: the image (relative to the MTL file) and its -s scale."""

    line: int
    file: str
    scale: tuple[float, float] = (1.0, 1.0)
    # Options read past: -o and -t (offset, turbulence; not modelled unless zero) and the others.
    ignored: tuple[str, ...] = ()


@dataclass
class MtlLibrary:
    materials: dict[str, MtlMaterial]
    warnings: list[str]


def parse_mtl(data: bytes, path: Path, shown: str) -> MtlLibrary:
    """The materials of an MTL file; `path` names it in errors, `shown` in warnings."""
    materials: dict[str, MtlMaterial] = {}
    warned: dict[str, int] = {}
    warnings: list[str] = []
    current: MtlMaterial | None = None
    # A UTF-8 byte order mark (Windows editors write one) would be part of the first key.
    data = lf_line_ends(data.removeprefix(b"\xef\xbb\xbf"))
    for number, raw in enumerate(data.split(b"\n"), start=1):
        words = raw.split(b"#", 1)[0].decode("utf-8", errors="replace").split()
        if not words:
            continue
        key, args = words[0], words[1:]
        if key == "newmtl":
            if current is not None:
                _check_ni(current, path, shown, warnings)
            name = " ".join(args)
            current = MtlMaterial(name, number)
            materials[name] = current
            continue
        if current is None:
            if not _is_statement(key):
                raise SceneError(path, f"line {number}", "not a material library: its first "
                                 "statement is not an MTL one (expected newmtl)")
            raise SceneError(path, f"line {number}", f"{key} before the first newmtl")
        if key in _COLORS:
            current.colors[key] = _color(path, number, key, args)
        elif key == "Ni":
            value = _number(path, number, key, args, check=False)
            if L.IOR_RANGE[0] <= value <= L.IOR_RANGE[1]:
                current.numbers[key], current.outside_ni = value, None
            else:
                current.numbers.pop(key, None)
                current.outside_ni = (number, value)
        elif key in _NUMBERS:
            current.numbers[key] = _number(path, number, key, args)
        elif key == "illum":
            current.illum = _illum(path, number, args)
        elif key == "map_Kd":
            current.map_kd = _texture_map(path, number, key, args)
        else:
            warned.setdefault(key, number)
    if current is not None:
        _check_ni(current, path, shown, warnings)
    warnings += [f"{shown}: line {line}: {_cut(key)} is not modelled by clray (ignored in the "
                 "whole file)" for key, line in warned.items()]
    return MtlLibrary(materials, warnings)


def _check_ni(mtl: MtlMaterial, path: Path, shown: str, warnings: list[str]) -> None:
    """At the end of a material's block, where its illum is known: an Ni outside IOR_RANGE is
    an error where the material refracts by it (illum 4, 6, 7, 9), else unset (the default
    index, which only those models use) with a warning naming the file and line. Blender
    2.62 writes `Ni 0.000000` for every material."""
    if mtl.outside_ni is None:
        return
    line, value = mtl.outside_ni
    low, high = L.IOR_RANGE
    if mtl.illum in TRANSMITTING:
        raise _error(path, line, "Ni", f"must be in [{low:g}, {high:g}] (illum {mtl.illum} "
                     f"refracts by it), got {value:g}")
    warnings.append(f"{shown}: line {line}: Ni {value:g} is outside [{low:g}, {high:g}]: read "
                    f"as unset (material {_cut(mtl.name)!r} does not refract)")


def _is_statement(key: str) -> bool:
    """Whether `key` is an MTL statement (read, or warned of as not modelled)."""
    return (key in (*_COLORS, *_NUMBERS, *_UNMODELLED, "newmtl", "illum")
            or key.startswith("map_"))


def _cut(text: str) -> str:
    """Text of the file, cut to ECHO_CHARS characters, for a message."""
    return text if len(text) <= ECHO_CHARS else text[:ECHO_CHARS] + "..."


def _error(path: Path, number: int, key: str, message: str) -> SceneError:
    return SceneError(path, f"line {number}", f"{key}: {message}")


def _floats(path: Path, number: int, key: str, args: list[str]) -> list[float]:
    try:
        values = [float(a) for a in args]
    except ValueError:
        raise _error(path, number, key, f"expected numbers, got {_cut(' '.join(args))!r}") from None
    if not all(math.isfinite(v) and abs(v) <= L.MAX_MAGNITUDE for v in values):
        raise _error(path, number, key, "numbers must be finite")
    return values


def _color(path: Path, number: int, key: str, args: list[str]) -> Vec3:
    if args and args[0] in ("spectral", "xyz"):
        raise _error(path, number, key, f"the {args[0]} form is not supported (give r g b)")
    values = _floats(path, number, key, args)
    if len(values) == 1:  # one number is a grey
        values = values * 3
    if len(values) != 3:
        raise _error(path, number, key, f"expected 1 or 3 numbers, got {len(values)}")
    if min(values) < 0 or max(values) > L.MAX_COLOR:
        raise _error(path, number, key, f"components must be in [0, {L.MAX_COLOR:g}]")
    return (values[0], values[1], values[2])


_NUMBER_RANGE = {"Ns": (0.0, L.MAX_SHININESS), "Ni": L.IOR_RANGE, "d": (0.0, 1.0),
                 "Tr": (0.0, 1.0)}


def _number(path: Path, number: int, key: str, args: list[str], check: bool = True) -> float:
    # `d -halo 0.5`: the halo form is read as plain dissolve.
    values = _floats(path, number, key, args[1:] if args[:1] == ["-halo"] else args)
    if len(values) != 1:
        raise _error(path, number, key, f"expected 1 number, got {len(values)}")
    low, high = _NUMBER_RANGE[key]
    if check and not low <= values[0] <= high:
        raise _error(path, number, key, f"must be in [{low:g}, {high:g}], got {values[0]:g}")
    return values[0]


def _illum(path: Path, number: int, args: list[str]) -> int:
    # ASCII digits only (str.isdigit() takes '¹', which int() refuses), and leading zeros
    # stripped before int(): thousands of digits would hit Python's integer-string limit.
    digits = (args[0].lstrip("0") or "0") if len(args) == 1 else ""
    if not (digits.isascii() and digits.isdigit() and len(digits) <= 2 and int(digits) <= 10):
        raise _error(path, number, "illum", f"expected an integer 0-10, got "
                     f"{_cut(' '.join(args))!r}")
    return int(digits)


def _texture_map(path: Path, number: int, key: str, args: list[str]) -> TextureMap:
    scale, ignored, i = (1.0, 1.0), [], 0
    while i < len(args) - 1 and args[i] in _MAP_OPTIONS:
        option, n = args[i], _MAP_OPTIONS[args[i]]
        values = args[i + 1:i + 1 + n]
        if option in _UVW_OPTIONS:
            # u is required; v and w may be left out (1 for -s, 0 for -o and -t): only the
            # numbers that follow are the option's, the next word may be the file name.
            given = []
            while values and len(given) < n:
                try:
                    given.append(float(values[0]))
                except ValueError:
                    break
                values = values[1:]
            if not given or not all(math.isfinite(v) for v in given):
                raise _error(path, number, key, f"{option}: expected numbers")
            if option == "-s":
                scale = (given[0], given[1] if len(given) > 1 else 1.0)
                if min(scale) <= 0:
                    raise _error(path, number, key, "-s: scales must be > 0")
            elif any(given[:2]):  # a zero offset or turbulence changes nothing
                ignored.append(option)
            i += 1 + len(given)
            continue
        ignored.append(option)
        i += 1 + n
    if i >= len(args):
        raise _error(path, number, key, "expected an image file name")
    return TextureMap(number, " ".join(args[i:]), scale, tuple(ignored))


def _mean(c: Vec3) -> float:
    return (c[0] + c[1] + c[2]) / 3.0


def to_material(mtl: MtlMaterial) -> Material:
    """The clray material of an MTL one, by the table in docs/scene_format.md."""
    kd = mtl.colors.get("Kd", (1.0, 1.0, 1.0))
    ks = _mean(mtl.colors.get("Ks", (0.0, 0.0, 0.0)))
    illum = 2 if mtl.illum is None else mtl.illum
    dissolve = mtl.numbers.get("d", 1.0 - mtl.numbers.get("Tr", 0.0))
    # Dissolve: see-through without bending. The MTL spec: "Dissolve works on all
    # illumination models", constant colour (illum 0) included.
    transmit, ior = min(1.0 - dissolve, L.MAX_BOUNCE_WEIGHT), 1.0
    if illum == 0:  # colour only: Kd under the ambient light, and the dissolve
        return Material(name=mtl.name, color=kd, ambient=1.0, diffuse=0.0, specular=0.0,
                        transmit=transmit, ior=ior,
                        emission=mtl.colors.get("Ke", (0.0, 0.0, 0.0)))
    if illum in TRANSMITTING:
        tf = mtl.colors.get("Tf")
        transmit = _mean(tf) if tf is not None else transmit
        ior = mtl.numbers.get("Ni", 1.0)
    transmit = min(transmit, L.MAX_BOUNCE_WEIGHT)
    reflect = min(ks, L.MAX_BOUNCE_WEIGHT) if illum in REFLECTING else 0.0
    fresnel = illum == 7 and transmit > 0
    if fresnel:
        # With Fresnel, reflect + transmit is what leaves the surface in all.
        reflect = min(reflect, L.MAX_BOUNCE_WEIGHT - transmit)
    return Material(
        name=mtl.name,
        color=kd,
        ambient=_mean(mtl.colors.get("Ka", (0.0, 0.0, 0.0))),
        diffuse=1.0,
        specular=ks if illum >= 2 else 0.0,
        shininess=mtl.numbers.get("Ns", Material.shininess),
        reflect=reflect,
        transmit=transmit,
        ior=ior,
        fresnel=fresnel,
        emission=mtl.colors.get("Ke", (0.0, 0.0, 0.0)),
    )
