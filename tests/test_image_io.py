import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from clray import image_io
from clray.errors import SettingsError
from clray.image_io import (
    Encoding,
    png_bytes,
    read_pfm,
    to_png_samples,
    write_image,
)
from clray.render import RenderResult
from clray.scene.colour import srgb_encode

LINEAR = Encoding(linear=True)


def test_pfm_round_trip_keeps_values_and_orientation(tmp_path) -> None:
    rng = np.random.default_rng(1)
    image = rng.normal(size=(5, 7, 3)).astype(np.float32)
    image[0, 0] = [np.inf, -np.inf, np.nan]
    image[4, 6, 1] = np.nan
    path = tmp_path / "a.pfm"
    write_image(path, image)
    back = read_pfm(path)
    assert back.dtype == np.float32 and back.shape == (5, 7, 3)
    np.testing.assert_array_equal(back, image)  # NaN compares equal here


def test_greyscale_pfm_round_trip(tmp_path) -> None:
    # A pass of one number a pixel (depth, the indices) is a "Pf" file, which read_pfm refused:
    # clray could not read back its own pass files.
    depth = np.arange(6, dtype=np.float32).reshape(2, 3)
    depth[1, 2] = np.inf
    path = tmp_path / "a.depth.pfm"
    path.write_bytes(image_io.pfm_bytes(depth))
    back = read_pfm(path)
    assert back.dtype == np.float32 and back.shape == (2, 3)
    np.testing.assert_array_equal(back, depth)


def test_pfm_layout_is_little_endian_bottom_row_first(tmp_path) -> None:
    image = np.zeros((2, 3, 3), dtype=np.float32)
    image[0] = 1.0  # top row
    path = tmp_path / "a.pfm"
    write_image(path, image)
    data = path.read_bytes()
    header = b"PF\n3 2\n-1.0\n"
    assert data.startswith(header)
    pixels = np.frombuffer(data[len(header):], dtype="<f4").reshape(2, 3, 3)
    assert (pixels[0] == 0).all() and (pixels[1] == 1).all()


def test_read_big_endian_pfm(tmp_path) -> None:
    image = np.arange(2 * 2 * 3, dtype=np.float32).reshape(2, 2, 3)
    path = tmp_path / "be.pfm"
    path.write_bytes(b"PF\n2 2\n1.0\n" + image[::-1].astype(">f4").tobytes())
    np.testing.assert_array_equal(read_pfm(path), image)


def test_read_pfm_rejects_truncated_and_unknown_files(tmp_path) -> None:
    short = tmp_path / "short.pfm"
    short.write_bytes(b"PF\n2 2\n-1.0\n" + bytes(8))
    with pytest.raises(ValueError, match="truncated"):
        read_pfm(short)
    short_grey = tmp_path / "short_grey.pfm"
    short_grey.write_bytes(b"Pf\n2 2\n-1.0\n" + bytes(12))
    with pytest.raises(ValueError, match="truncated"):
        read_pfm(short_grey)
    other = tmp_path / "other.pfm"
    other.write_bytes(b"P6\n1 1\n255\n" + bytes(3))
    with pytest.raises(ValueError, match=r"colour .* or greyscale"):
        read_pfm(other)
    # -2 x -2 asks for 12 values, as 2 x 2 does: the header's sizes, not the bytes, are wrong.
    negative = tmp_path / "negative.pfm"
    negative.write_bytes(b"PF\n-2 -2\n-1.0\n" + bytes(48))
    with pytest.raises(ValueError, match="positive width and height, got -2x-2"):
        read_pfm(negative)


def test_png_is_8bit_rgb_of_the_right_size(tmp_path) -> None:
    image = np.full((24, 32, 3), 0.5, dtype=np.float32)
    path = tmp_path / "a.png"
    write_image(path, image, LINEAR)
    with Image.open(path) as png:
        assert png.mode == "RGB" and png.size == (32, 24)
        assert (np.asarray(png) == 128).all()  # round(127.5) -> 128 (half to even)


