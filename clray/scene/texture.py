"""Image texture files -> (H, W, 3) float32 texels in [0, 1] as stored, row 0 at the top.

The image's declared size is checked against the limits before any pixel is decoded: a PNG of
a few hundred bytes can declare 100000 x 100000 pixels. 16-bit images are scaled to [0, 1]
(Pillow's conversion to 8-bit RGB would clip them), float images are clipped to [0, 1]. The
loader then decodes sRGB files to linear (clray.scene.assets, docs/rendering.md).
"""

from __future__ import annotations

import contextlib
import os
import struct
import sys
import tempfile
import warnings
from collections.abc import Iterator
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from clray.errors import plural
from clray.scene import limits as L

if TYPE_CHECKING:
    from PIL.Image import Image

_SIXTEEN_BIT = ("I;16", "I;16L", "I;16B", "I;16N")
COLORSPACES = ("srgb", "linear")  # what a texture file's values are
_MAX_CAPTURED = 4096  # bytes of libtiff's messages kept for the warnings


class TextureError(Exception):
    """A one-line reason, for the loader to put into a SceneError with its key."""


def read_texture(stream: BinaryIO, texels_left: int) -> tuple[np.ndarray, bool, list[str]]:
    """(texels, deep, warnings) of the image in `stream`, if its size is within the limits and
    within `texels_left` (what the scene's earlier textures left of MAX_TEXELS). `deep`: the
    file holds more than 8 bits a sample (16-bit or float), which the loader takes as linear."""
    from PIL import Image  # only scenes with image textures pay for importing Pillow

    with warnings.catch_warnings(record=True) as caught, _c_stderr() as printed:
        warnings.simplefilter("always")
        try:
            with Image.open(stream) as img:
                check_size(img.size, texels_left)
                deep = _is_deep(img)
                texels = _texels(img)
        except TextureError:
            raise
        except Image.DecompressionBombError:
            # Pillow refuses before telling the size; its threshold is above both of ours.
            raise TextureError(
                f"image is over the limits of {L.MAX_TEXTURE_SIDE} pixels a side and "
                f"{L.MAX_TEXELS} texels"
            ) from None
        except MemoryError:
            raise TextureError("out of memory while decoding the image") from None
        except Exception as exc:
            # Pillow's format plugins raise many types on malformed files (OSError,
            # SyntaxError, struct.error, EOFError, IndexError, ...): all mean a bad file.
            raise TextureError(_bad_file(exc)) from None
    told = [str(w.message) for w in caught if _worth_telling(w)]
    return texels, deep, told + [f"libtiff: {line}" for line in printed if line.strip()]


def _bad_file(exc: Exception) -> str:
    """What Pillow's exception says is wrong with the file, in words and without the type's
    name: the user can act on "truncated", not on "OSError"."""
    from PIL import UnidentifiedImageError

    text = str(exc).strip()
    if isinstance(exc, UnidentifiedImageError):
        # Its text names the stream object ("<_io.BufferedReader name=...>"), not the problem.
        return "not an image in a format Pillow reads, or its header is damaged"
    if isinstance(exc, (EOFError, struct.error)) or "truncated" in text.lower():
        # "image file is truncated (12 bytes not processed)", "Truncated File Read", or a
        # header field read past the end ("unpack requires a buffer of 4 bytes").
        return "the file is truncated (it ends before its image data does)"
    return f"the image data is damaged or unsupported ({text})" if text else \
        "the image data is damaged or unsupported"


@contextlib.contextmanager
def _c_stderr() -> Iterator[list[str]]:
    """The lines C code (libtiff, inside Pillow) prints straight to file descriptor 2 while
    the block runs, captured so that they can be told as clray warnings instead."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield lines
            finally:
                os.dup2(saved, 2)
                sink.seek(0)
                lines.extend(sink.read(_MAX_CAPTURED).decode("utf-8", "replace").splitlines())
    finally:
        os.close(saved)


def _worth_telling(warning: warnings.WarningMessage) -> bool:
    from PIL import Image

    # The size limit is ours and stricter, and alpha is dropped, so Pillow's advice about
    # converting palette transparency to RGBA does not apply.
    if issubclass(warning.category, Image.DecompressionBombWarning):
        return False
    return "Transparency expressed in bytes" not in str(warning.message)


def check_size(size: tuple[int, int], texels_left: int) -> None:
    """TextureError if an image of `size` (width, height) is over the limits or over
    `texels_left`."""
    width, height = size
    if width < 1 or height < 1:
        raise TextureError(f"image has no pixels ({width}x{height})")
    if max(width, height) > L.MAX_TEXTURE_SIDE:
        raise TextureError(
            f"image is {width}x{height}, over the limit of {L.MAX_TEXTURE_SIDE} pixels a side"
        )
    if width * height > texels_left:
        raise TextureError(
            f"image is {width}x{height} = {plural(width * height, 'texel')}, over what is left "
            f"({texels_left}) of the limit of {L.MAX_TEXELS} texels for all textures"
        )


def _is_deep(img: Image) -> bool:
    # Pillow opens a 16-bit RGB(A) PNG or TIFF as 8-bit "RGB"; only the raw mode of its
    # undecoded tiles ("RGB;16B") still tells the file's depth.
    if img.mode in _SIXTEEN_BIT or img.mode in ("I", "F"):
        return True
    return any(";16" in str(tile.args) for tile in img.tile)


def _texels(img: Image) -> np.ndarray:
    if img.mode in _SIXTEEN_BIT or img.mode == "I":
        grey = np.asarray(img).astype(np.float32)
        grey = np.clip(grey, 0.0, 65535.0) / np.float32(65535.0)
    elif img.mode == "F":
        grey = np.nan_to_num(np.asarray(img, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        grey = np.clip(grey, 0.0, 1.0)
    else:
        rgb = np.asarray(img.convert("RGB"), dtype=np.float32)
        return np.ascontiguousarray(rgb / np.float32(255.0))
    return np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2), dtype=np.float32)
