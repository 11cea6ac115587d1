import os
from pathlib import Path

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene import obj
from clray.scene.obj import parse_obj, read_obj

DATA = Path(__file__).parent / "data"

SQUARE_V = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
"""


def write(tmp_path: Path, text: str, name: str = "m.obj") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def corners(mesh):
    """Per triangle corner: (position, uv, normal), independent of the vertex order the
    re-indexing chose."""
    out = []
    for face in mesh.faces:
        out.append(
            [
                (
                    tuple(mesh.vertices[i]),
                    None if mesh.uvs is None else tuple(mesh.uvs[i]),
                    None if mesh.normals is None else tuple(mesh.normals[i]),
                )
                for i in face
            ]
        )
    return out


def test_positions_only_triangle(tmp_path):
    mesh = read_obj(write(tmp_path, SQUARE_V + "f 1 2 3\n"))
    assert mesh.vertices.dtype == np.float64 and mesh.vertices.shape == (4, 3)
    assert mesh.faces.dtype == np.int64
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])
    assert mesh.normals is None and mesh.uvs is None


def test_quad_is_fan_triangulated(tmp_path):
    mesh = read_obj(write(tmp_path, SQUARE_V + "f 1 2 3 4\n"))
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


def test_mixed_polygon_sizes_keep_file_order(tmp_path):
    text = SQUARE_V + "v 2 0 0\nv 2 1 0\nf 1 2 3 4 5 6\nf 1 2 3\nf 2 5 6 3\n"
    mesh = read_obj(write(tmp_path, text))
    np.testing.assert_array_equal(
        mesh.faces,
        [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5], [0, 1, 2], [1, 4, 5], [1, 5, 2]],
    )


def test_v_vt_form(tmp_path):
    text = SQUARE_V + "vt 0 0\nvt 1 0\nvt 1 1\nf 1/1 2/2 3/3\n"
    mesh = read_obj(write(tmp_path, text))
    assert mesh.normals is None
    assert corners(mesh) == [
        [((0, 0, 0), (0, 0), None), ((1, 0, 0), (1, 0), None), ((1, 1, 0), (1, 1), None)]
    ]


@pytest.mark.parametrize("uvs", [["0.25", "0.5", "0.75"], ["0.25", "0.5 0.125", "0.75 1 0"],
                                 ["0.25 0.5 0.5", "0.5", "0.75 1"]])
def test_vt_with_u_alone_reads_v_as_0(tmp_path, uvs):
    # The OBJ specification makes v optional (default 0): `vt u` was refused. Each statement
    # keeps its own values, not the next one's.
    text = SQUARE_V + "".join(f"vt {uv}\n" for uv in uvs) + "f 1/1 2/2 3/3\n"
    mesh = read_obj(write(tmp_path, text))
    want = [tuple(float(x) for x in [*uv.split(), "0"][:2]) for uv in uvs]
    assert [uv for _, uv, _ in corners(mesh)[0]] == want


def test_v_vn_form(tmp_path):
    text = SQUARE_V + "vn 0 0 1\nvn 0 1 0\nf 1//1 2//2 3//1\n"
    mesh = read_obj(write(tmp_path, text))
    assert mesh.uvs is None
    assert corners(mesh) == [
        [((0, 0, 0), None, (0, 0, 1)), ((1, 0, 0), None, (0, 1, 0)), ((1, 1, 0), None, (0, 0, 1))]
    ]


def test_v_vt_vn_form_splits_vertices_with_distinct_attributes(tmp_path):
    # Position 1 is used with two different UVs, so it becomes two output vertices.
    text = SQUARE_V + "vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/2/1 3/3/1 4/1/1\n"
    mesh = read_obj(write(tmp_path, text))
    assert len(mesh.vertices) == 5
    assert mesh.normals.shape == (5, 3) and mesh.uvs.shape == (5, 2)
    assert corners(mesh) == [
        [
            ((0, 0, 0), (0, 0), (0, 0, 1)),
            ((1, 0, 0), (1, 0), (0, 0, 1)),
            ((1, 1, 0), (1, 1), (0, 0, 1)),
        ],
        [
            ((0, 0, 0), (1, 0), (0, 0, 1)),
            ((1, 1, 0), (1, 1), (0, 0, 1)),
            ((0, 1, 0), (0, 0), (0, 0, 1)),
        ],
    ]


def test_negative_indices_count_back_from_the_latest_definition(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nf -4 -1 -2\n"
    mesh = read_obj(write(tmp_path, text))
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 3, 2]])


def test_negative_indices_for_uvs_and_normals(tmp_path):
    text = SQUARE_V + "vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\nf -4/-3/-1 -3/-2/-1 -2/-1/-1\n"
    mesh = read_obj(write(tmp_path, text))
    assert corners(mesh) == [
        [
            ((0, 0, 0), (0, 0), (0, 0, 1)),
            ((1, 0, 0), (1, 0), (0, 0, 1)),
            ((1, 1, 0), (1, 1), (0, 0, 1)),
        ]
    ]


def test_faces_without_normals_make_the_whole_mesh_flat(tmp_path):
    text = SQUARE_V + "vn 0 0 1\nf 1//1 2//1 3//1\nf 1 3 4\n"
    mesh = read_obj(write(tmp_path, text))
    assert mesh.normals is None and mesh.uvs is None
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


def test_ignored_statements_comments_and_whitespace(tmp_path):
    text = (
        "# a comment\n"
        "mtllib stuff.mtl\n"
        "o thing\n"
        "g group\n"
        "\n"
        "v 0 0 0 1.0  # w, then a comment\n"
        "v\t1 0 0 0.5 0.5 0.5\r\n"  # tab, vertex colour, CRLF
        "  v 0 1 0\n"
        "usemtl red\n"
        "s off\n"
        "l 1 2\n"
        "vp 0.5\n"
        "f 1 2 3 # trailing\n"
    )
    mesh = read_obj(write(tmp_path, text))
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])


def test_file_without_trailing_newline_and_exponents(tmp_path):
    mesh = read_obj(write(tmp_path, "v 1e-1 -2.5E+1 +3\nv 0 0 0\nv .5 0 0\nf 1 2 3"))
    np.testing.assert_array_equal(mesh.vertices[0], [0.1, -25.0, 3.0])
    np.testing.assert_array_equal(mesh.vertices[2], [0.5, 0, 0])


def test_no_faces_gives_empty_face_array(tmp_path):
    mesh = read_obj(write(tmp_path, "v 0 0 0\n"))
    assert mesh.faces.shape == (0, 3)


def test_fixture_cube():
    mesh = read_obj(DATA / "cube.obj")
    assert mesh.faces.shape == (12, 3)
    # 6 faces x 4 corners, each with its own normal.
    assert mesh.vertices.shape == (24, 3) and mesh.normals.shape == (24, 3)
    assert mesh.uvs.shape == (24, 2)
    tri = mesh.vertices[mesh.faces]
    geometric = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    # Counter-clockwise faces: the geometric normal agrees with the file's vertex normals.
    assert np.all(np.einsum("ij,ij->i", geometric, mesh.normals[mesh.faces[:, 0]]) > 0)


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (SQUARE_V + "f 1 2 0\n", 5, "vertex index 0 is invalid"),
        (SQUARE_V + "f 1 2 5\n", 5, "vertex index 5 out of range (4 in the file)"),
        (SQUARE_V + "f 1 2 -5\n", 5, "relative vertex index -5 out of range"),
        (SQUARE_V + "vt 0 0\nf 1/1 2/2 3/1\n", 6, "texture coordinate index 2 out of range"),
        (SQUARE_V + "vn 0 0 1\nf 1//1 2//1 3//3\n", 6, "normal index 3 out of range"),
        (SQUARE_V + "\nf 1 2\n", 6, "a face needs at least 3 vertices, got 2"),
        (SQUARE_V + "f\n", 5, "a face needs at least 3 vertices, got 0"),
        (SQUARE_V + "vt 0 0\nf 1/1 2 3\n", 6, "mixed vertex forms in one face (v/vt and v)"),
        (SQUARE_V + "vn 0 0 1\nf 1//1 2/1/1 3//1\n", 6, "mixed vertex forms"),
        (SQUARE_V + "f 1 2 x\n", 5, "bad vertex reference 'x'"),
        (SQUARE_V + "f 1 2 3.5\n", 5, "bad vertex reference '3.5'"),
        (SQUARE_V + "f 1 2 1-2\n", 5, "bad vertex reference '1-2'"),
        (SQUARE_V + "vn 0 0 1\nf 1// 2//1 3//1\n", 6, "bad vertex reference '1//'"),
        (SQUARE_V + "f 1/2/3/4 2 3\n", 5, "bad vertex reference '1/2/3/4'"),
        ("v 0 0 0\nv 1 zero 0\n", 2, "expected a number, got 'zero'"),
        ("v 0 0 0\nv 1 1_0 0\n", 2, "expected a number, got '1_0'"),
        ("v 0 0 0\nv 1 0\n", 2, "v: expected at least 3 numbers, got 2"),
        ("v 0 0 0\nvt\n", 2, "vt: expected at least 1 number, got 0"),
        ("v 0 0 0\nv 1 nan 0\n", 2, "v: numbers must be finite"),
        ("v 0 0 0\nvn 0 0 0\n", 2, "vn: zero-length normal"),
    ],
)
def test_errors_name_file_and_line(tmp_path, text, line, message):
    with pytest.raises(SceneError) as info:
        read_obj(write(tmp_path, text, "broken.obj"))
    text = str(info.value)
    assert text.startswith(f"broken.obj: line {line}: "), text
    assert message in text
    assert info.value.key == f"line {line}"


def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match=r"^nope\.obj: cannot read mesh file"):
        read_obj(tmp_path / "nope.obj")


def reference_obj(text: str) -> tuple[list, list]:
    """A straightforward line-by-line reader: (positions, triangles as position triples),
    0-based, for texts whose faces are all valid."""
    positions: list[tuple[float, ...]] = []
    triangles = []
    for line in text.splitlines():
        tokens = line.split("#")[0].split()
        if not tokens:
            continue
        if tokens[0] == "v":
            positions.append(tuple(float(t) for t in tokens[1:4]))
        elif tokens[0] == "f":
            refs = []
            for t in tokens[1:]:
                i = int(t.split("/")[0])
                refs.append(i - 1 if i > 0 else len(positions) + i)
            triangles += [(refs[0], refs[k], refs[k + 1]) for k in range(1, len(refs) - 1)]
    return positions, triangles


def positions_of_faces(mesh) -> list:
    return [tuple(tuple(mesh.vertices[i]) for i in face) for face in mesh.faces]


REFERENCE_TEXTS = {
    "plain": SQUARE_V + "f 1 2 3 4\n",
    "v/vt": SQUARE_V + "vt 0 0\nvt 1 1\nf 1/1 2/2 3/1\nf 3/2 4/1 1/1\n",
    "v//vn": SQUARE_V + "vn 0 0 1\nf 1//1 2//1 3//1 4//1\n",
    "v/vt/vn": SQUARE_V + "vt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\n",
    "forms differ between faces": (
        SQUARE_V
        + "vt 0 0\nvn 0 0 1\nf 1 2 3\nf 1/1 3/1 4/1\nf 2//1 3//1 4//1\nf 1/1/1 2/1/1 4/1/1\n"
    ),
    "relative": SQUARE_V + "vn 0 0 1\nf -4//-1 -3//1 -2//-1\nv 9 9 9\nf -5 -2 -1\n",
    "signed indices": SQUARE_V + "f +1 +2 +3\n",
    "crlf and tabs": SQUARE_V.replace("\n", "\r\n") + "f\t1\t2 \t3\r\n\r\nf 1 3 4\r\n",
    "indented and blank lines": "\n\n  v 0 0 0\n\tv 1 0 0\n \n v 0 1 0\n\n   f 1 2 3   \n\n",
    "comments everywhere": (
        "# header\nv 0 0 0 # origin\nv 1 0 0#x\n#v 7 7 7\nv 0 1 0\n# f 9 9 9\nf 1 2 3 # tri\n"
    ),
    "slashes in other statements": (
        SQUARE_V + "mtllib a/b.mtl\nf 1 2 3\nusemtl x//y\nf 1 3 4\ng a/b/c\n"
    ),
    "long numbers": (
        "v 0.12345678901234567890 -123456789012345678901234 1e-300\n"
        "v 00000000000000000000001.5 .5 5.\nv -0 +0.0 -.25\n"
        "f 000000000001 2 0000000003\n"
    ),
    "exponents and odd spellings": "v 1e3 -2.5E-2 +3E+0\nv 1.e1 .1e1 0e0\nv 7 8 9\nf 1 2 3\n",
    "no trailing newline": SQUARE_V + "f 4 3 2",
    "big polygon": SQUARE_V + "v 2 0 0\nv 2 1 0\nf 1 2 5 6 3 4\n",
}


@pytest.mark.parametrize("name", list(REFERENCE_TEXTS))
def test_matches_a_line_by_line_reader(tmp_path, name):
    text = REFERENCE_TEXTS[name]
    positions, triangles = reference_obj(text)
    mesh = read_obj(write(tmp_path, text))
    expected = [tuple(positions[i] for i in tri) for tri in triangles]
    assert positions_of_faces(mesh) == expected


def test_vertex_numbers_are_exactly_what_float_reads(tmp_path):
    rng = np.random.default_rng(7)
    tokens = []
    for _ in range(3000):
        digits = "".join(rng.choice(list("0123456789"), size=int(rng.integers(1, 20))))
        cut = int(rng.integers(0, len(digits) + 1))
        sign = rng.choice(["", "-", "+"])
        shape = int(rng.integers(0, 4))
        if shape == 0:
            token = sign + digits
        elif shape == 1:
            token = f"{sign}{digits[:cut]}.{digits[cut:]}"
        elif shape == 2:
            # Exponents up to 10 keep 19-digit mantissas within the reader's 1e30 limit.
            token = f"{sign}{digits[:cut] or '0'}.{digits[cut:]}e{int(rng.integers(-30, 11))}"
        else:
            token = repr(float(rng.normal() * 10.0 ** int(rng.integers(-8, 8))))
        if token.strip("+-.") == "":
            token = "0"
        tokens.append(token)
    tokens += ["9007199254740993", "0.9007199254740993", "4503599627370497.5", "1" * 16]
    while len(tokens) % 3:
        tokens.append("1")
    lines = [f"v {' '.join(tokens[i : i + 3])}" for i in range(0, len(tokens), 3)]
    mesh = read_obj(write(tmp_path, "\n".join(lines) + "\nf 1 2 3\n"))
    expected = np.array([float(t) for t in tokens]).reshape(-1, 3)
    # Bitwise, so -0.0 against 0.0 and the last bit of the rounding count too.
    assert mesh.vertices.tobytes() == expected.tobytes()


def test_shared_indices_keep_every_vertex_in_file_order(tmp_path):
    # `f a//a` throughout takes the no-sort path; an unused vertex must still be dropped.
    text = SQUARE_V + "v 9 9 9\n" + "vn 0 0 1\n" * 5 + "f 4//4 1//1 2//2\nf 2//2 3//3 4//4\n"
    mesh = read_obj(write(tmp_path, text))
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[3, 0, 1], [1, 2, 3]])
    assert mesh.normals.shape == (4, 3)


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (SQUARE_V.replace("\n", "\r\n") + "\r\nf 1 2 9\r\n", 6, "vertex index 9 out of range"),
        ("# c\n\n  \nv 0 0 0\n\t\nv 1 x 0 # why\n", 6, "expected a number, got 'x'"),
        ("v 0 0 0\nv 1 1 1.2.3\n", 2, "expected a number, got '1.2.3'"),
        ("v 0 0 0\nv 1 1 12345678901234567.5x\n", 2, "got '12345678901234567.5x'"),
        ("v 0 0 0\nv 1 1 -\n", 2, "expected a number, got '-'"),
        ("v 0 0 0\nv 1 1 .\n", 2, "expected a number, got '.'"),
        ("v 0 0 0\nv 1 1 1/2\n", 2, "expected a number, got '1/2'"),
        ("v 0 0 0\nv 1 1 0x10\n", 2, "expected a number, got '0x10'"),
        ("v 0 0 0\nv 1 1 1\x002\n", 2, "expected a number, got '1\\x002'"),
        ("v 0 0 0\nvt 0 1e999\n", 2, "vt: numbers must be finite"),
        (SQUARE_V + "f 1 2 3\nf 1 2 +\n", 6, "bad vertex reference '+'"),
        (SQUARE_V + "f 1 2 3\nf 1 2 123456789\n", 6, "vertex index 123456789 out of range"),
        (SQUARE_V + "f 1 2 99999999999999999999\n", 5, "out of range"),
        (SQUARE_V + "vt 0 0\nf 1/ 2/1 3/1\n", 6, "bad vertex reference '1/'"),
        (SQUARE_V + "vt 0 0\nf 1/1 2/1 /3\n", 6, "bad vertex reference '/3'"),
        (SQUARE_V + "vt 0 0\nf 1/1 2/1 3/-\n", 6, "bad vertex reference '3/-'"),
        (SQUARE_V + "f 1 2 3\nf 1///2 2 3\n", 6, "bad vertex reference '1///2'"),
        (SQUARE_V + "vn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 2 3\n", 7, "mixed vertex forms"),
        (SQUARE_V + "vn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 2//1 3//-2\n", 7, "relative normal"),
    ],
)
def test_more_errors_name_the_line(tmp_path, text, line, message):
    with pytest.raises(SceneError) as info:
        read_obj(write(tmp_path, text, "broken.obj"))
    assert str(info.value).startswith(f"broken.obj: line {line}: "), str(info.value)
    assert message in str(info.value)


@pytest.mark.parametrize(("text", "line", "message"), [
    ("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", 2, "v: numbers must be at most 1e+30 in magnitude"),
    ("v 0 0 0\nvt 0 -2e30\n", 2, "vt: numbers must be at most 1e+30 in magnitude"),
    ("v 0 0 0\nvn 1e300 0 0\n", 2, "vn: numbers must be at most 1e+30 in magnitude"),
    ("v 0 0 0\n\nvn 0 0 -0.0\n", 3, "vn: zero-length normal"),
])
def test_numbers_past_float32_name_the_line(tmp_path, text, line, message):
    with pytest.raises(SceneError) as info:
        read_obj(write(tmp_path, text))
    assert str(info.value) == f"m.obj: line {line}: {message}"


@pytest.mark.parametrize("normal", ["1e-200 1e-200 1e-200", "1e30 1e30 1e30", "3 3 3"])
def test_normals_are_normalised_in_float64(tmp_path, normal):
    # Squaring 1e-200 underflows to 0, and 1e30 overflows float32: both used to give zero
    # or infinite normals.
    mesh = read_obj(write(tmp_path, SQUARE_V + f"vn {normal}\nf 1//1 2//1 3//1\n"))
    assert np.allclose(mesh.normals, 3**-0.5, rtol=0, atol=1e-15)


def test_fifo_mesh_is_refused(tmp_path):
    os.mkfifo(tmp_path / "m.obj")
    with pytest.raises(SceneError, match=r"^m\.obj: cannot read mesh file: not a regular file$"):
        read_obj(tmp_path / "m.obj")


REGULAR_TEXTS = {
    "positions": SQUARE_V + "f 1 2 3\nf 1 3 4\n",
    "quads": SQUARE_V + "f 1 2 3 4\nf 4 3 2 1\n",
    "v/vt": SQUARE_V + "vt 0 0\nvt 1 1\nf 1/1 2/2 3/1\nf 3/2 4/1 1/1\n",
    "v//vn": SQUARE_V + "vn 0 0 1\nvn 0 0 -1\nf 1//1 2//2 3//1\n",
    "v/vt/vn": SQUARE_V + "vt 0 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\n",
    "comments and other statements": (
        "# header\nmtllib m.mtl\no thing\n" + SQUARE_V
        + "\ns off\nusemtl a\nf 1 2 3\ng b\nf 1 3 4\n"
    ),
    "interleaved runs": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 1 1 0\nf 2 4 3\n",
    "colours and w": "v 0 0 0 1 0.5 0\nv 1 0 0 1 0.5 0\nv 0 1 0 1 0.5 0\nf 3 2 1\n",
    "exponents and long numbers": (
        "v 1e3 -2.5E-2 +3E+0\nv 0.12345678901234567890 .5 5.\nv -0 +0.0 -.25\nf 1 2 3\n"
    ),
    "no trailing newline": SQUARE_V + "f 4 3 2",
}


def test_regular_files_take_the_fast_path():
    for name, text in REGULAR_TEXTS.items():
        assert obj._parse_regular(text.encode()) is not None, name


@pytest.mark.parametrize("text", [*REGULAR_TEXTS.values(), *REFERENCE_TEXTS.values(),
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 # c\n",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3 1\n",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1/1 2/1 3/1\n",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nvp 1 2\nf 1 2 3\n",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -1\n",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\x00\n"])
def test_fast_path_reads_what_the_general_parser_reads(monkeypatch, text):
    data = text.encode()
    fast = obj._parse_regular(data)
    monkeypatch.setattr(obj, "_parse_regular", lambda _: None)
    try:
        general = obj.parse_obj(data, Path("m.obj"))
    except SceneError:
        assert fast is None
        return
    if fast is not None:
        for field in ("vertices", "faces", "normals", "uvs"):
            a, b = getattr(fast, field), getattr(general, field)
            assert (a is None) == (b is None), field
            if a is not None:
                assert a.tobytes() == b.tobytes() and a.shape == b.shape, field


@pytest.mark.parametrize("text", [
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3x\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n",
    "v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 nan\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 1e40\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 1-2\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/ 2/ 3/\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
])
def test_regular_layout_with_errors_leaves_them_to_the_general_parser(text):
    assert obj._parse_regular(text.encode()) is None


@pytest.mark.parametrize("text", [
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n",  # the common layout
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3 # general parser\n",
])
def test_a_byte_order_mark_is_not_part_of_the_first_line(text):
    with_bom = obj.parse_obj(b"\xef\xbb\xbf" + text.encode(), Path("m.obj"))
    np.testing.assert_array_equal(with_bom.vertices[with_bom.faces],
                                  [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]])


def test_a_byte_order_mark_before_mtllib_keeps_the_library():
    data = b"\xef\xbb\xbfmtllib m.mtl\n" + SQUARE_V.encode() + b"usemtl a\nf 1 2 3\n"
    mesh = obj.parse_obj(data, Path("m.obj"))
    assert mesh.material_libraries == ((1, "m.mtl"),)
    assert mesh.material_names == ("a",)


# The corners' (u, v) in each plane: the axes of u and v (the plane's normal is u x v).
_PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def _signed_areas(mesh, plane="xy") -> np.ndarray:
    u, v = _PLANES[plane]
    p = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces]
    a, b = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return (a[:, u] * b[:, v] - a[:, v] * b[:, u]) / 2


@pytest.mark.parametrize("plane", sorted(_PLANES))
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize(("corners", "area"), [
    # A chevron, its reflex corner second: the fan around the first filled its notch.
    ([(0, 3), (2, 1), (4, 3), (2, 0)], 2.0),
    # The same chevron, its reflex corner last (quads take a path of their own).
    ([(4, 3), (2, 0), (0, 3), (2, 1)], 2.0),
    # A pentagon of one reflex corner, third: the fan around that corner.
    ([(0, 0), (4, 0), (2, 1), (4, 4), (0, 4)], 12.0),
    # A crown of two reflex corners: ear-clipped.
    ([(0, 0), (6, 0), (6, 4), (4, 2), (3, 4), (2, 2), (0, 4)], 18.0),
    # A U of two reflex corners (its fan covers 11).
    ([(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)], 7.0),
])
def test_a_concave_polygon_covers_its_own_area(corners, area, reverse, plane):
    # In each axis plane and both windings: ear clipping works in a plane of two axes,
    # picked by the normal, whose order sets which way round counts as convex.
    corners = corners[::-1] if reverse else corners
    u, v = _PLANES[plane]

    def point(x, y):
        p = [0, 0, 0]
        p[u], p[v] = x, y
        return " ".join(map(str, p))

    text = "".join(f"v {point(x, y)}\n" for x, y in corners)
    text += "f " + " ".join(str(i + 1) for i in range(len(corners))) + "\n"
    mesh = parse_obj(text.encode(), Path("c.obj"))
    signed = _signed_areas(mesh, plane)
    assert len(signed) == len(corners) - 2
    # Every triangle wound as the polygon (the chevron's corners run clockwise), and
    # together exactly its area: no overlap.
    x, y = np.array(corners, dtype=float).T
    orientation = np.sign((x * np.roll(y, -1) - y * np.roll(x, -1)).sum())
    assert np.all(signed * orientation >= 0)
    assert abs(signed.sum()) == pytest.approx(area)
    # The PLY reader triangulates its faces alike.
    ply = (f"ply\nformat ascii 1.0\nelement vertex {len(corners)}\nproperty float x\n"
           "property float y\nproperty float z\nelement face 1\n"
           "property list uchar int vertex_indices\nend_header\n"
           + "".join(f"{point(x, y)}\n" for x, y in corners)
           + f"{len(corners)} " + " ".join(map(str, range(len(corners)))) + "\n")
    from clray.scene.ply import read_ply
    np.testing.assert_array_equal(read_ply(ply.encode(), Path("c.ply")).mesh.faces, mesh.faces)


@pytest.mark.parametrize("text", [
    # Crossing itself (a bow tie: no area about its Newell normal).
    "v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4\n",
    # Concave but not planar: the chevron with a corner lifted far off its plane.
    "v 0 3 0\nv 2 1 2\nv 4 3 0\nv 2 0 0\nf 1 2 3 4\n",
])
def test_self_crossing_and_non_planar_polygons_stay_fans(text):
    mesh = parse_obj(text.encode(), Path("c.obj"))
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


_U = [(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)]  # area 7, its fan 11
_U_TEXT = "".join(f"v {x} {y} 0\n" for x, y in _U)
_U_FACE = "f " + " ".join(str(i + 1) for i in range(len(_U))) + "\n"


def _polygon_areas(mesh, polygons: int, k: int) -> list[float]:
    return [float(abs(_signed_areas(mesh)[i * (k - 2):(i + 1) * (k - 2)]).sum())
            for i in range(polygons)]


def test_ear_clipping_stops_at_the_files_budget_with_one_warning(monkeypatch):
    # Room for two U-shaped 8-gons: the third and fourth stay fans, with one warning.
    cost = 8 * (8 + obj._EAR_CLIP_EXTRA)
    monkeypatch.setattr(obj, "_EAR_CLIP_BUDGET", 2 * cost + cost // 2)
    mesh = parse_obj((_U_TEXT + _U_FACE * 4).encode(), Path("u.obj"))
    assert _polygon_areas(mesh, 4, 8) == pytest.approx([7, 7, 11, 11])
    assert len(mesh.warnings) == 1
    assert mesh.warnings[0].startswith("2 polygon(s) of two or more reflex corners left as "
                                       "fans")
    assert "budget" in mesh.warnings[0]
    # Within the budget: no warning.
    assert parse_obj((_U_TEXT + _U_FACE * 2).encode(), Path("u.obj")).warnings == ()
    # The PLY reader spends the same budget.
    from clray.scene.ply import read_ply
    ply = ("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
           "property float z\nelement face 4\nproperty list uchar int vertex_indices\n"
           "end_header\n" + "".join(f"{x} {y} 0\n" for x, y in _U)
           + "8 0 1 2 3 4 5 6 7\n" * 4)
    ply_mesh = read_ply(ply.encode(), Path("u.ply")).mesh
    np.testing.assert_array_equal(ply_mesh.faces, mesh.faces)
    assert ply_mesh.warnings == mesh.warnings


def test_ear_clipping_a_file_of_many_large_polygons_is_bounded(monkeypatch):
    # 200 stars of 256 corners (128 reflex): about 20 ms each to ear-clip, 4 s in all
    # before the budget; now only as many as _EAR_CLIP_BUDGET pays for.
    k = 256
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    r = np.where(np.arange(k) % 2, 1.0, 0.6)
    xy = np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
    text = "".join(f"v {x:.4f} {y:.4f} 0\n" for x, y in xy)
    text += ("f " + " ".join(str(i + 1) for i in range(k)) + "\n") * 200
    clipped = []
    ear_clip = obj._ear_clip
    monkeypatch.setattr(obj, "_ear_clip", lambda p, n: clipped.append(1) or ear_clip(p, n))
    mesh = parse_obj(text.encode(), Path("s.obj"))
    paid = obj._EAR_CLIP_BUDGET // (k * (k + obj._EAR_CLIP_EXTRA))
    assert 0 < len(clipped) == paid < 200
    assert mesh.warnings[0].startswith(f"{200 - paid} polygon(s) ")


def test_a_scene_takes_the_mesh_files_warning(tmp_path, monkeypatch):
    from clray.scene.assets import meshes_read_once
    from clray.scene.load import scene_from_dict
    monkeypatch.setattr(obj, "_EAR_CLIP_BUDGET", 0)
    (tmp_path / "u.obj").write_text(_U_TEXT + _U_FACE)
    data = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
            "objects": [{"type": "mesh", "file": "u.obj"},
                        {"type": "mesh", "file": "u.obj"}]}
    with meshes_read_once():
        # Once a scene, also for the second scene that finds the file already read.
        for _ in range(2):
            scene = scene_from_dict(data, tmp_path / "s.toml")
            told = [w for w in scene.warnings if "left as fans" in w]
            assert len(told) == 1 and "u.obj: 1 polygon(s)" in told[0]


def test_convexity_is_tested_a_bounded_number_of_corners_at_a_time(monkeypatch):
    # 2048 convex 1000-gons: the test's float64 temporaries (about 100 bytes a corner) come
    # a chunk of corners at a time, not 2048 polygons' (200 MB) at once.
    import tracemalloc
    k, polygons = 1000, 2048
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    positions = np.stack([np.cos(t), np.sin(t), np.zeros(k)], axis=1)
    v = np.tile(np.arange(k), polygons)
    count = np.full(polygons, k)

    def peak(shapes: bool) -> int:
        with monkeypatch.context() as patch:
            if not shapes:
                patch.setattr(obj, "_shape_polygons", lambda *args: None)
            tracemalloc.start()
            try:
                obj._fan(count, positions, v)
                return tracemalloc.get_traced_memory()[1]
            finally:
                tracemalloc.stop()

    # Beyond the fan's own peak (the same polygons, their shapes not looked at).
    assert peak(True) - peak(False) < 40 << 20
