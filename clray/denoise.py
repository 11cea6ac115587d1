"""Denoising a rendered image with Intel Open Image Denoise (docs/denoising.md), through the
pyoidn binding, an optional extra: OIDN's RT filter on the linear image, guided by the albedo
and normal passes where given, each first denoised on its own.

The passes are means over a pixel's samples, so they are noisy wherever those samples see
different things: a defocused or minified texture's albedo at a few samples a pixel. Given as
they are, OIDN keeps the image's noise where the guide shows the same pattern (depth_of_field
at 4 spp: rmse 0.058 before, 0.053 after); OIDN's manual advises denoising each guide with the
same filter first and telling the filter they are clean (0.026; docs/denoising.md)."""

from __future__ import annotations

import atexit
import threading

import numpy as np

from clray.errors import ClrayError, SettingsError

DENOISE_GUIDES = ("albedo", "normal")  # the passes that guide OIDN's RT filter
DENOISE_MISSING = "denoising needs Open Image Denoise's binding: pip install 'clray[denoise]'"

# Pixels of mirrored image (and guides) around the image while OIDN filters it, cropped after.
# OIDN's network sees past an edge as black: unpadded, a flat 0.5 image came back about 0.09 at
# 1x1, and a 64x64 one off by up to 0.0228 in its outer 4 pixels against 0.0017 inside. Largest
# error, flat 0.5 at 1x1, 2x3, 64x64 and 27x48, by pad: 4 px 0.0045 to 0.0054, 8 px 0.0010 to
# 0.0020, 16 px 0.0005 to 0.0014 (the unpadded interior's own error), 32 px 0.0003 to 0.0010.
# 16 px costs a 1920x1080 image 5 % more pixels to filter (docs/denoising.md).
PAD = 16
FLOAT32_MAX = float(np.finfo(np.float32).max)


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


# One OIDN device and a filter per guide, made on first use and kept: making them took about
# 0.1 s a guide, as long as filtering a 192x108 guide. OIDN objects are not for two threads at
# once, hence the lock; they are released at exit, before the interpreter tears down pyoidn.
_guide_lock = threading.Lock()
_guide_filters: dict[str, object] = {}


def _release_guide_filters() -> None:
    with _guide_lock:
        device = _guide_filters.pop("device", None)
        for pass_filter in _guide_filters.values():
            pass_filter.release()
        _guide_filters.clear()
        if device is not None:
            device.release()


def _guide_filter(pyoidn, name: str):
    """The RT filter that denoises the pass `name` given alone, and its device."""
    if "device" not in _guide_filters:
        device = pyoidn.Device()
        device.commit()
        _guide_filters["device"] = device
        atexit.register(_release_guide_filters)
    device = _guide_filters["device"]
    if name not in _guide_filters:
        pass_filter = pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)
        pass_filter.set_quality(pyoidn.OIDN_QUALITY_HIGH)
        _guide_filters[name] = pass_filter
    return _guide_filters[name], device


def _float32(values: np.ndarray, low: float, high: float) -> np.ndarray:
    """values as float32 within [low, high], a non-finite value first counted as 0. Clipped in
    their own type before the cast: a float64 beyond float32's range would become inf (and
    numpy's RuntimeWarning), hence black, where it is only very bright."""
    finite = np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0)  # a copy
    in_place = finite.dtype.kind == "f" and finite.dtype.itemsize >= 4  # float32 or wider
    clipped = np.clip(finite, np.float32(low), np.float32(high), out=finite if in_place else None)
    return clipped.astype(np.float32, copy=False)


def _padded(values: np.ndarray) -> np.ndarray:
    """values mirrored PAD pixels out on each side of the image (repeatedly where a side is
    shorter than PAD: numpy's symmetric mode repeats the mirror)."""
    return np.pad(values, ((PAD, PAD), (PAD, PAD), (0, 0)), mode="symmetric")


def _guide(pyoidn, name: str, values: np.ndarray | None, shape: tuple[int, ...],
           low: float) -> np.ndarray | None:
    """A guide pass as OIDN takes it (the image's shape, float32, finite, within [low, 1],
    padded as the image is), denoised by the RT filter given that pass alone."""
    if values is None:
        return None
    values = np.asarray(values)
    if values.shape != shape:
        raise SettingsError(f"the {name} pass has shape {values.shape}; the image has {shape}")
    guide = _padded(_float32(values, low, 1.0))
    clean = np.empty_like(guide)
    with _guide_lock:
        pass_filter, device = _guide_filter(pyoidn, name)
        pass_filter.set_image(name, guide, pyoidn.OIDN_FORMAT_FLOAT3)
        pass_filter.set_image(pyoidn.OIDN_IMAGE_OUTPUT, clean, pyoidn.OIDN_FORMAT_FLOAT3)
        pass_filter.commit()
        pass_filter.execute()
        error = device.get_error()
    if error:
        raise ClrayError(f"Open Image Denoise failed on the {name} pass: {error}")
    return clean


def denoise(image: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None) -> np.ndarray:
    """The (H, W, 3) linear image denoised by OIDN's RT filter for HDR input, as float32.

    albedo (linear, [0, 1]) and normal (unit vectors, any fixed space) are the render's passes
    of the same shape, each denoised first; OIDN takes the normal only with the albedo. A
    non-finite value of the image counts as black, as in a PNG (docs/rendering.md): a neural
    filter would spread one NaN over its whole neighbourhood. A finite value beyond float32's
    range (a float64 image) counts as float32's largest, not as inf (which would be black).
    OIDN scales the image by an exposure of its own, from its average brightness, so one huge
    pixel shifts the whole image: one of 1e20 in a flat 0.5 40x40 image moved its median to
    0.85, one of 3.4e38 to 12.7, and one of 3.4e38 in an 8x8 image turned it all black (inside
    OIDN); clamp such pixels first where they are not meant. Raises ClrayError naming the extra
    when the binding is missing, SettingsError (a ValueError) for shapes that do not match."""
    pyoidn = _binding()
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        raise SettingsError(f"expected an (H, W, 3) image, got shape {image.shape}")
    if normal is not None and albedo is None:
        raise SettingsError("Open Image Denoise takes the normal pass only with the albedo pass")
    # HDR colour must be finite and non-negative for the filter.
    colour = _padded(_float32(image, 0.0, FLOAT32_MAX))
    try:
        albedo = _guide(pyoidn, "albedo", albedo, image.shape, 0.0)
        normal = _guide(pyoidn, "normal", normal, image.shape, -1.0)
        out = np.asarray(pyoidn.denoise(colour, albedo=albedo, normal=normal, hdr=True,
                                        clean_aux=albedo is not None), dtype=np.float32)
        # A copy, not a view: the padded frame is not kept alive with the result.
        return out[PAD:-PAD, PAD:-PAD].copy()
    except RuntimeError as err:  # OIDN's own failure, e.g. a CPU it does not support
        raise ClrayError(f"Open Image Denoise failed: {err}") from None
