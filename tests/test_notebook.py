"""Render results in notebooks: the PNG Jupyter shows (_repr_png_), and the progressive
display of bands (clray.notebook) through a stand-in for IPython.display."""

from __future__ import annotations

import gc
import importlib
import io
import sys
import types
import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clray.errors import ClrayError, SettingsError
from clray.image_io import Encoding, to_png_samples
from clray.model_scene import load_model_scene
from clray.notebook import show_progressive
from clray.render import RenderResult, RenderSettings, render
from clray.tuning import Tuning

ROOT = Path(__file__).resolve().parent.parent


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


class _FakeDisplay:
    """IPython.display's Image and display(display_id=True), recording what is shown."""

    def __init__(self) -> None:
        self.shown: list[bytes] = []

    class Image:
        def __init__(self, data: bytes) -> None:
            self.data = data

    def display(self, obj: _FakeDisplay.Image, display_id: bool) -> object:
        assert display_id is True
        self.shown.append(obj.data)
        fake = self

        class Handle:
            def update(self, new: _FakeDisplay.Image) -> None:
                fake.shown.append(new.data)

        return Handle()


def _fake_ipython(monkeypatch: pytest.MonkeyPatch) -> _FakeDisplay:
    display = _FakeDisplay()
    package = types.ModuleType("IPython")
    package.display = display
    monkeypatch.setitem(sys.modules, "IPython", package)
    return display


def test_show_progressive_shows_each_band_then_the_result(cl_device, monkeypatch) -> None:
    display = _fake_ipython(monkeypatch)
    width, height, rows = 24, 9, 3
    # Bands of three rows: three bands, each its own update.
    settings = RenderSettings(width=width, height=height, spp=2, tuning=Tuning(
        first_launch_pixel_samples=width * 2 * rows, max_launch_pixel_samples=width * 2 * rows))
    heard = []
    scene = ROOT / "scenes" / "soft_lights.toml"
    result = show_progressive(scene, replace(settings, on_band=lambda first, band: heard.append(
        (first, band.shape[0]))))
    np.testing.assert_array_equal(result.image, render(scene, settings).image)
    assert heard == [(0, 3), (3, 3), (6, 3)]  # the caller's own hook still hears every band
    # Black at first, then the rows so far over black, then the result's own PNG.
    assert len(display.shown) == 1 + 3 + 1
    assert display.shown[-1] == result._repr_png_()
    expected = np.zeros_like(result.image)
    assert np.array_equal(_decoded(display.shown[0]), to_png_samples(expected))
    for band, png in enumerate(display.shown[1:-1]):
        expected[band * rows:(band + 1) * rows] = result.image[band * rows:(band + 1) * rows]
        np.testing.assert_array_equal(_decoded(png), to_png_samples(expected, result.encoding))


def test_show_progressive_without_ipython_says_so(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "IPython", None)
    with pytest.raises(ClrayError, match="IPython"):
        show_progressive(ROOT / "scenes" / "soft_lights.toml")


def test_show_progressive_refuses_settings_that_are_not_render_settings(monkeypatch) -> None:
    # As render() does: a dict of overrides had been taken for the defaults where empty, and
    # an AttributeError otherwise.
    _fake_ipython(monkeypatch)
    for settings in ({}, {"width": 4}):
        with pytest.raises(SettingsError, match=r"^settings: expected a clray\.RenderSettings"):
            show_progressive(ROOT / "scenes" / "spheres.toml", settings)  # type: ignore[arg-type]


def test_show_progressive_outside_a_notebook_returns_the_render(cl_device, monkeypatch) -> None:
    # IPython's display(..., display_id=True) returns None where no kernel runs (a script,
    # IPython's terminal): there is nothing to update, and the render is still returned.
    display = _fake_ipython(monkeypatch)
    shown = display.shown
    monkeypatch.setattr(display, "display", lambda obj, display_id: shown.append(obj.data))
    scene = ROOT / "scenes" / "spheres.toml"
    settings = RenderSettings(width=16, height=12)
    result = show_progressive(scene, settings)
    np.testing.assert_array_equal(result.image, render(scene, settings).image)
    assert len(shown) == 1  # the black first frame, shown once and never updated


def test_show_progressive_with_ipython_but_no_kernel(cl_device) -> None:
    # The real IPython, where it is installed, as a script that imports it runs.
    pytest.importorskip("IPython.display")
    result = show_progressive(ROOT / "scenes" / "spheres.toml", RenderSettings(width=8, height=6))
    assert result.image.shape == (6, 8, 3)


def test_show_progressive_takes_what_render_takes(cl_device, monkeypatch) -> None:
    # A mesh file (its automatic scene) and a callable, as render() takes them.
    _fake_ipython(monkeypatch)
    mesh = ROOT / "scenes" / "meshes" / "cornell_box.obj"
    settings = RenderSettings(width=16, height=12)
    expected = render(mesh, settings).image
    np.testing.assert_array_equal(show_progressive(mesh, settings).image, expected)
    np.testing.assert_array_equal(
        show_progressive(lambda: load_model_scene(mesh), settings).image, expected)


@pytest.mark.parametrize("given", ["path", "callable"])
def test_show_progressive_lets_a_handed_over_scene_go_before_the_render(
        cl_device, monkeypatch, given: str) -> None:
    # As render() does: given a path or a callable, no one else holds the scene, and its
    # arrays go once it is packed, before the kernels run.
    _fake_ipython(monkeypatch)
    render_module = importlib.import_module("clray.render")
    loaded: list[weakref.ref] = []
    alive: list[bool] = []
    load, render_packed = render_module.load_scene, render_module.render_packed

    def loading(path: object) -> object:
        scene = load(path)
        loaded.append(weakref.ref(scene))
        return scene

    def spy(*args: object, **kwargs: object) -> object:
        gc.collect()
        alive.append(loaded[-1]() is not None)
        return render_packed(*args, **kwargs)

    monkeypatch.setattr(render_module, "load_scene", loading)
    monkeypatch.setattr(render_module, "render_packed", spy)
    scene = ROOT / "scenes" / "spheres.toml"
    show_progressive(scene if given == "path" else lambda: loading(scene),
                     RenderSettings(width=16, height=12))
    assert alive == [False]
