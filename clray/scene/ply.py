"""Stanford PLY reader: ASCII and binary (little and big endian) meshes.

The vertex element gives positions (x, y, z), and where present normals (nx, ny, nz), texture
coordinates (u, v; s, t; texture_u, texture_v) and colours (red, green, blue); the face
element's list property (vertex_indices or vertex_index) gives polygons, triangulated as the
OBJ reader does (convex ones as fans, concave ones split by their shape), and a tristrips
element's gives triangle strips (-1 restarts a strip).
Other elements (edge, material, ...) and properties, lists among them (MeshLab's per-corner
`texcoord`), are read past and ignored; elements after the last needed one are not read at
all. Binary elements are read with one numpy view where
every record has one size (a million-face triangle mesh); where list lengths change from
record to record, one pass finds where each record starts and numpy gathers the values
(docs/scene_format.md compares this reader with plyfile and trimesh).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clray.errors import SceneError, plural
from clray.host_memory import fits_host_memory
from clray.scene import limits
from clray.scene.limits import MAX_MAGNITUDE
from clray.scene.obj import ObjMesh, _fan
from clray.vectors import unit

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
# A list's count type as a struct code, for the record-by-record pass over varying lists.
_STRUCT_CODES = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I"}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))
_FACE_LISTS = ("vertex_indices", "vertex_index")
# A line of whitespace only between two others, in an ASCII body.
_BLANK_LINE = re.compile(rb"\n[ \t\r\f\v]*\n")
# Header lines a file may have before end_header; a real header has a few dozen.
_MAX_HEADER_LINES = 10000
# The elements the mesh is built from; the others are read past (or, after the last of these,
# not read at all).
_NEEDED = ("vertex", "face", "tristrips")
# Records of an ignored element whose list lengths change from record to record, walked one
# by one in Python to find where the element ends (only where a needed element follows it):
# at most this many, about a second's work (a 30 MB file of 20 M such records took 22 s).
MAX_SKIPPED_RECORDS = 2**22


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
        if self.data[3:4] == b"\r" and self.data[4:5] != b"\n":
            raise self.error(None, "CR-only line endings are not read (expected LF or CRLF "
                             "line endings)")
        end, body = self.end_header()
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
                    raise self.error(where, f"expected 'element NAME COUNT', got "
                                     f"{line.strip()[:80]!r}")
                # Every record takes a byte at least: a count above the file's size cannot be
                # met, and one of thousands of digits is refused before int() (Python's
                # integer-string limit) sees it.
                digits = words[2].lstrip("0") or "0"
                if len(digits) > len(str(len(self.data))) or int(digits) > len(self.data):
                    shown = digits if len(digits) <= 20 else f"a count of {len(digits)} digits"
                    raise self.error(f"element {words[1][:40]}", f"{shown} records cannot fit "
                                     f"in a file of {plural(len(self.data), 'byte')}")
                elements.append((words[1], int(digits), []))
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

    def end_header(self) -> tuple[int, int]:
        """(offset of the end_header line, offset of the body). The line is the keyword alone
        (a comment may mention end_header before it), among the first _MAX_HEADER_LINES lines;
        the header is walked line by line, a binary body never."""
        data, at = self.data, 0
        for _ in range(_MAX_HEADER_LINES + 1):
            newline = data.find(b"\n", at)
            line_end = len(data) if newline < 0 else newline
            # A copy of 64 bytes at most: a line of binary bytes may run on for megabytes.
            line = data[at:min(line_end, at + 64)]
            if line_end - at <= 64 and line.strip() == b"end_header":
                return at + line.index(b"end_header"), min(line_end + 1, len(data))
            if newline < 0:
                raise self.error(None, "no end_header line")
            at = newline + 1
        raise self.error(None, f"header of over {_MAX_HEADER_LINES} lines (no end_header line "
                         "among them)")

    def property(self, words: list[str], where: str) -> _Property:
        if len(words) == 5 and words[1] == "list":
            if words[2] not in _TYPES or words[3] not in _TYPES:
                raise self.error(where, f"unknown type in {' '.join(words)!r}")
            # Items may be of any type (MeshLab writes `property list uchar float texcoord`),
            # the count must be an integer.
            if _TYPES[words[2]][0] not in "iu":
                raise self.error(where, "a list's count must be of an integer type")
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
        for el in elements[:_last_needed(elements)]:
            if el.name not in _NEEDED:
                offset = self.binary_skip(buf, el, offset, order)
            elif not el.has_list():
                dtype = np.dtype([(p.name, order + p.type) for p in el.properties])
                size = dtype.itemsize * el.count
                if offset + size > len(buf):
                    raise self.truncated(el, (len(buf) - offset) // max(dtype.itemsize, 1))
                records = np.frombuffer(buf, dtype, el.count, offset)
                out[el.name] = {p.name: records[p.name] for p in el.properties}
                offset += size
            else:
                read = self.binary_uniform(buf, el, offset, order)
                if read is None:
                    read = self.binary_lists(el, offset, order)
                out[el.name], offset = read
        return out

    def binary_skip(self, buf: memoryview, el: _Element, offset: int, order: str) -> int:
        """Where an ignored element that a needed one follows ends: by arithmetic for fixed
        records, by one numpy view where every list has the first record's length, else by a
        walk that keeps nothing a record (and takes at most MAX_SKIPPED_RECORDS)."""
        if not el.has_list():
            size = sum(np.dtype(p.type).itemsize for p in el.properties)
            if offset + size * el.count > len(buf):
                raise self.truncated(el, (len(buf) - offset) // max(size, 1))
            return offset + size * el.count
        read = self.binary_uniform(buf, el, offset, order, keep=False)
        if read is not None:
            return read[1]
        if el.count > MAX_SKIPPED_RECORDS:
            raise self.error(f"element {el.name}", f"{el.count} records of lists that change "
                             f"length before the mesh's elements; at most "
                             f"{MAX_SKIPPED_RECORDS} are read past (write it after vertex "
                             "and face)")
        segments, gap = [], 0
        for p in el.properties:
            size = np.dtype(p.type).itemsize
            if p.count_type is None:
                gap += size
                continue
            count = struct.Struct(order + _STRUCT_CODES[p.count_type])
            segments.append((gap, count.unpack_from, count.size, size))
            gap = 0
        data, end, at = self.data, len(self.data), offset
        for record in range(el.count):
            for before, unpack, count_size, item_size in segments:
                at += before
                if at + count_size > end:
                    raise self.truncated(el, record)
                k = unpack(data, at)[0]
                if k < 0:
                    raise self.error(f"element {el.name}", f"record {record}: list length {k}")
                at += count_size + k * item_size
            at += gap
            if at > end:
                raise self.truncated(el, record)
        return at

    def binary_uniform(self, buf: memoryview, el: _Element, offset: int, order: str,
                       keep: bool = True) -> tuple[dict[str, object], int] | None:
        """An element whose every list has the first record's length (a triangle mesh's
        faces) as one numpy view; None where a length changes (or the file ends early).
        With keep False (an element skipped) the lengths are checked and no column is
        made: only where the element ends counts."""
        fields, at = [], offset
        for p in el.properties:
            if p.count_type is None:
                fields.append((p.name, order + p.type))
                at += np.dtype(p.type).itemsize
                continue
            count_dtype = np.dtype(order + p.count_type)
            if at + count_dtype.itemsize > len(buf):
                return None
            k = int(np.frombuffer(buf, count_dtype, 1, at)[0])
            if k < 0 or k * np.dtype(p.type).itemsize > len(buf) - at:
                return None
            fields += [(f"\0count {p.name}", count_dtype), (p.name, order + p.type, (k,))]
            at += count_dtype.itemsize + k * np.dtype(p.type).itemsize
        dtype = np.dtype(fields)
        if offset + dtype.itemsize * el.count > len(buf):
            return None
        view = np.frombuffer(buf, dtype, el.count, offset)
        # Each record's lengths equal the first's: then, record by record, every record
        # starts where the view puts it, and the view is the element.
        columns: dict[str, object] = {}
        for p in el.properties:
            if p.count_type is None:
                columns[p.name] = view[p.name]
                continue
            lengths = view[f"\0count {p.name}"]
            # Two reductions, no boolean array of a byte a record.
            if len(lengths) and lengths.min() != lengths.max():
                return None
            if not keep:
                continue
            # One length for every record: a read-only broadcast of it, not an int64 a record.
            counts = np.broadcast_to(np.int64(lengths[0]) if len(lengths) else np.int64(0),
                                     lengths.shape)
            columns[p.name] = (counts, _as_items(view[p.name].reshape(-1), p))
        return columns, offset + dtype.itemsize * el.count

    def binary_lists(self, el: _Element, offset: int, order: str
                     ) -> tuple[dict[str, object], int]:
        """An element whose list lengths change from record to record (triangles and quads
        mixed): one pass over the records finds where each starts and its lists' lengths
        (the only sequential part: a record starts where the one before ends), then numpy
        gathers every property at once. Linear in the records: a run of records of one
        length per numpy view was quadratic where lengths alternate."""
        props = el.properties
        sizes = [np.dtype(p.type).itemsize for p in props]
        # The record as (fixed bytes before a list, the list's count reader, count size,
        # item size) per list, and the fixed bytes after the last list.
        segments, gap = [], 0
        # The face list _mesh triangulates needs 3 items a record: checked here, record by
        # record, so that a file of 0- and 1-item lists fails at its first record rather than
        # after a pass over millions (14.7 s and 1.8 GB for 30 MB).
        faces = next((n for n in _FACE_LISTS if any(p.name == n for p in props)), None)
        for p, size in zip(props, sizes, strict=True):
            if p.count_type is None:
                gap += size
                continue
            count = struct.Struct(order + _STRUCT_CODES[p.count_type])
            least = 3 if el.name == "face" and p.name == faces and p.type[0] in "iu" else 0
            segments.append((gap, count.unpack_from, count.size, size, least))
            gap = 0
        tail = gap
        data, end = self.data, len(self.data)
        starts: list[int] = []
        lengths: list[list[int]] = [[] for _ in segments]
        at = offset
        for record in range(el.count):
            starts.append(at)
            for (before, unpack, count_size, item_size, least), found in zip(
                    segments, lengths, strict=True):
                at += before
                if at + count_size > end:
                    raise self.truncated(el, record)
                k = unpack(data, at)[0]
                if k < least:
                    raise (_few_corners(self, record, k) if k >= 0 else self.error(
                        f"element {el.name}", f"record {record}: list length {k}"))
                found.append(k)
                at += count_size + k * item_size
            at += tail
            if at > end:
                raise self.truncated(el, record)
        raw = np.frombuffer(data, np.uint8)
        position = np.array(starts, dtype=np.int64)
        columns: dict[str, object] = {}
        lists = iter(lengths)
        for p, size in zip(props, sizes, strict=True):
            dtype = np.dtype(order + p.type)
            if p.count_type is None:
                columns[p.name] = _gather(raw, position, dtype)
                position = position + size
                continue
            counts = np.array(next(lists), dtype=np.int64)
            count_size = np.dtype(p.count_type).itemsize
            first = np.repeat(position + count_size, counts)
            within = np.arange(len(first)) - np.repeat(np.cumsum(counts) - counts, counts)
            items = _gather(raw, first + within * size, dtype)
            columns[p.name] = (counts, _as_items(items, p))
            position = position + count_size + counts * size
        return columns, at

    def truncated(self, el: _Element, records: int) -> SceneError:
        return self.error(f"element {el.name}", f"file ends after {records} of {el.count} "
                          "records")

    # -- ASCII -------------------------------------------------------------------------

    def ascii(self, elements: list[_Element], offset: int) -> dict[str, dict[str, object]]:
        body = self.data[offset:]
        read = elements[:_last_needed(elements)]
        first_line = self.data[:offset].count(b"\n") + 1
        numbers: Sequence[int]  # the file's line number of each line, for errors
        first_end = body.find(b"\n")
        if not body[:first_end if first_end >= 0 else len(body)].strip() or \
                _BLANK_LINE.search(body):
            # Blank lines (some writers leave one between elements) hold no record: read past,
            # as readers that take the body token by token (rply, trimesh) do. One regex pass
            # finds them, so only a file that has them pays for the filtering.
            lines = body.split(b"\n")
            kept = [i for i, line in enumerate(lines) if line.strip()]
            lines = [lines[i] for i in kept]
            numbers = [first_line + i for i in kept]
        else:
            # The lines up to the last needed element's, the rest of the file as one piece.
            lines = body.split(b"\n", sum(el.count for el in read))
            numbers = range(first_line, first_line + len(lines))
        out: dict[str, dict[str, object]] = {}
        row = 0
        for el in read:
            mine = lines[row:row + el.count]
            if len(mine) < el.count or (el.count and not mine[-1].strip()):
                got = sum(1 for line in mine if line.strip())
                raise self.truncated(el, got)
            # An ignored element is one line a record: its lines are counted, not parsed.
            if el.name in _NEEDED:
                out[el.name] = self.ascii_element(el, mine, numbers[row:row + el.count])
            row += el.count
        return out

    def ascii_element(self, el: _Element, lines: list[bytes], numbers: Sequence[int]
                      ) -> dict[str, object]:
        props = el.properties
        if not el.has_list():
            tokens = b" ".join(lines).split()
            if len(tokens) != len(props) * el.count:
                self.ascii_line_error(el, lines, numbers, len(props))
            values = self.ascii_numbers(tokens, el, lines, numbers).reshape(el.count,
                                                                                len(props))
            return {p.name: self.typed(values[:, i], p, el) for i, p in enumerate(props)}
        scalars: dict[str, list[float]] = {p.name: [] for p in props if p.count_type is None}
        lists: dict[str, tuple[list[int], list]] = {p.name: ([], []) for p in props
                                                    if p.count_type is not None}
        n_lists = len(lists)
        # A face needs 3 items: checked as each line is read, as the binary reader does, so the
        # error names its line and comes before the rest of the file is parsed.
        faces = next((n for n in _FACE_LISTS if n in lists), None) if el.name == "face" else None
        for i, line in enumerate(lines):
            words = line.split()
            at = 0
            short = None
            try:
                for p in props:
                    if p.count_type is None:
                        scalars[p.name].append(float(words[at]))
                        at += 1
                        continue
                    # int() of bytes takes ASCII digits only; a count of thousands of digits
                    # is a ValueError (Python's integer-string limit) like any bad count.
                    k = int(words[at])
                    listed = words[at + 1:at + 1 + k]
                    if k < 0 or len(listed) != k:
                        raise ValueError
                    if k < 3 and p.name == faces and np.dtype(p.type).kind in "iu":
                        short = k
                    if np.dtype(p.type).kind == "f":
                        values: list = [float(w) for w in listed]
                    else:
                        values = [int(w) for w in listed]
                        if any(abs(v) >= 2**62 for v in values):
                            raise ValueError
                    lists[p.name][0].append(k)
                    lists[p.name][1].extend(values)
                    at += 1 + k
                if at != len(words):
                    raise ValueError
            except (ValueError, IndexError):
                shape = ("a list (its length first)" if n_lists == 1 else
                         f"{n_lists} lists (each its length first)")
                raise self.error(f"element {el.name}, line {numbers[i]}",
                                 f"expected {plural(len(scalars), 'number')} and {shape}, got "
                                 f"{b' '.join(words)[:60]!r}") from None
            if short is not None:
                raise self.error(f"element face, line {numbers[i]}",
                                 f"a face needs at least 3 vertices, got {short}")
        out: dict[str, object] = {name: np.array(v, dtype=np.float64)
                                  for name, v in scalars.items()}
        for p in props:
            if p.count_type is not None:
                counts, items = lists[p.name]
                kind = np.float64 if np.dtype(p.type).kind == "f" else np.int64
                out[p.name] = (np.array(counts, dtype=np.int64), np.array(items, dtype=kind))
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
                      numbers: Sequence[int]) -> np.ndarray:
        try:
            # Token by token in C, as fast as np.array(tokens).astype(float) and parsed by the
            # same float(): that array of fixed-width strings is as wide as the longest token,
            # so one number of 2000 digits among 2.4 M tokens took 4.8 GB.
            return np.fromiter(map(float, tokens), np.float64, len(tokens))
        except ValueError:
            for i, line in enumerate(lines):
                for word in line.split():
                    try:
                        float(word)
                    except ValueError:
                        raise self.error(f"element {el.name}, line {numbers[i]}",
                                         f"expected a number, got {word[:40]!r}") from None
            raise

    def ascii_line_error(self, el: _Element, lines: list[bytes], numbers: Sequence[int],
                         want: int) -> None:
        for i, line in enumerate(lines):
            if len(line.split()) != want:
                raise self.error(f"element {el.name}, line {numbers[i]}",
                                 f"expected {plural(want, 'number')}, got {len(line.split())}")


def _last_needed(elements: list[_Element]) -> int:
    """How many elements are read: up to the last needed one. The elements after it are not
    read at all (nothing of the mesh needs to know where they end)."""
    return max((i + 1 for i, el in enumerate(elements) if el.name in _NEEDED), default=0)


def read_ply(data: bytes, path: Path) -> PlyMesh:
    """Parse a PLY file already in memory; `path` names the file in error messages, which
    name the element (and for ASCII files the line) too."""
    reader = _Reader(data, path)
    fmt, elements, body = reader.header()
    for el in elements:
        # Every face is a triangle at least: a count over the limit for all meshes is refused
        # from the header, before a pass over its records.
        if el.name == "face" and el.count > limits.MAX_TRIANGLES:
            raise reader.error("element face", f"{el.count} faces make at least as many "
                               f"triangles, over the limit of {limits.MAX_TRIANGLES} for all "
                               "meshes")
    # Before the records are read into arrays (a polygon makes more triangles than one). At
    # most the faces the file's bytes hold (4 bytes the least: a binary count and three
    # indices, each a byte): a truncated file is said to be truncated, not too big.
    faces = sum(el.count for el in elements if el.name == "face")
    fits_host_memory(path, min(faces, (len(data) - body) // 4))
    if fmt == "ascii":
        if len(data) > limits.MAX_MESH_BYTES:
            # Text is parsed token by token, at several times its size in memory: binary files
            # alone (numpy views of their blocks) may be as large as MAX_BINARY_MESH_BYTES.
            raise reader.error(None, f"an ASCII PLY file is at most {limits.MAX_MESH_BYTES} "
                               f"bytes, this one has {len(data)} (write it as binary)")
        columns = reader.ascii(elements, body)
    else:
        columns = reader.binary(elements, body, _FORMATS[fmt])
    return _mesh(reader, columns)


def _mesh(reader: _Reader, columns: dict[str, dict[str, object]]) -> PlyMesh:
    vertex = columns.get("vertex")
    if vertex is None or not all(name in vertex for name in "xyz"):
        raise reader.error("element vertex", "needs an element vertex with x, y, z properties")
    # Positions the file stores as 4-byte floats stay float32 (Mesh.vertices): 12 B a vertex
    # for as long as the scene is kept, not 24, and every use widens them exactly.
    single = all(getattr(vertex[n], "dtype", None) in (np.dtype("<f4"), np.dtype(">f4"))
                 for n in "xyz")
    vertices = _stack(reader, vertex, ("x", "y", "z"), np.float32 if single else np.float64)
    _check_numbers(reader, vertices, "element vertex", "x, y, z")
    normals = None
    if all(name in vertex for name in ("nx", "ny", "nz")):
        normals = _stack(reader, vertex, ("nx", "ny", "nz"))
        _check_numbers(reader, normals, "element vertex", "nx, ny, nz")
        zero = np.flatnonzero(~np.any(normals != 0.0, axis=1))
        if len(zero):
            raise reader.error("element vertex", f"record {int(zero[0])}: zero-length normal")
        normals = unit(normals)
    uvs = None
    for pair in _UV_NAMES:
        if all(name in vertex for name in pair):
            uvs = _stack(reader, vertex, pair)
            _check_numbers(reader, uvs, "element vertex", ", ".join(pair))
            break
    colors = _colors(reader, vertex)
    parts = []
    told: tuple[str, ...] = ()
    face = _index_list(reader, columns, "face", len(vertices))
    if face is not None:
        counts, items = face
        small = np.flatnonzero(counts < 3)
        if len(small):
            raise _few_corners(reader, int(small[0]), int(counts[small[0]]))
        # A triangle mesh's items are its faces as they are: no fan to gather (a copy of
        # 24 bytes a triangle).
        if np.all(counts == 3):
            parts.append(items.reshape(-1, 3))
        else:
            corners, told = _fan(counts, vertices, items)
            parts.append(items[corners])
    strips = _index_list(reader, columns, "tristrips", len(vertices))
    if strips is not None:
        parts.append(_strip_triangles(*strips))
    if not parts:
        raise reader.error("element face", "needs an element face (or tristrips) with a "
                           "vertex_indices list")
    faces = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return PlyMesh(ObjMesh(vertices, faces, normals, uvs, warnings=told), colors)


def _few_corners(reader: _Reader, record: int, count: int) -> SceneError:
    return reader.error("element face", f"record {record}: a face needs at least 3 vertices, "
                        f"got {count}")


def _index_list(reader: _Reader, columns: dict[str, dict[str, object]], element: str,
                n_vertices: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(counts, items) of the element's vertex_indices list, checked: integers in range, and
    for tristrips -1 too (a restart)."""
    table = columns.get(element)
    name = next((n for n in _FACE_LISTS if table is not None and n in table), None)
    if name is None:
        return None
    where = f"element {element}"
    if not isinstance(table[name], tuple):
        raise reader.error(where, f"{name} must be a list (property list TYPE TYPE {name})")
    counts, items = table[name]
    if items.dtype.kind not in "iu":
        raise reader.error(where, f"{name} must be a list of an integer type")
    low = -1 if element == "tristrips" else 0
    # Checked by reductions, with no boolean array of every index unless one is out of range.
    if len(items) and not (items.min() >= low and items.max() < n_vertices):
        outside = np.flatnonzero((items < low) | (items >= n_vertices))[0]
        record = int(np.searchsorted(np.cumsum(counts), outside, side="right"))
        raise reader.error(where, f"record {record}: vertex index {int(items[outside])} "
                           f"out of range ({plural(n_vertices, 'vertex', 'vertices')})")
    # int32 where every vertex index fits it (the kernels index vertices with int32): a file's
    # int32 indices as they are, not an int64 copy (12 bytes a triangle, not 24).
    return counts, items.astype(_index_type(n_vertices), copy=False)


