"""Render results in notebooks: the PNG Jupyter shows (_repr_png_)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clray.image_io import Encoding
from clray.render import RenderResult


def _decoded(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as image:
        return np.asarray(image)


@pytest.mark.parametrize("encoding", [Encoding(), Encoding(linear=True, exposure=1.5),
                                      Encoding(png_bits=16)], ids=("srgb8", "linear", "bits16"))
def test_repr_png_is_the_png_save_writes(tmp_path: Path, encoding: Encoding) -> None:
    rng = np.random.default_rng(7)
    image = rng.uniform(-0.2, 1.3, (9, 13, 3)).astype(np.float32)
    image[0, 0] = (np.nan, np.inf, -np.inf)
    result = RenderResult(image, {}, encoding)
    result.save(tmp_path / "saved.png")
    saved = (tmp_path / "saved.png").read_bytes()
    shown = result._repr_png_()
    assert _decoded(shown).shape == (9, 13, 3)
    np.testing.assert_array_equal(_decoded(shown), _decoded(saved))
    assert shown == saved
