"""Fuzzing harness: hostile scene files, OBJ meshes and their MTL libraries, PLY meshes, textures
and flags against `clray render`.

    python -m tests.fuzz --cases 100000 --seed 1          # long run, summary at the end
    python -m tests.fuzz --cases 2000 --strategies obj texture --render-fraction 0.1

Every case is classified as
  - ok: it loaded (or, for the fraction that is rendered, rendered with finite pixels only);
  - clean: an error the way the README promises it: exit 2 or 3, exactly one `clray: error:`
    line (other stderr lines only `clray: warning:`), naming the file and the key or line for
    a scene error, and no output file left behind;
  - bug: anything else (a traceback, another exit code, a raw warning, NaN pixels, a partial
    file, a hang). Each bug is saved, shrunk where the case is a scene table, under --bugs.

Most cases only load the scene in-process (milliseconds); --render-fraction of them run the
whole command in-process on an 8x6 image. tests/test_fuzz.py runs a few of each strategy with
hypothesis as part of the normal suite.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import io
import json
import math
import os
import random
import re
import shutil
import signal
import stat
import struct
import sys
import tempfile
import time
import traceback
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from clray import cli
from clray.errors import SceneError
from clray.scene.load import load_scene

STRATEGIES = ("scene", "bytes", "obj", "mtl", "ply", "gltf", "texture", "flags")
CASE_SECONDS = 30  # a case still running after this is a hang

# -- hostile values -------------------------------------------------------------------------------

NUMBERS: list[Any] = [
    0, -0.0, 1, -1, 0.5, 2, 3, 8, 1e-300, 5e-324, 1e-31, 1e-30, 1e30, 1.0000001e30, 1e39, 1e300,
    -1e308, 1.7976931348623157e308, math.nan, math.inf, -math.inf, 2**31, 2**63, 2**64, 10**400,
    -(10**400), 16384, 16385, 4096, 4097, 16, 17, 2**32 - 1, 2**32, 180, 90, 89.9999999, 1e-12,
    100, 0.01, 0.0099, 1e6, 1.000001e6, True, False, 1e18, 1e-18,
]
STRINGS = [
    "", "a", "sphere", "plane", "box", "triangle", "mesh", "cylinder", "cone", "checker",
    "image", "point", "directional", "m", "x\ny", "a" * 300, "../../nowhere", "/dev/zero",
    "t.png", "t16.png", "m.obj", "loop.obj", "fifo.obj", "dir", "bomb.png", "\u2028", "a\x00b",
    "clray: error: fake", "é", "tab\tname", "\udc80x", "gradient", "orthographic",
    "perspective", "instance", "pawn",
]
# Arrays nested this deep, written out as brackets by scene_text: as Python lists they would
# exhaust the recursion of this module's own writers.
DEEP = "\x00deep:{}\x00"
_DEEP_JSON = re.compile(r'"\\u0000deep:(\d+)\\u0000"')

KEYS = [
    "render", "camera", "materials", "lights", "objects", "width", "height", "spp", "max_depth",
    "background", "ambient", "seed", "position", "look_at", "up", "vfov", "hfov", "color",
    "diffuse", "specular", "shininess", "reflect", "transmit", "ior", "texture", "type", "size",
    "color2", "blend", "file", "repeat", "attenuation", "direction", "center", "radius", "point",
    "normal", "min", "max", "vertices", "faces", "transform", "scale", "rotate", "translate",
    "base", "axis", "angle", "capped", "material", "apex", "", "x\ny", "a.b", "objects[0]",
    "aperture", "focus_distance", "fresnel", "bottom", "top", "groups", "group", "matrix",
]


def hostile_value(rng: random.Random, depth: int = 0) -> Any:
    roll = rng.random()
    if roll < 0.4:
        return rng.choice(NUMBERS)
    if roll < 0.55:
        return rng.choice(STRINGS)
    if roll < 0.75:
        return [rng.choice(NUMBERS) for _ in range(rng.choice([0, 1, 2, 3, 3, 3, 4]))]
    if roll < 0.8:
        return DEEP.format(rng.choice([5, 30, 65, 100, 400, 1200, 100_000]))
    if roll < 0.85:
        return [[rng.choice(NUMBERS) for _ in range(3)] for _ in range(rng.randint(0, 4))]
    if roll < 0.9 and depth < 2:
        return {rng.choice(KEYS): hostile_value(rng, depth + 1) for _ in range(rng.randint(0, 3))}
    return rng.choice([None, {}, [], [{}], [[0, 1, 2]], [{"type": "sphere"}]])


# -- base scenes ----------------------------------------------------------------------------------

def base_scene(rng: random.Random) -> dict:
    """A valid 8x6 scene using every section, object type (instances of a group, and a shape in
    its own frame, among them), texture kind and light type."""
    objects: list[dict] = [
        {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "material": "glass"},
        {"type": "plane", "point": [0, -0.5, 0], "normal": [0, 1, 0], "material": "floor"},
        {"type": "box", "min": [-2, -0.5, -2], "max": [-1, 0.5, -1], "material": "mirror"},
        {"type": "triangle", "vertices": [[1, 0, 0], [2, 0, 0], [1, 1, 0]]},
        {"type": "mesh", "file": "m.obj", "material": "tex",
         "transform": {"scale": 0.5, "rotate": [0, 30, 0], "translate": [1, 0, 1]}},
        {"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]},
        {"type": "cylinder", "base": [2, -0.5, 0], "axis": [0, 1, 0], "radius": 0.3,
         "height": 1},
        {"type": "cone", "apex": [-2, 1, 1], "axis": [0, -1, 0], "angle": 20, "height": 1,
         "capped": False, "material": {"color": [0.2, 0.8, 0.2], "specular": 0.5}},
        {"type": "sphere", "center": [0, 0, 0], "radius": 0.3, "material": "mirror",
         "transform": {"scale": [1, 0.2, 1], "rotate": [10, 0, 20], "translate": [0, 1.5, 0]}},
        {"type": "instance", "group": "pawn", "transform": {"translate": [-1, 0, 2]}},
        {"type": "instance", "group": "pawn", "material": "glass",
         "transform": {"matrix": [[1, 0.3, 0, 1], [0, 1, 0, 0], [0, 0, 1, 2], [0, 0, 0, 1]]}},
    ]
    rng.shuffle(objects)
    return {
        "render": {"width": 8, "height": 6, "spp": 1, "max_depth": 3,
                   "background": rng.choice([
                       [0.1, 0.1, 0.2],
                       {"type": "gradient", "bottom": [0.2, 0.1, 0], "top": [0.1, 0.2, 0.9]},
                       {"type": "image", "file": "t.png"}]),
                   "ambient": [0.2, 0.2, 0.2], "seed": 1,
                   "linear": False, "exposure": 0.5, "png_bits": 8},
        "camera": rng.choice([
            {"position": [0, 2, 6], "look_at": [0, 0, 0], "up": [0, 1, 0], "vfov": 40},
            {"position": [0, 2, 6], "look_at": [0, 0, 0], "vfov": 40, "aperture": 0.2,
             "focus_distance": 5},
            {"position": [0, 2, 6], "look_at": [0, 0, 0], "type": "orthographic", "height": 4}]),
        "materials": {
            "glass": {"transmit": 0.9, "reflect": 0.1, "ior": 1.5, "specular": 0.5,
                      "fresnel": rng.random() < 0.5},
            "mirror": {"reflect": 0.8, "color": [0.9, 0.9, 0.9]},
            "floor": {"texture": {"type": "checker", "size": 0.5, "color2": [0, 0, 0]}},
            "tex": {"texture": {"type": "image", "file": rng.choice(["t.png", "t16.png"]),
                                "repeat": [2, 1], "blend": 0.8, "colorspace": "srgb"}},
        },
        "lights": [
            {"type": "point", "position": [-3, 5, 4], "color": [0.8, 0.8, 0.8],
             "attenuation": [1, 0, 0.01]},
            {"type": "directional", "direction": [1, -2, -1], "color": [0.3, 0.3, 0.3]},
            {"type": "spot", "position": [2, 4, 3], "direction": [-1, -2, -1], "angle": 30,
             "inner_angle": 20, "attenuation": [1, 0.1, 0]},
            {"type": "rect", "corner": [-1, 3, -1], "u": [2, 0, 0], "v": [0, 0, 1],
             "color": [0.5, 0.5, 0.5]},
            {"type": "disc", "center": [1, 3, 1], "normal": [0, -1, 0], "radius": 0.5},
            {"type": "sphere", "center": [-2, 2, 2], "radius": 0.2, "color": [3, 3, 3]},
        ],
        "groups": {"pawn": {"objects": [
            {"type": "sphere", "center": [0, 0.8, 0], "radius": 0.2, "material": "mirror"},
            {"type": "cylinder", "base": [0, 0, 0], "axis": [0, 1, 0], "radius": 0.1,
             "height": 0.7},
            {"type": "mesh", "vertices": [[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]],
             "faces": [[0, 1, 2]], "material": "tex"}]}},
        "objects": objects,
    }


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list) and len(node) < 50:
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def mutate(data: dict, rng: random.Random) -> dict:
    """1 to 4 random edits: replace a value, drop a key or element, add a key."""
    for _ in range(rng.randint(1, 4)):
        path = rng.choice(_paths(data)[1:])
        parent = data
        for step in path[:-1]:
            parent = parent[step]
        last = path[-1]
        op = rng.random()
        if op < 0.65:
            parent[last] = hostile_value(rng)
        elif op < 0.8:
            del parent[last]
        elif isinstance(parent[last], dict):
            parent[last][rng.choice(KEYS)] = hostile_value(rng)
        elif isinstance(parent[last], list) and parent[last]:
            parent[last].append(parent[last][0])
        else:
            parent[last] = hostile_value(rng)
    return data


# -- writing scene files --------------------------------------------------------------------------

def toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value) if value.bit_length() < 1000 else "1" + "0" * 400
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    return '"null"'  # TOML has no null; a string stands in


def scene_text(data: Any, suffix: str) -> str:
    if suffix == ".json":
        text = json.dumps(data, indent=1)
    elif not isinstance(data, dict):
        text = f"x = {toml_value(data)}\n"
    else:
        text = "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in data.items())
    return _DEEP_JSON.sub(lambda m: "[" * int(m[1]) + "1" + "]" * int(m[1]), text)


def byte_mutate(raw: bytes, rng: random.Random) -> bytes:
    data = bytearray(raw)
    for _ in range(rng.randint(1, 8)):
        at = rng.randrange(len(data) + 1)
        op = rng.random()
        if op < 0.3 and data:
            data[min(at, len(data) - 1)] = rng.randrange(256)
        elif op < 0.5:
            data[at:at] = rng.choice([b"[", b"]", b"{", b"}", b'"', b"\n", b"=", b",", b"\xff",
                                      b"9" * rng.choice([5, 50, 5000]), b"1e999", b"\x00",
                                      b"'''", b"#", b"[[objects]]\n"])
        elif op < 0.75:
            del data[at:at + rng.randint(1, 40)]
        else:
            start = rng.randrange(len(data) + 1)
            data[at:at] = data[start:start + rng.randint(1, 200)]
    return bytes(data)


# -- OBJ files and textures -----------------------------------------------------------------------

OBJ_NUMBERS = ["0", "1", "-1", "0.5", "1e39", "-1e39", "1e30", "nan", "inf", "1e-200", "-0",
               "1.5e-45", "abc", "1/2", "+.5", "5.", "1e", "9" * 40, "0x10", "1_0"]
OBJ_INDICES = ["1", "2", "3", "4", "-1", "-4", "0", "99999999999999999999", "1/1", "1//1",
               "1/1/1", "1/", "//", "1/1/", "a", "-0", "+2"]


def obj_text(rng: random.Random) -> bytes:
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "vt 0 0", "vt 1 1", "vn 0 0 1"]
    for _ in range(rng.randint(0, 12)):
        kind = rng.choice(["v", "vt", "vn", "f", "f", "#", "o", "", "usemtl"])
        if kind in ("v", "vt", "vn"):
            count = rng.choice([1, 2, 3, 3, 3, 4])
            lines.append(" ".join([kind, *(rng.choice(OBJ_NUMBERS) for _ in range(count))]))
        elif kind == "f":
            count = rng.choice([1, 2, 3, 3, 4, 5])
            lines.append(" ".join(["f", *(rng.choice(OBJ_INDICES) for _ in range(count))]))
        else:
            lines.append(f"{kind} {rng.choice(STRINGS[:12])}")
    lines.append(rng.choice(["f 1 2 3", "f 1//1 2//1 3//1", "f 1/1 2/2 3/1", "f 4 3 2 1"]))
    rng.shuffle(lines)
    text = rng.choice(["\n", "\r\n", "\n\n"]).join(lines).encode("utf-8", "surrogatepass")
    return byte_mutate(text, rng) if rng.random() < 0.2 else text


MTL_KEYS = ["Ka", "Kd", "Ks", "Tf", "Ke", "Ns", "Ni", "d", "Tr", "illum", "map_Kd", "bump",
            "Pr", "newmtl", "", "#", "map_Kd -s", "map_Kd -o", "d -halo"]
MTL_VALUES = ["0", "1", "0.5", "-1", "1e30", "1e400", "nan", "x", "11", "10", "spectral f.rfl",
              "xyz 1 1 1", "t.png", "missing.png", "dir", "fifo.obj", "bomb.png", "1 1", "a b c",
              # isdigit() takes a superscript, int() does not; thousands of digits hit
              # Python's integer-string limit; leading zeros are still a number.
              "\u00b9", "9" * 5000, "0" * 5000 + "7", "\u0663"]


def mtl_text(rng: random.Random) -> tuple[bytes, bytes]:
    """(OBJ, MTL): a quad whose faces use materials of a hostile library."""
    names = ["a", "b", "", "c d", "\u00e9"]
    obj = ["mtllib case.mtl", rng.choice(["", "mtllib missing.mtl", "mtllib dir", "mtllib"]),
           "v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "vt 0 0", "vt 1 0", "vt 1 1"]
    for _ in range(rng.randint(1, 4)):
        obj += [f"usemtl {rng.choice(names)}", rng.choice(["f 1/1 2/2 3/3", "f 1 2 3 4"])]
    mtl = ["newmtl a"] if rng.random() < 0.9 else []
    for _ in range(rng.randint(0, 14)):
        key = rng.choice(MTL_KEYS)
        if key == "newmtl" or rng.random() < 0.2:
            mtl.append(f"newmtl {rng.choice(names)}")
        else:
            mtl.append(" ".join([key, *(rng.choice(MTL_VALUES) for _ in
                                        range(rng.choice([0, 1, 1, 3])))]))
    text = "\n".join(mtl).encode("utf-8", "surrogatepass")
    return "\n".join(obj).encode(), byte_mutate(text, rng) if rng.random() < 0.2 else text


def ply_bytes(rng: random.Random) -> bytes:
    """A small PLY, ASCII or binary, with a hostile header line or body."""
    fmt = rng.choice(["ascii", "binary_little_endian", "binary_big_endian"])
    vertex = ["property float x", "property float y", "property float z"]
    if rng.random() < 0.5:
        vertex += ["property float nx", "property float ny", "property float nz"]
    count_type, count_code = rng.choice([("uchar", "B"), ("uchar", "B"), ("char", "b"),
                                         ("uint", "I"), ("float", "f")])
    face_element = rng.choice(["face", "face", "tristrips"])  # strips: -1 restarts them
    face = [f"property list {count_type} int vertex_indices"]
    header = ["ply", f"format {fmt} 1.0", "element vertex 4", *vertex, f"element {face_element} 2",
              *face, "end_header"]
    if rng.random() < 0.5:
        at = rng.randrange(len(header))
        header[at] = rng.choice(["element vertex 99999999999", "element face 0", "property x",
                                 "property float x", "property list uchar float q",
                                 "element vertex \u00b2", "comment", "format ascii 2.0", "",
                                 "element face " + "9" * 5000, "element vertex 0" + "0" * 5000,
                                 "property list uchar int x", "property list uchar int ny",
                                 "property list uchar int red", "element tristrips 1",
                                 # MeshLab's per-corner UVs, and a second list to read past.
                                 "property list uchar float texcoord",
                                 "property list uchar int vertex_indices",
                                 "property list uchar float vertex_indices"])
    n_props = len(vertex)
    values = [[rng.choice([0.0, 1.0, 0.5, -1.0, 1e30, 3e38, math.nan, math.inf]) if
               rng.random() < 0.1 else float(i % 2 + k) for k in range(n_props)] for i in range(4)]
    faces = [[3, 0, 1, 2], [rng.choice([3, 4, 2, 0, 255, -1]), 0, 2, 3, rng.choice([1, 4, -1])]]
    if rng.random() < 0.3:  # lists whose length changes from record to record
        faces = [[k, *rng.choice([[0, 1, 2, 3, 0], [3, -1, 2, 1, 0], [0, 0, 1, 2, 3]])[:k]]
                 for k in (rng.choice([3, 4, 5]) for _ in range(2))]
    if fmt == "ascii":
        body = "\n".join(" ".join(f"{v:g}" for v in row) for row in values) + "\n"
        body += "\n".join(" ".join(str(v) for v in f[:max(f[0], 0) + 1]) for f in faces) + "\n"
        raw = ("\n".join(header) + "\n" + body).encode()
    else:
        order = "<" if fmt.endswith("little_endian") else ">"
        body = b"".join(struct.pack(order + f"{n_props}f", *row) for row in values)
        for f in faces:
            k = f[0] % 128
            items = (f[1:] * 100)[:k]
            body += struct.pack(order + count_code, min(f[0], 127) if count_code == "b" else k)
            body += struct.pack(order + f"{k}i", *items)
        raw = ("\n".join(header) + "\n").encode() + body
    return byte_mutate(raw, rng) if rng.random() < 0.15 else raw


def png_header_only(width: int, height: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b""))
            + chunk(b"IEND", b""))


def texture_bytes(rng: random.Random) -> tuple[bytes, str]:
    """(file contents, suffix) of a random, often broken, image."""
    from PIL import Image

    roll = rng.random()
    if roll < 0.15:
        side = rng.choice([0, 1, 16384, 16385, 100_000, 2**31 - 1])
        return png_header_only(side, rng.choice([1, side, 6000])), ".png"
    if roll < 0.2:
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 300))), ".png"
    mode = rng.choice(["L", "RGB", "RGBA", "P", "I;16", "F", "LA", "1", "I", "CMYK"])
    size = (rng.randint(1, 9), rng.randint(1, 9))
    suffix = ".tiff" if mode in ("F", "I", "CMYK") else rng.choice([".png", ".png", ".gif",
                                                                     ".bmp"])
    if mode in ("I;16", "LA") and suffix != ".png":
        suffix = ".png"
    if mode == "F":
        values = np.array([rng.choice([0.0, 0.5, 2.0, -1.0, math.nan, math.inf])
                           for _ in range(size[0] * size[1])], dtype=np.float32)
        image = Image.fromarray(values.reshape(size[1], size[0]))
    elif mode == "I;16":
        image = Image.fromarray(np.full((size[1], size[0]), rng.randrange(65536), np.uint16))
    else:
        image = Image.new(mode, size)
        if mode == "P" and suffix == ".png" and rng.random() < 0.5:
            image.info["transparency"] = bytes([0, 255])
    stream = io.BytesIO()
    image.save(stream, format={".png": "PNG", ".gif": "GIF", ".bmp": "BMP",
                               ".tiff": "TIFF"}[suffix])
    data = stream.getvalue()
    if rng.random() < 0.3:
        data = data[: rng.randrange(len(data) + 1)] if rng.random() < 0.5 else \
            byte_mutate(data, rng)
    return data, suffix


# -- flags ----------------------------------------------------------------------------------------

FLAG_VALUES = {
    "-W": ["1", "8", "0", "-3", "16385", "2147483648", "9" * 50, "", "1e3", "0x10", " 8", "٣"],
    "-H": ["1", "6", "0", "16385", str(2**31), "two"],
    "--spp": ["1", "2", "0", "4097", str(2**31), str(2**63)],
    "--max-depth": ["0", "3", "-1", "17", str(2**31)],
    "--seed": ["0", "1", str(2**32 - 1), str(2**32), "-1", "9" * 5000],
    "--precision": ["float", "double", "half", ""],
    "-o": ["out.png", "out.pfm", "", ".", "..", "out.jpg", "out", "dir", "dir/", "nodir/x.png",
           "file/x.png", "x\ny.png", "OUT.PNG", "a" * 300 + ".png"],
    "--stats-json": ["s.json", "", ".", "dir", "dir/", "nodir/s.json", "out.png", "x\ny.json"],
    "--min-weight": ["0", "0.5", "1", "-1", "nan", "inf", "1e-40", "2"],
    "--exposure": ["0", "-2", "3.5", "nan", "-inf", "1e400", "-1e9", "40"],
    "--png-bits": ["8", "16", "4", "", "8.0"],
    "--aov": ["depth", "normal,albedo", "depth,depth", "nothing", "", ",", "DEPTH"],
    "--frames": ["0", "0:2", "5", "-1", "a:b", "3:1", "0:99999999"],
    # A scene file's camera is its own: these apply to mesh files only.
    "--view": ["front", "top", "iso", "x"],
    "--up": ["y", "z", "-z", "w"],
}
FLAG_SWITCHES = ["--srgb", "--linear", "-q", "-v", "--no-such-flag", "-W", "--aov-preview",
                 "--resume", "--ground", "--no-tuning"]


MESH_FILES = ["m.obj", "fifo.obj", "loop.obj", "missing.ply", "dir", "t.png", ""]
SCENE_FLAGS = ["--view", "--up"]  # `clray scene`'s own, with the switch --ground


def flags(rng: random.Random) -> list[str]:
    if rng.random() < 0.1:  # `clray scene MODEL`: the automatic scene written out
        argv = ["scene", rng.choice(MESH_FILES)]
        for _ in range(rng.randint(0, 3)):
            flag = rng.choice([*SCENE_FLAGS, "--ground"])
            argv += [flag] if flag == "--ground" else [flag, rng.choice(FLAG_VALUES[flag])]
        return argv
    argv = ["render", rng.choice(["scene.toml", "scene.json", "missing.toml", "fifo.toml", "dir",
                                  "", "scene.yaml", *MESH_FILES[:3]])]
    for _ in range(rng.randint(0, 5)):
        if rng.random() < 0.15:
            argv.append(rng.choice(FLAG_SWITCHES))
        else:
            flag = rng.choice(list(FLAG_VALUES))
            argv += [flag, rng.choice(FLAG_VALUES[flag])]
    return argv


# -- running one case -----------------------------------------------------------------------------

@dataclass
class Case:
    strategy: str
    files: dict[str, bytes]  # written into the work folder before the run
    argv: list[str] | None = None  # the command to run; None: load files["scene"] only
    data: Any = None  # the scene table, for shrinking
    suffix: str = ".toml"


@dataclass
class Outcome:
    kind: str  # "ok" | "clean" | "bug"
    detail: str = ""
    rendered: bool = False
    extra: dict = field(default_factory=dict)


class _Hang(Exception):
    pass


def gltf_bytes(rng: random.Random) -> tuple[str, bytes]:
    """(name, bytes) of a small glTF (an instanced mesh under a parent node, a textured
    material), .glb or .gltf with a data: URI, its JSON mutated (a value replaced by a hostile
    one, a key deleted, an accessor or view pointed out of range), or its bytes cut or
    mutated."""
    from tests.gltf_files import glb_bytes, instanced_cubes

    b = instanced_cubes()
    if rng.random() < 0.5:
        texels = np.zeros((2, 2, 3), np.uint8)
        b.doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {
            "index": b.image(texels)}
        b.doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = b.accessor(
            np.zeros((8, 2), np.float32), "VEC2")
    if rng.random() < 0.3:  # vertex colours, in range or not
        b.doc["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = b.accessor(
            np.float32(rng.choice([0.5, 2.0, -1.0])) * np.ones((8, 3), np.float32), "VEC3")
    glb = rng.random() < 0.5
    doc = b.document(None if glb else "data:application/octet-stream;base64,"
                     + base64.b64encode(b.blob).decode())
    for _ in range(rng.randint(0, 4)):
        _mutate_json(doc, rng)
    blob = bytes(b.blob)
    raw = glb_bytes(doc, blob) if glb else json.dumps(doc).encode()
    cut = rng.random()
    if cut < 0.15:
        raw = raw[: rng.randrange(len(raw))]
    elif cut < 0.3:
        raw = byte_mutate(raw, rng)
    return ("case.glb" if glb else "case.gltf"), raw


_GLTF_VALUES: list[Any] = [-1, 0, 1, 2, 3, 7, 99, 2**31, 10**400, 1e300, -0.5, 0.5, None, "x",
                           [], {}, [0, 0, 0, 0], True, 4, 5, 6, 5126, 5125, 5121, 5120, "VEC4",
                           "SCALAR", "MAT4", "data:,", "../m.obj", "/etc/x", "fifo.obj", "dir",
                           "KHR_draco_mesh_compression"]


def _mutate_json(doc: Any, rng: random.Random) -> None:
    """Replace or delete one value somewhere in `doc`."""
    node, depth = doc, rng.randint(1, 6)
    for _ in range(depth):
        keys = list(node) if isinstance(node, dict) else list(range(len(node))) \
            if isinstance(node, list) else []
        if not keys:
            return
        key = rng.choice(keys)
        child = node[key]
        if not isinstance(child, dict | list) or rng.random() < 0.3:
            if isinstance(node, dict) and rng.random() < 0.2:
                del node[key]
            else:
                node[key] = rng.choice(_GLTF_VALUES + NUMBERS[:20])
            return
        node = child


def make_workdir(folder: Path) -> None:
    """The files cases may name besides their own: valid, 16-bit and broken textures, a mesh,
    a FIFO, a symlink loop, a directory, a regular file where a folder is expected."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 3), (200, 100, 50)).save(folder / "t.png")
    Image.fromarray(np.full((3, 4), 30000, np.uint16)).save(folder / "t16.png")
    (folder / "bomb.png").write_bytes(png_header_only(100_000, 100_000))
    (folder / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"
                                  "f 1/1/1 2/2/1 3/3/1\n")
    for name in ("fifo.obj", "fifo.toml"):
        if not (folder / name).exists():
            os.mkfifo(folder / name)
    if not (folder / "loop.obj").is_symlink():
        os.symlink("loop.obj", folder / "loop.obj")
    (folder / "dir").mkdir(exist_ok=True)
    (folder / "file").write_text("")
    base = base_scene(random.Random(0))
    (folder / "scene.toml").write_text(scene_text(base, ".toml"))
    (folder / "scene.json").write_text(scene_text(base, ".json"))


