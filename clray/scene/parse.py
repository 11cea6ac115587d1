"""Scene file bytes -> plain data (dicts, lists, numbers, strings), or one SceneError.

Besides syntax errors, the parsers can fail in ways their own error types do not cover: a file
nested hundreds of levels deep exhausts Python's recursion limit, and an integer literal longer
than Python's int-to-string digit limit raises a bare ValueError. Both become ordinary scene
errors naming the line.
"""

from __future__ import annotations

import json
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

from clray.errors import SceneError, utf8_problem

# The depth reported for a file too deeply nested for the parsers: no scene value nests more
# than 4 deep, so such a file is in error whatever the parser's own limit.
MAX_NESTING = 64

# Brackets outside strings and comments, to find where nesting goes past MAX_NESTING.
_BRACKETS = {
    ".toml": re.compile(
        r'"""[\s\S]*?"""|' r"'''[\s\S]*?'''|" r'"(?:\\.|[^"\\\n])*"|' r"'[^'\n]*'|#[^\n]*|[\[\]{}]"
    ),
    ".json": re.compile(r'"(?:\\.|[^"\\])*"|[\[\]{}]'),
}


def parse_scene_text(raw: bytes, suffix: str, path: Path) -> Any:
    """Decode UTF-8 and parse as TOML (suffix ".toml") or JSON (".json")."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(path, None, utf8_problem(raw, exc)) from None
    kind = "TOML" if suffix == ".toml" else "JSON"
    try:
        return tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # The message already ends in "(at line L, column C)".
        raise SceneError(path, None, f"invalid TOML: {exc}") from None
    except json.JSONDecodeError as exc:
        raise SceneError(
            path, None, f"invalid JSON: {exc.msg} (at line {exc.lineno}, column {exc.colno})"
        ) from None
    except RecursionError:
        line = _too_deep_line(text, suffix)
        where = f" (at line {line})" if line else ""
        raise SceneError(
            path, None, f"invalid {kind}: arrays or tables nested more than {MAX_NESTING} "
            f"levels deep{where}"
        ) from None
    except ValueError as exc:
        # int() refusing a literal past sys.get_int_max_str_digits().
        limit = sys.get_int_max_str_digits()
        found = re.search(rf"[0-9][0-9_]{{{limit},}}", text)
        if found is None:
            raise SceneError(path, None, f"invalid {kind}: {exc}") from None
        raise SceneError(
            path, None, f"invalid {kind}: an integer literal has more than {limit} digits "
            f"(at line {_line_of(text, found.start())})"
        ) from None


def _line_of(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def _too_deep_line(text: str, suffix: str) -> int | None:
    depth = 0
    for match in _BRACKETS[suffix].finditer(text):
        token = match.group()
        if token in "[{":
            depth += 1
            if depth > MAX_NESTING:
                return _line_of(text, match.start())
        elif token in "]}":
            depth = max(depth - 1, 0)
    return None
