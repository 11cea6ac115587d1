"""Renders in Jupyter: a RenderResult shows itself (RenderResult._repr_png_); show_progressive
shows the bands of rows as they arrive, through IPython's display, which every notebook has
and clray does not require."""

from __future__ import annotations

import dataclasses

import numpy as np

from clray.errors import ClrayError
from clray.image_io import png_bytes, to_png_samples
from clray.render import (
    RenderResult,
    RenderSettings,
    SceneSource,
    png_encoding,
    render,
    resolved_settings,
    scene_from,
    settings_or_default,
)

IPYTHON_MISSING = "show_progressive needs IPython's display (run it in Jupyter or IPython)"


def _display():
    try:
        from IPython import display
    except ImportError:
        raise ClrayError(IPYTHON_MISSING) from None
    return display


def show_progressive(scene: SceneSource, settings: RenderSettings | None = None
                     ) -> RenderResult:
    """Render as render() does, showing the image in the notebook as each band of rows
    arrives (rows still to come are black), then the finished image (denoised where the
    settings ask). Returns the result; settings.on_band, if any, still hears every band.
    Outside a notebook's kernel (plain Python or IPython's terminal, where nothing can be
    updated in place) it shows nothing and returns the result."""
    display = _display()
    settings = settings_or_default(settings)
    # Handed to render() as render takes a path or a callable (a list's pop): given one,
    # render holds the scene alone and lets it go once packed, here too.
    held = [scene_from(scene, settings)]
    resolved = resolved_settings(held[0], settings)
    encoding = png_encoding(held[0], settings)
    canvas = np.zeros((resolved["height"], resolved["width"], 3), dtype=np.float32)

    def frame() -> object:
        return display.Image(data=png_bytes(to_png_samples(canvas, encoding), encoding.linear))

    # None where no notebook's kernel runs: IPython's display then has no display to update.
    handle = display.display(frame(), display_id=True)
    user_hook = settings.on_band

    def on_band(first_row: int, rows: np.ndarray) -> None:
        canvas[first_row:first_row + len(rows)] = rows
        if handle is not None:
            handle.update(frame())
        if user_hook is not None:
            user_hook(first_row, rows)

    result = render(held.pop, dataclasses.replace(settings, on_band=on_band))
    if handle is not None:
        handle.update(display.Image(data=result._repr_png_()))
    return result