def generate(strategy: str, rng: random.Random) -> Case:
    if strategy == "scene":
        suffix = rng.choice([".toml", ".json"])
        return _with_data(Case(strategy, {}, suffix=suffix), mutate(base_scene(rng), rng))
    if strategy == "bytes":
        suffix = rng.choice([".toml", ".json"])
        raw = scene_text(base_scene(rng), suffix).encode()
        return Case(strategy, {f"case{suffix}": byte_mutate(raw, rng)}, suffix=suffix)
    if strategy == "obj":
        data = base_scene(rng)
        data["objects"].append({"type": "mesh", "file": "case.obj",
                                "transform": {"scale": rng.choice([1, -1, 1e-20, 1e20, 1e30])}})
        return _with_data(Case(strategy, {"case.obj": obj_text(rng)}), data)
    if strategy == "mtl":
        data = base_scene(rng)
        data["objects"].append({"type": "mesh", "file": "case.obj"})
        obj, mtl = mtl_text(rng)
        return _with_data(Case(strategy, {"case.obj": obj, "case.mtl": mtl}), data)
    if strategy == "ply":
        data = base_scene(rng)
        data["objects"].append({"type": "mesh", "file": "case.ply"})
        return _with_data(Case(strategy, {"case.ply": ply_bytes(rng)}), data)
    if strategy == "gltf":
        data = base_scene(rng)
        name, raw = gltf_bytes(rng)
        data["objects"].append({"type": "mesh", "file": name})
        return _with_data(Case(strategy, {name: raw}), data)
    if strategy == "texture":
        data = base_scene(rng)
        raw, suffix = texture_bytes(rng)
        data["materials"]["tex"]["texture"]["file"] = f"case{suffix}"
        return _with_data(Case(strategy, {f"case{suffix}": raw}), data)
    return Case(strategy, {}, argv=flags(rng))


