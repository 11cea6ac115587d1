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
        return (tomllib.loads(text) if suffix == ".toml" else
                json.loads(text, object_pairs_hook=_unique_keys))
    except _DuplicateKey as exc:
        # TOML refuses a key given twice; json keeps the last one silently.
        line, column = _duplicate_at(text, exc.key)
        raise SceneError(path, None, f"invalid JSON: duplicate key {json.dumps(exc.key)} "
                         f"(at line {line}, column {column})") from None
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


class _DuplicateKey(ValueError):
    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's dict, refusing a key it has twice."""
    table = dict(pairs)  # in C: a Python loop over every key cost a large scene's load time
    if len(table) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise _DuplicateKey(key)
            seen.add(key)
    return table


# A JSON string, a bracket or a colon: enough to walk a file json has parsed.
_JSON_TOKENS = re.compile(r'"(?:\\.|[^"\\])*"|[\[\]{}:]')


def _duplicate_at(text: str, key: str) -> tuple[int, int]:
    """Line and column of the first key `key` that repeats one of its object's keys (the
    parse found one, but object_pairs_hook is not told where); (0, 0) if none is found."""
    objects: list[set[str] | None] = []  # a set of keys per open object, None per array
    tokens = list(_JSON_TOKENS.finditer(text))
    for i, token in enumerate(tokens):
        t = token.group()
        if t in "{[":
            objects.append(set() if t == "{" else None)
        elif t in "]}":
            objects.pop()
        elif (t.startswith('"') and i + 1 < len(tokens) and tokens[i + 1].group() == ":"
              and objects and objects[-1] is not None):
            name = json.loads(t)
            if name == key and name in objects[-1]:
                start = token.start()
                return _line_of(text, start), start - text.rfind("\n", 0, start)
            objects[-1].add(name)
    return 0, 0


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
