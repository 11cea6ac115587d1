"""Wavefront OBJ reader: positions, normals, texture coordinates and polygon faces.

Meshes of a few hundred thousand faces are common, so the file is tokenised with numpy on
its raw bytes instead of line by line in Python: a per-line Python loop costs about a
second for a 12 MB file, the vectorised passes a small fraction of that. Per-token Python
work happens only to pin down the line of an error the vectorised passes detected.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clray.errors import SceneError


@dataclass(frozen=True, eq=False)
class ObjMesh:
    """One shared vertex index for positions, normals and UVs, as the renderer wants it."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64, fan-triangulated polygons in file order
    normals: np.ndarray | None = None  # (V, 3) float64, as written in the file
    uvs: np.ndarray | None = None  # (V, 2) float64


# The bytes `bytes.split()` treats as whitespace, so token boundaries found with numpy agree
# with the ones Python finds when it has to look at a token itself.
_WS = np.zeros(256, dtype=bool)
_WS[[9, 10, 11, 12, 13, 32]] = True

_OTHER, _V, _VT, _VN, _F = range(5)
_SLASH = ord("/")

# Face vertex forms, and how many integers each holds once the slashes are gone.
_FORM_V, _FORM_VT, _FORM_VN, _FORM_VTN = range(4)
_FORM_NAMES = ("v", "v/vt", "v//vn", "v/vt/vn")
_FORM_COMPONENTS = np.array([1, 2, 2, 3])

# What the slow paths accept; stricter than float()/int(), which also take "1_0" and
# non-ASCII digits that numpy's bulk parser rejects.
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf)", re.I)
_INT = re.compile(r"[+-]?[0-9]+")


class _Tokens:
    """Every whitespace-separated token of the file, with the line it is on."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.path = path
        buf = np.frombuffer(data + b"\n", dtype=np.uint8)
        newlines = np.flatnonzero(buf == ord("\n"))
        if b"#" in data:
            buf = _blank_comments(buf, newlines)
        ws = _WS[buf]
        solid = ~ws
        starts = np.flatnonzero(solid[1:] & ws[:-1]) + 1
        if solid[0]:
            starts = np.concatenate(([0], starts))
        self.buf = buf
        self.starts = starts
        # The buffer ends in a newline, so every token ends before the last byte.
        self.ends = np.flatnonzero(solid[:-1] & ws[1:]) + 1  # exclusive
        self.line = np.searchsorted(newlines, starts) + 1  # 1-based line numbers
        first = np.ones(len(starts), dtype=bool)
        first[1:] = self.line[1:] != self.line[:-1]
        self.heads = np.flatnonzero(first)
        # Tokens per statement, the keyword included.
        self.counts = np.diff(np.append(self.heads, len(starts)))
        self.kind = self._classify()

    def _classify(self) -> np.ndarray:
        start = self.starts[self.heads]
        length = self.ends[self.heads] - start
        c0 = self.buf[start]
        c1 = self.buf[np.minimum(start + 1, len(self.buf) - 1)]
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

    def error(self, token: int, message: str) -> SceneError:
        return SceneError(self.path, f"line {self.line[token]}", message)

    def statements(self, kind: int) -> tuple[np.ndarray, np.ndarray]:
        """(index of the first value token, number of values) of each statement of a kind."""
        sel = np.flatnonzero(self.kind == kind)
        return self.heads[sel] + 1, self.counts[sel] - 1

    def joined(self, first: np.ndarray, count: np.ndarray) -> bytes:
        """The value tokens of the given statements as one blob: each statement's bytes from
        its first value to the whitespace byte after its last."""
        lo = self.starts[first]
        hi = self.ends[first + count - 1] + 1
        return self.buf[_ranges(lo, hi - lo)].tobytes()


def _blank_comments(buf: np.ndarray, newlines: np.ndarray) -> np.ndarray:
    """Turn everything from a `#` to the end of its line into spaces."""
    hashes = np.flatnonzero(buf == ord("#"))
    line = np.searchsorted(newlines, hashes)
    first = np.ones(len(hashes), dtype=bool)
    first[1:] = line[1:] != line[:-1]
    out = buf.copy()
    out[_ranges(hashes[first], newlines[line[first]] - hashes[first])] = ord(" ")
    return out


def _ranges(first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of arange(f, f + c) for each pair."""
    offsets = np.repeat(first - _exclusive_cumsum(counts), counts)
    return offsets + np.arange(counts.sum())


def _exclusive_cumsum(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=out[1:])
    return out