def _scene_name(case: Case) -> str:
    return f"case{case.suffix}"


def run_case(case: Case, work: Path, render: bool) -> Outcome:
    """Write the case's files into `work`, run it, classify the outcome, clean up."""
    files = case.files
    for name, data in files.items():
        (work / name).write_bytes(data)
    before = set(os.listdir(work))
    raw_before = _fd2_size()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_SECONDS)
    try:
        if case.argv is not None:
            outcome = _run_cli(case.argv, work, before)
        elif render:
            outcome = _run_cli(["render", _scene_name(case), "-W", "8", "-H", "6", "-o", "r.png",
                                "--stats-json", "r.json"], work, before)
        else:
            outcome = _run_load(work / _scene_name(case))
        raw = _fd2_since(raw_before)
        return Outcome("bug", f"raw output on stderr: {raw!r}") if raw else outcome
    except _Hang:
        return Outcome("bug", f"still running after {CASE_SECONDS} s")
    except Exception:
        return Outcome("bug", traceback.format_exc())
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        for name in set(os.listdir(work)) - before:
            _remove(work / name)
        for name in files:
            _remove(work / name)


def _fd2_size() -> int | None:
    """Where file descriptor 2 ends, if it is a file (as fuzz() and pytest make it): C code
    (libtiff, say) writes there directly, past any redirection of sys.stderr."""
    info = os.fstat(2)
    return info.st_size if stat.S_ISREG(info.st_mode) else None


