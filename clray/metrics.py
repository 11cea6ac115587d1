"""Image comparison in float64, for tests against the reference renderer and for studies.

Images are (H, W, C) or (H, W) arrays; "pixel" counts reduce over the channel axis of 3-D
inputs. Non-finite values propagate into rmse, psnr and max_abs (a NaN anywhere gives NaN), so a
broken image can never look close; count them separately with `nonfinite_count`. Two images
compared must have the same shape and at least one value, else every comparison is a ValueError:
an empty image is no evidence of a match (count_over would say no pixel differs).
"""

from __future__ import annotations

import math

import numpy as np

# A variant (clray study, clray tune) fails a scene when any pixel is non-finite or more pixels
# than this differ from the reference by over 2/255: a handful of silhouette pixels may
# legitimately flip between builds.
FAIL_FRACTION = 0.002
FAIL_MIN_PIXELS = 2


def fail_allowance(n_pixels: int) -> int:
    """How many of an image's pixels may differ from the reference by over 2/255."""
    return max(FAIL_MIN_PIXELS, math.floor(FAIL_FRACTION * n_pixels))


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.size == 0:
        raise ValueError(f"images are empty: shape {a.shape}, nothing to compare")
    return a, b


def _diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = _pair(a, b)
    with np.errstate(invalid="ignore"):  # inf - inf: the NaN it gives is the answer wanted
        return a - b


def per_pixel(mask: np.ndarray) -> np.ndarray:
    """An (H, W, C) mask reduced to (H, W): true where any channel is; 2-D masks unchanged."""
    if mask.ndim != 3:
        return mask
    # OR-ing the channels by hand: any(axis=-1) over a short last axis is ten times slower.
    out = mask[..., 0].copy()
    for k in range(1, mask.shape[-1]):
        out |= mask[..., k]
    return out


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(_diff(a, b) ** 2)))


def psnr(a: np.ndarray, b: np.ndarray, max_value: float = 1.0) -> float:
    """20 log10(max_value / rmse) in dB; inf for identical images."""
    error = rmse(a, b)
    if error == 0.0:
        return float("inf")
    return float(20.0 * np.log10(max_value / error))


def max_abs(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(_diff(a, b))))


def count_over(a: np.ndarray, b: np.ndarray, threshold: float) -> int:
    """Pixels where any channel differs by more than `threshold`.

    A channel that is NaN in either image counts as over; equal infinities do not.
    """
    a, b = _pair(a, b)
    close = (np.abs(_diff(a, b)) <= threshold) | (a == b)
    return int(np.count_nonzero(per_pixel(~close)))


def nonfinite_count(image: np.ndarray) -> int:
    """Pixels with at least one NaN or infinite channel."""
    return int(np.count_nonzero(per_pixel(~np.isfinite(np.asarray(image)))))
