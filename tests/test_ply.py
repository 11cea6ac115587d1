"""The PLY reader: the three formats give the same mesh, polygons are fan-triangulated as in
OBJ files, unknown elements and properties are read past, and errors name file and element.
Files are written here with struct, independently of the reader."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene.load import scene_from_dict
from clray.scene.obj import parse_obj
from clray.scene.ply import read_ply

VERTS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 1.5, 0.25]])
NORMALS = np.array([[0, 0, 1], [0, 0, 2], [0, 1, 1], [0, 0, 1], [1, 0, 0]], dtype=float)
UVS = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.75]])
COLORS = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30], [255, 255, 255]])
# A triangle, a quad and a pentagon: fans give 1 + 2 + 3 triangles.
POLYGONS = [[0, 1, 2], [0, 1, 2, 3], [0, 1, 2, 4, 3]]
FANNED = [[0, 1, 2], [0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 4], [0, 4, 3]]

HEADER_VERTEX = ("element vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float nx\nproperty float ny\nproperty float nz\n"
                 "property float u\nproperty float v\n"
                 "property uchar red\nproperty uchar green\nproperty uchar blue\n")
# A scalar after the list, and an element the reader ignores.
HEADER_FACE = ("element face 3\nproperty list uchar int vertex_indices\nproperty int flags\n"
               "element edge 1\nproperty int vertex1\nproperty int vertex2\n")


def ply_bytes(fmt: str, polygons: list = POLYGONS) -> bytes:
    header = (f"ply\nformat {fmt} 1.0\ncomment made by hand\n{HEADER_VERTEX}"
              f"{HEADER_FACE.replace('face 3', f'face {len(polygons)}')}end_header\n")
    if fmt == "ascii":
        rows = [" ".join(f"{x:g}" for x in (*p, *n, *t)) + " " + " ".join(map(str, c))
                for p, n, t, c in zip(VERTS, NORMALS, UVS, COLORS, strict=True)]
        rows += [f"{len(f)} {' '.join(map(str, f))} 7" for f in polygons]
        rows += ["0 1"]
        return (header + "\n".join(rows) + "\n").encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    body = b"".join(struct.pack(order + "8f3B", *p, *n, *t, *c)
                    for p, n, t, c in zip(VERTS, NORMALS, UVS, COLORS, strict=True))
    body += b"".join(struct.pack(f"{order}B{len(f)}ii", len(f), *f, 7) for f in polygons)
    body += struct.pack(order + "2i", 0, 1)
    return header.encode() + body


FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_gives_the_mesh(fmt):
    ply = read_ply(ply_bytes(fmt), Path("m.ply"))
    mesh = ply.mesh
    np.testing.assert_array_equal(mesh.vertices, VERTS.astype(np.float32))
    np.testing.assert_array_equal(mesh.faces, FANNED)
    unit = NORMALS / np.linalg.norm(NORMALS, axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.normals, unit, rtol=1e-7)
    np.testing.assert_array_equal(mesh.uvs, UVS.astype(np.float32))
    np.testing.assert_allclose(ply.colors, COLORS / 255.0)


def test_fan_matches_the_obj_reader():
    text = "".join(f"v {x} {y} {z}\n" for x, y, z in VERTS)
    text += "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in POLYGONS)
    obj = parse_obj(text.encode(), Path("m.obj"))
    ply = read_ply(ply_bytes("binary_little_endian"), Path("m.ply")).mesh
    np.testing.assert_array_equal(obj.vertices[obj.faces], ply.vertices[ply.faces])


def test_binary_runs_of_one_list_length():
    # Triangles, then quads, then triangles: three runs, each one view.
    polygons = [[0, 1, 2]] * 3 + [[0, 1, 2, 3]] * 2 + [[1, 2, 4]] * 2
    mesh = read_ply(ply_bytes("binary_little_endian", polygons), Path("m.ply")).mesh
    expected = [[0, 1, 2]] * 3 + [[0, 1, 2], [0, 2, 3]] * 2 + [[1, 2, 4]] * 2
    np.testing.assert_array_equal(mesh.faces, expected)


def test_scene_mesh_file_takes_ply(tmp_path):
    (tmp_path / "m.ply").write_bytes(ply_bytes("binary_big_endian"))
    data = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
            "objects": [{"type": "mesh", "file": "m.ply",
                         "transform": {"translate": [1, 0, 0]}}]}
    scene = scene_from_dict(data, tmp_path / "s.toml")
    mesh = scene.objects[0]
    np.testing.assert_array_equal(mesh.vertices, VERTS.astype(np.float32) + np.array([1, 0, 0]))
    assert len(mesh.faces) == len(FANNED)
    assert any("vertex colours are not rendered yet" in w for w in scene.warnings)


def _errors(data: bytes) -> str:
    with pytest.raises(SceneError) as info:
        read_ply(data, Path("bad.ply"))
    return str(info.value)


@pytest.mark.parametrize("fmt", FORMATS[1:])
def test_truncated_binary_names_the_element(fmt):
    data = ply_bytes(fmt)
    message = _errors(data[:-20])
    assert "bad.ply" in message and "element face" in message and "records" in message


def test_truncated_vertex_element():
    data = ply_bytes("binary_little_endian")
    end = data.index(b"end_header\n") + len(b"end_header\n")
    message = _errors(data[:end + 40])
    assert "element vertex" in message and "1 of 5" in message


@pytest.mark.parametrize(
    "edit, where, text",
    [
        ((b"0.5 1.5 0.25", b"0.5 x.5 0.25"), "element vertex, line", "expected a number"),
        ((b"3 0 1 2 7", b"3 0 1 9 7"), "element face", "out of range"),
        ((b"3 0 1 2 7", b"2 0 1 7"), "element face", "at least 3 vertices"),
        ((b"4 0 1 2 3 7", b"4 0 1 2 7"), "element face, line", "a list"),
        ((b"property float nx", b"property float128 nx"), "header line", "property TYPE NAME"),
        ((b"format ascii 1.0", b"format ascii 2.0"), "header line", "format"),
        ((b"ply\n", b"plyx\n"), "bad.ply", "not a PLY file"),
        ((b"end_header", b"end_hdr"), "bad.ply", "end_header"),
        ((b"property float x\n", b"property float q\n"), "element vertex", "x, y, z"),
        ((b"vertex_indices", b"corners"), "element face", "vertex_indices"),
        ((b"\n0 0 0 0 0 1", b"\nnan 0 0 0 0 1"), "element vertex", "finite"),
    ],
)
def test_ascii_errors_name_file_and_element(edit, where, text):
    message = _errors(ply_bytes("ascii").replace(*edit, 1))
    assert "bad.ply" in message and where in message and text in message, message


_HEADER = b"ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\n" \
    b"property float z\nelement face 1\n"


@pytest.mark.parametrize(("data", "message"), [
    (_HEADER % 1 + b"property list uchar int vertex_indices\nend_header\n0 0 0\n3 0 0 1\n",
     "bad.ply: element face: record 0: vertex index 1 out of range (1 vertex)"),
    (_HEADER % 3 + b"property list uchar int vertex_indices\nelement extra 1\nproperty float w\n"
     b"end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n1 2\n",
     "bad.ply: element extra, line 16: expected 1 number, got 2"),
    (_HEADER % 3 + b"property float q\nproperty list uchar int vertex_indices\nend_header\n"
     b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
     "bad.ply: element face, line 14: expected 1 number and a list (its length first), got "
     "b'3 0 1 2'"),
])
def test_counts_of_one_take_the_singular(data, message):
    assert _errors(data) == message


def test_zero_normal_is_an_error():
    data = ply_bytes("ascii").replace(b"0 0 0 0 0 1", b"0 0 0 0 0 0", 1)
    assert "zero-length normal" in _errors(data)
