"""The colour pipeline (docs/rendering.md): sRGB-encoded, tagged PNG by default, linear PNG with
gAMA 1.0, exposure, 16-bit PNG, OpenEXR, and 8-bit textures decoded from sRGB."""

from __future__ import annotations

import json
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clray import cli
from clray.errors import ClrayError, SceneError
from clray.image_io import (
    Encoding,
    clipped_pixels,
    png_bytes,
    read_pfm,
    to_png_samples,
    write_image,
)
from clray.render import RenderSettings, render
from clray.scene.colour import srgb_decode, srgb_encode
from clray.scene.load import load_scene

TINY = ["-W", "32", "-H", "24"]

SCENE = """\
[render]
width = 32
height = 24
max_depth = 1
{render_extra}

[camera]
position = [0, 1, 5]
look_at = [0, 0.5, 0]

[materials.red]
color = [1, 0.4, 0.2]
specular = 0.8

[[lights]]
type = "point"
position = [-4, 6, 4]
color = [1.5, 1.5, 1.5]

[[objects]]
type = "sphere"
center = [0, 0.5, 0]
radius = 1
material = "red"
"""

# A square facing the camera and filling the view, lit by the ambient light alone: each pixel
# is material ambient (1) x render ambient (1) x texel.
TEXTURED = """\
[render]
width = 8
height = 8
ambient = [1, 1, 1]

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
vfov = 20

[materials.m]
ambient = 1
diffuse = 0
texture = {{ type = "image", file = "{file}"{extra} }}

[[objects]]
type = "box"
min = [-5, -5, 0]
max = [5, 5, 0]
material = "m"
"""


def run(capsys, *argv: str | Path) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    found, at = [], 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        assert struct.unpack(">I", data[at + 8 + length : at + 12 + length])[0] == zlib.crc32(
            kind + body
        )
        found.append((kind, body))
        at += 12 + length
    return found


def read_png(data: bytes) -> np.ndarray:
    """(H, W, 3) uint8 or uint16 samples of an RGB PNG whose rows use filter None or Up, as
    clray writes them; independent of the writer's code, for 16-bit files Pillow cannot read."""
    parts = chunks(data)
    width, height, bits, colour, _, _, interlace = struct.unpack(">IIBBBBB", parts[0][1])
    assert colour == 2 and interlace == 0 and bits in (8, 16)
    raw = zlib.decompress(b"".join(body for kind, body in parts if kind == b"IDAT"))
    stride = width * 3 * bits // 8
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(height, stride + 1)
    out = np.empty((height, stride), dtype=np.uint8)
    for y in range(height):
        assert rows[y, 0] in (0, 2)
        out[y] = rows[y, 1:] if rows[y, 0] == 0 or y == 0 else rows[y, 1:] + out[y - 1]
    dtype = np.dtype(">u2") if bits == 16 else np.dtype(np.uint8)
    return out.view(dtype).reshape(height, width, 3).astype(dtype.newbyteorder("="))


def tag(data: bytes) -> list[tuple[bytes, bytes]]:
    return [(kind, body) for kind, body in chunks(data) if kind in (b"sRGB", b"gAMA", b"iCCP")]


# --- encoding, without a device -----------------------------------------------------------------

def test_default_png_is_tagged_srgb_and_linear_png_gamma_one() -> None:
    pixels = np.zeros((2, 2, 3), dtype=np.uint8)
    assert tag(png_bytes(pixels)) == [(b"sRGB", b"\x00")]
    # gAMA stores 100000 / gamma: 100000 is gamma 1.0, linear values.
    assert tag(png_bytes(pixels, linear=True)) == [(b"gAMA", struct.pack(">I", 100000))]


