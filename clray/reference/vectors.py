"""Vector helpers of the oracle, as kernels/real.h has them for the kernels."""

from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def safe_normalize(v: np.ndarray) -> np.ndarray:
    # A zero vector (a ray through a cone's apex) stays zero rather than becoming NaN.
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(length > 0.0, length, 1.0)


def vec(v: tuple[float, float, float]) -> np.ndarray:
    return np.asarray(v, dtype=np.float64)


def frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """frame(a) of docs/rendering.md: two unit vectors completing the unit vector a."""
    h = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = safe_normalize(np.cross(a, h))
    return e1, np.cross(a, e1)
