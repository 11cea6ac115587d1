"""Image files: 8-bit PNG for looking at, float32 PFM for measuring.

Rendered images are (H, W, 3) float32 linear radiance with row 0 at the top. PNG clamps them;
PFM keeps every value, non-finite ones included, so tests and studies can count them.
Files are written to a temporary name in the target directory and renamed into place, so a
reader never sees a half-written image; a symlink's target is written, not the link, and a
device or pipe (/dev/stdout) is written directly.
"""

from __future__ import annotations

import io
import os
import secrets
import stat
import struct
import zlib
from pathlib import Path

import numpy as np

SUFFIXES = (".png", ".pfm")


def check_suffix(path: str | Path) -> str:
    """The lower-case suffix of `path`, or ValueError naming the supported ones."""
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(
            f"{Path(path).name}: unsupported image type {suffix or '(no suffix)'!r}; "
            f"use one of {', '.join(SUFFIXES)}"
        )
    return suffix


def _as_rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    return image


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function for values already in [0, 1]."""
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(linear, 1.0 / 2.4) - 0.055)


def to_png_bytes(image: np.ndarray, srgb: bool = False) -> np.ndarray:
    """(H, W, 3) uint8: non-finite -> 0, clamp to [0, 1], optional sRGB, then round(255 v)."""
    values = np.array(_as_rgb(image), dtype=np.float64)
    np.nan_to_num(values, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    np.clip(values, 0.0, 1.0, out=values)
    if srgb:
        values = srgb_encode(values)
    values *= 255.0
    return np.rint(values, out=values).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bytes(pixels: np.ndarray) -> bytes:
    """8-bit RGB PNG of (H, W, 3) uint8 pixels, no other chunks.

    Written here rather than by Pillow, whose per-row adaptive filter choice and default
    zlib level take several times as long for a 1280x720 frame: every row uses the "Up"
    filter (difference from the row above, one numpy subtraction), which suits rendered
    images, and zlib level 1 compresses that to within a few per cent of the default.
    """
    pixels = np.ascontiguousarray(_as_rgb(pixels), dtype=np.uint8)
    height, width, _ = pixels.shape
    rows = pixels.reshape(height, width * 3)
    filtered = np.empty((height, width * 3 + 1), dtype=np.uint8)
    filtered[:, 0] = 2  # filter type Up
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # modulo 256, as PNG wants
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, no interlace
    return b"".join((
        b"\x89PNG\r\n\x1a\n",
        _png_chunk(b"IHDR", header),
        _png_chunk(b"IDAT", zlib.compress(filtered.tobytes(), 1)),
        _png_chunk(b"IEND", b""),
    ))


def pfm_bytes(image: np.ndarray) -> bytes:
    """Colour PFM, little-endian (negative scale), rows stored bottom to top as the format says."""
    pixels = np.asarray(_as_rgb(image), dtype="<f4")
    height, width, _ = pixels.shape
    header = f"PF\n{width} {height}\n-1.0\n".encode("ascii")
    return header + np.ascontiguousarray(pixels[::-1]).tobytes()


def read_pfm(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 with row 0 at the top; greyscale ("Pf") files are not accepted."""
    data = Path(path).read_bytes()
    stream = io.BytesIO(data)
    try:
        kind = stream.readline().strip()
        width, height = (int(v) for v in stream.readline().split())
        scale = float(stream.readline().strip())
    except ValueError as err:
        raise ValueError(f"{Path(path).name}: not a PFM header") from err
    if kind != b"PF":
        raise ValueError(f"{Path(path).name}: expected a colour PFM ('PF'), got {kind[:8]!r}")
    dtype = "<f4" if scale < 0 else ">f4"
    count = width * height * 3
    offset = stream.tell()
    if len(data) - offset < 4 * count:
        raise ValueError(f"{Path(path).name}: truncated PFM ({width}x{height} needs {4 * count} "
                         f"bytes of pixels, has {len(data) - offset})")
    pixels = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    return pixels.reshape(height, width, 3)[::-1].astype(np.float32)


def output_target(path: str | Path) -> Path:
    """Where writing `path` lands: a symlink's final target (its folder must take the file),
    else `path` itself. Writing there keeps the link a link and never writes elsewhere."""
    path = Path(path)
    try:
        linked = path.is_symlink()
    except (OSError, ValueError):  # a name the system refuses: the writer reports it
        return path
    return Path(os.path.realpath(path)) if linked else path


def is_special_file(path: Path) -> bool:
    """An existing file that is not a regular file: a device (/dev/stdout), a pipe."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def write_bytes_atomically(path: str | Path, payload: bytes) -> None:
    """Write `payload` so that `path` is either untouched or complete, never partial.

    Through a symlink the target is replaced, not the link. A device or pipe cannot be
    replaced by a rename (it would become a regular file): it is written directly."""
    path = output_target(path)
    if is_special_file(path):
        with open(path, "wb") as stream:
            stream.write(payload)
        return
    # Same directory, so os.replace is a rename on one file system; created with 0o666 rather
    # than through mkstemp so the finished file gets the usual umask-derived permissions.
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as stream:
            stream.write(payload)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_image(path: str | Path, image: np.ndarray, srgb: bool = False) -> None:
    """Write `image` as PNG or PFM, chosen by the suffix of `path`.

    `srgb` applies to PNG only: PFM always holds linear values.
    """
    path = Path(path)
    if check_suffix(path) == ".pfm":
        payload = pfm_bytes(image)
    else:
        payload = png_bytes(to_png_bytes(image, srgb))
    write_bytes_atomically(path, payload)