def _bulk_parse(blob: bytes, dtype: type, expected: int) -> np.ndarray | None:
    """All numbers in a blob, or None when some token is not exactly one number."""
    with warnings.catch_warnings():
        # numpy < 2.3 only warns when it stops at a token it cannot read.
        warnings.simplefilter("error", DeprecationWarning)
        try:
            values = np.fromstring(blob, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    # A token such as "1-2" reads as two numbers; the count exposes it.
    return values if len(values) == expected else None


def _floats(tok: _Tokens, kind: int, name: str, want: int) -> tuple[np.ndarray, np.ndarray]:
    """(values (N, want), line numbers) of the `v`/`vt`/`vn` statements."""
    first, count = tok.statements(kind)
    short = np.flatnonzero(count < want)
    if len(short):
        i = short[0]
        raise tok.error(first[i] - 1, f"{name}: expected at least {want} numbers, got {count[i]}")
    tokens = _ranges(first, count)
    values = _bulk_parse(tok.joined(first, count), np.float64, len(tokens))
    if values is None:
        values = np.array([_python_float(tok, t) for t in tokens], dtype=np.float64)
    # Extra values (a `w`, vertex colours) are allowed and ignored.
    picked = values[(_exclusive_cumsum(count)[:, None] + np.arange(want))]
    bad = np.flatnonzero(~np.isfinite(picked).all(axis=1))
    if len(bad):
        raise tok.error(first[bad[0]] - 1, f"{name}: numbers must be finite")
    return picked, tok.line[first - 1]


def _python_float(tok: _Tokens, token: int) -> float:
    text = tok.text(token)
    if _FLOAT.fullmatch(text) is None:
        raise tok.error(token, f"expected a number, got {text!r}")
    return float(text)


def _faces(tok: _Tokens) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per face-vertex token: (form, components (N, 3) with -1 for absent, line), and the
    per-face vertex counts."""
    first, count = tok.statements(_F)
    few = np.flatnonzero(count < 3)
    if len(few):
        i = few[0]
        raise tok.error(first[i] - 1, f"f: a face needs at least 3 vertices, got {count[i]}")
    tokens = _ranges(first, count)
    buf = tok.buf
    slashes = np.flatnonzero(buf == _SLASH)
    owner = np.searchsorted(tok.starts, slashes, side="right") - 1
    n_slash = np.bincount(owner, minlength=len(tok.starts))[tokens]
    doubled = slashes[buf[slashes + 1] == _SLASH]
    n_double = np.bincount(
        np.searchsorted(tok.starts, doubled, side="right") - 1, minlength=len(tok.starts)
    )[tokens]
    form = np.select(
        [n_slash == 0, n_slash == 1, (n_slash == 2) & (n_double == 1), n_slash == 2],
        [_FORM_V, _FORM_VT, _FORM_VN, _FORM_VTN],
        default=-1,
    )
    bad = np.flatnonzero(form < 0)
    if len(bad):
        t = tokens[bad[0]]
        raise tok.error(t, f"f: bad vertex reference {tok.text(t)!r}")
    face_of = np.repeat(np.arange(len(count)), count)
    lead = form[_exclusive_cumsum(count)]
    mixed = np.flatnonzero(form != lead[face_of])
    if len(mixed):
        t = tokens[mixed[0]]
        raise tok.error(
            t,
            f"f: mixed vertex forms in one face ({_FORM_NAMES[lead[face_of[mixed[0]]]]} and "
            f"{_FORM_NAMES[form[mixed[0]]]})",
        )

    n_comp = _FORM_COMPONENTS[form]
    blob = tok.joined(first, count).replace(b"/", b" ")
    values = _bulk_parse(blob, np.int64, int(n_comp.sum()))
    if values is None:
        values = _python_indices(tok, tokens, form)
    at = _exclusive_cumsum(n_comp)
    comp = np.full((len(tokens), 3), -1, dtype=np.int64)
    comp[:, 0] = values[at]
    has_vt = (form == _FORM_VT) | (form == _FORM_VTN)
    comp[has_vt, 1] = values[at[has_vt] + 1]
    comp[form == _FORM_VN, 2] = values[at[form == _FORM_VN] + 1]
    comp[form == _FORM_VTN, 2] = values[at[form == _FORM_VTN] + 2]
    return form, comp, tokens, count


def _python_indices(tok: _Tokens, tokens: np.ndarray, form: np.ndarray) -> np.ndarray:
    """The slow path of the face parse: find the token that is not made of integers."""
    out = []
    for t, f in zip(tokens.tolist(), form.tolist(), strict=True):
        parts = tok.text(t).split("/")
        if f == _FORM_VN:
            del parts[1]  # the empty slot of v//vn
        for part in parts:
            if _INT.fullmatch(part) is None:
                raise tok.error(t, f"f: bad vertex reference {tok.text(t)!r}")
            out.append(int(part))
    return np.array(out, dtype=np.int64)


def _resolve(
    tok: _Tokens,
    raw: np.ndarray,
    tokens: np.ndarray,
    defined_at: np.ndarray,
    name: str,
) -> np.ndarray:
    """1-based and negative (relative) OBJ indices -> 0-based, with range checks."""
    line = tok.line[tokens]
    # A negative index counts back from the last element defined before its line.
    before = np.searchsorted(defined_at, line)
    index = np.where(raw < 0, before + raw, raw - 1)
    bad = np.flatnonzero((raw == 0) | (index < 0) | (index >= len(defined_at)))
    if len(bad):
        i = bad[0]
        if raw[i] == 0:
            message = f"f: {name} index 0 is invalid (OBJ indices start at 1)"
        elif raw[i] < 0:
            message = (
                f"f: relative {name} index {raw[i]} out of range "
                f"({before[i]} defined before this line)"
            )
        else:
            message = f"f: {name} index {raw[i]} out of range ({len(defined_at)} in the file)"
        raise tok.error(tokens[i], message)
    return index


def _fan(count: np.ndarray) -> np.ndarray:
    """(T, 3) positions into the face-vertex list: each polygon as a fan around its first
    vertex."""
    n_tri = count - 2
    poly = np.repeat(np.arange(len(count)), n_tri)
    k = np.arange(n_tri.sum()) - np.repeat(_exclusive_cumsum(n_tri), n_tri) + 1
    base = _exclusive_cumsum(count)[poly]
    return np.stack([base, base + k, base + k + 1], axis=1)


def _unique_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(keys, axis=0) via one int64 key per row when the ranges allow it: sorting
    one integer column is several times faster than sorting rows."""
    span = keys.max(axis=0) + 1
    if np.prod(span.astype(np.float64)) < 2.0**62:
        flat = np.ravel_multi_index(tuple(keys.T), span)
        uniq, inverse = np.unique(flat, return_inverse=True)
        return np.stack(np.unravel_index(uniq, span), axis=1), inverse
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    return uniq, inverse.reshape(-1)


def read_obj(path: Path) -> ObjMesh:
    """Read an OBJ file. Faces are fan-triangulated; every statement other than `v`, `vt`,
    `vn` and `f` (`o`, `g`, `s`, `usemtl`, `mtllib`, ...) is ignored."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(path, None, f"cannot read mesh file: {exc.strerror}") from None
    return parse_obj(data, path)


def parse_obj(data: bytes, path: Path) -> ObjMesh:
    """Parse OBJ text already in memory; `path` names the file in error messages."""
    tok = _Tokens(data, path)
    positions, v_lines = _floats(tok, _V, "v", 3)
    uv_values, vt_lines = _floats(tok, _VT, "vt", 2)
    normal_values, vn_lines = _floats(tok, _VN, "vn", 3)
    zero = np.flatnonzero(~np.any(normal_values != 0.0, axis=1))
    if len(zero):
        raise SceneError(path, f"line {vn_lines[zero[0]]}", "vn: zero-length normal")

    form, comp, tokens, count = _faces(tok)
    v = _resolve(tok, comp[:, 0], tokens, v_lines, "vertex")
    has_vt = (form == _FORM_VT) | (form == _FORM_VTN)
    has_vn = (form == _FORM_VN) | (form == _FORM_VTN)
    vt = np.full(len(tokens), -1, dtype=np.int64)
    vt[has_vt] = _resolve(tok, comp[has_vt, 1], tokens[has_vt], vt_lines, "texture coordinate")
    vn = np.full(len(tokens), -1, dtype=np.int64)
    vn[has_vn] = _resolve(tok, comp[has_vn, 2], tokens[has_vn], vn_lines, "normal")

    corners = _fan(count)
    # Normals and UVs are per vertex in the output, so a mesh gets them only when every
    # face has them; otherwise the faces without would have nothing to interpolate.
    use_uv = len(tokens) > 0 and bool(has_vt.all())
    use_vn = len(tokens) > 0 and bool(has_vn.all())
    if not (use_uv or use_vn):
        return ObjMesh(vertices=positions, faces=v[corners])

    columns = [v] + ([vt] if use_uv else []) + ([vn] if use_vn else [])
    uniq, inverse = _unique_rows(np.stack(columns, axis=1))
    return ObjMesh(
        vertices=positions[uniq[:, 0]],
        faces=inverse[corners],
        normals=normal_values[uniq[:, -1]] if use_vn else None,
        uvs=uv_values[uniq[:, 1]] if use_uv else None,
    )
