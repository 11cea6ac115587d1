"""An OBJ mesh's own materials: its `mtllib` libraries read (once each), their materials added
to the scene's (once each), and each triangle's `usemtl` material resolved, with `map_Kd`
images through the texture path. docs/scene_format.md (OBJ materials) has the rules."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from clray.errors import SceneError
from clray.scene.assets import Assets
from clray.scene.model import Material
from clray.scene.mtl import MtlMaterial, to_material
from clray.scene.obj import ObjMesh
from clray.scene.values import Values, file_name, show

if TYPE_CHECKING:
    from clray.scene.parse_materials import MaterialTable


def obj_face_materials(obj: ObjMesh, name: str, key: str, default: int, v: Values,
                       assets: Assets, materials: MaterialTable) -> np.ndarray:
    """Each triangle's scene material: faces whose material cannot be found (no `usemtl`, a
    library missing or without it) take `default`, with a warning naming the file and line."""
    found: dict[str, int] = {}
    folder = Path(name).parent
    for line, lib in obj.material_libraries:
        where = f"{key}: {file_name(name)}: line {line}"
        try:
            read = assets.material_library(folder / lib, where, lib)
        except SceneError as err:
            # Which reference is wrong: the library may be any file (`mtllib` names it).
            raise SceneError(err.file, err.key, f"{err.message} ({file_name(name)} line {line} "
                             "names it in mtllib)") from None
        if read is None:
            continue
        library, identity = read
        for mname, mtl in library.materials.items():
            if mname in found:
                continue
            ref = (identity, mname)
            if ref not in materials.from_libraries:
                material = _textured(to_material(mtl), mtl, folder / lib,
                                     f"{where}: {file_name(lib)}", v, assets)
                materials.from_libraries[ref] = materials.add(material)
            found[mname] = materials.from_libraries[ref]
    missing = [m for m in obj.material_names if m not in found]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        assets.warnings.append(f"{key}: {file_name(name)}: usemtl {show(missing[0])}{more} is "
                               "in no material library the file names; those faces take the "
                               "default material")
    table = np.array([found.get(m, default) for m in obj.material_names] + [default],
                     dtype=np.int64)
    return table[obj.face_groups]


def _textured(material: Material, mtl: MtlMaterial, library: Path, where: str, v: Values,
              assets: Assets) -> Material:
    """`material` with the MTL material's map_Kd (relative to its library) as an image
    texture replacing Kd; a texture that cannot be read is a warning naming it as written."""
    from clray.scene.parse_materials import parse_texture

    texture_map = mtl.map_kd
    if texture_map is None:
        return material
    shown = f"{where}: line {texture_map.line}: map_Kd"
    for option in texture_map.ignored:
        assets.warnings.append(f"{shown}: option {option} is not modelled (ignored)")
    spec = {"type": "image", "file": (library.parent / texture_map.file).as_posix(),
            "repeat": list(texture_map.scale)}
    try:
        # Messages name the image as the MTL file writes it, as they do its mtllib name: the
        # joined path is not what the file says (a URL's // collapses: "sub/http:/x/t.png").
        texture = parse_texture(spec, shown, v, assets, written=texture_map.file)
    except SceneError as err:
        assets.warnings.append(f"{shown}: {err.message} (the material keeps Kd)")
        return material
    return dataclasses.replace(material, texture=texture)
