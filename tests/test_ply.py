"""The PLY reader: the three formats give the same mesh, polygons are fan-triangulated as in
OBJ files, unknown elements and properties are read past, and errors name file and element.
Files are written here with struct, independently of the reader."""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene import limits
from clray.scene.colour import srgb_decode
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
    # The file's (sRGB) colours, decoded, carried to the mesh (rendered: test_gltf).
    np.testing.assert_allclose(mesh.colors, srgb_decode(COLORS / 255.0))


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
        ((b"3 0 1 2 7", b"2 0 1 7"), "element face, line", "at least 3 vertices, got 2"),
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
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nelement face 0\n"
     b"property list uchar int vertex_indices\nend_header\n1 2\n",
     "bad.ply: element vertex, line 8: expected 1 number, got 2"),
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


# -- issue 43: readers that never crash, scans as scanners write them --------------------------

_TRIANGLE = (b"element vertex 3\nproperty float x\nproperty float y\nproperty float z\n")


def _binary(header: bytes, body: bytes) -> bytes:
    return b"ply\nformat binary_little_endian 1.0\n" + header + b"end_header\n" + body


def _ascii(header: bytes, body: bytes) -> bytes:
    return b"ply\nformat ascii 1.0\n" + header + b"end_header\n" + body


@pytest.mark.parametrize("name", ["x", "ny", "red"])
@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_a_vertex_property_declared_as_a_list_is_an_error(name, fmt):
    props = ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    header = b"element vertex 1\n" + b"".join(
        (b"property list uchar int %s\n" if p == name else b"property float %s\n") % p.encode()
        for p in props) + b"element face 0\nproperty list uchar int vertex_indices\n"
    if fmt == "ascii":
        data = _ascii(header, " ".join("1 5" if p == name else "1" for p in props).encode()
                      + b"\n")
    else:
        data = _binary(header, b"".join(struct.pack("<Bi", 1, 5) if p == name else
                                        struct.pack("<f", 1) for p in props))
    message = _errors(data)
    assert message == f"bad.ply: element vertex: {name} must be a number, not a list " \
        f"(property TYPE {name})"


@pytest.mark.parametrize(("count", "text"), [
    ("9" * 5000, "a count of 5000 digits records cannot fit in a file of {} bytes"),
    ("99999999999", "99999999999 records cannot fit in a file of {} bytes"),
    ("0" * 5000 + "3", "file ends after 1 of 3 records"),  # leading zeros are a count
])
def test_an_element_count_beyond_the_file_is_an_error(count, text):
    data = _ascii(b"element vertex " + count.encode() + b"\nproperty float x\n", b"0\n")
    assert _errors(data) == f"bad.ply: element vertex: {text.format(len(data))}"


def _mixed(n: int) -> bytes:
    header = _TRIANGLE + b"element face %d\nproperty list uchar int vertex_indices\n" % n
    body = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    body += (struct.pack("<B3i", 3, 0, 1, 2) + struct.pack("<B4i", 4, 0, 1, 2, 0)) * (n // 2)
    return _binary(header.replace(b"vertex 3", b"vertex 3"), body)


def test_binary_lists_of_changing_length_load_whole():
    # Triangles and quads alternating, 160k records (14 s when the loader was quadratic, 0.3 s
    # linear: the figures are docs/scene_format.md's; speed is not asserted here).
    mesh = read_ply(_mixed(160_000), Path("m.ply")).mesh
    assert mesh.faces.shape == (240_000, 3)
    np.testing.assert_array_equal(mesh.faces[:3], [[0, 1, 2], [0, 1, 2], [0, 2, 0]])


def test_changing_lists_match_ascii_and_truncation_is_named():
    binary = read_ply(_mixed(6), Path("m.ply")).mesh
    ascii_ = _ascii(_TRIANGLE + b"element face 6\nproperty list uchar int vertex_indices\n",
                    b"0 0 0\n1 0 0\n0 1 0\n" + b"3 0 1 2\n4 0 1 2 0\n" * 3)
    np.testing.assert_array_equal(binary.faces, read_ply(ascii_, Path("m.ply")).mesh.faces)
    assert _errors(_mixed(6)[:-3]) == "bad.ply: element face: file ends after 5 of 6 records"


_MESHLAB = (_TRIANGLE + b"element face 1\nproperty list uchar int vertex_indices\n"
            b"property list uchar float texcoord\nproperty list uchar int extra\n"
            b"property uchar flags\n")


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_face_texcoord_and_a_second_integer_list_are_read_past(fmt):
    # MeshLab writes per-corner UVs as a float list; a second integer list is read past too.
    if fmt == "ascii":
        data = _ascii(_MESHLAB, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2 6 0 0 1 0 0 1 2 7 8 9\n")
    else:
        data = _binary(_MESHLAB, struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
                       + struct.pack("<B3iB6fB2iB", 3, 0, 1, 2, 6, 0, 0, 1, 0, 0, 1, 2, 7, 8, 9))
    mesh = read_ply(data, Path("m.ply")).mesh
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])