@pytest.mark.parametrize("linear", [False, True])
def test_16bit_png_round_trip(tmp_path, linear) -> None:
    rng = np.random.default_rng(7)
    image = rng.uniform(0, 1, size=(9, 13, 3))
    image[0, 0] = [0, 1, 0.5]
    path = tmp_path / "a.png"
    write_image(path, image, Encoding(linear=linear, png_bits=16))
    data = path.read_bytes()
    assert struct.unpack(">IIBB", chunks(data)[0][1][:10]) == (13, 9, 16, 2)
    samples = read_png(data)
    assert samples.dtype == np.uint16 and samples.shape == (9, 13, 3)
    want = image if linear else srgb_encode(image)
    np.testing.assert_array_equal(samples, np.rint(want * 65535))
    assert samples[0, 0].tolist() == [0, 65535, 32768 if linear else 48192]
    # Pillow reads the same file (as 8-bit RGB): the layout is a valid PNG.
    with Image.open(path) as png:
        assert png.size == (13, 9)
        np.testing.assert_allclose(np.asarray(png, dtype=float), samples / 257, atol=1)


def test_8bit_png_layout_read_back_by_our_reader() -> None:
    pixels = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3) * 3
    np.testing.assert_array_equal(read_png(png_bytes(pixels)), pixels)


def test_exposure_scales_by_powers_of_two_before_the_clamp() -> None:
    image = np.array([[[0.1, 0.2, 0.3], [0.4, 0.6, 0.05]]])
    for stops in (1, -1, 2.5):
        got = to_png_samples(image, Encoding(linear=True, exposure=stops, png_bits=16))
        want = np.rint(np.clip(image * 2.0**stops, 0, 1) * 65535)
        np.testing.assert_array_equal(got, want)
    doubled = to_png_samples(image, Encoding(linear=True, exposure=1, png_bits=16))
    assert doubled[0, 0].tolist() == [13107, 26214, 39321]  # 0.2, 0.4, 0.6 of 65535
    assert doubled[0, 1, :2].tolist() == [52428, 65535]  # 0.8; 1.2 clamps to 1
    # In sRGB the exposure applies to the linear values, before the curve.
    np.testing.assert_array_equal(to_png_samples(image, Encoding(exposure=1)),
                                  to_png_samples(image * 2))


def test_clipped_pixels_counts_what_the_png_clamps() -> None:
    image = np.array([[[0.9, 0.1, 0.1], [1.5, 0, 0], [np.inf, 0, 0], [0.6, 0.6, 0.6]]])
    assert clipped_pixels(image) == 1
    assert clipped_pixels(image, exposure=1) == 3
    assert clipped_pixels(image, exposure=-1) == 0


def test_clipped_pixels_of_float32_images_agree_with_float64() -> None:
    # Rendered images are float32 and take a path without the float64 copy: the same counts.
    rng = np.random.default_rng(3)
    image = (rng.random((40, 50, 3)) * 1.05).astype(np.float32)
    image[0, :6] = [[np.nan, 2, 0], [np.inf, 0, 0], [-np.inf, 0.5, 0],
                    [np.nextafter(np.float32(1), np.float32(2)), 0, 0], [1, 1, 1], [0, 0, np.nan]]
    for exposure in (0, 0.5, -0.25):
        expected = clipped_pixels(image.astype(np.float64), exposure)
        assert clipped_pixels(image, exposure) == expected
    assert 0 < clipped_pixels(image) < image.shape[0] * image.shape[1]


@pytest.mark.parametrize(("kwargs", "needle"), [
    ({"exposure": float("nan")}, "exposure must be a number of stops in"),
    ({"exposure": float("inf")}, "exposure"),
    ({"exposure": 33}, r"\[-32, 32\]"),
    ({"exposure": True}, "exposure"),
    ({"png_bits": 12}, "png_bits must be 8 or 16"),
    ({"png_bits": 8.0}, "png_bits must be 8 or 16"),
    ({"linear": "yes"}, "linear must be True or False"),
])
def test_encoding_refuses_bad_values(kwargs, needle) -> None:
    with pytest.raises(ValueError, match=needle):
        Encoding(**kwargs)


