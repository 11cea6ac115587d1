"""Stanford PLY reader: ASCII and binary (little and big endian) meshes.

The vertex element gives positions (x, y, z), and where present normals (nx, ny, nz), texture
coordinates (u, v; s, t; texture_u, texture_v) and colours (red, green, blue); the face
element's list property (vertex_indices or vertex_index) gives polygons, fan-triangulated as
the OBJ reader does. Other elements (edge, material, ...) and properties are read past and
ignored. Binary elements are read with one numpy view per run of records of one size, so a
million-face triangle mesh is one view; only a list whose length changes from record to
record costs a run each (docs/scene_format.md compares this reader with plyfile and trimesh).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clray.errors import SceneError, plural
from clray.scene.limits import MAX_MAGNITUDE
from clray.scene.model import unit
from clray.scene.obj import ObjMesh, _fan

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))
_FACE_LISTS = ("vertex_indices", "vertex_index")
# Header lines a file may have before end_header; a real header has a few dozen.
_MAX_HEADER_LINES = 10000


@dataclass(frozen=True)
class _Property:
    name: str
    type: str  # numpy type code without byte order
    count_type: str | None = None  # set for a list property


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: tuple[_Property, ...]

    def has_list(self) -> bool:
        return any(p.count_type is not None for p in self.properties)


@dataclass(frozen=True, eq=False)
class PlyMesh:
    """The mesh, and the vertex colours (V, 3) in [0, 1] where the file has them."""

    mesh: ObjMesh
    colors: np.ndarray | None


class _Reader:
    def __init__(self, data: bytes, path: Path) -> None:
        self.data = data
        self.path = path

    def error(self, where: str | None, message: str) -> SceneError:
        return SceneError(self.path, where, message)

    def header(self) -> tuple[str, list[_Element], int]:
        """(format, elements, offset of the body)."""
        if not self.data.startswith(b"ply") or self.data[3:4] not in (b"\n", b"\r"):
            raise self.error(None, "not a PLY file (it must start with a 'ply' line)")
        end = self.data.find(b"end_header")
        if end < 0:
            raise self.error(None, "no end_header line")
        newline = self.data.find(b"\n", end)
        body = len(self.data) if newline < 0 else newline + 1
        lines = self.data[:end].decode("ascii", errors="replace").splitlines()
        if len(lines) > _MAX_HEADER_LINES:
            raise self.error(None, f"header of over {_MAX_HEADER_LINES} lines")
        fmt = None
        elements: list[tuple[str, int, list[_Property]]] = []
        for number, line in enumerate(lines[1:], start=2):
            words = line.split()
            where = f"header line {number}"
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format":
                if len(words) != 3 or words[1] not in _FORMATS or words[2] != "1.0":
                    raise self.error(where, f"expected 'format ascii|binary_little_endian|"
                                     f"binary_big_endian 1.0', got {line.strip()!r}")
                fmt = words[1]
            elif words[0] == "element":
                if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):
                    raise self.error(where, f"expected 'element NAME COUNT', got {line.strip()!r}")
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property":
                if not elements:
                    raise self.error(where, "property before any element")
                elements[-1][2].append(self.property(words, where))
            else:
                raise self.error(where, f"unknown header keyword {words[0]!r}")
        if fmt is None:
            raise self.error(None, "no format line in the header")
        for name, count, props in elements:
            names = [p.name for p in props]
            if len(set(names)) != len(names):
                raise self.error(f"element {name}", "two properties of one name")
            if count and not props:
                raise self.error(f"element {name}", "records without properties")
        return fmt, [_Element(n, c, tuple(p)) for n, c, p in elements], body

    def property(self, words: list[str], where: str) -> _Property:
        if len(words) == 5 and words[1] == "list":
            if words[2] not in _TYPES or words[3] not in _TYPES:
                raise self.error(where, f"unknown type in {' '.join(words)!r}")
            if _TYPES[words[2]][0] not in "iu" or _TYPES[words[3]][0] not in "iu":
                raise self.error(where, "a list's count and items must be integer types")
            return _Property(words[4], _TYPES[words[3]], _TYPES[words[2]])
        if len(words) != 3 or words[1] not in _TYPES:
            raise self.error(where, f"expected 'property TYPE NAME' (TYPE one of "
                             f"{', '.join(sorted(set(_TYPES)))}), got {' '.join(words)!r}")
        return _Property(words[2], _TYPES[words[1]])

    # -- binary ------------------------------------------------------------------------

    def binary(self, elements: list[_Element], offset: int, order: str
               ) -> dict[str, dict[str, object]]:
        buf = memoryview(self.data)
        out: dict[str, dict[str, object]] = {}
        for el in elements:
            lists = [p for p in el.properties if p.count_type is not None]
            if len(lists) > 1:
                raise self.error(f"element {el.name}", "more than one list property per "
                                 "element is not supported")
            if not lists:
                dtype = np.dtype([(p.name, order + p.type) for p in el.properties])
                size = dtype.itemsize * el.count
                if offset + size > len(buf):
                    raise self.truncated(el, (len(buf) - offset) // max(dtype.itemsize, 1))
                records = np.frombuffer(buf, dtype, el.count, offset)
                out[el.name] = {p.name: records[p.name] for p in el.properties}
                offset += size
            else:
                out[el.name], offset = self.binary_lists(buf, el, offset, order)
        return out

    def binary_lists(self, buf: memoryview, el: _Element, offset: int, order: str
                     ) -> tuple[dict[str, object], int]:
        """An element with one list property: runs of records whose lists have one length,
        each run read as one numpy view."""
        props = el.properties
        at = next(i for i, p in enumerate(props) if p.count_type is not None)
        lst = props[at]
        before = sum(np.dtype(p.type).itemsize for p in props[:at])
        count_dtype = np.dtype(order + lst.count_type)
        runs: list[np.ndarray] = []
        done = 0
        while done < el.count:
            if offset + before + count_dtype.itemsize > len(buf):
                raise self.truncated(el, done)
            k = int(np.frombuffer(buf, count_dtype, 1, offset + before)[0])
            if k < 0:
                raise self.error(f"element {el.name}", f"record {done}: list length {k}")
            if k * np.dtype(lst.type).itemsize > len(buf) - offset:
                raise self.truncated(el, done)
            fields = [(p.name, order + p.type) for p in props[:at]]
            fields += [("_count", count_dtype), ("_items", order + lst.type, (k,))]
            fields += [(p.name, order + p.type) for p in props[at + 1:]]
            dtype = np.dtype(fields)
            fit = min(el.count - done, (len(buf) - offset) // dtype.itemsize)
            if fit == 0:
                raise self.truncated(el, done)
            view = np.frombuffer(buf, dtype, fit, offset)
            other = np.flatnonzero(view["_count"] != k)
            n = fit if len(other) == 0 else int(other[0])
            runs.append(view[:n])
            done += n
            offset += n * dtype.itemsize
        counts = np.concatenate([r["_count"].astype(np.int64) for r in runs]) if runs else \
            np.zeros(0, dtype=np.int64)
        items = (np.concatenate([r["_items"].reshape(-1).astype(np.int64) for r in runs])
                 if runs else np.zeros(0, dtype=np.int64))
        columns: dict[str, object] = {lst.name: (counts, items)}
        for p in props:
            if p is not lst:
                columns[p.name] = (np.concatenate([r[p.name] for r in runs]) if runs
                                   else np.zeros(0, dtype=p.type))
        return columns, offset

    def truncated(self, el: _Element, records: int) -> SceneError:
        return self.error(f"element {el.name}", f"file ends after {records} of {el.count} "
                          "records")

    # -- ASCII -------------------------------------------------------------------------

    def ascii(self, elements: list[_Element], offset: int) -> dict[str, dict[str, object]]:
        lines = self.data[offset:].split(b"\n")
        first_line = self.data[:offset].count(b"\n") + 1
        out: dict[str, dict[str, object]] = {}
        row = 0
        for el in elements:
            mine = lines[row:row + el.count]
            if len(mine) < el.count or (el.count and not mine[-1].strip()):
                got = sum(1 for line in mine if line.strip())
                raise self.truncated(el, got)
            out[el.name] = self.ascii_element(el, mine, first_line + row)
            row += el.count
        return out

    def ascii_element(self, el: _Element, lines: list[bytes], first_line: int
                      ) -> dict[str, object]:
        props = el.properties
        if not el.has_list():
            tokens = b" ".join(lines).split()
            if len(tokens) != len(props) * el.count:
                self.ascii_line_error(el, lines, first_line, len(props))
            values = self.ascii_numbers(tokens, el, lines, first_line).reshape(el.count,
                                                                                len(props))
            return {p.name: self.typed(values[:, i], p, el) for i, p in enumerate(props)}
        rows = [line.split() for line in lines]
        at = next(i for i, p in enumerate(props) if p.count_type is not None)
        if any(p.count_type is not None for p in props[at + 1:]):
            raise self.error(f"element {el.name}", "more than one list property per element "
                             "is not supported")
        columns: dict[str, list] = {p.name: [] for p in props}
        counts, items = [], []
        for i, words in enumerate(rows):
            where = f"element {el.name}, line {first_line + i}"
            try:
                k = int(words[at])
                want = len(props) + k
                if k < 0 or len(words) != want:
                    raise ValueError
                for p, w in zip(props[:at], words[:at], strict=True):
                    columns[p.name].append(float(w))
                listed = [int(w) for w in words[at + 1:at + 1 + k]]
                if any(abs(v) >= 2**62 for v in listed):
                    raise ValueError
                items.extend(listed)
                for p, w in zip(props[at + 1:], words[at + 1 + k:], strict=True):
                    columns[p.name].append(float(w))
            except (ValueError, IndexError):
                raise self.error(where, f"expected {plural(len(props) - 1, 'number')} and a "
                                 f"list (its length first), got {b' '.join(words)[:60]!r}"
                                 ) from None
            counts.append(k)
        out: dict[str, object] = {p.name: np.array(columns[p.name]) for p in props
                                  if p.count_type is None}
        out[props[at].name] = (np.array(counts, dtype=np.int64), np.array(items, dtype=np.int64))
        return out

    def typed(self, values: np.ndarray, prop: _Property, el: _Element) -> np.ndarray:
        """An ASCII column as its declared type: integer types (colours as 0-255) must hold
        whole numbers in their range."""
        kind = np.dtype(prop.type)
        if kind.kind == "f":
            return values
        info = np.iinfo(kind)
        bad = np.flatnonzero((values != np.round(values)) | (values < info.min)
                             | (values > info.max))
        if len(bad):
            raise self.error(f"element {el.name}", f"record {int(bad[0])}: {prop.name} must be "
                             f"a whole number in [{info.min}, {info.max}]")
        return values.astype(kind)

    def ascii_numbers(self, tokens: list[bytes], el: _Element, lines: list[bytes],
                      first_line: int) -> np.ndarray:
        try:
            return np.array(tokens).astype(np.float64)
        except ValueError:
            for i, line in enumerate(lines):
                for word in line.split():
                    try:
                        float(word)
                    except ValueError:
                        raise self.error(f"element {el.name}, line {first_line + i}",
                                         f"expected a number, got {word[:40]!r}") from None
            raise

    def ascii_line_error(self, el: _Element, lines: list[bytes], first_line: int,
                         want: int) -> None:
        for i, line in enumerate(lines):
            if len(line.split()) != want:
                raise self.error(f"element {el.name}, line {first_line + i}",
                                 f"expected {plural(want, 'number')}, got {len(line.split())}")


def read_ply(data: bytes, path: Path) -> PlyMesh:
    """Parse a PLY file already in memory; `path` names the file in error messages, which
    name the element (and for ASCII files the line) too."""
    reader = _Reader(data, path)
    fmt, elements, body = reader.header()
    if fmt == "ascii":
        columns = reader.ascii(elements, body)
    else:
        columns = reader.binary(elements, body, _FORMATS[fmt])
    return _mesh(reader, columns)


def _mesh(reader: _Reader, columns: dict[str, dict[str, object]]) -> PlyMesh:
    vertex = columns.get("vertex")
    if vertex is None or not all(name in vertex for name in "xyz"):
        raise reader.error("element vertex", "needs an element vertex with x, y, z properties")
    vertices = _stack(vertex, ("x", "y", "z"))
    _check_numbers(reader, vertices, "element vertex", "x, y, z")
    normals = None
    if all(name in vertex for name in ("nx", "ny", "nz")):
        normals = _stack(vertex, ("nx", "ny", "nz"))
        _check_numbers(reader, normals, "element vertex", "nx, ny, nz")
        zero = np.flatnonzero(~np.any(normals != 0.0, axis=1))
        if len(zero):
            raise reader.error("element vertex", f"record {int(zero[0])}: zero-length normal")
        normals = unit(normals)
    uvs = None
    for pair in _UV_NAMES:
        if all(name in vertex for name in pair):
            uvs = _stack(vertex, pair)
            _check_numbers(reader, uvs, "element vertex", ", ".join(pair))
            break
    colors = _colors(vertex)
    face = columns.get("face")
    name = next((n for n in _FACE_LISTS if face is not None and n in face), None)
    if name is None or not isinstance(face[name], tuple):
        raise reader.error("element face", "needs an element face with a vertex_indices list")
    counts, items = face[name]
    small = np.flatnonzero(counts < 3)
    if len(small):
        i = int(small[0])
        raise reader.error("element face", f"record {i}: a face needs at least 3 vertices, "
                           f"got {int(counts[i])}")
    outside = np.flatnonzero((items < 0) | (items >= len(vertices)))
    if len(outside):
        face_of = int(np.searchsorted(np.cumsum(counts), outside[0], side="right"))
        raise reader.error("element face", f"record {face_of}: vertex index "
                           f"{int(items[outside[0]])} out of range "
                           f"({plural(len(vertices), 'vertex', 'vertices')})")
    faces = items[_fan(counts)]
    return PlyMesh(ObjMesh(vertices, faces, normals, uvs), colors)


def _stack(columns: dict[str, object], names: tuple[str, ...]) -> np.ndarray:
    return np.stack([np.asarray(columns[n], dtype=np.float64) for n in names], axis=1)


def _check_numbers(reader: _Reader, values: np.ndarray, where: str, names: str) -> None:
    bad = np.flatnonzero(~np.all(np.isfinite(values) & (np.abs(values) <= MAX_MAGNITUDE),
                                 axis=1))
    if len(bad):
        raise reader.error(where, f"record {int(bad[0])}: {names} must be finite and at most "
                           f"{MAX_MAGNITUDE:g} in magnitude")


def _colors(vertex: dict[str, object]) -> np.ndarray | None:
    for names in (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue")):
        if all(n in vertex for n in names):
            raw = [np.asarray(vertex[n]) for n in names]
            scale = 255.0 if raw[0].dtype.kind in "iu" else 1.0
            return np.clip(np.stack(raw, axis=1).astype(np.float64) / scale, 0.0, 1.0)
    return None
