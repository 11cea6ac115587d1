"""Errors a user can act on, each mapped to an exit code of the command line (README.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_USAGE = 2
EXIT_SCENE = 3
EXIT_OPENCL = 4

_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(char: str) -> str:
    if char in _ESCAPES:
        return _ESCAPES[char]
    code = ord(char)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 else \
        f"\\U{code:08x}"


def one_line(text: str) -> str:
    """`text` with every non-printable character escaped: a file name holding a newline (or a
    line separator) must not split a message into lines that look like separate errors."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else _escape(c) for c in text)


def utf8_problem(raw: bytes, err: UnicodeDecodeError) -> str:
    """Where `raw` stops being UTF-8, as an editor shows the place: "line 3, column 7: not
    valid UTF-8 (byte 0xff)". The decoder's byte offset is no help to find it in an editor."""
    before = raw[: err.start].decode("utf-8")  # valid: the decoder stopped at the first error
    line = before.count("\n") + 1
    column = len(before) - before.rfind("\n")  # characters, 1-based
    bad = " ".join(f"0x{b:02x}" for b in raw[err.start : err.end])
    return (f"line {line}, column {column}: not valid UTF-8 "
            f"({'byte' if err.end - err.start == 1 else 'bytes'} {bad})")


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """`count` with the noun in the form that count takes: "1 tile", "0 tiles", "2 tiles";
    `nouns` for a plural not made with an s ("1 vertex", "3 vertices")."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"


SHOW_ITEMS = 8  # array elements (and defined names) shown in a message
_SHOW_DEPTH = 3  # nested arrays shown in a message


def show(value: Any, depth: int = 0) -> str:
    """A value as the user wrote it, short enough for a one-line message."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value[:100], ensure_ascii=False)
    elif isinstance(value, int) and value.bit_length() > 200:
        # repr() of a huge integer is slow, and past 4300 digits refused.
        text = f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    elif isinstance(value, int | float):
        text = repr(value)
    elif isinstance(value, list | tuple):
        if depth >= _SHOW_DEPTH:
            text = "[...]"
        else:
            shown = [show(v, depth + 1) for v in value[:SHOW_ITEMS]]
            text = "[" + ", ".join(shown + ["..."] * (len(value) > SHOW_ITEMS)) + "]"
    elif isinstance(value, dict):
        text = "a table"
    else:
        text = type(value).__name__
    return text if len(text) <= 60 else text[:57] + "..."


class ClrayError(Exception):
    """Base class: the message is one line, fit to print without a traceback."""

    exit_code = EXIT_RUNTIME


class SceneError(ClrayError):
    """Bad scene, mesh or texture input: `file: key.path: what was expected`."""

    exit_code = EXIT_SCENE

    def __init__(self, file: str | Path | None, key: str | None, message: str) -> None:
        self.file = None if file is None else Path(file)
        self.key = key
        self.message = message
        parts = [p for p in (None if file is None else Path(file).name, key, message) if p]
        super().__init__(one_line(": ".join(parts)))

    def with_path(self) -> str:
        """The message naming the file by its path as given (on the command line, or joined to
        the folder of the scene that names it), not by its base name alone, which an included
        scene or a mesh in another folder may share: what the command line prints. A path the
        loader made absolute (an animation's scene, a mesh file's automatic scene) is named
        from the working directory where it lies below it, as it was given there."""
        parts = [p for p in (None if self.file is None else shown_path(self.file), self.key,
                             self.message) if p]
        return one_line(": ".join(parts))


def shown_path(path: Path) -> str:
    """`path` as a message to the user names it: relative to the working directory where it is
    absolute and lies below it, else as it is."""
    if path.is_absolute():
        try:
            return str(path.relative_to(Path.cwd()))
        except (ValueError, OSError):  # elsewhere, or no working directory any more
            pass
    return str(path)


class SettingsError(ClrayError, ValueError):
    """A render setting out of range, from a command-line flag or RenderSettings: the same rules
    and wording as the scene file's [render] table (clray.scene.limits)."""

    exit_code = EXIT_USAGE


class DeviceError(ClrayError):
    """No OpenCL platform or device, a failed build (with its log), or out of resources."""

    exit_code = EXIT_OPENCL
