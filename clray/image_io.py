"""Image files: PNG (8- or 16-bit) for looking at, float32 PFM and OpenEXR for measuring.

Rendered images are (H, W, 3) float32 linear radiance with row 0 at the top. PNG output goes
through the colour pipeline of docs/rendering.md (exposure, clamp to [0, 1], sRGB curve unless
linear) and is tagged so that viewers know its encoding; PFM and EXR keep every value as
rendered, non-finite ones included, so tests and studies can count them.
Files are written to a temporary name in the target directory and renamed into place, so a
reader never sees a half-written image; a symlink's target is written, not the link, and a
device or pipe (/dev/stdout) is written directly.
"""

from __future__ import annotations

import errno
import functools
import io
import numbers
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clray.errors import ClrayError, SettingsError
from clray.metrics import per_pixel
from clray.output import WriteSet, write_set
from clray.scene import limits
from clray.scene.colour import srgb_encode

SUFFIXES = (".png", ".pfm", ".exr")
FLOAT_SUFFIXES = (".pfm", ".exr")
PNG_BITS = limits.PNG_BITS
EXPOSURE_RULE = f"a number of stops in [{-limits.MAX_EXPOSURE:g}, {limits.MAX_EXPOSURE:g}]"
EXR_MISSING = "writing .exr needs the OpenEXR package: pip install 'clray[exr]'"


def check_suffix(path: str | Path) -> str:
    """The lower-case suffix of `path`, or SettingsError (a ValueError) naming the path and
    the supported suffixes."""
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        # The whole path as given, quoted: its name alone is empty for "." or "dir/".
        what = f"unsupported image type {suffix!r}" if suffix else "no image type suffix"
        raise SettingsError(f"{os.fspath(path)!r}: {what}; use one of {', '.join(SUFFIXES)}")
    return suffix


@dataclass(frozen=True)
class Encoding:
    """How PNG output encodes linear radiance (docs/rendering.md); PFM and EXR ignore it.

    linear: False writes the sRGB curve (tagged with an sRGB chunk), True writes linear values
    (tagged gAMA 1.0). exposure: stops; PNG values are radiance * 2**exposure before the clamp.
    png_bits: 8 or 16 bits a sample.
    """

    linear: bool = False
    exposure: float = 0.0
    png_bits: int = 8

    def __post_init__(self) -> None:
        if not isinstance(self.linear, bool):
            raise SettingsError(f"linear must be True or False, got {self.linear!r}")
        if not is_exposure(self.exposure):
            raise SettingsError(f"exposure must be {EXPOSURE_RULE}, got {self.exposure!r}")
        if (isinstance(self.png_bits, bool) or not isinstance(self.png_bits, numbers.Integral)
                or self.png_bits not in PNG_BITS):
            raise SettingsError(f"png_bits must be 8 or 16, got {self.png_bits!r}")


def is_exposure(value: object) -> bool:
    """Whether `value` is an exposure in stops (EXPOSURE_RULE), however it arrives."""
    # The bound alone, which NaN and the infinities fail too (math.isfinite raises on a Python
    # int past a float's range).
    return (not isinstance(value, bool) and isinstance(value, numbers.Real)
            and abs(value) <= limits.MAX_EXPOSURE)


def as_pixels(values: object, name: str = "image", grey: bool = False) -> np.ndarray:
    """`values` as an (H, W, 3) array of real numbers, or with `grey` (H, W) too; SettingsError
    naming the argument `name` for anything else. Complex values, strings, dates and objects
    are refused, not cast: numpy would drop imaginary parts, fail on text with its own
    ValueError, and turn None into NaN."""
    shapes = "(H, W) or (H, W, 3)" if grey else "(H, W, 3)"
    try:
        pixels = np.asarray(values)
    except ValueError:  # nested sequences of different lengths
        raise SettingsError(f"{name}: expected an {shapes} array of real numbers, got "
                            f"nested sequences of different lengths") from None
    if pixels.dtype.kind not in "biuf":
        raise SettingsError(f"{name}: expected an {shapes} array of real numbers, got "
                            f"dtype {pixels.dtype}")
    if (pixels.ndim not in ((2, 3) if grey else (3,))
            or (pixels.ndim == 3 and pixels.shape[2] != 3) or 0 in pixels.shape):
        raise SettingsError(f"{name}: expected an {shapes} array of real numbers, got shape "
                            f"{pixels.shape}")
    return pixels