def test_png_clamps_and_zeroes_nonfinite() -> None:
    image = np.array([[[-1.0, 2.0, np.nan], [np.inf, -np.inf, 0.2]]], dtype=np.float32)
    assert to_png_samples(image, LINEAR).tolist() == [[[0, 255, 0], [0, 0, 51]]]


def test_png_srgb_encoding() -> None:
    image = np.array([[[0.0, 0.001, 0.5], [0.2140, 1.0, 0.0031308]]])
    expected = np.rint(srgb_encode(image) * 255)
    assert (to_png_samples(image) == expected).all()  # sRGB is the default
    assert to_png_samples(image)[0, 0, 2] == 188  # 0.5 linear is 0.7354 encoded
    assert srgb_encode(np.array([0.001]))[0] == pytest.approx(0.01292)


@pytest.mark.parametrize("name", ["a.jpg", "a", "a.tiff"])
def test_unsupported_suffix_names_the_supported_ones(tmp_path, name) -> None:
    with pytest.raises(ValueError, match=r"\.png, \.pfm, \.exr"):
        write_image(tmp_path / name, np.zeros((1, 1, 3)))
    assert list(tmp_path.iterdir()) == []


def test_bad_shape_leaves_no_file(tmp_path) -> None:
    with pytest.raises(ValueError, match="shape"):
        write_image(tmp_path / "a.png", np.zeros((4, 4)))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("name", "problem"), [
    ("x.jpg", "unsupported image type '.jpg'"),
    ("noext", "no image type suffix"),
    (".", "no image type suffix"),
])
def test_unsupported_suffix_is_a_settings_error_naming_the_path(tmp_path, monkeypatch, name,
                                                                problem) -> None:
    # "." named an empty file name before (": unsupported image type ...").
    monkeypatch.chdir(tmp_path)
    for write in (lambda: write_image(name, np.zeros((1, 1, 3))),
                  lambda: RenderResult(np.zeros((1, 1, 3), np.float32), {}).save(name)):
        with pytest.raises(SettingsError) as info:
            write()
        assert str(info.value) == f"{name!r}: {problem}; use one of .png, .pfm, .exr"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("image", "got"), [
    (np.zeros((4, 4, 2)), "shape (4, 4, 2)"),
    (np.zeros((0, 4, 3)), "shape (0, 4, 3)"),
    (np.full((2, 2, 3), "a"), "dtype <U1"),
    (np.full((2, 2, 3), None), "dtype object"),
    (np.zeros((2, 2, 3), complex), "dtype complex128"),
    ([[[0, 0, 0]], [[0]]], "nested sequences of different lengths"),
])
@pytest.mark.parametrize("suffix", [".png", ".pfm", ".exr"])
def test_a_bad_image_is_a_settings_error_and_leaves_no_file(tmp_path, image, got,
                                                           suffix) -> None:
    for write in (lambda: write_image(tmp_path / f"a{suffix}", image),
                  lambda: RenderResult(image, {}, aovs={"depth": np.zeros((2, 2))}
                                       ).save(tmp_path / f"a{suffix}", previews=True)):
        with pytest.raises(SettingsError) as info:
            write()
        assert str(info.value).startswith("image: expected an (H, W")
        assert str(info.value).endswith(f"array of real numbers, got {got}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.int64, bool])
@pytest.mark.parametrize("suffix", [".png", ".pfm", ".exr"])
def test_an_integer_image_is_not_radiance_and_leaves_no_file(tmp_path, dtype, suffix) -> None:
    # An integer (or bool) array is most likely an image already encoded: its 8-bit codes were
    # written as radiance (a PNG of 200 saturated to 255, a PFM of 200.0) rather than refused.
    image = np.full((2, 2, 3), 200).astype(dtype)
    message = (f"image: expected floating-point linear radiance, got dtype "
               f"{np.dtype(dtype)} (an image already encoded?)")
    writes = [lambda: write_image(tmp_path / f"a{suffix}", image),
              lambda: RenderResult(image, {}, aovs={"depth": np.zeros((2, 2))}
                                   ).save(tmp_path / f"a{suffix}", previews=True)]
    if suffix != ".exr":
        writes.append(lambda: image_io.image_bytes(suffix, image))
    for write in writes:
        with pytest.raises(SettingsError) as info:
            write()
        assert str(info.value) == message
    assert list(tmp_path.iterdir()) == []
    # The same values as floats are radiance, written.
    write_image(tmp_path / "a.pfm", image.astype(np.float32))
    np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), image.astype(np.float32))


