"""The sRGB transfer curve (IEC 61966-2-1): textures decoded on loading, PNGs encoded on output.

Its own module at the bottom of the layers, so that the scene loader (which decodes sRGB
textures) and the image writer (which encodes) share it without the scene importing upward.
"""

from __future__ import annotations

import numpy as np


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function for values already in [0, 1]."""
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(linear, 1.0 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """The inverse of srgb_encode (the exact curve, not gamma 2.2), for values in [0, 1]."""
    return np.where(encoded <= 0.04045, encoded / 12.92,
                    np.power((encoded + 0.055) / 1.055, 2.4))
