"""Denoising a rendered image with Intel Open Image Denoise (docs/denoising.md), through the
pyoidn binding, an optional extra: OIDN's RT filter on the linear image, guided by the albedo
and normal passes where given."""

from __future__ import annotations

import numpy as np

from clray.errors import ClrayError

DENOISE_GUIDES = ("albedo", "normal")  # the passes that guide OIDN's RT filter
DENOISE_MISSING = "denoising needs Open Image Denoise's binding: pip install 'clray[denoise]'"


def _binding():
    try:
        import pyoidn
    except ImportError:
        raise ClrayError(DENOISE_MISSING) from None
    return pyoidn


def check_denoiser() -> None:
    """Raise ClrayError naming the extra if the binding is missing, so that a command can tell
    before rendering."""
    _binding()


def _guide(name: str, values: np.ndarray | None, shape: tuple[int, ...], low: float
           ) -> np.ndarray | None:
    """A guide pass as OIDN takes it: the image's shape, float32, finite, within [low, 1]."""
    if values is None:
        return None
    values = np.asarray(values)
    if values.shape != shape:
        raise ValueError(f"the {name} pass has shape {values.shape}; the image has {shape}")
    return np.clip(np.nan_to_num(values.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0),
                   low, 1.0)


def denoise(image: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None) -> np.ndarray:
    """The (H, W, 3) linear image denoised by OIDN's RT filter for HDR input, as float32.

    albedo (linear, [0, 1]) and normal (unit vectors, any fixed space) are the render's passes
    of the same shape; OIDN takes the normal only together with the albedo. A non-finite value
    of the image counts as black, as in a PNG (docs/rendering.md): a neural filter would spread
    one NaN over its whole neighbourhood. Raises ClrayError naming the extra when the binding is
    missing, ValueError for shapes that do not match."""
    pyoidn = _binding()
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    if normal is not None and albedo is None:
        raise ValueError("Open Image Denoise takes the normal pass only with the albedo pass")
    # HDR colour must be finite and non-negative for the filter.
    colour = np.clip(np.nan_to_num(image.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0),
                     0.0, None)
    try:
        return np.asarray(pyoidn.denoise(colour, albedo=_guide("albedo", albedo, image.shape, 0.0),
                                         normal=_guide("normal", normal, image.shape, -1.0),
                                         hdr=True), dtype=np.float32)
    except RuntimeError as err:  # OIDN's own failure, e.g. a CPU it does not support
        raise ClrayError(f"Open Image Denoise failed: {err}") from None