def _fd2_since(size: int | None) -> bytes:
    if size is None:
        return b""
    return os.pread(2, 300, size)


@contextlib.contextmanager
def _fd2_to_a_file() -> Any:
    """Point file descriptor 2 at a scratch file for the run, so _fd2_since can see raw
    output; yields a stream to the real stderr for progress messages."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink, os.fdopen(os.dup(saved), "w", buffering=1) as real:
        os.dup2(sink.fileno(), 2)
        try:
            yield real
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def _alarm(_signum: int, _frame: object) -> None:
    raise _Hang


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


# A scene error names a key path (`objects[3].radius`, `materials."x".ior`) or a line.
_LOCATED = re.compile(r'^[^:]+: (line \d+: |(?:[\w\[\].-]|"(?:[^"\\]|\\.)*"(?:\.\.\.)?)+: '
                      r"|.*\(at (line \d+|end of document))"
                      # A PLY file's element (its name a word of any characters, as the
                      # header gives it) and line, or header line.
                      r"|^[^:]+: (element \S+?(, line \d+)?|header line \d+): ")
_FILE_LEVEL = ("cannot read scene file", "not valid UTF-8", "unknown scene file type",
               "expected a table at the top level", "cannot read mesh file", "not a PLY file",
               "no end_header line", "no format line", "header of over",
               "expected a mesh file",  # `clray scene` given a file of another kind
               # A glTF file's whole-file errors (its other errors name the JSON path).
               "truncated .glb", "not glTF JSON", "JSON nested too deeply",
               "expected a JSON object at the top level", ".glb version", ".glb: the first")


def _check_scene_error(message: str) -> str | None:
    """Why a scene error message breaks the promise, or None."""
    if "\n" in message:
        return "message spans lines"
    if _LOCATED.match(message) is None and not any(p in message for p in _FILE_LEVEL):
        return "message names neither a key nor a line"
    return None


def _run_load(path: Path) -> Outcome:
    with warnings_as_errors():
        try:
            load_scene(path)
        except SceneError as err:
            problem = _check_scene_error(str(err))
            return Outcome("bug", problem + ": " + str(err)) if problem else \
                Outcome("clean", str(err))
    return Outcome("ok")


@contextlib.contextmanager
def warnings_as_errors() -> Any:
    import warnings

    # A warning that gets out of the loader reaches the user raw: that is a bug too.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def _run_cli(argv: list[str], work: Path, before: set[str]) -> Outcome:
    err = io.StringIO()
    cwd = os.getcwd()
    os.chdir(work)
    try:
        # stdout with a binary buffer beneath, as a terminal's: `clray scene` writes bytes.
        out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = cli.main(argv)
    finally:
        os.chdir(cwd)
    lines = err.getvalue().splitlines()
    # -v adds the run's figures, indented, after the summary line.
    verbose = "-v" in argv or "--verbose" in argv
    stray = [line for line in lines
             if not line.startswith("clray: ") and not (verbose and line.startswith("  "))]
    errors = [line for line in lines if line.startswith("clray: error: ")]
    new = sorted(set(os.listdir(work)) - before)
    if stray:
        return Outcome("bug", f"exit {code}, stray stderr line {stray[0]!r}")
    if code == 0:
        if errors:
            return Outcome("bug", f"exit 0 with {errors[0]!r}")
        if any("NaN or infinite" in line for line in lines):
            return Outcome("bug", "non-finite pixels: " + " | ".join(lines))
        return Outcome("ok", rendered=True)
    # Exit 1 is promised for an output that cannot be written, and only for that.
    writing = code == 1 and len(errors) == 1 and errors[0].startswith("clray: error: cannot "
                                                                      "write ")
    if code not in (2, 3) and not writing:
        return Outcome("bug", f"exit {code}: " + " | ".join(lines))
    if len(errors) != 1 or any(not line.startswith("clray: warning: ") for line in lines
                               if line not in errors):
        return Outcome("bug", f"exit {code}, not one error line: " + " | ".join(lines))
    if new:
        return Outcome("bug", f"exit {code} left files {new}")
    if code == 3:
        problem = _check_scene_error(errors[0][len("clray: error: "):])
        if problem:
            return Outcome("bug", f"{problem}: {errors[0]}")
    return Outcome("clean", errors[0])


# -- shrinking and saving bugs --------------------------------------------------------------------

def shrink(case: Case, work: Path, render: bool, outcome: Outcome) -> Case:
    """Drop keys and array elements of the scene table while the same bug remains."""
    if case.data is None:
        return case
    signature = outcome.detail.strip().splitlines()[-1:] if outcome.detail else []
    changed = True
    while changed:
        changed = False
        for path in sorted(_paths(case.data)[1:], key=len):
            trial = json.loads(json.dumps(case.data, default=str))
            parent = trial
            try:
                for step in path[:-1]:
                    parent = parent[step]
                del parent[path[-1]]
            except (KeyError, IndexError, TypeError):
                continue
            candidate = _with_data(case, trial)
            result = run_case(candidate, work, render)
            if result.kind == "bug" and result.detail.strip().splitlines()[-1:] == signature:
                case, changed = candidate, True
                break
    return case


def _with_data(case: Case, data: Any) -> Case:
    """`case` with its scene file written from `data`."""
    files = {**case.files, _scene_name(case): scene_text(data, case.suffix).encode(
        "utf-8", "surrogatepass")}
    return Case(case.strategy, files, case.argv, data, case.suffix)


def save_bug(case: Case, outcome: Outcome, folder: Path, number: int, render: bool) -> Path:
    out = folder / f"{case.strategy}-{number:05d}"
    out.mkdir(parents=True, exist_ok=True)
    for name, data in case.files.items():
        (out / name).write_bytes(data)
    command = case.argv or ["render", _scene_name(case)] + (["-W", "8", "-H", "6"] if render
                                                            else [])
    (out / "report.txt").write_text(
        f"strategy: {case.strategy}\nrun in a folder made by tests.fuzz.make_workdir, with "
        f"these files: clray {' '.join(map(repr, command))}\n\n{outcome.detail}\n")
    return out


# -- the long run ---------------------------------------------------------------------------------

def fuzz(cases: int, seed: int, strategies: tuple[str, ...], render_fraction: float,
         bugs: Path, time_limit: float | None = None) -> dict:
    """Run `cases` cases, round robin over `strategies`; progress and bugs go to stderr."""
    rng = random.Random(seed)
    counts: dict[str, Counter] = {s: Counter() for s in strategies}
    started = time.perf_counter()
    saved = 0
    with tempfile.TemporaryDirectory(prefix="clray-fuzz-") as tmp, _fd2_to_a_file() as real:
        work = Path(tmp)

        def say(message: str) -> None:
            print(message, file=real)

        make_workdir(work)
        for n in range(cases):
            if time_limit is not None and time.perf_counter() - started > time_limit:
                break
            strategy = strategies[n % len(strategies)]
            case_rng = random.Random(rng.getrandbits(64))
            case = generate(strategy, case_rng)
            render = case.argv is None and case_rng.random() < render_fraction
            outcome = run_case(case, work, render)
            key = outcome.kind if outcome.kind != "ok" else ("rendered" if outcome.rendered
                                                             else "loaded")
            counts[strategy][key] += 1
            if outcome.kind == "bug":
                saved += 1
                small = shrink(case, work, render, outcome)
                where = save_bug(small, run_case(small, work, render), bugs, saved, render)
                say(f"bug #{saved} ({strategy}): {outcome.detail.strip().splitlines()[-1][:200]}"
                    f" -> {where}")
            if (n + 1) % 5000 == 0:
                say(f"{n + 1} cases, {time.perf_counter() - started:.0f} s, {saved} bugs")
    total = {k: sum(c[k] for c in counts.values())
             for k in ("loaded", "rendered", "clean", "bug")}
    return {"seed": seed, "cases": sum(sum(c.values()) for c in counts.values()),
            "seconds": round(time.perf_counter() - started, 1), "total": total,
            "by_strategy": {s: dict(c) for s, c in counts.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__.split(
        "\n\n")[0])
    parser.add_argument("--cases", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--strategies", nargs="+", choices=STRATEGIES, default=list(STRATEGIES))
    parser.add_argument("--render-fraction", type=float, default=0.02,
                        help="share of scene, bytes, obj and texture cases run through the "
                             "whole command (8x6 image) rather than only loaded")
    parser.add_argument("--time-limit", type=float, help="stop after this many seconds")
    parser.add_argument("--bugs", type=Path, default=Path("fuzz-bugs"),
                        help="folder for the reproducers")
    parser.add_argument("--json", type=Path, help="also write the summary here")
    args = parser.parse_args(argv)
    summary = fuzz(args.cases, args.seed, tuple(args.strategies), args.render_fraction,
                   args.bugs, args.time_limit)
    text = json.dumps(summary, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 1 if summary["total"]["bug"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