def test_encoding_takes_numpy_numbers() -> None:
    encoding = Encoding(exposure=np.float32(1.5), png_bits=np.int64(16))
    assert to_png_samples(np.full((1, 1, 3), 0.25), encoding).dtype == np.uint16


def test_exr_round_trip_keeps_every_value(tmp_path) -> None:
    openexr = pytest.importorskip("OpenEXR")
    rng = np.random.default_rng(2)
    image = rng.normal(size=(5, 7, 3)).astype(np.float32) * 10
    image[0, 0] = [np.inf, -np.inf, np.nan]
    path = tmp_path / "a.exr"
    write_image(path, image, Encoding(exposure=3))  # float formats ignore the encoding
    pixels = openexr.File(str(path)).channels()["RGB"].pixels
    assert pixels.dtype == np.float32
    np.testing.assert_array_equal(pixels, image)


def test_exr_without_the_package_names_the_extra(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR now raises ImportError
    with pytest.raises(ClrayError, match=r"pip install 'clray\[exr\]'"):
        write_image(tmp_path / "a.exr", np.zeros((1, 1, 3)))
    assert list(tmp_path.iterdir()) == []


# --- the command line, scene files and RenderSettings --------------------------------------------

@pytest.fixture
def scene(tmp_scene, tmp_path, monkeypatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return tmp_scene(SCENE.format(render_extra=""))


def test_default_png_is_the_linear_render_srgb_encoded(capsys, cl_device, scene, tmp_path) -> None:
    assert run(capsys, "render", scene, "-q")[0] == 0  # default name: scene.png
    assert run(capsys, "render", scene, "-q", "-o", "linear.png", "--linear",
               "--png-bits", "16")[0] == 0
    assert run(capsys, "render", scene, "-q", "-o", "linear8.png", "--linear")[0] == 0
    assert run(capsys, "render", scene, "-q", "-o", "float.pfm")[0] == 0
    default = (tmp_path / "scene.png").read_bytes()
    assert tag(default) == [(b"sRGB", b"\x00")]
    with Image.open(tmp_path / "scene.png") as png:
        shown = np.asarray(png, dtype=np.int64)
    linear = read_png((tmp_path / "linear.png").read_bytes()) / 65535.0
    encoded = np.rint(srgb_encode(linear) * 255)
    assert np.abs(shown - encoded).max() <= 1
    radiance = read_pfm(tmp_path / "float.pfm")
    assert radiance.max() > 0.5 and shown.max() > 200  # a lit image, not a black one
    np.testing.assert_array_equal(shown, to_png_samples(radiance))
    linear8 = (tmp_path / "linear8.png").read_bytes()
    assert tag(linear8) == [(b"gAMA", struct.pack(">I", 100000))]
    assert (shown >= read_png(linear8)).all()


def test_cli_scene_and_render_settings_reach_the_same_encoding(capsys, cl_device, tmp_scene,
                                                                tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    plain = tmp_scene(SCENE.format(render_extra=""))
    tagged = tmp_scene(SCENE.format(render_extra="linear = true\nexposure = 1\npng_bits = 16"),
                       name="tagged.toml")
    assert run(capsys, "render", plain, "-q", "-o", "ref.pfm")[0] == 0
    assert run(capsys, "render", plain, "-q", "-o", "flags.png", "--linear", "--exposure", "1",
               "--png-bits", "16")[0] == 0
    assert run(capsys, "render", tagged, "-q", "-o", "file.png")[0] == 0
    render(load_scene(plain), RenderSettings(linear=True, exposure=1.0, png_bits=16)).save(
        tmp_path / "api.png")
    want = png_bytes(to_png_samples(read_pfm(tmp_path / "ref.pfm"),
                                     Encoding(linear=True, exposure=1, png_bits=16)), linear=True)
    for name in ("flags.png", "file.png", "api.png"):
        assert (tmp_path / name).read_bytes() == want, name
    # Flags override the file, settings override the file.
    assert run(capsys, "render", tagged, "-q", "-o", "over.png", "--srgb", "--exposure", "0",
               "--png-bits", "8")[0] == 0
    back = render(load_scene(tagged), RenderSettings(linear=False, exposure=0, png_bits=8))
    back.save(tmp_path / "api_over.png")
    default = png_bytes(to_png_samples(read_pfm(tmp_path / "ref.pfm")))
    assert (tmp_path / "over.png").read_bytes() == default
    assert (tmp_path / "api_over.png").read_bytes() == default


@pytest.mark.parametrize(("kwargs", "needle"), [
    ({"exposure": float("nan")}, r"RenderSettings.exposure: must be finite, got nan"),
    # An int past a float's range is out of range, not an OverflowError from math.isfinite.
    ({"exposure": 10**400}, r"RenderSettings.exposure: must be in \[-\d+, \d+\]"),
    ({"png_bits": 4}, r"RenderSettings.png_bits: expected 8 or 16, got 4"),
    ({"linear": 1}, r"RenderSettings.linear: expected True or False, got 1"),
])
def test_bad_render_settings_fail_before_rendering(kwargs, needle) -> None:
    # No device fixture: RenderSettings refuses the value itself, before any render.
    with pytest.raises(ValueError, match=needle):
        RenderSettings(device="no such device", **kwargs)


def test_stats_count_clipped_pixels(capsys, cl_device, scene, tmp_path) -> None:
    assert run(capsys, "render", scene, "-q", "-o", "a.png", "--exposure", "4",
               "--stats-json", "s.json")[0] == 0
    assert run(capsys, "render", scene, "-q", "-o", "a.pfm")[0] == 0
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["clipped_pixels"] == clipped_pixels(read_pfm(tmp_path / "a.pfm"), 4) > 0


@pytest.mark.parametrize(("argv", "needle"), [
    (["--exposure", "nan"], "--exposure: must be finite, got 'nan'"),
    (["--exposure", "inf"], "got 'inf'"),
    (["--exposure", "33"], "got '33'"),
    (["--exposure", "one"], "got 'one'"),
    (["--png-bits", "12"], "--png-bits"),
    (["--linear", "--srgb"], "not allowed with argument"),
    (["-o", "a.pfm", "--exposure", "1"], "--exposure applies to PNG output only"),
    (["-o", "a.exr", "--srgb", "--png-bits", "16"], "--srgb, --png-bits applies to PNG output"),
])
def test_bad_colour_flags_are_usage_errors(capsys, scene, argv, needle) -> None:
    code, out, err = run(capsys, "render", scene, *argv)
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and err.startswith("clray: error: ")
    assert needle in err


def test_exr_without_the_package_fails_before_rendering(capsys, scene, tmp_path,
                                                         monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    # No cl_device: the check comes before the scene is even loaded on a device.
    code, _, err = run(capsys, "render", scene, "-o", "a.exr")
    assert code == 1
    assert err == "clray: error: writing .exr needs the OpenEXR package: " \
                  "pip install 'clray[exr]'\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


@pytest.mark.parametrize(("extra", "key", "needle"), [
    ("exposure = nan", "render.exposure", "must be finite"),
    ("exposure = 40", "render.exposure", "must be in [-32, 32], got 40"),
    ('exposure = "1"', "render.exposure", "expected a number"),
    ("png_bits = 12", "render.png_bits", "expected 8 or 16, got 12"),
    ("png_bits = true", "render.png_bits", "expected 8 or 16, got true"),
    ('linear = "yes"', "render.linear", "expected true or false"),
])
def test_bad_render_keys_name_file_and_key(tmp_scene, extra, key, needle) -> None:
    path = tmp_scene(SCENE.format(render_extra=extra))
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    assert str(caught.value).startswith(f"scene.toml: {key}: ")
    assert needle in str(caught.value)


# --- textures -----------------------------------------------------------------------------------

def textured(tmp_scene, tmp_path, image: Image.Image, extra: str = "") -> Path:
    image.save(tmp_path / "tex.png")
    return tmp_scene(TEXTURED.format(file="tex.png", extra=extra))


def test_grey_128_srgb_texture_renders_back_to_128(capsys, cl_device, tmp_scene,
                                                    tmp_path) -> None:
    path = textured(tmp_scene, tmp_path, Image.new("RGB", (4, 4), (128, 128, 128)))
    scene = load_scene(path)
    texture = scene.materials[0].texture
    assert texture.colorspace == "srgb"
    np.testing.assert_allclose(texture.image, srgb_decode(np.float64(128 / 255)), rtol=1e-6)
    result = render(scene)
    np.testing.assert_allclose(result.image, 0.2158605, atol=1e-5)  # linear, as always
    assert run(capsys, "render", path, "-q", "-o", tmp_path / "out.png")[0] == 0
    with Image.open(tmp_path / "out.png") as png:
        pixels = np.asarray(png, dtype=int)
    assert np.abs(pixels - 128).max() <= 1


def test_linear_colorspace_keeps_8bit_texels_as_stored(cl_device, tmp_scene, tmp_path) -> None:
    path = textured(tmp_scene, tmp_path, Image.new("RGB", (4, 4), (128, 64, 255)),
                    extra=', colorspace = "linear"')
    scene = load_scene(path)
    assert scene.materials[0].texture.colorspace == "linear"
    np.testing.assert_allclose(render(scene).image, np.broadcast_to([128 / 255, 64 / 255, 1],
                                                                    (8, 8, 3)), atol=1e-5)


@pytest.mark.parametrize(("colorspace", "want"), [("", 32896 / 65535),
                                                  (', colorspace = "srgb"', 0.2158605)])
def test_16bit_texture_is_linear_unless_said(tmp_scene, tmp_path, colorspace, want) -> None:
    grey = Image.fromarray(np.full((4, 4), 32896, dtype=np.uint16))  # 128 * 257
    assert grey.mode == "I;16"
    scene = load_scene(textured(tmp_scene, tmp_path, grey, extra=colorspace))
    np.testing.assert_allclose(scene.materials[0].texture.image, want, atol=1e-6)


def test_16bit_rgb_png_texture_counts_as_deep(tmp_scene, tmp_path) -> None:
    # Pillow reads 16-bit RGB PNGs as 8-bit "RGB"; the file is still linear by default.
    samples = np.full((2, 2, 3), 128 * 257, dtype=np.uint16)
    (tmp_path / "tex.png").write_bytes(png_bytes(samples, linear=True))
    scene = load_scene(tmp_scene(TEXTURED.format(file="tex.png", extra="")))
    assert scene.materials[0].texture.colorspace == "linear"
    np.testing.assert_allclose(scene.materials[0].texture.image, 128 / 255, atol=1e-6)


def test_one_file_in_two_colorspaces(tmp_scene, tmp_path) -> None:
    Image.new("RGB", (2, 2), (128, 128, 128)).save(tmp_path / "tex.png")
    text = TEXTURED.format(file="tex.png", extra="") + """
[materials.raw]
texture = { type = "image", file = "tex.png", colorspace = "linear" }

[materials.again]
texture = { type = "image", file = "tex.png" }
"""
    materials = {m.name: m for m in load_scene(tmp_scene(text)).materials}
    np.testing.assert_allclose(materials["m"].texture.image, 0.2158605, atol=1e-6)
    np.testing.assert_allclose(materials["raw"].texture.image, 128 / 255, atol=1e-6)
    assert materials["again"].texture.image is materials["m"].texture.image  # decoded once


@pytest.mark.parametrize("value", ['"rgb"', '"sRGB"', "1", "true"])
def test_unknown_colorspace_names_file_and_key(tmp_scene, tmp_path, value) -> None:
    path = textured(tmp_scene, tmp_path, Image.new("RGB", (2, 2)), extra=f", colorspace = {value}")
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    assert str(caught.value).startswith(
        "scene.toml: materials.m.texture.colorspace: expected \"srgb\" or \"linear\", got ")
