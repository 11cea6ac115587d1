"""Wavefront OBJ reader: positions, normals, texture coordinates and polygon faces.

Meshes of a few hundred thousand faces are common, so the file is tokenised with numpy on
its raw bytes instead of line by line in Python: a per-line Python loop costs seconds for a
25 MB file, the vectorised passes a tenth of one. Numbers in the usual fixed-point notation
are read eight bytes at a time as 64-bit words (`_fast_floats`), the face indices by one
numpy parse of the face lines; Python reads a token itself only when the vectorised passes
cannot (exponents, long numbers) or to pin down the line of an error they detected. A file in
the layout nearly every exporter writes is first tried by `_parse_regular`, which checks that
layout line by line and skips finding every token's bounds (about 1.5x faster on a 26 MB
mesh); anything else, errors included, is left to the general parser.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clray.errors import SceneError
from clray.scene.files import UnreadableFile, lf_line_ends, read_regular
from clray.scene.limits import MAX_MAGNITUDE, MAX_MESH_BYTES
from clray.vectors import unit


@dataclass(frozen=True, eq=False)
class ObjMesh:
    """One shared vertex index for positions, normals and UVs, as the renderer wants it."""

    vertices: np.ndarray  # (V, 3) float64; float32 as a PLY file stores them (Mesh.vertices)
    # (F, 3) int64 (int32 from a PLY file), in file order: convex polygons as fans, concave
    # ones split by their shape (_fan)
    faces: np.ndarray
    normals: np.ndarray | None = None  # (V, 3) float64, unit length
    uvs: np.ndarray | None = None  # (V, 2) float64
    # Materials named by `usemtl`, in order of first use; face_groups gives each triangle's
    # index into them (-1 before the first `usemtl`), None in a file without `usemtl`.
    material_names: tuple[str, ...] = ()
    face_groups: np.ndarray | None = None
    # `mtllib` statements: (line, file name as written) each, in file order.
    material_libraries: tuple[tuple[int, str], ...] = ()
    # (V, 3) float64 linear vertex colours in [0, 1] (PLY, glTF and inline meshes; not OBJ).
    colors: np.ndarray | None = None
    # What reading the file warns of (polygons left as fans past the ear-clipping budget).
    warnings: tuple[str, ...] = ()


# The bytes `bytes.split()` treats as whitespace, so token boundaries found with numpy agree
# with the ones Python finds when it has to look at a token itself.
_WS = np.zeros(256, dtype=bool)
_WS[[9, 10, 11, 12, 13, 32]] = True

_OTHER, _V, _VT, _VN, _F = range(5)
_NL = ord("\n")
_SLASH = ord("/")
_SPACE = ord(" ")
_BOM = b"\xef\xbb\xbf"  # UTF-8's byte order mark

# Face vertex forms, and how many integers each holds once the slashes are gone.
_FORM_V, _FORM_VT, _FORM_VN, _FORM_VTN = range(4)
_FORM_NAMES = ("v", "v/vt", "v//vn", "v/vt/vn")
_FORM_COMPONENTS = np.array([1, 2, 2, 3])

# What the slow paths accept; stricter than float()/int(), which also take "1_0" and
# non-ASCII digits that the vectorised parsers reject.
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf)", re.I)
_INT = re.compile(r"[+-]?[0-9]+")

# Whitespace in front of the file: every token has two 8-byte words' worth of bytes before
# its end, so `_fast_floats` never reads before the buffer.
_PAD = 16

# Byte-parallel ("SWAR") constants for eight ASCII bytes in a little-endian uint64.
_EACH = 0x0101010101010101
_ZEROS = np.uint64(0x30 * _EACH)
_LOW7 = np.uint64(0x7F * _EACH)
_HIGH = np.uint64(0x80 * _EACH)
_DOTS = np.uint64(0x2E * _EACH)
_PLUS_46 = np.uint64(0x46 * _EACH)
_PLUS_50 = np.uint64(0x50 * _EACH)
# _KEEP[k]: the k highest-addressed bytes of a word, the ones just before a token's end.
_KEEP = np.array([((1 << (8 * k)) - 1) << (64 - 8 * k) for k in range(9)], dtype=np.uint64)
_FILL = _ZEROS & ~_KEEP
_MAX_FAST_DIGITS = 16  # two words
_POW10_INT = np.array([10**k for k in range(_MAX_FAST_DIGITS + 1)], dtype=np.uint64)
_POW10_FLOAT = np.array([10.0**k for k in range(_MAX_FAST_DIGITS + 1)])
# Integers up to 2**53 are exact doubles; one division of two exact doubles is correctly
# rounded, so such a mantissa over a power of ten <= 10**22 is exactly what float() gives.
_EXACT = np.uint64(2**53)


class _Tokens:
    """Every whitespace-separated token of the file, grouped into statements (lines)."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.path = path
        buf = _padded(data)
        control = np.flatnonzero(buf < 32)
        self.newlines = control[buf[control] == _NL]
        if b"#" in data:
            buf = _blank_comments(buf, self.newlines)
        if np.any(buf[control] - 9 > 4):
            # Control bytes other than \t\n\v\f\r are token bytes, as for bytes.split().
            solid = ~_WS[buf]
        else:
            solid = buf > 32
        self.buf = buf
        # The buffer starts and ends with whitespace, so the edges alternate start, end.
        edges = np.flatnonzero(solid[1:] != solid[:-1]) + 1
        self.starts = edges[0::2]
        self.ends = edges[1::2]  # exclusive
        self.heads = self._heads(solid)
        # Tokens per statement, the keyword included.
        self.counts = np.diff(self.heads, append=len(self.starts))
        self.kind = self._classify()

    def _heads(self, solid: np.ndarray) -> np.ndarray:
        """The first token of every line: one with a newline between it and the previous."""
        if len(self.starts) == 0:
            return self.starts
        head = self.buf[self.starts - 1] == _NL
        head[0] = True
        # Only a gap of two or more whitespace bytes can hide a newline further back.
        wide = np.flatnonzero(~head & ~solid[self.starts - 2])
        if len(wide):
            head[wide] = np.searchsorted(self.newlines, self.ends[wide - 1]) != np.searchsorted(
                self.newlines, self.starts[wide]
            )
        return np.flatnonzero(head)

    def _classify(self) -> np.ndarray:
        start = self.starts[self.heads]
        length = self.ends[self.heads] - start
        c0 = self.buf[start]
        c1 = self.buf[start + 1]  # the buffer ends in a newline, so this stays inside
        kind = np.full(len(start), _OTHER, dtype=np.int8)
        kind[(length == 1) & (c0 == ord("v"))] = _V
        kind[(length == 1) & (c0 == ord("f"))] = _F
        two_v = (length == 2) & (c0 == ord("v"))
        kind[two_v & (c1 == ord("t"))] = _VT
        kind[two_v & (c1 == ord("n"))] = _VN
        return kind

    def text(self, token: int) -> str:
        raw = self.buf[self.starts[token] : self.ends[token]].tobytes()
        return raw.decode("utf-8", errors="replace")

    def line(self, token: int) -> int:
        return int(np.searchsorted(self.newlines, self.starts[token])) + 1

    def error(self, token: int, message: str) -> SceneError:
        return SceneError(self.path, f"line {self.line(token)}", message)

    def statements(self, kind: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(statement numbers, index of the first value token, number of values) of each
        statement of a kind."""
        sel = np.flatnonzero(self.kind == kind)
        return sel, self.heads[sel] + 1, self.counts[sel] - 1

    def statement_of(self, tokens: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.heads, tokens, side="right") - 1


def _padded(data: bytes) -> np.ndarray:
    """The file's bytes between `_PAD` spaces and a newline plus `_PAD` spaces, copied once
    (concatenating bytes would copy a large file twice)."""
    buf = np.empty(len(data) + 2 * _PAD + 1, dtype=np.uint8)
    buf[:_PAD] = _SPACE
    buf[_PAD : _PAD + len(data)] = np.frombuffer(data, dtype=np.uint8)
    buf[_PAD + len(data)] = _NL
    buf[-_PAD:] = _SPACE
    return buf


def _blank_comments(buf: np.ndarray, newlines: np.ndarray) -> np.ndarray:
    """Turn everything from a `#` to the end of its line into spaces."""
    hashes = np.flatnonzero(buf == ord("#"))
    line = np.searchsorted(newlines, hashes)
    first = np.ones(len(hashes), dtype=bool)
    first[1:] = line[1:] != line[:-1]
    out = buf.copy()
    out[_ranges(hashes[first], newlines[line[first]] - hashes[first])] = _SPACE
    return out


def _ranges(first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of arange(f, f + c) for each pair."""
    offsets = np.repeat(first - _exclusive_cumsum(counts), counts)
    return offsets + np.arange(counts.sum())


def _exclusive_cumsum(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=out[1:])
    return out


def _words(buf: np.ndarray) -> np.ndarray:
    """The little-endian uint64 of the 8 bytes from each offset of `buf` (a view)."""
    return np.ndarray((len(buf) - 7,), dtype="<u8", buffer=buf, strides=(1,))


def _dots(x: np.ndarray) -> np.ndarray:
    """High bit of each byte of `x` that is a '.'."""
    d = x ^ _DOTS
    out = d & _LOW7
    out += _LOW7
    out |= d
    np.invert(out, out=out)
    out &= _HIGH
    return out


def _not_digits(x: np.ndarray) -> np.ndarray:
    """High bit of each byte of `x` that is not an ASCII digit."""
    # Bit 7 of (b & 0x7f) + 0x46 is set for b >= 0x3a, of (b & 0x7f) + 0x50 for b >= 0x30;
    # bytes >= 0x80 are caught by their own bit 7. No sum carries into the next byte.
    low = x & _LOW7
    out = low + _PLUS_46
    out |= x
    low += _PLUS_50
    np.invert(low, out=low)
    out |= low
    out &= _HIGH
    return out


def _eight_digits(x: np.ndarray) -> np.ndarray:
    """The value of eight ASCII digits, the lowest-addressed byte the most significant
    (the multiply-and-shift steps combine digit pairs, then pairs of pairs, and so on)."""
    x = x & np.uint64(0x0F0F0F0F0F0F0F0F)
    for mask, factor, shift in _DIGIT_STEPS:
        x *= factor
        x >>= shift
        if mask is not None:
            x &= mask
    return x


_DIGIT_STEPS = (
    (np.uint64(0x00FF00FF00FF00FF), np.uint64(2561), np.uint64(8)),
    (np.uint64(0x0000FFFF0000FFFF), np.uint64(6553601), np.uint64(16)),
    (None, np.uint64(42949672960001), np.uint64(32)),
)


def _word_before(buf: np.ndarray, end: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The word ending at each `end`, its bytes before the last `size` (0..8) set to '0'."""
    x = _words(buf)[end - 8]
    x &= _KEEP[size]
    x |= _FILL[size]
    return x


def _fast_floats(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(values, ok): the tokens [start, end) of the form [+-]digits[.digits] with at most 16
    digits and a mantissa up to 2**53, read as exactly the doubles float() gives; ok is
    False where a token is anything else, its value then meaningless."""
    first = buf[start]
    negative = first == ord("-")
    n = end - start
    n -= negative | (first == ord("+"))  # digits and the dot
    ok = (n >= 1) & (n <= _MAX_FAST_DIGITS)
    size = np.minimum(n, 8)
    lo = _word_before(buf, end, size)
    np.subtract(n, 8, out=size)
    np.clip(size, 0, 8, out=size)
    hi = _word_before(buf, end - 8, size)
    dots_lo, dots_hi = _dots(lo), _dots(hi)
    ok &= _not_digits(lo) == dots_lo
    ok &= _not_digits(hi) == dots_hi
    one = np.uint64(1)
    has_lo, has_hi = dots_lo != 0, dots_hi != 0
    # At most one dot, and at least one digit besides it.
    ok &= (dots_lo & (dots_lo - one)) == 0
    ok &= (dots_hi & (dots_hi - one)) == 0
    ok &= ~(has_lo & has_hi)
    has_dot = has_lo | has_hi
    ok &= n > has_dot
    # frexp(2**p) has exponent p + 1; the dot's high bit is bit 8k + 7 for byte k, and
    # 7 - k digits follow it in the low word, 15 - k if it is in the high one.
    dot_bits = np.where(has_lo, dots_lo, dots_hi).astype(np.float64)
    decimals = np.frexp(dot_bits)[1] >> 3
    np.subtract(np.where(has_lo, 8, 16), decimals, out=decimals)
    decimals[~(has_dot & ok)] = 0
    # A dot reads as a '0' digit, so `joined` is the integer part times 10**(decimals + 1)
    # plus the fraction digits as an integer.
    dots_lo >>= np.uint64(6)
    lo += dots_lo
    dots_hi >>= np.uint64(6)
    hi += dots_hi
    joined = _eight_digits(hi)
    joined *= np.uint64(10**8)
    joined += _eight_digits(lo)
    scale = _POW10_INT[decimals]
    integer = joined // np.where(has_dot, scale * np.uint64(10), np.uint64(10**17))
    integer *= scale
    integer *= np.uint64(9)
    joined -= integer  # now the mantissa: integer part * 10**decimals + fraction digits
    ok &= joined <= _EXACT
    values = joined.astype(np.float64)
    values /= _POW10_FLOAT[decimals]
    np.negative(values, out=values, where=negative)
    return values, ok


def _value_tokens(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The value tokens of statements, in file order."""
    if len(count) and np.all(count == count[0]):
        # The usual file: every statement of a kind the same length.
        return (first[:, None] + np.arange(count[0])).reshape(-1)
    return _ranges(first, count)


def _floats(tok: _Tokens, kind: int, name: str, want: int, least: int | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """(values (N, want), statement numbers) of the `v`/`vt`/`vn` statements: each gives at
    least `least` (default `want`) numbers, those it leaves out are 0 (`vt u`: v is optional,
    0 by the OBJ specification)."""
    least = want if least is None else least
    stmt, first, count = tok.statements(kind)
    short = np.flatnonzero(count < least)
    if len(short):
        i = short[0]
        raise tok.error(first[i] - 1, f"{name}: expected at least {least} "
                        f"number{'s' * (least != 1)}, got {count[i]}")
    tokens = _value_tokens(first, count)
    values, ok = _fast_floats(tok.buf, tok.starts[tokens], tok.ends[tokens])
    for i in np.flatnonzero(~ok).tolist():
        values[i] = _python_float(tok, int(tokens[i]))
    # Extra values (a `w`, vertex colours) are allowed and ignored.
    if np.all(count == want):
        picked = values.reshape(-1, want)
    elif least == want or count.min() >= want:
        picked = values[_exclusive_cumsum(count)[:, None] + np.arange(want)]
    else:  # some statements leave values out: those read as 0, not the next statement's
        index = _exclusive_cumsum(count)[:, None] + np.arange(want)
        given = np.arange(want) < count[:, None]
        picked = np.where(given, values[np.where(given, index, 0)], 0.0)
    bad = np.flatnonzero(~np.isfinite(picked).all(axis=1))
    if len(bad):
        raise tok.error(first[bad[0]] - 1, f"{name}: numbers must be finite")
    # Past this the kernels' float32 arithmetic (and the bounding boxes) would overflow.
    huge = np.flatnonzero((np.abs(picked) > MAX_MAGNITUDE).any(axis=1))
    if len(huge):
        raise tok.error(
            first[huge[0]] - 1, f"{name}: numbers must be at most {MAX_MAGNITUDE:g} in magnitude"
        )
    return picked, stmt


def _python_float(tok: _Tokens, token: int) -> float:
    text = tok.text(token)
    if _FLOAT.fullmatch(text) is None:
        raise tok.error(token, f"expected a number, got {text!r}")
    return float(text)


def _fast_ints(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(values, ok): the tokens [start, end) of the form [+-]digits with at most 8 digits;
    ok is False where a token is anything else (empty included), its value then 0."""
    first = buf[start]
    negative = first == ord("-")
    n = end - start
    n -= negative | (first == ord("+"))
    ok = (n >= 1) & (n <= 8)
    np.clip(n, 0, 8, out=n)
    x = _word_before(buf, end, n)
    ok &= _not_digits(x) == 0
    values = _eight_digits(x).view(np.int64)  # below 10**8, so the same bits
    values[~ok] = 0
    np.negative(values, out=values, where=negative)
    return values, ok


def _slashes(start: np.ndarray, end: np.ndarray, buf: np.ndarray) -> tuple[np.ndarray, ...]:
    """(number of slashes, first slash, second slash) of each token [start, end)."""
    n = len(start)
    lo = start[0]
    found = np.flatnonzero(buf[lo : end[-1]] == _SLASH) + lo
    k = len(found) // n
    if len(found) == k * n and k <= 2:
        # Shortcut for the usual file, one form throughout: the i-th k slashes lie in the
        # i-th token. As there are exactly k * n, every token then holds exactly its k.
        mine = found.reshape(n, k)
        if k == 0 or np.all((mine[:, 0] >= start) & (mine[:, -1] < end)):
            count = np.full(n, k)
            if k == 0:
                return count, end, end
            return count, mine[:, 0], mine[:, -1]
    owner = np.searchsorted(start, found, side="right") - 1
    inside = found < end[owner]  # not a slash between tokens or in another statement
    found, owner = found[inside], owner[inside]
    count = np.bincount(owner, minlength=n)
    at = np.minimum(_exclusive_cumsum(count), max(len(found) - 1, 0))
    if len(found) == 0:
        return count, end, end
    return count, found[at], found[np.minimum(at + 1, len(found) - 1)]


def _faces(tok: _Tokens) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per face-vertex token: (form, components (N, 3) with -1 for absent, token index), and
    the per-face vertex counts."""
    _, first, count = tok.statements(_F)
    few = np.flatnonzero(count < 3)
    if len(few):
        i = few[0]
        raise tok.error(first[i] - 1, f"f: a face needs at least 3 vertices, got {count[i]}")
    tokens = _value_tokens(first, count)
    comp = np.full((len(tokens), 3), -1, dtype=np.int64)
    if len(tokens) == 0:
        return np.zeros(0, dtype=np.int64), comp, tokens, count
    start, end = tok.starts[tokens], tok.ends[tokens]
    n_slash, first_slash, second_slash = _slashes(start, end, tok.buf)
    doubled = second_slash == first_slash + 1
    form = np.select(
        [n_slash == 0, n_slash == 1, (n_slash == 2) & doubled, n_slash == 2],
        [_FORM_V, _FORM_VT, _FORM_VN, _FORM_VTN],
        default=-1,
    )
    bad = np.flatnonzero(form < 0)
    if len(bad):
        t = tokens[bad[0]]
        raise tok.error(t, f"f: bad vertex reference {tok.text(t)!r}")
    lead = form[_exclusive_cumsum(count)]
    mixed = np.flatnonzero(form != np.repeat(lead, count))
    if len(mixed):
        t = tokens[mixed[0]]
        face = np.searchsorted(_exclusive_cumsum(count), mixed[0], side="right") - 1
        raise tok.error(
            t,
            f"f: mixed vertex forms in one face ({_FORM_NAMES[lead[face]]} and "
            f"{_FORM_NAMES[form[mixed[0]]]})",
        )

    # Each component as a byte range: position up to the first slash, texture coordinate
    # between the slashes, normal after the last one.
    has_vt = (form == _FORM_VT) | (form == _FORM_VTN)
    has_vn = (form == _FORM_VN) | (form == _FORM_VTN)
    vt_end = np.where(form == _FORM_VT, end, second_slash)
    ranges = [
        (np.arange(len(tokens)), start, np.where(form == _FORM_V, end, first_slash)),
        (np.flatnonzero(has_vt), first_slash + 1, vt_end),
        (np.flatnonzero(has_vn), second_slash + 1, end),
    ]
    failed = np.zeros(len(tokens), dtype=bool)
    for k, (which, lo, hi) in enumerate(ranges):
        if len(which) == len(tokens):
            values, ok = _fast_ints(tok.buf, lo, hi)
        else:
            values, ok = _fast_ints(tok.buf, lo[which], hi[which])
        comp[which, k] = values
        failed[which[~ok]] = True
    for i in np.flatnonzero(failed).tolist():
        comp[i] = _python_indices(tok, int(tokens[i]), int(form[i]))
    return form, comp, tokens, count


def _python_indices(tok: _Tokens, token: int, form: int) -> list[int]:
    """The slow path of the face parse, for a token the vectorised one could not read."""
    parts = tok.text(token).split("/")
    if form == _FORM_VN:
        del parts[1]  # the empty slot of v//vn
    out = []
    for part in parts:
        if _INT.fullmatch(part) is None:
            raise tok.error(token, f"f: bad vertex reference {tok.text(token)!r}")
        if len(part.lstrip("+-0")) > 18:
            raise tok.error(token, f"f: vertex reference {tok.text(token)!r} out of range")
        out.append(int(part))
    slots = {_FORM_V: (0,), _FORM_VT: (0, 1), _FORM_VN: (0, 2), _FORM_VTN: (0, 1, 2)}[form]
    comp = [-1, -1, -1]
    for slot, value in zip(slots, out, strict=True):
        comp[slot] = value
    return comp


def _resolve(
    tok: _Tokens,
    raw: np.ndarray,
    tokens: np.ndarray,
    defined_in: np.ndarray,
    name: str,
) -> np.ndarray:
    """1-based and negative (relative) OBJ indices -> 0-based, with range checks.
    `defined_in` holds the statement number of each element's definition."""
    index = raw - 1
    relative = np.flatnonzero(raw < 0)
    if len(relative):
        # A negative index counts back from the last element defined before its line.
        before = np.searchsorted(defined_in, tok.statement_of(tokens[relative]))
        index[relative] = before + raw[relative]
    bad = np.flatnonzero((raw == 0) | (index < 0) | (index >= len(defined_in)))
    if len(bad):
        i = bad[0]
        if raw[i] == 0:
            message = f"f: {name} index 0 is invalid (OBJ indices start at 1)"
        elif raw[i] < 0:
            before = np.searchsorted(defined_in, tok.statement_of(tokens[i]))
            message = (
                f"f: relative {name} index {raw[i]} out of range "
                f"({before} defined before this line)"
            )
        else:
            message = f"f: {name} index {raw[i]} out of range ({len(defined_in)} in the file)"
        raise tok.error(tokens[i], message)
    return index


def _fan(count: np.ndarray, positions: np.ndarray, v: np.ndarray
         ) -> tuple[np.ndarray, tuple[str, ...]]:
    """(T, 3) positions into the face-vertex list `v`, count - 2 triangles a polygon in
    order, and what the triangulation warns of.

    A convex polygon (every turn the same way about its Newell normal) is a fan around its
    first vertex. A polygon with reflex corners (by the corners' positions, `positions[v]`)
    is triangulated by its shape: with one reflex corner, as a fan around that corner (the
    polygon is star-shaped from it); with more, by ear clipping in its plane. Polygons that
    are not planar (a corner off the plane by more than _PLANAR of the polygon's extent),
    whose area is zero or that cross themselves (no ear) stay fans around their first vertex;
    so do those of two or more reflex corners that are not ear-clipped: over _MAX_EAR_CLIP
    corners, or past the file's _EAR_CLIP_BUDGET, which is the one warning."""
    if np.all(count == 3):
        return np.arange(3 * len(count)).reshape(-1, 3), ()
    n_tri = count - 2
    poly = np.repeat(np.arange(len(count)), n_tri)
    k = np.arange(n_tri.sum()) - np.repeat(_exclusive_cumsum(n_tri), n_tri) + 1
    base = _exclusive_cumsum(count)[poly]
    tris = np.stack([base, base + k, base + k + 1], axis=1)
    budget = _EarClipBudget(_EAR_CLIP_BUDGET)
    _shape_polygons(tris, count, positions, v, budget)
    if not budget.over:
        return tris, ()
    return tris, (f"{budget.over} polygon(s) of two or more reflex corners left as fans "
                  "around their first vertex: ear clipping them was past the file's budget "
                  f"of {_EAR_CLIP_BUDGET} (the sum of k (k + {_EAR_CLIP_EXTRA}) over polygons "
                  "of k corners; ear clipping is O(k^2) in Python)",)


# A polygon is planar when no corner is further from its plane than this part of its extent.
_PLANAR = 1e-3
# Turns within this part of |edge in| |edge out| |normal| of zero count as straight on.
_TURN_EPS = 1e-9
# Polygons of more corners than this are not ear-clipped (ear clipping is O(n^2) in Python).
_MAX_EAR_CLIP = 256
# Ear clipping a polygon of k corners costs about k (k + _EAR_CLIP_EXTRA) times 0.3 to 0.5 us
# (measured on a 2-core EPYC: 45 us a concave pentagon, 80 us the U-shaped 8-gon, 21 ms a
# 256-corner star); a file's polygons are ear-clipped until the sum reaches this (about a
# second), the rest stay fans.
_EAR_CLIP_EXTRA = 16
_EAR_CLIP_BUDGET = 2_500_000
# Corners tested for convexity at once (bounds the temporaries, about 105 bytes a corner):
# max(1, _CORNER_CHUNK // k) polygons of k corners.
_CORNER_CHUNK = 1 << 17


@dataclass
class _EarClipBudget:
    """What is left of a file's _EAR_CLIP_BUDGET, and the polygons it left as fans."""

    left: int
    over: int = 0

    def take(self, k: int) -> bool:
        cost = k * (k + _EAR_CLIP_EXTRA)
        if cost > self.left:
            self.over += 1
            return False
        self.left -= cost
        return True


def _shape_polygons(tris: np.ndarray, count: np.ndarray, positions: np.ndarray,
                    v: np.ndarray, budget: _EarClipBudget) -> None:
    """Replace, in `tris`, the fan of each planar polygon with reflex corners. The convexity
    test is vectorised over every polygon of one corner count (a chunk of about
    _CORNER_CHUNK corners at a time): only polygons with a reflex corner go further. Counts
    are taken in increasing order, so `budget` ear-clips smaller polygons first."""
    first_tri = _exclusive_cumsum(count - 2)
    base = _exclusive_cumsum(count)
    for k in np.unique(count[count > 3]).tolist():
        polys = np.flatnonzero(count == k)
        if k == 4:
            _shape_quads(tris, polys, first_tri, base, positions, v)
            continue
        # Corners 0..k-1 then 0 and 1 again: every edge and its successor are views.
        wrap = np.arange(k + 2) % k
        step = max(1, _CORNER_CHUNK // k)
        for at in range(0, len(polys), step):
            chunk = polys[at:at + step]
            corner = v[base[chunk][:, None] + wrap]
            # Each coordinate (P, k + 2), from the polygon's first corner.
            x, y, z = (positions[corner, c].astype(np.float64) for c in range(3))
            x -= x[:, :1]
            y -= y[:, :1]
            z -= z[:, :1]
            bent, reflex, unit_n = _reflex_corners(x, y, z)
            if not len(bent):
                continue
            one = reflex.sum(axis=1) == 1
            polys_one = chunk[bent[one]]
            _fan_around_reflex(tris, first_tri[polys_one], base[polys_one], reflex[one])
            for i in np.flatnonzero(~one).tolist():
                poly_i = int(chunk[bent[i]])
                p = np.stack([x[bent[i], :k], y[bent[i], :k], z[bent[i], :k]], axis=1)
                _ear_clip_polygon(tris[first_tri[poly_i]:first_tri[poly_i] + k - 2],
                                  base[poly_i], p, unit_n[i], budget)


def _reflex_corners(x: np.ndarray, y: np.ndarray, z: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The convexity and planarity test of P polygons of k corners, each coordinate (P, k + 2)
    from the polygon's first corner and wrapped (corners 0..k-1, 0, 1): (the polygons with a
    reflex corner that are planar and of nonzero area, (B,); their reflex corners, (B, k)
    bool; their unit Newell normals, (B, 3))."""
    k = x.shape[1] - 2
    # Newell's normal: the sum of p_i x p_i+1 (p_0 is the origin: k - 2 terms).
    a, b = slice(1, k - 1), slice(2, k)
    nx = (y[:, a] * z[:, b] - z[:, a] * y[:, b]).sum(axis=1)[:, None]
    ny = (z[:, a] * x[:, b] - x[:, a] * z[:, b]).sum(axis=1)[:, None]
    nz = (x[:, a] * y[:, b] - y[:, a] * x[:, b]).sum(axis=1)[:, None]
    ex, ey, ez = np.diff(x, axis=1), np.diff(y, axis=1), np.diff(z, axis=1)
    # The turn at corner i + 1: (edge i x edge i + 1) . normal.
    ix, iy, iz = ex[:, :-1], ey[:, :-1], ez[:, :-1]
    ox, oy, oz = ex[:, 1:], ey[:, 1:], ez[:, 1:]
    turn = (nx * (iy * oz - iz * oy) + ny * (iz * ox - ix * oz)
            + nz * (ix * oy - iy * ox))
    maybe = np.flatnonzero((turn < 0).any(axis=1))
    if not len(maybe):
        return maybe, np.zeros((0, k), dtype=bool), np.zeros((0, 3))
    e = np.stack([ex[maybe, :k], ey[maybe, :k], ez[maybe, :k]], axis=2)
    length = np.linalg.norm(e, axis=2)  # of the edge out of each corner
    normal = np.concatenate([nx[maybe], ny[maybe], nz[maybe]], axis=1)
    size = np.linalg.norm(normal, axis=1)
    scale = length * np.roll(length, -1, axis=1) * size[:, None]
    reflex = np.roll(turn[maybe] < -_TURN_EPS * scale, 1, axis=1)  # by corner
    keep = reflex.any(axis=1) & (size > 0)
    bent, reflex, normal, size = maybe[keep], reflex[keep], normal[keep], size[keep]
    # Planar: every corner within _PLANAR of the extent from the first's plane.
    unit_n = normal / size[:, None]
    off = np.abs(x[bent, :k] * unit_n[:, :1] + y[bent, :k] * unit_n[:, 1:2]
                 + z[bent, :k] * unit_n[:, 2:]).max(axis=1)
    planar = off <= _PLANAR * length[keep].max(axis=1)
    return bent[planar], reflex[planar], unit_n[planar]


def _fan_around_reflex(tris: np.ndarray, first_tri: np.ndarray, base: np.ndarray,
                       reflex: np.ndarray) -> None:
    """The fan around the one reflex corner r of each polygon, (r, r + j, r + j + 1), into
    `tris` at rows first_tri..first_tri + k - 3 (`reflex` (P, k) marks r)."""
    k = reflex.shape[1]
    r = np.argmax(reflex, axis=1)[:, None]
    j = np.arange(1, k - 1)
    local = np.stack([np.broadcast_to(r, (len(r), k - 2)), (r + j) % k,
                      (r + j + 1) % k], axis=2)
    tris[first_tri[:, None] + np.arange(k - 2)] = base[:, None, None] + local


def _ear_clip_polygon(rows: np.ndarray, base: int, p: np.ndarray, normal: np.ndarray,
                      budget: _EarClipBudget) -> None:
    """Ear-clip the planar polygon `p` (k, 3) into `rows` (its k - 2 triangles, from corner
    number `base`) where it has at most _MAX_EAR_CLIP corners and `budget` allows; its fan
    stays otherwise, or where it has no ear."""
    k = len(p)
    if k > _MAX_EAR_CLIP or not budget.take(k):
        return
    clipped = _ear_clip(p, normal)
    if clipped is not None:
        rows[:] = base + clipped


def _shape_quads(tris: np.ndarray, polys: np.ndarray, first_tri: np.ndarray,
                 base: np.ndarray, positions: np.ndarray, v: np.ndarray) -> None:
    """_shape_polygons for quads, the common polygon, at a fraction of the general test's
    cost (1M quads: 0.45 s there): a quad's fan (0, 1, 2), (0, 2, 3) is right unless its two
    triangles face opposite ways, a reflex corner at 1 or 3; it then takes the other
    diagonal, (1, 2, 3), (1, 3, 0), where that one's triangles face alike and the quad is
    planar, and stays a fan otherwise (crossing itself, or bent). A corner straight on
    (a triangle of no area) keeps the fan, as in the general test."""
    for at in range(0, len(polys), _CORNER_CHUNK // 4):
        chunk = polys[at:at + _CORNER_CHUNK // 4]
        p = positions[v[base[chunk][:, None] + np.arange(4)]].astype(np.float64)
        # Coordinate by coordinate: np.cross and einsum on (P, 3) took 3 times as long.
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = [[p[:, k, i] - p[:, 0, i] for i in range(3)]
                                                    for k in (1, 2, 3)]
        bent = ((ay * bz - az * by) * (by * cz - bz * cy) + (az * bx - ax * bz)
                * (bz * cx - bx * cz) + (ax * by - ay * bx) * (bx * cy - by * cx)) < 0
        if not bent.any():
            continue
        chunk, p = chunk[bent], p[bent]
        a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
        other = np.einsum("pc,pc->p", np.cross(b - a, c - a), np.cross(c - a, -a)) > 0
        # Planar as _shape_polygons asks: no corner off the plane by more than _PLANAR of
        # the longest edge (the normal: the diagonals' cross product, Newell's for a quad).
        normal = np.cross(b, c - a)
        size = np.linalg.norm(normal, axis=1)
        unit_n = normal / np.where(size > 0, size, 1.0)[:, None]
        off = np.abs(np.einsum("pkc,pc->pk", p - p[:, :1], unit_n)).max(axis=1)
        longest = np.linalg.norm(np.roll(p, -1, axis=1) - p, axis=2).max(axis=1)
        flip = chunk[other & (size > 0) & (off <= _PLANAR * longest)]
        rows = first_tri[flip]
        tris[rows] = base[flip][:, None] + np.array([1, 2, 3])
        tris[rows + 1] = base[flip][:, None] + np.array([1, 3, 0])


def _ear_clip(p: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """(n - 2, 3) corner numbers triangulating the planar polygon `p` (n, 3) whose Newell
    normal is `normal`, by ear clipping; None where no ear is found (it crosses itself)."""
    # In the plane: the two axes other than the normal's largest, in cyclic order after it
    # ((y, z), (z, x), (x, y): a x b is +drop) so that the polygon runs counterclockwise.
    drop = int(np.argmax(np.abs(normal)))
    a, b = (drop + 1) % 3, (drop + 2) % 3
    if normal[drop] < 0:
        a, b = b, a
    xy = [(float(x), float(y)) for x, y in p[:, [a, b]]]
    extent = max(max(abs(x), abs(y)) for x, y in xy) or 1.0
    eps = 1e-12 * extent * extent

    def cross(o: int, s: int, t: int) -> float:
        (ox, oy), (sx, sy), (tx, ty) = xy[o], xy[s], xy[t]
        return (sx - ox) * (ty - oy) - (sy - oy) * (tx - ox)

    left = list(range(len(xy)))
    out = []
    while len(left) > 3:
        n = len(left)
        ear = None
        for j in range(n):
            o, s, t = left[j - 1], left[j], left[(j + 1) % n]
            if cross(o, s, t) <= eps:
                continue  # reflex or straight on
            if any(cross(o, s, q) >= -eps and cross(s, t, q) >= -eps and cross(t, o, q) >= -eps
                   for q in left if q not in (o, s, t)):
                continue
            ear = j
            break
        if ear is None:
            # A corner straight on between its neighbours: a triangle of no area.
            ear = next((j for j in range(n)
                        if abs(cross(left[j - 1], left[j], left[(j + 1) % n])) <= eps), None)
            if ear is None:
                return None
        out.append((left[ear - 1], left[ear], left[(ear + 1) % n]))
        del left[ear]
    out.append(tuple(left))
    return np.array(out, dtype=np.int64)


def _unique_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(keys, axis=0) without sorting rows where it can."""
    if np.all(keys == keys[:, :1]):
        # Exporters often number normals and UVs like the positions (`f 7//7`); then the
        # rows are their first column, and marking the used values replaces the sort.
        used = np.zeros(int(keys[:, 0].max()) + 1, dtype=bool)
        used[keys[:, 0]] = True
        uniq = np.flatnonzero(used)
        new_index = np.cumsum(used) - 1
        return np.repeat(uniq[:, None], keys.shape[1], axis=1), new_index[keys[:, 0]]
    span = keys.max(axis=0) + 1
    if np.prod(span.astype(np.float64)) < 2.0**62:
        # One int64 key per row: sorting one integer column is several times faster than
        # sorting rows.
        flat = np.ravel_multi_index(tuple(keys.T), span)
        uniq, inverse = np.unique(flat, return_inverse=True)
        return np.stack(np.unravel_index(uniq, span), axis=1), inverse
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    return uniq, inverse.reshape(-1)


def read_obj(path: Path) -> ObjMesh:
    """Read an OBJ file. Convex faces are triangulated as fans, concave ones split by their
    shape (_fan); every statement other than `v`, `vt`, `vn` and `f` (`o`, `g`, `s`, `usemtl`,
    `mtllib`, ...) is ignored."""
    path = Path(path)
    try:
        data = read_regular(path, MAX_MESH_BYTES)
    except UnreadableFile as exc:
        raise SceneError(path, None, f"cannot read mesh file: {exc}") from None
    return parse_obj(data, path)


def parse_obj(data: bytes, path: Path) -> ObjMesh:
    """Parse OBJ text already in memory; `path` names the file in error messages."""
    # Windows editors (Notepad) start UTF-8 text with a byte order mark: left in, it would be
    # part of the first keyword (`\ufeffv` is not `v`), losing that line and shifting every
    # index after it. It holds no newline, so line numbers are unchanged.
    if data.startswith(_BOM):
        data = data[len(_BOM):]
    data = lf_line_ends(data)
    mesh = _parse_regular(data)
    if mesh is not None:
        return mesh
    tok = _Tokens(data, path)
    positions, v_stmt = _floats(tok, _V, "v", 3)
    uv_values, vt_stmt = _floats(tok, _VT, "vt", 2, least=1)
    normal_values, vn_stmt = _floats(tok, _VN, "vn", 3)
    zero = np.flatnonzero(~np.any(normal_values != 0.0, axis=1))
    if len(zero):
        raise tok.error(tok.heads[vn_stmt[zero[0]]], "vn: zero-length normal")
    # In float64 and scaled first, so that `vn 1e-200 1e-200 1e-200` gives a unit normal
    # rather than a zero or infinite one.
    normal_values = unit(normal_values)

    form, comp, tokens, count = _faces(tok)
    v = _resolve(tok, comp[:, 0], tokens, v_stmt, "vertex")
    has_vt = (form == _FORM_VT) | (form == _FORM_VTN)
    has_vn = (form == _FORM_VN) | (form == _FORM_VTN)
    use_uv = len(tokens) > 0 and bool(has_vt.all())
    use_vn = len(tokens) > 0 and bool(has_vn.all())
    vt = _component(tok, comp[:, 1], tokens, has_vt, use_uv, vt_stmt, "texture coordinate")
    vn = _component(tok, comp[:, 2], tokens, has_vn, use_vn, vn_stmt, "normal")

    mesh = _mesh(positions, uv_values if use_uv else None, normal_values if use_vn else None,
                 v, vt, vn, *_fan(count, positions, v))
    face_at = tok.starts[tok.heads[tok.kind == _F]] - _PAD
    return _with_materials(data, mesh, face_at, count)


def _mesh(
    positions: np.ndarray,
    uv_values: np.ndarray | None,
    normal_values: np.ndarray | None,
    v: np.ndarray,
    vt: np.ndarray,
    vn: np.ndarray,
    corners: np.ndarray,
    warnings: tuple[str, ...],
) -> ObjMesh:
    """One shared index per distinct (position, uv, normal) of the faces' corners; UVs or
    normals passed as None are not used; `warnings`, the triangulation's (_fan)."""
    # Normals and UVs are per vertex in the output, so a mesh gets them only when every
    # face has them; otherwise the faces without would have nothing to interpolate.
    use_uv, use_vn = uv_values is not None, normal_values is not None
    if not (use_uv or use_vn):
        return ObjMesh(vertices=positions, faces=v[corners], warnings=warnings)

    columns = [v] + ([vt] if use_uv else []) + ([vn] if use_vn else [])
    uniq, inverse = _unique_rows(np.stack(columns, axis=1))
    return ObjMesh(
        vertices=positions[uniq[:, 0]],
        faces=inverse[corners],
        normals=normal_values[uniq[:, -1]] if use_vn else None,
        uvs=uv_values[uniq[:, 1]] if use_uv else None,
        warnings=warnings,
    )


def _component(
    tok: _Tokens,
    raw: np.ndarray,
    tokens: np.ndarray,
    present: np.ndarray,
    everywhere: bool,
    defined_in: np.ndarray,
    name: str,
) -> np.ndarray:
    """Resolved UV or normal indices, -1 where a face-vertex has none."""
    if everywhere:
        return _resolve(tok, raw, tokens, defined_in, name)
    out = np.full(len(tokens), -1, dtype=np.int64)
    out[present] = _resolve(tok, raw[present], tokens[present], defined_in, name)
    return out


# The layout nearly every exporter writes, which `_parse_regular` reads without tokenising
# the file: one space between tokens, `\n` line ends and no other control bytes, the same
# number of values on every line of a kind, one vertex form in all faces, indices from 1,
# comments only on lines of their own.

# Runs of lines of one kind found one by one; where a file alternates more often (faces
# between `usemtl`, `g` and `o` lines), one pass over the span of all of them finds the
# spaces and keeps those on lines of the kind, rather than paying Python's overhead per run.
_MAX_RUNS = 256


def _parse_regular(data: bytes) -> ObjMesh | None:
    """The mesh of a file in the common layout, or None where the file departs from it in
    any way (including every error), for the general parser to read or to report with its
    line number. Faster than the general parser, which must find every token's bounds."""
    buf = _padded(data)
    newlines = np.flatnonzero(buf == _NL)
    # Whitespace is then only spaces and newlines, and a space the only byte below 33 within
    # a line.
    if np.count_nonzero(buf < _SPACE) != len(newlines):
        return None
    starts = np.empty(len(newlines), dtype=np.int64)
    starts[0] = _PAD
    starts[1:] = newlines[:-1] + 1
    c0, c1, c2 = buf[starts], buf[starts + 1], buf[starts + 2]
    kind = np.full(len(starts), _OTHER, dtype=np.int8)
    kind[(c0 == ord("v")) & (c1 == _SPACE)] = _V
    kind[(c0 == ord("f")) & (c1 == _SPACE)] = _F
    two_v = (c0 == ord("v")) & (c2 == _SPACE)
    kind[two_v & (c1 == ord("t"))] = _VT
    kind[two_v & (c1 == ord("n"))] = _VN
    other = kind == _OTHER
    # Ignored lines start with their keyword or are empty: a `v`/`f` one that is none of
    # the four above (`vp`, `f` alone) or one starting with whitespace is not read here.
    if np.any(other & ((c0 == ord("v")) | (c0 == ord("f")) | ((c0 <= _SPACE) & (c0 != _NL)))):
        return None
    if b"#" in data and np.count_nonzero(buf == ord("#")) != np.count_nonzero(c0 == ord("#")):
        return None

    lines = {}
    for k in (_V, _VT, _VN, _F):
        sel = np.flatnonzero(kind == k)
        ws = _line_spaces(buf, starts, newlines, sel)
        if ws is None:
            return None
        lines[k] = ws
    positions = _regular_floats(buf, lines[_V], 3)
    uv_values = _regular_floats(buf, lines[_VT], 2)
    normal_values = _regular_floats(buf, lines[_VN], 3)
    if positions is None or uv_values is None or normal_values is None:
        return None
    if not np.all(np.any(normal_values != 0.0, axis=1)):
        return None
    normal_values = unit(normal_values)

    ws = lines[_F]
    if len(ws) == 0 or ws.shape[1] < 4:
        return None
    start, end = ws[:, :-1].reshape(-1) + 1, ws[:, 1:].reshape(-1)
    slashes = _regular_slashes(buf, start, end)
    if slashes is None:
        return None
    form, first_slash, second_slash = slashes
    use_uv, use_vn = form in (_FORM_VT, _FORM_VTN), form in (_FORM_VN, _FORM_VTN)
    v = _regular_ints(buf, start, end if form == _FORM_V else first_slash, len(positions))
    vt = vn = v
    if use_uv:
        vt = _regular_ints(buf, first_slash + 1, end if form == _FORM_VT else second_slash,
                           len(uv_values))
    if use_vn:
        vn = _regular_ints(buf, second_slash + 1, end, len(normal_values))
    if v is None or vt is None or vn is None:
        return None
    count = np.full(len(ws), ws.shape[1] - 1)
    mesh = _mesh(positions, uv_values if use_uv else None, normal_values if use_vn else None,
                 v, vt, vn, *_fan(count, positions, v))
    return _with_materials(data, mesh, starts[kind == _F] - _PAD, count)


def _line_spaces(
    buf: np.ndarray, starts: np.ndarray, newlines: np.ndarray, sel: np.ndarray
) -> np.ndarray | None:
    """(lines, tokens + 1): the offsets of the spaces after each token of the selected lines
    and of their newline, or None unless every line has the same number of single-spaced,
    non-empty tokens."""
    if len(sel) == 0:
        return np.zeros((0, 1), dtype=np.int64)
    # Consecutive selected lines form a run whose spaces one pass finds.
    breaks = np.flatnonzero(np.diff(sel) != 1) + 1
    if len(breaks) >= _MAX_RUNS:
        lo, hi = int(starts[sel[0]]), int(newlines[sel[-1]])
        ws = np.flatnonzero(buf[lo : hi + 1] <= _SPACE) + lo
        mine = np.zeros(len(starts), dtype=bool)
        mine[sel] = True
        # A space's line is that of the first newline at or after it.
        ws = ws[mine[np.searchsorted(newlines, ws)]]
    else:
        first = sel[np.concatenate(([0], breaks))]
        last = sel[np.concatenate((breaks - 1, [len(sel) - 1]))]
        ws = np.concatenate([np.flatnonzero(buf[lo : hi + 1] <= _SPACE) + lo
                             for lo, hi in zip(starts[first].tolist(), newlines[last].tolist(),
                                               strict=True)])
    per_line, rest = divmod(len(ws), len(sel))
    if rest or per_line < 2:
        return None
    ws = ws.reshape(len(sel), per_line)
    # Each row ending in its line's newline makes the others that line's spaces (the only
    # other bytes found, `_parse_regular` checked).
    if not np.array_equal(ws[:, -1], newlines[sel]):
        return None
    if not np.all(ws[:, 1:] - ws[:, :-1] > 1):
        return None
    return ws


def _regular_floats(buf: np.ndarray, ws: np.ndarray, want: int) -> np.ndarray | None:
    """(lines, want) values of lines whose tokens `_line_spaces` found, keyword first."""
    if len(ws) == 0:
        return np.zeros((0, want))
    if ws.shape[1] - 1 < want:
        return None
    start, end = ws[:, :-1].reshape(-1) + 1, ws[:, 1:].reshape(-1)
    values, ok = _fast_floats(buf, start, end)
    for i in np.flatnonzero(~ok).tolist():
        text = buf[start[i] : end[i]].tobytes().decode("utf-8", errors="replace")
        if _FLOAT.fullmatch(text) is None:
            return None
        values[i] = float(text)
    picked = values.reshape(len(ws), -1)[:, :want]
    if not (np.all(np.isfinite(picked)) and np.all(np.abs(picked) <= MAX_MAGNITUDE)):
        return None
    return picked


def _regular_slashes(
    buf: np.ndarray, start: np.ndarray, end: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray] | None:
    """(form, first slash, second slash) of face tokens all of one form, or None."""
    found = np.flatnonzero(buf[start[0] : end[-1]] == _SLASH) + start[0]
    k, rest = divmod(len(found), len(start))
    if rest or k > 2:
        return None
    if k == 0:
        return _FORM_V, end, end
    # Exactly k slashes per token in all when the i-th k of them lie in the i-th token.
    mine = found.reshape(len(start), k)
    if not (np.all(mine[:, 0] > start) and np.all(mine[:, -1] < end - 1)):
        return None
    if k == 1:
        return _FORM_VT, mine[:, 0], mine[:, 0]
    doubled = mine[:, 1] == mine[:, 0] + 1
    if np.all(doubled):
        return _FORM_VN, mine[:, 0], mine[:, 1]
    if np.any(doubled):
        return None
    return _FORM_VTN, mine[:, 0], mine[:, 1]


def _regular_ints(buf: np.ndarray, start: np.ndarray, end: np.ndarray,
                  defined: int) -> np.ndarray | None:
    """0-based indices from the 1-based ones in [start, end), or None unless all are plain
    numbers in range."""
    values, ok = _fast_ints(buf, start, end)
    if not np.all(ok):
        return None
    values -= 1
    if len(values) and not (values.min() >= 0 and values.max() < defined):
        return None
    return values


def _statements(data: bytes, keyword: bytes) -> list[tuple[int, int, str]]:
    """(byte offset, line, rest of the line) of each `keyword` statement. A file has a few
    of these at most per material, so they are found with bytes.find rather than a pass over
    every line."""
    found = []
    at = data.find(keyword)
    counted, line = 0, 1  # newlines before `counted`, counted once in all
    while at >= 0:
        line_start = data.rfind(b"\n", 0, at) + 1
        end = data.find(b"\n", at)
        end = len(data) if end < 0 else end
        after = data[at + len(keyword):at + len(keyword) + 1]
        if not data[line_start:at].strip() and after in (b" ", b"\t"):
            rest = data[at + len(keyword):end].split(b"#", 1)[0].strip()
            line += data.count(b"\n", counted, at)
            counted = at
            found.append((at, line, rest.decode("utf-8", errors="replace")))
        at = data.find(keyword, end)
    return found


def _with_materials(data: bytes, mesh: ObjMesh, face_at: np.ndarray,
                    count: np.ndarray) -> ObjMesh:
    """`mesh` with the file's `mtllib` names and each triangle's `usemtl` group. face_at: the
    byte offset of each polygon's statement; count: its corners."""
    if b"usemtl" not in data and b"mtllib" not in data:
        return mesh
    libraries = tuple((line, name) for _, line, rest in _statements(data, b"mtllib")
                      for name in rest.split())
    uses = _statements(data, b"usemtl")
    if not uses:
        return dataclasses.replace(mesh, material_libraries=libraries)
    names: dict[str, int] = {}
    group_of_use = np.array([names.setdefault(rest, len(names)) for _, _, rest in uses] + [-1])
    use_at = np.array([at for at, _, _ in uses])
    # -1 picks the appended -1: faces before the first usemtl have no material of the file's.
    polygon_group = group_of_use[np.searchsorted(use_at, face_at) - 1]
    return dataclasses.replace(mesh, material_names=tuple(names),
                               face_groups=np.repeat(polygon_group, count - 2),
                               material_libraries=libraries)
