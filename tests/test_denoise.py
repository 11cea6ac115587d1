"""Denoising (clray.denoise, docs/denoising.md): against a clean synthetic image, and the
one-line error when the optional binding is missing."""

from __future__ import annotations

import importlib
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from clray import cli
from clray.denoise import DENOISE_MISSING, check_denoiser, denoise
from clray.errors import ClrayError, SettingsError
from clray.image_io import read_pfm
from clray.metrics import rmse
from clray.passes import pass_paths
from clray.render import RenderSettings, render
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent


def _clean_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image, albedo, normal) of a lit checkerboard floor and a disc: smooth lighting times a
    texture with sharp edges, which a denoiser must keep."""
    height, width = 96, 128
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    checker = ((x // 16 + y // 16) % 2).astype(bool)
    albedo = np.where(checker[..., None], (0.8, 0.7, 0.2), (0.15, 0.3, 0.7))
    disc = (x - 80) ** 2 + (y - 40) ** 2 < 22 ** 2
    albedo[disc] = (0.9, 0.9, 0.9)
    normal = np.zeros((height, width, 3))
    normal[..., 1] = 1.0
    dz = np.sqrt(np.clip(1 - ((x - 80) ** 2 + (y - 40) ** 2) / 22 ** 2, 0, 1))
    normal[disc] = np.stack([(x - 80) / 22, (40 - y) / 22, dz], -1)[disc]
    light = 0.4 + 1.2 * np.exp(-((x - 30) ** 2 + (y - 70) ** 2) / 2000)
    shade = np.clip(0.3 + 0.7 * normal[..., 1:2] + 0.5 * normal[..., 2:], 0, None)
    image = albedo * light[..., None] * shade
    return (image.astype(np.float32), albedo.astype(np.float32),
            (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32))


def _noisy(image: np.ndarray, samples: int) -> np.ndarray:
    """Monte Carlo-like noise: the mean of `samples` exponential draws a pixel, unbiased."""
    rng = np.random.default_rng(3)
    return (image * rng.gamma(samples, 1 / samples, image.shape)).astype(np.float32)


@pytest.mark.parametrize("guided", [False, True], ids=("alone", "guided"))
def test_denoising_brings_a_noisy_image_closer_to_the_clean_one(guided: bool) -> None:
    pytest.importorskip("pyoidn")
    clean, albedo, normal = _clean_scene()
    noisy = _noisy(clean, 4)
    guides = {"albedo": albedo, "normal": normal} if guided else {}
    denoised = denoise(noisy, **guides)
    assert denoised.dtype == np.float32 and denoised.shape == clean.shape
    assert rmse(denoised, clean) < 0.5 * rmse(noisy, clean)


def test_guides_keep_the_texture_edges() -> None:
    pytest.importorskip("pyoidn")
    clean, albedo, normal = _clean_scene()
    noisy = _noisy(clean, 2)
    assert rmse(denoise(noisy, albedo, normal), clean) < rmse(denoise(noisy), clean)


def test_non_finite_pixels_count_as_black() -> None:
    pytest.importorskip("pyoidn")
    clean, albedo, normal = _clean_scene()
    noisy = _noisy(clean, 4)
    noisy[10, 10] = (np.nan, np.inf, -np.inf)
    denoised = denoise(noisy, albedo, normal)
    assert np.isfinite(denoised).all()
    assert rmse(denoised, clean) < 0.5 * rmse(np.nan_to_num(noisy, posinf=0, neginf=0), clean)


# Unpadded, OIDN took what lies past the image's edges for black: a flat 0.5 came back about
# 0.09 at 1x1 and off by up to 0.0228 in a 64x64 image's outer 4 pixels. Its own error on a
# flat 0.5 is up to 0.0017 inside that image (8 px and more from an edge), and padded up to
# 0.0014 at these sizes: the tolerance is that interior error and half again.
FLAT_TOLERANCE = 0.0025


@pytest.mark.parametrize("guided", [False, True], ids=("alone", "guided"))
@pytest.mark.parametrize("height, width", [(1, 1), (2, 3), (64, 64)])
def test_a_flat_image_denoises_to_itself_up_to_its_edges(height: int, width: int,
                                                         guided: bool) -> None:
    pytest.importorskip("pyoidn")
    image = np.full((height, width, 3), 0.5, np.float32)
    guides = {"albedo": np.full_like(image, 0.5),
              "normal": np.tile(np.float32([0.0, 0.0, 1.0]), (height, width, 1))}
    denoised = denoise(image, **(guides if guided else {}))
    assert denoised.shape == image.shape and denoised.dtype == np.float32
    np.testing.assert_allclose(denoised, 0.5, rtol=0, atol=FLAT_TOLERANCE)


def test_float64_beyond_float32_counts_as_float32_max_not_black() -> None:
    """A float64 value too large for float32 became inf in the cast (numpy's RuntimeWarning),
    hence black; it is the brightest float32 instead."""
    pytest.importorskip("pyoidn")
    image = np.full((40, 40, 3), 0.5)
    image[20, 20] = 1e300
    brightest = np.full(image.shape, 0.5, np.float32)
    brightest[20, 20] = np.finfo(np.float32).max
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        denoised = denoise(image)
    np.testing.assert_array_equal(denoised, denoise(brightest))
    assert (denoised[20, 20] > 1.0).all()


def test_mismatched_passes_are_refused() -> None:
    pytest.importorskip("pyoidn")
    clean, albedo, normal = _clean_scene()
    with pytest.raises(SettingsError, match="albedo pass has shape"):
        denoise(clean, albedo[:-1], normal)
    with pytest.raises(SettingsError, match="normal pass only with the albedo"):
        denoise(clean, normal=normal)


def test_missing_binding_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import pyoidn raises ImportError
    with pytest.raises(ClrayError) as err:
        check_denoiser()
    assert str(err.value) == DENOISE_MISSING
    assert "pip install 'clray[denoise]'" in DENOISE_MISSING and "\n" not in DENOISE_MISSING
    with pytest.raises(ClrayError, match=r"clray\[denoise\]"):
        denoise(np.zeros((2, 2, 3), np.float32))


SMALL = {"width": 48, "height": 27, "spp": 4}


def test_render_denoises_and_keeps_the_noisy_image(cl_device) -> None:
    pytest.importorskip("pyoidn")
    scene = ROOT / "scenes" / "soft_lights.toml"
    plain = render(scene, RenderSettings(**SMALL))
    result = render(scene, RenderSettings(**SMALL, denoise=True, aovs=("depth",)))
    np.testing.assert_array_equal(result.noisy, plain.image)
    assert result.image.shape == plain.image.shape and result.image.dtype == np.float32
    assert not np.array_equal(result.image, plain.image)
    # The guides were traced for the denoiser, but only the passes asked for are kept.
    assert list(result.aovs) == ["depth"]
    assert result.stats["denoise_s"] > 0 and plain.noisy is None


def test_noisy_guides_of_a_defocused_texture_do_not_keep_the_noise(cl_device) -> None:
    """depth_of_field's blurred checkerboard gives an albedo pass as noisy as the image at 4 spp:
    taken as it is, OIDN kept the noise (rmse 0.0535 against 0.0584 undenoised; denoising the
    guides first: 0.0269)."""
    pytest.importorskip("pyoidn")
    scene = ROOT / "scenes" / "depth_of_field.toml"
    size = {"width": 160, "height": 100}
    reference = render(scene, RenderSettings(**size, spp=256, seed=7)).image
    result = render(scene, RenderSettings(**size, spp=4, denoise=True))
    assert rmse(result.image, reference) < 0.6 * rmse(result.noisy, reference)


def test_render_guides_the_denoiser_with_its_own_passes(cl_device) -> None:
    """The test above passes with no guides at all: this one sees them. OIDN on the CPU gives
    the same values for the same input, so the render's image is denoise() of its noisy image
    and its own albedo and normal passes, bit for bit."""
    pytest.importorskip("pyoidn")
    scene = ROOT / "scenes" / "depth_of_field.toml"
    result = render(scene, RenderSettings(**SMALL, denoise=True, aovs=("albedo", "normal")))
    guided = denoise(result.noisy, result.aovs["albedo"], result.aovs["normal"])
    np.testing.assert_array_equal(result.image, guided)
    assert not np.array_equal(guided, denoise(result.noisy))  # the guides change the image
    # The same guides where the passes are not asked for (traced for the denoiser alone).
    unasked = render(scene, RenderSettings(**SMALL, denoise=True))
    np.testing.assert_array_equal(unasked.image, result.image)


def test_render_without_the_binding_fails_before_the_device(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    module = importlib.import_module("clray.render")  # clray.render is also the function
    monkeypatch.setattr(module, "select_device", lambda spec: pytest.fail("device used"))
    with pytest.raises(ClrayError, match=r"clray\[denoise\]"):
        render(ROOT / "scenes" / "soft_lights.toml", RenderSettings(**SMALL, denoise=True))


def test_denoise_setting_is_checked() -> None:
    with pytest.raises(SettingsError, match=r"RenderSettings\.denoise: expected True or False"):
        RenderSettings(denoise="yes")


def test_cli_denoise_writes_the_denoised_image(capsys, tmp_path: Path) -> None:
    pytest.importorskip("pyoidn")
    scene = ROOT / "scenes" / "soft_lights.toml"
    size = ["-W", str(SMALL["width"]), "-H", str(SMALL["height"]), "--spp", str(SMALL["spp"])]
    out, stats = tmp_path / "out.pfm", tmp_path / "stats.json"
    assert cli.main(["render", str(scene), "-o", str(out), *size, "--denoise", "-q",
                     "--stats-json", str(stats)]) == 0
    expected = render(scene, RenderSettings(**SMALL, denoise=True))
    # OIDN on the CPU gives the same values for the same input, call after call.
    np.testing.assert_array_equal(read_pfm(out), expected.image)
    assert json.loads(stats.read_text())["denoise_s"] > 0
    # No pass files beside it: the guides were traced for the denoiser, not asked for.
    assert sorted(tmp_path.iterdir()) == sorted([out, stats])


def test_cli_denoise_without_the_binding_is_one_line(capsys, monkeypatch,
                                                     tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    out = tmp_path / "out.png"
    code = cli.main(["render", str(ROOT / "scenes" / "soft_lights.toml"), "-o", str(out),
                     "--denoise"])
    err = capsys.readouterr().err
    assert code == 1 and not out.exists()
    assert err.strip().splitlines() == [f"clray: error: {DENOISE_MISSING}"]


def test_dask_still_refuses_to_denoise() -> None:
    pytest.importorskip("distributed")
    from clray.distributed import render_still

    # Refused before the client is used: tiles trace no passes to guide the denoiser.
    with pytest.raises(SettingsError, match="cannot be denoised"):
        render_still(None, load_scene(ROOT / "scenes" / "soft_lights.toml"),
                     RenderSettings(denoise=True))


def test_cli_dask_still_refuses_to_denoise_before_connecting(capsys, tmp_path: Path) -> None:
    # A usage error before any work: it used to wait out --dask-timeout on an address where no
    # scheduler answers, then say "cannot connect" (exit 1).
    code = cli.main(["render", str(ROOT / "scenes" / "soft_lights.toml"), "-o",
                     str(tmp_path / "out.png"), "--denoise", "--dask", "tcp://127.0.0.1:1",
                     "--dask-timeout", "3"])
    err = capsys.readouterr().err
    assert code == 2 and list(tmp_path.iterdir()) == []
    assert err.startswith("clray: error: --denoise: a still rendered in tiles on Dask has no "
                          "passes") and len(err.splitlines()) == 1


def test_cli_denoise_with_aov_writes_the_passes_as_rendered(capsys, tmp_path: Path) -> None:
    """The passes asked for are the render's own, not the guides as the denoiser cleaned them."""
    pytest.importorskip("pyoidn")
    scene = ROOT / "scenes" / "depth_of_field.toml"
    size = ["-W", str(SMALL["width"]), "-H", str(SMALL["height"]), "--spp", str(SMALL["spp"])]
    out = tmp_path / "out.pfm"
    assert cli.main(["render", str(scene), "-o", str(out), *size, "--denoise", "--aov",
                     "albedo,depth", "-q"]) == 0
    plain = render(scene, RenderSettings(**SMALL, aovs=("albedo", "depth")))
    denoised = render(scene, RenderSettings(**SMALL, aovs=("albedo", "depth"), denoise=True))
    np.testing.assert_array_equal(denoised.aovs["albedo"], plain.aovs["albedo"])
    np.testing.assert_array_equal(read_pfm(out), denoised.image)
    np.testing.assert_array_equal(read_pfm(pass_paths(out, ("albedo",), False)[0]),
                                  plain.aovs["albedo"])
