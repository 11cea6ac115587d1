"""The message helpers every layer shares (clray.errors): counts with the noun's right form."""

from __future__ import annotations

import pytest

from clray.errors import plural


@pytest.mark.parametrize(("count", "noun", "nouns", "expected"), [
    (1, "tile", None, "1 tile"),
    (0, "tile", None, "0 tiles"),
    (2, "run", None, "2 runs"),
    (1, "vertex", "vertices", "1 vertex"),
    (3, "vertex", "vertices", "3 vertices"),
    (1, "emissive triangle", None, "1 emissive triangle"),
])
def test_plural_takes_the_singular_for_one_alone(count, noun, nouns, expected) -> None:
    assert plural(count, noun, nouns) == expected
