"""An object's or instance's `transform` table: scale, rotate, translate, or a 4x4 matrix."""

from __future__ import annotations

from typing import Any

import numpy as np

from clray.scene import limits as L
from clray.scene.transform import rotation_matrix
from clray.scene.values import Values, show

TRANSFORM_KEYS = ("translate", "rotate", "scale", "matrix")


def parse_transform(value: Any, key: str, v: Values) -> tuple[np.ndarray, np.ndarray]:
    """(A, t) of x -> A x + t, in float64: scale, then rotate about x, y, z in turn, then
    translate; or a 4x4 `matrix` (row-major, last row 0 0 0 1)."""
    spec = v.table(value, key)
    v.keys(spec, key, TRANSFORM_KEYS, ())
    if "matrix" in spec:
        others = [k for k in ("translate", "rotate", "scale") if k in spec]
        if others:
            raise v.error(key, f"give matrix or {', '.join(others)}, not both")
        return _matrix(spec["matrix"], f"{key}.matrix", v)
    translate = np.array(v.vec3(spec.get("translate", (0, 0, 0)), f"{key}.translate"))
    rotation = rotation_matrix(v.vec3(spec.get("rotate", (0, 0, 0)), f"{key}.rotate"))
    skey = f"{key}.scale"
    scale_value = spec.get("scale", 1.0)
    if isinstance(scale_value, list):
        scale = np.array(v.vec3(scale_value, skey))
    else:
        scale = np.full(3, v.number(scale_value, skey))
    if not scale.all():
        raise v.error(skey, f"must be nonzero, got {show(scale_value)}")
    if np.min(np.abs(scale)) < L.MIN_LENGTH:
        raise v.error(
            skey, f"must be at least {L.MIN_LENGTH:g} in magnitude, got {show(scale_value)}"
        )
    return rotation * scale, translate


def _matrix(value: Any, key: str, v: Values) -> tuple[np.ndarray, np.ndarray]:
    rows = value if isinstance(value, list) and len(value) == 4 else None
    if rows is None:
        raise v.error(key, f"expected 4 rows of 4 numbers, got {show(value)}")
    m = np.array([v.numbers(row, f"{key}[{i}]", 4) for i, row in enumerate(rows)])
    if m[3].tolist() != [0.0, 0.0, 0.0, 1.0]:
        raise v.error(f"{key}[3]", f"must be [0, 0, 0, 1] (an affine transform), got "
                      f"{show(rows[3])}")
    if np.linalg.svd(m[:3, :3], compute_uv=False).min() < L.MIN_LENGTH:
        raise v.error(key, "is singular: it flattens space (its 3x3 part must be "
                      "invertible)")
    return m[:3, :3], m[:3, 3]
