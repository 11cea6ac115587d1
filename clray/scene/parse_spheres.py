"""A `spheres` object: many spheres from a .npy/.npz file or arrays given inline, with one
material or one per sphere through material_index."""

from __future__ import annotations

from typing import Any

import numpy as np

from clray.errors import plural
from clray.scene import limits as L
from clray.scene.assets import SPHERE_ARRAYS, Assets
from clray.scene.model import Spheres
from clray.scene.parse_materials import MaterialTable
from clray.scene.values import Values, show


def parse_spheres(spec: dict, key: str, material: int | None, v: Values, assets: Assets,
                  materials: MaterialTable) -> Spheres:
    """A `spheres` object: arrays from a .npy/.npz file or given inline (lists, or numpy
    arrays from Python), one material or one per sphere through material_index."""
    arrays = _sphere_arrays(spec, key, v, assets)
    if "centers" not in arrays:
        raise v.error(key, "a spheres object needs centers (a file or the centers key)")
    # Counted by the shape alone, before any pass over (or copy of) the values.
    centers = v.shaped_array(arrays["centers"], f"{key}.centers", (None, 3))
    n = len(centers)
    assets.take_spheres(n, key)
    centers = v.array(centers, f"{key}.centers", (None, 3)).astype(np.float64)
    radii = _radii(spec, arrays, key, n, v)
    if material is not None:
        if "material_index" in arrays:
            raise v.error(f"{key}.material_index", "only with materials (a list)")
        return Spheres(centers, radii, np.full(n, material, dtype=np.int64))
    names = spec["materials"]
    if not isinstance(names, list) or not names:
        raise v.error(f"{key}.materials", f"expected a list of material names or inline "
                      f"tables, got {show(names)}")
    refs = np.array([materials.ref(m, f"{key}.materials[{j}]") for j, m in enumerate(names)],
                    dtype=np.int64)
    if "material_index" not in arrays:
        raise v.error(key, "materials needs material_index (in the file or as a key)")
    index = v.array(arrays["material_index"], f"{key}.material_index", (n,), integer=True)
    outside = (index < 0) | (index >= len(refs))
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise v.error(f"{key}.material_index[{i}]", f"index {index[i]} out of range "
                      f"(0-based, {plural(len(refs), 'material')})")
    return Spheres(centers, radii, refs[index])


def _radii(spec: dict, arrays: dict[str, Any], key: str, n: int, v: Values) -> np.ndarray:
    """One radius for all `n` spheres, or one each."""
    if "radii" in arrays and "radius" in spec:
        raise v.error(key, "give radius or radii, not both")
    if "radius" in spec:
        return np.full(n, v.length(spec["radius"], f"{key}.radius"))
    if "radii" not in arrays:
        raise v.error(key, "a spheres object needs radius or radii")
    radii = v.array(arrays["radii"], f"{key}.radii", (n,)).astype(np.float64)
    small = ~(radii >= L.MIN_LENGTH)
    if small.any():
        i = int(np.flatnonzero(small)[0])
        raise v.error(f"{key}.radii[{i}]", f"must be >= {L.MIN_LENGTH:g}, "
                      f"got {show(radii[i].item())}")
    return radii


def _sphere_arrays(spec: dict, key: str, v: Values, assets: Assets) -> dict[str, Any]:
    inline = {name: spec[name] for name in SPHERE_ARRAYS if name in spec}
    if "file" not in spec:
        return inline
    from_file = assets.sphere_file(spec["file"], f"{key}.file")
    both = [name for name in SPHERE_ARRAYS if name in inline and name in from_file]
    if both:
        raise v.error(key, f"{both[0]} is in the file: give it there or as a key, not both")
    return {**from_file, **inline}