def test_an_encoding_that_is_not_an_encoding_is_a_settings_error(tmp_path) -> None:
    image = np.zeros((2, 2, 3), np.float32)
    for write in (lambda: write_image(tmp_path / "a.png", image, {"linear": True}),
                  lambda: RenderResult(image, {}, {"linear": True},
                                       {"depth": np.zeros((2, 2))}).save(tmp_path / "a.png")):
        with pytest.raises(SettingsError) as info:
            write()  # type: ignore[arg-type]
        assert str(info.value) == "encoding: expected a clray.image_io.Encoding, got dict"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SettingsError, match="png_bits must be 8 or 16"):
        Encoding(png_bits=12)


def test_write_replaces_existing_file_and_leaves_no_temp(tmp_path) -> None:
    path = tmp_path / "a.png"
    path.write_bytes(b"old")
    write_image(path, np.ones((2, 2, 3)))
    with Image.open(path) as png:
        assert (np.asarray(png) == 255).all()
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 1), (33, 17), (720, 1280)])
def test_png_bytes_decode_to_the_same_pixels(shape) -> None:
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    pixels = rng.integers(0, 256, size=(*shape, 3), dtype=np.uint8)
    pixels[0, 0] = [0, 255, 0]  # the extremes, where a wrong modulo would show
    with Image.open(io.BytesIO(png_bytes(pixels))) as png:
        assert png.mode == "RGB" and png.size == (shape[1], shape[0])
        np.testing.assert_array_equal(np.asarray(png), pixels)


def test_png_bytes_layout_is_plain_8bit_rgb() -> None:
    pixels = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    data = png_bytes(pixels)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, at = [], 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        assert struct.unpack(">I", data[at + 8 + length : at + 12 + length])[0] == zlib.crc32(
            kind + body
        )
        chunks.append((kind, body))
        at += 12 + length
    assert [kind for kind, _ in chunks] == [b"IHDR", b"sRGB", b"IDAT", b"IEND"]
    assert chunks[0][1] == struct.pack(">IIBBBBB", 3, 2, 8, 2, 0, 0, 0)
    assert chunks[1][1] == b"\x00"  # rendering intent: perceptual
    rows = np.frombuffer(zlib.decompress(chunks[2][1]), dtype=np.uint8).reshape(2, 10)
    # Row 1 holds its difference from row 0 (filter type 2, "Up"), modulo 256.
    assert rows[:, 0].tolist() == [2, 2]
    assert rows[0, 1:].tolist() == list(range(9))
    assert rows[1, 1:].tolist() == [9] * 9


def test_png_file_holds_the_converted_pixels(tmp_path) -> None:
    rng = np.random.default_rng(3)
    image = rng.uniform(-0.2, 1.2, size=(40, 60, 3)).astype(np.float32)
    image[5, 5] = np.nan
    for linear in (False, True):
        path = tmp_path / f"{linear}.png"
        write_image(path, image, Encoding(linear=linear))
        with Image.open(path) as png:
            np.testing.assert_array_equal(np.asarray(png),
                                          to_png_samples(image, Encoding(linear=linear)))


def test_srgb_table_gives_the_formulas_codes() -> None:
    # The default encoding of float32 images goes through a table; it must give exactly the
    # float64 formula's codes. Every bit pattern within 4096 of each step between two codes,
    # every 97th pattern in [0, 1], and the values the formula clamps or zeroes.
    _, starts_at = image_io._srgb8_table()
    steps = starts_at[starts_at > 0].astype(np.int64)
    assert len(steps) == 255  # one step into each code above 0
    near = (steps[:, None] + np.arange(-4096, 4096)).ravel()
    strided = np.arange(0, 0x3F800001, 97)
    bits = np.concatenate([near, strided]).astype(np.uint32)
    values = bits.view(np.float32)
    special = np.array([0.0, -0.0, 1.0, np.nextafter(1, 2), 3e38, np.inf, -np.inf, np.nan,
                        -1e-30, 1e-45, -1.0], dtype=np.float32)
    image = np.repeat(np.concatenate([values, special])[:, None, None], 3, axis=2)
    assert np.array_equal(image_io.to_png_samples(image),
                          image_io.to_png_samples(image.astype(np.float64)))