def _index_type(n_vertices: int) -> type:
    return np.int32 if n_vertices <= np.iinfo(np.int32).max else np.int64


def _strip_triangles(counts: np.ndarray, items: np.ndarray) -> np.ndarray:
    """(T, 3) triangles of triangle strips: each record a strip, -1 restarting it.

    The winding rule is OpenGL's GL_TRIANGLE_STRIP, which the Stanford scans' strips (the
    Cyberware and zipper tools behind the bunny, dragon and Buddha, written for SGI's GL)
    follow: triangle j of a strip is (s[j], s[j+1], s[j+2]) for even j and (s[j+1], s[j],
    s[j+2]) for odd j, so every triangle keeps the orientation of the first. Degenerate
    triangles (two corners alike, which strips use to turn corners or join) are dropped."""
    n = len(items)
    if n < 3:
        return np.zeros((0, 3), dtype=np.int64)
    # A strip starts at each record's first item and after each -1.
    begins = np.zeros(n, dtype=bool)
    begins[(np.cumsum(counts) - counts)[counts > 0]] = True
    begins[1:] |= items[:-1] == -1
    start = np.maximum.accumulate(np.where(begins, np.arange(n), 0))
    j = np.arange(n - 2)
    # A triangle at j: its three items in one strip (no -1, no record or restart between).
    ok = (start[j] == start[j + 2]) & (items[j] >= 0) & (items[j + 1] >= 0) & (items[j + 2] >= 0)
    j = j[ok]
    odd = (j - start[j]) % 2 == 1
    a, b, c = items[j], items[j + 1], items[j + 2]
    tris = np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return tris[keep]


