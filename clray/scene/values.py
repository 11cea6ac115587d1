"""The generic checks of scene values: a number, a colour, a direction, a table of known keys.

Each check returns the value in the form the scene model takes, or raises one SceneError naming
the file and the key path (`objects[3].radius`) and showing the value as the user wrote it, cut
short. Every section's parser, the [animation] table's and the asset readers' use these, so a
rule and its wording live in one place.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from clray.errors import SHOW_ITEMS, SceneError, plural, show
from clray.scene import limits as L
from clray.vectors import Vec3, unit

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_PLAIN_NAME = re.compile(r"[\w./+-]{1,100}")


def show_defined(names: list[str]) -> str:
    """The first few of `names` for an 'unknown name (defined: ...)' message."""
    shown = [show(n) for n in names[:SHOW_ITEMS]]
    return ", ".join(shown + ["..."] * (len(names) > SHOW_ITEMS)) or "none"


def key_path(prefix: str | None, name: str) -> str:
    """`prefix.name`, the name quoted unless it is a bare TOML key (an empty key, or one with
    dots or newlines, must stay visible and unambiguous)."""
    if _BARE_KEY.fullmatch(name) and len(name) <= 60:
        shown = name
    else:  # a long name is cut inside its quotes, so the quotes still close
        shown = json.dumps(name[:50], ensure_ascii=False) + "..." * (len(name) > 50)
    return f"{prefix}.{shown}" if prefix else shown


def string_keys(table: dict, file: Path | None, key: str | None) -> dict:
    """`table`, if every key is a string: a dict from Python may have keys of any type, which
    no key path (nor the messages made of them) can name."""
    for name in table:
        if not isinstance(name, str):
            raise SceneError(file, key, f"keys must be strings, got {show(name)}")
    return table


def file_name(name: str) -> str:
    """A file name for a message: as written if plain, else quoted and escaped."""
    return name if _PLAIN_NAME.fullmatch(name) else show(name)


def python_number(value: Any) -> Any:
    """A numpy integer or float scalar (from Python callers) as Python's own, so that
    np.float32 and np.int64 are numbers as np.float64 (a float subclass) is; anything else
    as it is."""
    return value.item() if isinstance(value, np.integer | np.floating) else value


def is_number(value: Any) -> bool:
    # bool is an int subclass in Python, but `true` is not a number in a scene file.
    return isinstance(value, int | float) and not isinstance(value, bool)


def out_of_range(value: int | float, limit: float) -> str | None:
    """Why a number is unusable, or None. Integers are compared exactly: float() of one
    beyond the double range raises OverflowError."""
    if isinstance(value, float) and not math.isfinite(value):
        return "must be finite"
    if abs(value) > limit:
        return f"must be at most {limit:g} in magnitude"
    return None


class Values:
    """The checks, with the scene file that every error they raise names."""

    def __init__(self, path: Path | None) -> None:
        self.path = path

    def error(self, key: str | None, message: str) -> SceneError:
        return SceneError(self.path, key, message)

    def table(self, value: Any, key: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(key, f"expected a table, got {show(value)}")
        return string_keys(value, self.path, key)

    def keys(
        self, table: dict, key: str | None, allowed: tuple[str, ...], required: tuple[str, ...]
    ) -> None:
        string_keys(table, self.path, key)
        for name in table:
            if name not in allowed:
                expected = ", ".join(allowed)
                raise self.error(key_path(key, name), f"unknown key (expected one of: {expected})")
        for name in required:
            if name not in table:
                raise self.error(key_path(key, name), "missing required key")

    def kind(self, spec: dict, key: str, known: dict[str, tuple[str, ...]]) -> str:
        """The `type` of a light, texture, background or object: one of `known`."""
        if "type" not in spec:
            raise self.error(f"{key}.type", f"missing required key (one of: {', '.join(known)})")
        kind = spec["type"]
        if not isinstance(kind, str) or kind not in known:
            raise self.error(
                f"{key}.type", f"unknown type {show(kind)} (expected one of: {', '.join(known)})"
            )
        return kind

    def items(self, value: Any, key: str, limit: int) -> list[dict]:
        if not isinstance(value, list):
            raise self.error(key, f"expected an array of tables, got {show(value)}")
        if len(value) > limit:
            raise self.error(key, f"{len(value)} entries is over the limit of {limit}")
        return [self.table(item, f"{key}[{i}]") for i, item in enumerate(value)]

    def number(self, value: Any, key: str, limit: float = L.MAX_MAGNITUDE) -> float:
        value = python_number(value)
        if not is_number(value):
            raise self.error(key, f"expected a number, got {show(value)}")
        problem = out_of_range(value, limit)
        if problem:
            raise self.error(key, f"{problem}, got {show(value)}")
        return float(value)

    def bounded(self, value: Any, key: str, low: float, high: float = L.MAX_MAGNITUDE) -> float:
        value = python_number(value)  # shown as a number below, not as its numpy type
        x = self.number(value, key)
        if x < low:
            raise self.error(key, f"must be >= {low:g}, got {show(value)}")
        if x > high:
            raise self.error(key, f"must be <= {high:g}, got {show(value)}")
        return x

    def length(self, value: Any, key: str) -> float:
        """A strictly positive length, within float32's normal range."""
        value = python_number(value)  # shown as a number below, not as its numpy type
        x = self.number(value, key)
        if x <= 0:
            raise self.error(key, f"must be > 0, got {show(value)}")
        if x < L.MIN_LENGTH:
            raise self.error(key, f"must be >= {L.MIN_LENGTH:g}, got {show(value)}")
        return x

    def open_range(self, value: Any, key: str, low: float, high: float) -> float:
        value = python_number(value)  # shown as a number below, not as its numpy type
        x = self.number(value, key)
        if not low < x < high:
            raise self.error(key, f"must be in ({low:g}, {high:g}), got {show(value)}")
        return x

    def closed_range(self, value: Any, key: str, low: float, high: float) -> float:
        value = python_number(value)  # shown as a number below, not as its numpy type
        x = self.number(value, key)
        if not low <= x <= high:
            raise self.error(key, f"must be in [{low:g}, {high:g}], got {show(value)}")
        return x

    def integer(self, value: Any, key: str, low: int, high: int) -> int:
        value = python_number(value)  # shown as a number below, not as its numpy type
        problem = L.integer_problem(value, low, high)
        if problem:
            raise self.error(key, f"{problem}, got {show(value)}")
        return int(value)

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {show(value)}")
        return value

    def choice(self, value: Any, key: str, allowed: tuple) -> Any:
        if not L.is_choice(value, allowed):
            expected = " or ".join(show(v) for v in allowed)
            raise self.error(key, f"expected {expected}, got {show(value)}")
        return allowed[allowed.index(value)]  # a numpy integer or string as Python's own

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {show(value)}")
        return value

    def numbers(
        self, value: Any, key: str, n: int, limit: float = L.MAX_MAGNITUDE
    ) -> tuple[float, ...]:
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.error(key, f"expected {plural(n, 'number')}, got {show(value)}")
        value = [python_number(v) for v in value]
        if not all(is_number(v) for v in value):
            raise self.error(key, f"expected {plural(n, 'number')}, got {show(value)}")
        for v in value:
            problem = out_of_range(v, limit)
            if problem:
                raise self.error(key, f"{problem}, got {show(value)}")
        return tuple(float(v) for v in value)

    def vec3(self, value: Any, key: str) -> Vec3:
        x, y, z = self.numbers(value, key, 3)
        return (x, y, z)

    def non_negative(self, value: Any, key: str, limit: float = L.MAX_MAGNITUDE) -> Vec3:
        x, y, z = self.numbers(value, key, 3)
        if min(x, y, z) < 0:
            raise self.error(key, f"must be >= 0, got {show(value)}")
        if max(x, y, z) > limit:
            raise self.error(key, f"must be <= {limit:g}, got {show(value)}")
        return (x, y, z)

    def light_area(self, area: float, key: str, what: str) -> float:
        """An area light's emitting area (`what` says how it was found): the kernels divide by
        and multiply with it, so it must be a normal float32 number, far from overflow."""
        if not L.MIN_LENGTH <= area <= L.MAX_LIGHT_AREA:
            raise self.error(key, f"the light's area ({what}) must be in [{L.MIN_LENGTH:g}, "
                             f"{L.MAX_LIGHT_AREA:g}], got {area:.3g}")
        return area

    def color(self, value: Any, key: str) -> Vec3:
        return self.non_negative(value, key, L.MAX_COLOR)

    def direction(self, value: Any, key: str) -> Vec3:
        v = self.vec3(value, key)
        if not any(v):
            raise self.error(key, f"must be a nonzero vector, got {show(value)}")
        x, y, z = unit(v).tolist()
        return (x, y, z)

    def points(self, value: Any, key: str, exactly: int | None = None) -> tuple[Vec3, ...]:
        if not isinstance(value, list) or (exactly is not None and len(value) != exactly):
            what = plural(exactly, "point") if exactly else "a list of points"
            raise self.error(key, f"expected {what}, got {show(value)}")
        return tuple(self.vec3(p, f"{key}[{i}]") for i, p in enumerate(value))

    def array(self, value: Any, key: str, shape: tuple[int | None, ...],
              integer: bool = False) -> np.ndarray:
        """A numeric array (numpy, or nested lists) of `shape` (None: any length), with finite
        values within MAX_MAGNITUDE; the first bad row is named in the message."""
        a = self.shaped_array(value, key, shape, integer)
        if not integer:
            bad = ~np.isfinite(a)
            # Compared in the array's own type, the bound overflows a float16's (largest
            # 65504) to inf with numpy's RuntimeWarning on stderr; none of its values is over.
            if a.dtype.kind != "f" or float(np.finfo(a.dtype).max) > L.MAX_MAGNITUDE:
                bad |= np.abs(a) > L.MAX_MAGNITUDE
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise self.error(f"{key}[{row}]", f"must be finite and at most "
                                 f"{L.MAX_MAGNITUDE:g} in magnitude, got {show(a[row].tolist())}")
        return a

    def shaped_array(self, value: Any, key: str, shape: tuple[int | None, ...],
                     integer: bool = False) -> np.ndarray:
        """`value` as an array of `shape` and a numeric type, its values not yet looked at: a
        caller checks its size against a limit here, before array() passes over the values
        (with temporaries as large) and anything copies them. A numpy array is not copied
        (np.broadcast_to makes one of any size that takes no memory)."""
        # np.asarray takes true and false among numbers for 1 and 0 (only an all-boolean
        # list stays boolean, which the kind check below refuses); a scene's booleans are
        # not numbers.
        at = _boolean_at(value, len(shape))
        if at is not None:
            noun = "an integer" if integer else "a number"
            raise self.error(key + "".join(f"[{i}]" for i in at),
                             f"expected {noun}, got {show(_item(value, at))}")
        try:
            a = np.asarray(value)
        except (ValueError, TypeError):
            a = np.asarray(None)
        kinds = "iu" if integer else "iuf"
        shown = "x".join("N" if n is None else str(n) for n in shape)
        if (a.dtype.kind not in kinds or a.ndim != len(shape)
                or any(n is not None and n != m for n, m in zip(shape, a.shape, strict=True))):
            noun = "integer" if integer else "number"
            what = f"{shown} {noun}" if shown == "1" else f"{shown} {noun}s"
            raise self.error(key, f"expected an array of {what}, got {show(value)}")
        return a


def _boolean_at(value: Any, depth: int) -> tuple[int, ...] | None:
    """The indices of the first boolean in nested lists, `depth` levels down (the array's
    dimensions: anything deeper fails its shape check anyway), or None."""
    if not isinstance(value, list | tuple):
        return None
    for i, x in enumerate(value):
        if isinstance(x, bool | np.bool_):
            return (i,)
        inner = _boolean_at(x, depth - 1) if depth > 1 else None
        if inner is not None:
            return (i, *inner)
    return None


def _item(value: Any, at: tuple[int, ...]) -> Any:
    for i in at:
        value = value[i]
    return value


def rows(value: Any) -> int:
    """How many rows a list or array has, without converting it (0 for anything else, which
    its own check refuses)."""
    if isinstance(value, list):
        return len(value)
    if isinstance(value, np.ndarray) and value.ndim:
        return value.shape[0]
    return 0