def test_table_encodes_slice_by_slice(monkeypatch):
    # An image of several slices (the last one short) gets the formula's codes everywhere:
    # the table's slices neither skip nor repeat samples.
    monkeypatch.setattr(image_io, "_ENCODE_SLICE", 7)
    rng = np.random.default_rng(5)
    image = rng.uniform(-0.2, 1.3, (5, 9, 3)).astype(np.float32)
    image[0, 0] = [np.nan, np.inf, -np.inf]
    samples = image_io.to_png_samples(image)
    np.testing.assert_array_equal(samples, image_io._encode_float64(image, Encoding()))


@pytest.mark.parametrize(("suffix", "encoding"), [
    (".png", Encoding()), (".png", Encoding(png_bits=16)), (".png", Encoding(exposure=1)),
    (".png", Encoding(linear=True)), (".png", Encoding(linear=True, png_bits=16)),
    (".png", Encoding(exposure=-1, png_bits=16)), (".pfm", Encoding()), (".exr", Encoding())],
    ids=["png", "png16", "png-exposure", "png-linear", "png16-linear", "png16-exposure", "pfm",
         "exr"])
def test_image_host_bytes_bound_the_writers_memory(suffix, encoding, tmp_path):
    # image_host_bytes' figure a pixel bounds what writing an image takes beside it (numpy's
    # and Python's allocations, which tracemalloc sees), for an image that compresses badly and
    # is larger than the PNG table's slice of samples (whose temporaries do not grow with it).
    # Every PNG encoding: the formula's, for all but the default, took 99 bytes a pixel where
    # the figure said 18, and 16-bit PNG 39.
    import tracemalloc

    if suffix == ".exr":
        pytest.importorskip("OpenEXR")
    height, width = 768, 1024
    image = np.random.default_rng(2).uniform(-0.1, 1.3, (height, width, 3)).astype(np.float32)
    write_image(tmp_path / f"warm{suffix}", image[:1, :1])  # the PNG table is built once
    tracemalloc.start()
    try:
        write_image(tmp_path / f"a{suffix}", image, encoding)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= (image_io.image_host_bytes(width, height, suffix, encoding.png_bits)
                    - image.nbytes)
    assert image_io.image_host_bytes(width, height, suffix) == (
        image.nbytes + image_io.WRITE_BYTES[suffix] * height * width)


def test_image_bytes_refuses_exr_which_openexr_writes_as_a_file() -> None:
    # Not a PNG under an .exr name: OpenEXR's package writes files, not bytes (write_image).
    with pytest.raises(SettingsError, match=r"expected '\.png' or '\.pfm', got '\.exr'"):
        image_io.image_bytes(".exr", np.zeros((1, 1, 3), np.float32))


def test_formula_and_png_rows_slice_by_slice(monkeypatch):
    # Slices of a few rows (the last one short) give the codes and the file of the whole image
    # at once: the slices neither skip nor repeat rows, and each slice's first row is filtered
    # against the row above it.
    rng = np.random.default_rng(6)
    image = rng.uniform(-0.2, 1.3, (7, 5, 3)).astype(np.float32)
    encoding = Encoding(exposure=0.5, png_bits=16)
    whole = image_io.image_bytes(".png", image, encoding)
    monkeypatch.setattr(image_io, "_FORMULA_SLICE", 2 * 5 * 3)
    monkeypatch.setattr(image_io, "_ENCODE_SLICE", 3 * 5 * 3 * 2)
    np.testing.assert_array_equal(image_io.to_png_samples(image, encoding),
                                  image_io._encode_float64(image, encoding))
    assert image_io.image_bytes(".png", image, encoding) == whole
