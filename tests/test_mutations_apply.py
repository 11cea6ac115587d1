"""Every mutation of tests/mutate.py still applies: its snippet occurs exactly once in its file.

A snippet that no longer matches would make `python -m tests.mutate` report it stale instead of
testing it; this catches the drift when the code changes, not at the next mutation run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.mutate import MUTATIONS

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("mutation", MUTATIONS, ids=[mu.name for mu in MUTATIONS])
def test_snippet_occurs_once(mutation) -> None:
    text = (ROOT / mutation.path).read_text(encoding="utf-8")
    assert text.count(mutation.old) == 1
    assert mutation.new != mutation.old
