"""What the oracle's rays that hit nothing see (kernels/background.h): a colour, a vertical
gradient, or an equirectangular environment image."""

from __future__ import annotations

import numpy as np

from clray.scene.model import Background
from clray.vectors import safe_normalize, vec


def equirect_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of unit directions in the environment image: u = 0.5 looks along -z, u grows
    towards +x; v = 1 straight up."""
    u = 0.5 + np.arctan2(d[:, 0], -d[:, 2]) / (2.0 * np.pi)
    v = 0.5 + np.arcsin(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    return u, v


def environment_texel(texels: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The texels at columns x, rows y of an (H, W, 3) panorama (one fetch each)."""
    return texels[y, x]


def environment_bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an equirectangular (H, W, 3) image: wrapping across u, rows clamped
    at the poles (row 0 at v = 1)."""
    texels = np.asarray(image, dtype=np.float64)
    height, width = texels.shape[:2]
    s = (u - np.floor(u)) * width - 0.5
    t = np.clip((1.0 - v) * height - 0.5, 0.0, height - 1.0)
    x0, y0 = np.floor(s), np.floor(t)
    fx, fy = (s - x0)[:, None], (t - y0)[:, None]
    x0, y0 = x0.astype(np.int64) % width, y0.astype(np.int64)
    x1, y1 = (x0 + 1) % width, np.minimum(y0 + 1, height - 1)
    return ((1 - fx) * (1 - fy) * environment_texel(texels, x0, y0)
            + fx * (1 - fy) * environment_texel(texels, x1, y0)
            + (1 - fx) * fy * environment_texel(texels, x0, y1)
            + fx * fy * environment_texel(texels, x1, y1))


def background_radiance(background: tuple[float, float, float] | Background, d: np.ndarray
                        ) -> np.ndarray:
    """(N, 3): what rays of unit directions d that hit nothing see."""
    if not isinstance(background, Background):
        return np.broadcast_to(vec(background), d.shape)
    d = safe_normalize(d)
    if background.kind == "gradient":
        t = np.clip(0.5 * (d[:, 1:2] + 1.0), 0.0, 1.0)
        return (1.0 - t) * vec(background.bottom) + t * vec(background.top)
    return environment_bilinear(background.image, *equirect_uv(d))