def _stack(reader: _Reader, columns: dict[str, object], names: tuple[str, ...],
           dtype: type = np.float64) -> np.ndarray:
    for n in names:
        if isinstance(columns[n], tuple):
            raise reader.error("element vertex", f"{n} must be a number, not a list "
                               f"(property TYPE {n})")
    # Each column converted into its place: no float64 copy of each before the stacking.
    out = np.empty((len(columns[names[0]]), len(names)), dtype=dtype)
    for k, n in enumerate(names):
        out[:, k] = columns[n]
    return out


def _gather(raw: np.ndarray, positions: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Values of `dtype` starting at byte `positions` of `raw`, gathered a byte lane at a
    time (index arrays of one int64 per value, not per byte)."""
    out = np.empty((len(positions), dtype.itemsize), dtype=np.uint8)
    for lane in range(dtype.itemsize):
        out[:, lane] = raw[positions + lane]
    return out.view(dtype).reshape(-1)


def _as_items(items: np.ndarray, prop: _Property) -> np.ndarray:
    """A list's items: integer types as the file has them (indices, which _index_list checks
    and then narrows), float64 otherwise."""
    return items.astype(np.float64) if np.dtype(prop.type).kind == "f" else items


def _check_numbers(reader: _Reader, values: np.ndarray, where: str, names: str) -> None:
    # Two reductions for the common case (a NaN makes both NaN, failing the test); the
    # boolean arrays that find the first bad record only when there is one: at 2.6 M vertices
    # they were 80 MB of temporaries.
    if not len(values) or (values.min() >= -MAX_MAGNITUDE and values.max() <= MAX_MAGNITUDE):
        return
    bad = np.flatnonzero(~np.all(np.isfinite(values) & (np.abs(values) <= MAX_MAGNITUDE),
                                 axis=1))
    if len(bad):
        raise reader.error(where, f"record {int(bad[0])}: {names} must be finite and at most "
                           f"{MAX_MAGNITUDE:g} in magnitude")


def _colors(reader: _Reader, vertex: dict[str, object]) -> np.ndarray | None:
    for names in (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue")):
        if all(n in vertex for n in names):
            _stack(reader, vertex, names)  # numbers, not lists
            raw = [np.asarray(vertex[n]) for n in names]
            scale = 255.0 if raw[0].dtype.kind in "iu" else 1.0
            colors = np.stack(raw, axis=1).astype(np.float64) / scale
            # np.clip keeps a NaN: it would reach the renderer as NaN pixels.
            _check_numbers(reader, colors, "element vertex", ", ".join(names))
            return np.clip(colors, 0.0, 1.0)
    return None
