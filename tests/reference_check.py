"""The kernel-against-reference comparison that tests/test_render.py and
tests/test_area_lights.py share (not collected by pytest: the name does not start with test_)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clray.metrics import nonfinite_count, rmse
from clray.reference import render_reference
from clray.render import RenderSettings, render
from clray.scene import model as M


class Tolerance(NamedTuple):
    """What one scene needs, float32 kernel against the float64 reference: at most `off`
    pixels may differ by more than `err` in a channel (pixels where float32 legitimately
    resolves something else: the far horizon's texture lookups, a refraction that grazes a
    rim), and the other pixels' RMSE stays below `rmse`."""

    rmse: float
    err: float
    off: int = 0


def assert_kernel_matches_reference(scene: M.Scene, tol: Tolerance,
                                    settings: RenderSettings | None = None) -> None:
    image = render(scene, settings).image.astype(np.float64)
    expected = render_reference(scene)
    assert nonfinite_count(image) == 0
    err = np.abs(image - expected).max(axis=-1)
    off = err > tol.err
    worst = np.unravel_index(err.argmax(), err.shape)
    assert off.sum() <= tol.off, (f"{int(off.sum())} pixels off by more than {tol.err:g} "
                                  f"(worst {err.max():.3g} at (y, x) {worst})")
    assert rmse(image[~off], expected[~off]) < tol.rmse