def test_a_float_vertex_list_is_an_error():
    data = _ascii(_TRIANGLE + b"element face 1\nproperty list uchar float vertex_indices\n",
                  b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert _errors(data) == ("bad.ply: element face: vertex_indices must be a list of an "
                             "integer type")


# Six vertices on a zigzag: a strip 0 1 2 3 4 5 gives four triangles, all facing +z.
_ZIGZAG = b"0 0 0\n0 1 0\n1 0 0\n1 1 0\n2 0 0\n2 1 0\n"


def _strips(body: bytes, records: int, fmt: str = "ascii") -> bytes:
    header = (b"element vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
              b"element tristrips %d\nproperty list int int vertex_indices\n" % records)
    if fmt == "ascii":
        return _ascii(header, _ZIGZAG + body)
    verts = np.array(_ZIGZAG.split(), dtype=np.float32).tobytes()
    rows = [list(map(int, line.split())) for line in body.decode().splitlines()]
    return _binary(header, verts + b"".join(struct.pack(f"<{len(r)}i", *r) for r in rows))


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_tristrips_give_triangles_of_one_orientation(fmt):
    # One record: a strip of two triangles, a restart, a strip whose repeated 3s (two
    # degenerate triangles, dropped) keep the parity; then a second record.
    data = _strips(b"11 0 1 2 3 -1 2 3 3 3 4 5\n4 2 3 4 5\n", 2, fmt)
    faces = read_ply(data, Path("s.ply")).mesh.faces
    expected = [[0, 1, 2], [2, 1, 3],  # 0 1 2 3: even as read, odd with the first two swapped
                [4, 3, 5],  # 2 3 3 3 4 5: (2 3 3), (3 3 3), (3 3 4) dropped; odd (4 3 5)
                [2, 3, 4], [4, 3, 5]]  # 2 3 4 5
    np.testing.assert_array_equal(faces, expected)
    verts = read_ply(data, Path("s.ply")).mesh.vertices
    tri = verts[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(normals[:, 2] < 0)  # one orientation, the first triangle's (-z)


def test_tristrips_errors_name_the_element():
    assert _errors(_strips(b"3 0 1 9\n", 1)) == \
        "bad.ply: element tristrips: record 0: vertex index 9 out of range (6 vertices)"
    assert "element tristrips" in _errors(_strips(b"3 0 1 -2\n", 1))


def test_binary_mesh_files_may_be_larger_than_text_ones(tmp_path, monkeypatch):
    # Binary PLY (numpy views of its blocks) and .npz meshes are held to MAX_BINARY_MESH_BYTES;
    # text is parsed at several times its size, so an ASCII PLY or an OBJ is held to
    # MAX_MESH_BYTES, which these files are over here.
    from clray.scene import limits

    binary, text = ply_bytes("binary_little_endian"), ply_bytes("ascii")
    monkeypatch.setattr(limits, "MAX_MESH_BYTES", min(len(binary), len(text)) - 1)
    monkeypatch.setattr(limits, "MAX_BINARY_MESH_BYTES", max(len(binary), len(text)))
    (tmp_path / "b.ply").write_bytes(binary)
    (tmp_path / "a.ply").write_bytes(text)
    (tmp_path / "m.obj").write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" * 40 + b"f 1 2 3\n")

    def load(name: str):
        return scene_from_dict({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
                                "objects": [{"type": "mesh", "file": name}]}, tmp_path / "s.toml")

    assert len(load("b.ply").objects[0].faces) == len(FANNED)
    with pytest.raises(SceneError, match=r"a\.ply: an ASCII PLY file is at most \d+ bytes, this "
                                         r"one has \d+ \(write it as binary\)"):
        load("a.ply")
    with pytest.raises(SceneError, match=r"objects\[0\]\.file: .*over the limit"):
        load("m.obj")
    monkeypatch.setattr(limits, "MAX_BINARY_MESH_BYTES", len(binary) - 1)
    with pytest.raises(SceneError, match=r"over the limit"):
        load("b.ply")


@pytest.mark.parametrize("fmt", FORMATS)
def test_vertex_indices_are_int32_in_native_order(fmt):
    # The kernels index vertices with int32: a file's indices are kept as int32 (12 bytes a
    # triangle, not an int64 copy of 24), in the machine's byte order whatever the file's.
    faces = read_ply(ply_bytes(fmt, [[0, 1, 2]] * 4), Path("m.ply")).mesh.faces
    assert faces.dtype == np.dtype(np.int32) and faces.dtype.isnative
    np.testing.assert_array_equal(faces, [[0, 1, 2]] * 4)


@pytest.mark.parametrize("index", [2**31, 2**32 - 1])
def test_an_unsigned_index_past_int32_is_out_of_range_not_wrapped(index):
    # uint32 indices from 2**31 on would be negative as int32: the range is checked first.
    header = _TRIANGLE + b"element face 1\nproperty list uchar uint vertex_indices\n"
    body = struct.pack("<9f", *range(9)) + struct.pack("<B3I", 3, 0, 1, index)
    with pytest.raises(SceneError, match=rf"record 0: vertex index {index} out of range"):
        read_ply(_binary(header, body), Path("m.ply"))


def _positions_ply(path: Path, vertices: np.ndarray, kind: str) -> None:
    """A binary PLY of `vertices` (as properties of `kind`: float or double) fanned into
    triangles (0, k, k + 1)."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              + "".join(f"property {kind} {axis}\n" for axis in "xyz")
              + f"element face {len(vertices) - 2}\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    face = np.empty(len(vertices) - 2, dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = [[0, k, k + 1] for k in range(1, len(vertices) - 1)]
    path.write_bytes(header.encode() + vertices.astype("<f4" if kind == "float" else "<f8")
                     .tobytes() + face.tobytes())


def test_float_positions_stay_float32_and_pack_as_doubles(tmp_path):
    # A file's 4-byte positions stay float32 in the mesh (12 B a vertex for as long as the
    # scene is kept, not 24: docs/scale.md); every use widens them exactly, so the automatic
    # scene and its packed buffers are those of the same numbers read as doubles.
    from clray.device.pack import pack_scene
    from clray.model_scene import _bounds, load_model_scene, model_scene_data

    rng = np.random.default_rng(7)
    vertices = (rng.uniform(-1.0, 1.0, (40, 3)) * [3.0, 1.0, 0.3] + [1e3, -7.0, 0.1]).astype(
        np.float32)
    _positions_ply(tmp_path / "f.ply", vertices, "float")
    _positions_ply(tmp_path / "d.ply", vertices, "double")
    assert read_ply((tmp_path / "f.ply").read_bytes(), Path("f.ply")).mesh.vertices.dtype == \
        np.float32
    assert read_ply((tmp_path / "d.ply").read_bytes(), Path("d.ply")).mesh.vertices.dtype == \
        np.float64
    data = [model_scene_data(tmp_path / name) for name in ("f.ply", "d.ply")]
    assert data[0]["camera"] == data[1]["camera"]
    # The frame before its numbers are rounded for the file: centre, radius, low corner.
    for single, double in zip(_bounds(vertices), _bounds(vertices.astype(np.float64)),
                              strict=True):
        np.testing.assert_array_equal(single, double)
    packed = [pack_scene(load_model_scene(tmp_path / name), width=32, height=24, spp=1,
                         max_depth=0, seed=0).buffers() for name in ("f.ply", "d.ply")]
    for name, array in packed[0].items():
        assert array.tobytes() == packed[1][name].tobytes(), name


_FLOAT_COLOURS = (b"element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  b"property float red\nproperty float green\nproperty float blue\n"
                  b"element face 1\nproperty list uchar int vertex_indices\n")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_non_finite_float_colours_are_refused(value, fmt):
    # np.clip keeps a NaN, which reached the renderer as NaN pixels.
    rows = [[0, 0, 0, 1, 1, 1], [1, 0, 0, 1, 1, 1], [0, 1, 0, 0.5, float(value), 1]]
    if fmt == "ascii":
        body = b"".join(" ".join(map(str, r)).encode() + b"\n" for r in rows) + b"3 0 1 2\n"
        data = _ascii(_FLOAT_COLOURS, body)
    else:
        body = b"".join(struct.pack("<6f", *r) for r in rows) + struct.pack("<B3i", 3, 0, 1, 2)
        data = _binary(_FLOAT_COLOURS, body)
    assert _errors(data) == ("bad.ply: element vertex: record 2: red, green, blue must be "
                             "finite and at most 1e+30 in magnitude")


def _peak(data: bytes) -> int:
    tracemalloc.start()
    try:
        read_ply(data, Path("m.ply"))
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_one_long_number_does_not_widen_every_number():
    # An array of fixed-width byte strings is as wide as its longest token: one number of
    # 2000 digits among 3000 vertices cost 2000 bytes a token (18 MB here, 4.8 GB for the
    # reviewer's 800,000 vertices).
    def data(first: bytes) -> bytes:
        header = (b"element vertex 3000\nproperty float x\nproperty float y\nproperty float z\n"
                  b"element face 1\nproperty list uchar int vertex_indices\n")
        return _ascii(header, first + b" 0 0\n" + b"1 0 0\n" * 2999 + b"3 0 1 2\n")
    long = b"0." + b"0" * 2000 + b"1"
    mesh = read_ply(data(long), Path("m.ply")).mesh
    assert mesh.vertices[0, 0] == np.float32(float(long))
    assert _peak(data(long)) < 2 * _peak(data(b"0.1"))


def _short_faces(lists: list[list[int]], count: int) -> bytes:
    header = _TRIANGLE + b"element face %d\nproperty list uchar int vertex_indices\n" % count
    body = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    body += b"".join(struct.pack(f"<B{len(f)}i", len(f), *f) for f in lists)
    return _binary(header, body)


@pytest.mark.parametrize(("lists", "record", "got"), [
    ([[]], 0, 0),
    ([[0, 1, 2], [0, 1, 2, 0], [1], [], [1]], 2, 1),
])
def test_a_short_binary_face_fails_where_it_is_read(lists, record, got):
    # The file declares 100 faces and ends after these: the short face is reported as
    # it is read, not after a pass over every record (which here ends in a truncation).
    assert _errors(_short_faces(lists, 100)) == (
        f"bad.ply: element face: record {record}: a face needs at least 3 vertices, got {got}")


def test_a_short_ascii_face_names_its_line():
    # Header lines 1-10, vertices 11-13, faces from 14: the second face (line 15) has 2.
    data = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 3\nproperty list uchar int vertex_indices\n"
            b"comment two lines to count\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n2 0 1\n"
            b"3 0 1 2\n")
    assert _errors(data) == (
        "bad.ply: element face, line 15: a face needs at least 3 vertices, got 2")


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_a_face_count_over_the_triangle_limit_is_refused_from_the_header(fmt, monkeypatch):
    monkeypatch.setattr(limits, "MAX_TRIANGLES", 4)
    # Five faces declared, none written: the header alone is refused.
    header = _TRIANGLE + b"element face 5\nproperty list uchar int vertex_indices\n"
    data = (_ascii if fmt == "ascii" else _binary)(header, b"")
    assert _errors(data) == ("bad.ply: element face: 5 faces make at least as many triangles, "
                             "over the limit of 4 for all meshes")
    ok = _short_faces([[0, 1, 2]] * 4, 4)
    assert read_ply(ok, Path("m.ply")).mesh.faces.shape == (4, 3)


@pytest.mark.parametrize("comment", [b"comment written before end_header by a tool\n",
                                     b"comment end_header\n", b"end_header_x 1\n"])
def test_the_header_ends_at_a_whole_end_header_line(comment):
    header = b"ply\nformat ascii 1.0\n" + comment + _TRIANGLE
    data = (header + b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    if comment.startswith(b"comment"):
        np.testing.assert_array_equal(read_ply(data, Path("m.ply")).mesh.faces, [[0, 1, 2]])
    else:  # a line that only starts with the word is a keyword of its own
        assert _errors(data) == "bad.ply: header line 3: unknown header keyword 'end_header_x'"


_FACE = b"element face 1\nproperty list uchar int vertex_indices\n"


@pytest.mark.parametrize("body", [
    b"0 0 0\n1 0 0\n0 1 0\n\n3 0 1 2\n",  # between elements
    b"\n0 0 0\n1 0 0\n \t\n0 1 0\n3 0 1 2\n\n",  # first, within an element, last
    b"0 0 0\r\n1 0 0\r\n0 1 0\r\n\r\n3 0 1 2\r\n",  # CRLF
])
def test_blank_lines_in_an_ascii_body_are_read_past(body):
    mesh = read_ply(_ascii(_TRIANGLE + _FACE, body), Path("m.ply")).mesh
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])


@pytest.mark.parametrize("body, message", [
    # The header is 9 lines: errors after blank lines name the line of the file.
    (b"0 0 0\n\n1 0 0\n\n0 x 0\n3 0 1 2\n", "element vertex, line 14: expected a number, got b'x'"),
    (b"0 0 0\n1 0 0\n0 1 0\n\n\n3 0 1\n", "element face, line 15: expected 0 numbers and a list"),
    (b"0 0 0\n1 0 0\n0 1 0\n\n", "element face: file ends after 0 of 1 records"),
])
def test_errors_after_blank_lines_name_the_line(body, message):
    assert _errors(_ascii(_TRIANGLE + _FACE, body)).startswith(f"bad.ply: {message}")


_JUNK = b"element junk %d\nproperty list uchar uchar stuff\n"


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_an_ignored_element_after_the_mesh_is_not_read(fmt):
    # Its records are never walked: lists that run past the end of the file (binary) or
    # words that are not numbers (ASCII) do not matter. Walking 20 M such records took 22 s
    # and 1.8 GB for a 30 MB file.
    header = _TRIANGLE + _FACE + _JUNK % 50
    if fmt == "ascii":
        data = _ascii(header, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n" + b"x y\n" * 2)
    else:
        body = struct.pack("<9fB3i", 0, 0, 0, 1, 0, 0, 0, 1, 0, 3, 0, 1, 2)
        data = _binary(header, body + bytes([200]) * 60)
    np.testing.assert_array_equal(read_ply(data, Path("m.ply")).mesh.faces, [[0, 1, 2]])


def _junk_first(records: int) -> bytes:
    # Lists of 0 and 1 items alternating (no one view holds them), before the mesh.
    body = struct.pack("<9fB3i", 0, 0, 0, 1, 0, 0, 0, 1, 0, 3, 0, 1, 2)
    return _binary(_JUNK % records + _TRIANGLE + _FACE,
                   bytes([0, 1, 7]) * (records // 2) + body)


def test_an_ignored_element_before_the_mesh_is_walked_keeping_nothing_a_record():
    small, large = _junk_first(2000), _junk_first(200_000)
    np.testing.assert_array_equal(read_ply(large, Path("m.ply")).mesh.faces, [[0, 1, 2]])
    # Where each record starts and its lists' lengths were kept: 15 MB for 200,000 records.
    assert _peak(large) < _peak(small) + 100_000


def test_an_ignored_element_before_the_mesh_has_a_record_cap(monkeypatch):
    monkeypatch.setattr("clray.scene.ply.MAX_SKIPPED_RECORDS", 1000)
    assert _errors(_junk_first(2000)) == (
        "bad.ply: element junk: 2000 records of lists that change length before the mesh's "
        "elements; at most 1000 are read past (write it after vertex and face)")
    # Records of one list length are one numpy view, under no cap.
    body = struct.pack("<9fB3i", 0, 0, 0, 1, 0, 0, 0, 1, 0, 3, 0, 1, 2)
    uniform = _binary(_JUNK % 2000 + _TRIANGLE + _FACE, bytes([1, 7]) * 2000 + body)
    np.testing.assert_array_equal(read_ply(uniform, Path("m.ply")).mesh.faces, [[0, 1, 2]])


def test_cr_only_line_endings_are_named():
    data = _ascii(_TRIANGLE + _FACE, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").replace(b"\n", b"\r")
    assert _errors(data) == ("bad.ply: CR-only line endings are not read (expected LF or CRLF "
                             "line endings)")


def test_a_skipped_element_of_uniform_float_lists_is_not_converted(monkeypatch):
    # An element the mesh does not use, before vertex and face, of float lists of one
    # length: skipping it converted its lists to float64 (8 bytes an item) only to find
    # where it ends. Any conversion of its items is now an error.
    import clray.scene.ply as ply_module
    real = ply_module._as_items

    def as_items(items, prop):
        assert prop.name != "samples", "a skipped element's items were converted"
        return real(items, prop)

    monkeypatch.setattr(ply_module, "_as_items", as_items)
    header = ("ply\nformat binary_little_endian 1.0\nelement scan 50\n"
              "property list uchar float samples\nelement vertex 3\nproperty float x\n"
              "property float y\nproperty float z\nelement face 1\n"
              "property list uchar int vertex_indices\nend_header\n")
    body = struct.pack("<B4f", 4, 1, 2, 3, 4) * 50
    body += struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    mesh = read_ply(header.encode() + body, Path("s.ply")).mesh
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])