def as_radiance(values: object, name: str = "image") -> np.ndarray:
    """`values` as an (H, W, 3) array of linear radiance (as_pixels), which must be floating
    point: SettingsError for integers or bools, most likely an image already encoded (8-bit
    codes, say), which would be written as if each code were radiance."""
    pixels = as_pixels(values, name)
    if pixels.dtype.kind != "f":
        raise SettingsError(f"{name}: expected floating-point linear radiance, got dtype "
                            f"{pixels.dtype} (an image already encoded?)")
    return pixels


def _encode_float64(values: np.ndarray, encoding: Encoding) -> np.ndarray:
    """to_png_samples by the formula, in float64."""
    values = np.array(values, dtype=np.float64)
    np.nan_to_num(values, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    if encoding.exposure:
        values *= 2.0 ** encoding.exposure
    np.clip(values, 0.0, 1.0, out=values)
    if not encoding.linear:
        values = srgb_encode(values)
    top = (1 << encoding.png_bits) - 1
    values *= top
    return np.rint(values, out=values).astype(np.uint8 if top == 255 else np.uint16)


# The default encoding (8-bit sRGB, no exposure) of float32 values by table: the code of a value
# in [0, 1] is a non-decreasing step function of its bit pattern, and over a bucket of 2**15
# consecutive patterns (0.4 % of the value) the curve moves by less than one code, so each
# bucket needs its code at the top and the first pattern, if any, where that code starts. Both
# are found with the float64 formula itself, so the table gives exactly its codes: checked for
# every float32 in [0, 1] (tests/test_image_io.py checks every pattern near each step). The
# buckets cover every 32-bit pattern, so the values the formula clamps (finite above 1: 255) or
# zeroes (negatives, infinities, NaN) need no pass of their own.
_BUCKET_SHIFT = 15
_ONE_BITS = 0x3F800000  # 1.0f
_INF_BITS = 0x7F800000
# Samples the table encodes at a time (_srgb8_by_table), and bytes of rows png_bytes swaps.
_ENCODE_SLICE = 1 << 20
# Samples the formula encodes at a time (to_png_samples): its float64 temporaries take about
# 40 bytes a sample.
_FORMULA_SLICE = 1 << 16


@functools.cache
def _srgb8_table() -> tuple[np.ndarray, np.ndarray]:
    """(uint8 code at the top of each bucket, uint32 first pattern of that code where it starts
    inside the bucket, else 0)."""
    default = Encoding()
    unit = _ONE_BITS >> _BUCKET_SHIFT  # buckets below 1.0; bucket `unit` starts at 1.0
    starts = np.arange(unit + 1, dtype=np.int64) << _BUCKET_SHIFT

    def code(bits: np.ndarray) -> np.ndarray:
        return _encode_float64(bits.astype(np.uint32).view(np.float32), default)

    first = code(starts)
    step = np.flatnonzero(first[1:] > first[:-1])  # buckets whose next code starts in them
    lo, hi = starts[step], starts[step + 1]  # the next code starts in (lo, hi]
    for _ in range(_BUCKET_SHIFT + 1):
        mid = (lo + hi) // 2
        up = code(mid) > first[step]
        hi = np.where(up, mid, hi)
        lo = np.where(up, lo, mid)
    inside = hi < starts[step + 1]  # a code starting at the next bucket belongs to that one
    top = np.zeros(1 << (32 - _BUCKET_SHIFT), dtype=np.uint8)
    top[:unit + 1] = first
    top[step[inside]] += 1
    top[unit:_INF_BITS >> _BUCKET_SHIFT] = 255
    starts_at = np.zeros(len(top), dtype=np.uint32)
    starts_at[step[inside]] = hi[inside]
    return top, starts_at


def _srgb8_by_table(values: np.ndarray) -> np.ndarray:
    bits = np.ascontiguousarray(values, dtype=np.float32).view(np.uint32)
    top, starts_at = _srgb8_table()
    codes = np.empty(bits.shape, dtype=top.dtype)
    flat_bits, flat_codes = bits.reshape(-1), codes.reshape(-1)
    # A slice at a time: the whole image's buckets and thresholds (10 bytes a sample) would
    # take more memory than the float image itself (a 16384 x 16384 image: 6 GiB more).
    for start in range(0, flat_bits.size, _ENCODE_SLICE):
        part = flat_bits[start:start + _ENCODE_SLICE]
        bucket = part >> _BUCKET_SHIFT
        # One code below the bucket's top where the top's code starts later in it (never where
        # it starts at 0).
        np.subtract(top[bucket], part < starts_at[bucket],
                    out=flat_codes[start:start + _ENCODE_SLICE])
    return codes


def to_png_samples(image: np.ndarray, encoding: Encoding = Encoding()) -> np.ndarray:
    """(H, W, 3) uint8 or uint16 PNG samples: non-finite -> 0, times 2**exposure, clamp to
    [0, 1] per channel, sRGB curve unless linear, then round to the nearest code. The float64
    formula, or for float32 images in the default encoding a table that gives its codes
    exactly, twice as fast."""
    image = as_pixels(image)
    if image.dtype == np.float32 and encoding == Encoding():
        return _srgb8_by_table(image)
    # Rows at a time, as the table does: the formula's float64 copy and the sRGB curve's
    # temporaries of the whole image would take several times the float image (99 bytes a
    # pixel at the peak, against the table's 18).
    samples = np.empty(image.shape, dtype=np.uint8 if encoding.png_bits == 8 else np.uint16)
    rows = max(1, _FORMULA_SLICE // (image.shape[1] * 3))
    for top in range(0, image.shape[0], rows):
        samples[top:top + rows] = _encode_float64(image[top:top + rows], encoding)
    return samples


def clipped_pixels(image: np.ndarray, exposure: float = 0.0) -> int:
    """Pixels a PNG clamps: a finite channel above 1 after the exposure."""
    scaled = as_pixels(image)
    if exposure != 0 or scaled.dtype != np.float32:
        scaled = np.asarray(scaled, dtype=np.float64) * 2.0 ** exposure
    # Both comparisons are false for NaN.
    return int(np.count_nonzero(per_pixel((scaled > 1.0) & (scaled < np.inf))))


def _png_chunk(kind: bytes, *pieces: bytes) -> list[bytes]:
    """A chunk of data `pieces`, as pieces: png_bytes joins them all once, where concatenating
    them would copy the image's compressed data again, more than once."""
    crc = zlib.crc32(kind)
    for piece in pieces:
        crc = zlib.crc32(piece, crc)
    return [struct.pack(">I", sum(map(len, pieces))) + kind, *pieces, struct.pack(">I", crc)]


def png_bytes(pixels: np.ndarray, linear: bool = False) -> bytes:
    """RGB PNG of (H, W, 3) uint8 (8-bit) or uint16 (16-bit) samples, tagged with the
    encoding: an sRGB chunk, or for linear samples gAMA 1.0 so that viewers do not take them
    for sRGB (an untagged PNG is read as sRGB).

    Written here rather than by Pillow, whose per-row adaptive filter choice and default
    zlib level take several times as long for a 1280x720 frame (and which cannot write
    16-bit RGB): every row uses the "Up" filter (difference from the row above, one numpy
    subtraction, byte by byte as PNG defines it for any depth), which suits rendered images,
    and zlib level 1 compresses that to within a few per cent of the default.
    """
    pixels = as_pixels(pixels, "pixels")
    if pixels.dtype not in (np.uint8, np.uint16):
        raise SettingsError(f"pixels: expected uint8 or uint16 samples, got {pixels.dtype}")
    bits = 8 * pixels.dtype.itemsize
    height, width, _ = pixels.shape
    row_bytes = width * 3 * pixels.dtype.itemsize
    # Rows a slice at a time, each slice's big-endian samples (PNG's order) filtered and
    # compressed before the next: beside the samples and the file, memory holds only the
    # compressed data, never the whole image again in PNG's order or filtered.
    packer = zlib.compressobj(1)
    compressed = []
    step = max(1, _ENCODE_SLICE // row_bytes)
    for top in range(0, height, step):
        above = max(top - 1, 0)  # the row above the slice, which its first row's filter takes
        rows = np.ascontiguousarray(pixels[above:top + step],
                                    dtype=pixels.dtype.newbyteorder(">"))
        rows = rows.view(np.uint8).reshape(-1, row_bytes)
        filtered = np.empty((min(step, height - top), row_bytes + 1), dtype=np.uint8)
        filtered[:, 0] = 2  # filter type Up
        if top == 0:
            filtered[0, 1:] = rows[0]
        np.subtract(rows[1:], rows[:-1], out=filtered[len(filtered) + 1 - len(rows):, 1:])
        compressed.append(packer.compress(filtered.data))  # modulo 256 above, as PNG wants
    compressed.append(packer.flush())
    del rows, filtered  # the last slice's, not to be held while the file is joined
    header = struct.pack(">IIBBBBB", width, height, bits, 2, 0, 0, 0)  # RGB, no interlace
    # gAMA holds 100000 / gamma; sRGB's one byte is the rendering intent (0, perceptual).
    tag = (_png_chunk(b"gAMA", struct.pack(">I", 100000)) if linear
           else _png_chunk(b"sRGB", b"\x00"))
    return b"".join((
        b"\x89PNG\r\n\x1a\n",
        *_png_chunk(b"IHDR", header),
        *tag,
        *_png_chunk(b"IDAT", *compressed),
        *_png_chunk(b"IEND"),
    ))


def pfm_bytes(image: np.ndarray) -> bytes:
    """Colour PFM of an (H, W, 3) image, or greyscale ("Pf") of an (H, W) one (a pass of one
    number a pixel), little-endian (negative scale), rows stored bottom to top as the format
    says."""
    pixels = as_pixels(image, grey=True).astype("<f4", copy=False)
    grey = pixels.ndim == 2
    height, width = pixels.shape[:2]
    header = f"{'Pf' if grey else 'PF'}\n{width} {height}\n-1.0\n".encode("ascii")
    return header + np.ascontiguousarray(pixels[::-1]).tobytes()


def read_pfm(path: str | Path) -> np.ndarray:
    """float32 with row 0 at the top: (H, W, 3) from a colour ("PF") file, (H, W) from a
    greyscale ("Pf") one, as pfm_bytes writes a pass of one number a pixel (depth, indices)."""
    data = Path(path).read_bytes()
    stream = io.BytesIO(data)
    try:
        kind = stream.readline().strip()
        width, height = (int(v) for v in stream.readline().split())
        scale = float(stream.readline().strip())
    except ValueError as err:
        raise ValueError(f"{Path(path).name}: not a PFM header") from err
    if width < 1 or height < 1:
        raise ValueError(f"{Path(path).name}: expected a positive width and height, got {width}x"
                         f"{height}")
    if kind not in (b"PF", b"Pf"):
        raise ValueError(f"{Path(path).name}: expected a colour ('PF') or greyscale ('Pf') "
                         f"PFM, got {kind[:8]!r}")
    dtype = "<f4" if scale < 0 else ">f4"
    shape = (height, width) if kind == b"Pf" else (height, width, 3)
    count = int(np.prod(shape))
    offset = stream.tell()
    if len(data) - offset < 4 * count:
        raise ValueError(f"{Path(path).name}: truncated PFM ({width}x{height} needs {4 * count} "
                         f"bytes of pixels, has {len(data) - offset})")
    pixels = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    return pixels.reshape(shape)[::-1].astype(np.float32)


def write_exr(name: str, image: np.ndarray, channels: dict[str, np.ndarray] | None = None
              ) -> None:
    """Float32 RGB OpenEXR at the file name `name`, ZIP-compressed, with more float32
    `channels` of the image's size by their full names (a layer's, "depth.Z"); needs the
    optional OpenEXR package, which writes to a file name (to streams only in its newest
    releases): add_image gives it the temporary name of the file it becomes. The package's
    RuntimeError for a write that failed (a full disk) as an OSError naming `name`, as a
    failed write of another format's bytes would be."""
    try:
        import OpenEXR
    except ImportError:
        raise ClrayError(EXR_MISSING) from None
    pixels = np.ascontiguousarray(as_pixels(image), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    more = {channel: np.ascontiguousarray(values, dtype=np.float32)
            for channel, values in (channels or {}).items()}
    try:
        OpenEXR.File(header, {"RGB": pixels, **more}).write(name)
    except RuntimeError as err:
        # 'Failed to write pixel data to image file "NAME". No space left on device.': the
        # name is the caller's to give (a temporary one, which the user never named).
        words = str(err).replace(f' "{name}"', "").rstrip(".")
        raise OSError(errno.EIO, f"OpenEXR: {words}", name) from None


# Host bytes a pixel: the (H, W, 3) float32 image a render returns, and at most what writing it
# takes beside it, tracemalloc's peak of write_image (tests/test_image_io.py checks them, the
# PNG's for each encoding). A PNG holds its samples, their compressed data and the file, each
# twice as large at 16 bits. OpenEXR writes its file from the image's own memory, with buffers
# of its own that tracemalloc does not see (under half a byte a pixel, by the process's peak).
FLOAT_IMAGE_BYTES = 12
WRITE_BYTES = {".png": 18, ".pfm": 26, ".exr": 1}
PNG16_WRITE_BYTES = 20


def image_host_bytes(width: int, height: int, suffix: str, png_bits: int = 8) -> int:
    """About the most host memory a render's image of width x height takes, from the float
    image to its file written as `suffix` (.png, .pfm or .exr; a PNG of `png_bits` bits a
    sample)."""
    write = PNG16_WRITE_BYTES if suffix == ".png" and png_bits == 16 else WRITE_BYTES[suffix]
    return width * height * (FLOAT_IMAGE_BYTES + write)


def check_writer(path: str | Path) -> str:
    """The suffix of `path` (check_suffix), or ClrayError if the format it picks cannot be
    written here, so that the command can tell before rendering."""
    suffix = check_suffix(path)
    if suffix == ".exr":
        try:
            import OpenEXR  # noqa: F401
        except ImportError:
            raise ClrayError(EXR_MISSING) from None
    return suffix


def check_encoding(encoding: object) -> None:
    """SettingsError unless `encoding` is an Encoding: a dict of its fields would fail later,
    with an AttributeError, and only for PNG."""
    if not isinstance(encoding, Encoding):
        raise SettingsError(f"encoding: expected a clray.image_io.Encoding, got "
                            f"{type(encoding).__name__}")


def write_image(path: str | Path, image: np.ndarray, encoding: Encoding = Encoding()) -> None:
    """Write `image`, (H, W, 3) floating-point linear radiance, as PNG, PFM or EXR, chosen by
    the suffix of `path`.

    `encoding` applies to PNG only: PFM and EXR always hold the linear values as rendered.
    """
    with write_set() as files:
        add_image(files, path, image, encoding)


def add_image(files: WriteSet, path: str | Path, image: np.ndarray,
              encoding: Encoding = Encoding(), channels: dict[str, np.ndarray] | None = None
              ) -> None:
    """The file write_image writes, added to `files` (PNG and PFM as bytes, OpenEXR written by
    its package at the file's temporary name), with an OpenEXR image's more `channels`
    (write_exr). Bad arguments (an image that is not floating-point radiance, as_radiance),
    and a missing OpenEXR package, are refused before any file."""
    suffix = check_writer(path)
    check_encoding(encoding)
    if suffix == ".exr":
        pixels = as_radiance(image)
        files.add_written(path, lambda name: write_exr(name, pixels, channels))
    else:
        files.add(path, image_bytes(suffix, image, encoding))


def image_bytes(suffix: str, image: np.ndarray, encoding: Encoding = Encoding()) -> bytes:
    """The file `write_image` writes for `suffix` .png or .pfm, as bytes (OpenEXR's package
    writes files: write_exr); SettingsError for an image that is not floating-point radiance
    (as_radiance)."""
    check_encoding(encoding)
    if suffix not in (".png", ".pfm"):
        raise SettingsError(f"image_bytes: expected '.png' or '.pfm', got {suffix!r}")
    image = as_radiance(image)
    if suffix == ".pfm":
        return pfm_bytes(image)
    return png_bytes(to_png_samples(image, encoding), linear=encoding.linear)
