"""glTF 2.0 reader: `.gltf` (JSON, with its `.bin` buffers and images beside it or in data: URIs)
and `.glb` (the JSON and one binary chunk in one file), into meshes, their placements by the
node hierarchy, materials and the first camera.

Each glTF mesh becomes one ObjMesh, its primitives merged: triangles, strips and fans
(points and lines are left out with a warning naming their mode), positions, normals,
TEXCOORD_0 (flipped to clray's v-up convention) and COLOR_0, and a glTF material index per
face. The scene's nodes are walked depth-first from its roots, each node's matrix (or
translation, rotation, scale) applied to its children; every node with a mesh is a placement,
and clray.scene.parse_gltf turns a mesh placed more than once into instances. Anything not
modelled (skins, morph targets, animations, texture maps other than the base colour, extensions
that change shading) is one warning each; a file that cannot be read as glTF is a SceneError
naming the file and the JSON path of what is wrong (`accessors[3].count`). Accessors are numpy
views of the buffers checked against their bounds, so a file loads at about numpy's speed
(docs/scene_format.md compares this reader with pygltflib and trimesh).
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np

from clray.errors import SceneError, plural
from clray.host_memory import fits_host_memory
from clray.scene import limits as L
from clray.scene.limits import MAX_MAGNITUDE, MAX_OBJECTS, MAX_TRIANGLES
from clray.scene.obj import ObjMesh
from clray.vectors import unit

GLTF_SUFFIXES = (".gltf", ".glb")
_GLB_MAGIC = b"glTF"
_CHUNK_JSON, _CHUNK_BIN = 0x4E4F534A, 0x004E4942
_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_MODES = ("POINTS", "LINES", "LINE_LOOP", "LINE_STRIP", "TRIANGLES", "TRIANGLE_STRIP",
          "TRIANGLE_FAN")
# Extensions read as the specification has them; any other is a warning (used) or, where
# the geometry cannot be read without it, an error (required).
SUPPORTED_EXTENSIONS = ("KHR_materials_emissive_strength", "KHR_mesh_quantization")
_GEOMETRY_EXTENSIONS = ("KHR_draco_mesh_compression", "EXT_meshopt_compression")
# Nodes walked at most: a hierarchy deeper or larger than this is not a model to render.
_MAX_NODES = MAX_OBJECTS
# Elements an accessor without a buffer view (zeros, or sparse) may declare.
_MAX_ELEMENTS = 3 * MAX_TRIANGLES


@dataclass(frozen=True)
class GltfMaterial:
    """A glTF material's terms as the file gives them (parse_gltf maps them onto clray's)."""

    name: str
    color: tuple[float, float, float]  # baseColorFactor's rgb, linear
    alpha: float  # baseColorFactor's alpha where alphaMode is BLEND, else 1
    metallic: float
    roughness: float
    emission: tuple[float, float, float]  # emissiveFactor times emissiveStrength
    texture: int | None  # images[] index of baseColorTexture, read with TEXCOORD_0


@dataclass(frozen=True)
class GltfCamera:
    """A node's camera in the model's frame: perspective (vfov degrees) or orthographic
    (height of the view); aspect is width over height where the file gives it."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    vfov: float | None
    height: float | None
    aspect: float | None
    where: str = ""  # the JSON path that places it, for errors: "nodes[2].camera"


@dataclass(frozen=True, eq=False)
class GltfModel:
    """meshes[i]: glTF mesh i with its primitives merged (None where it has no triangles);
    its face_groups hold each face's glTF material index (-1: the primitive has none) and
    material_names the materials' names. placements: (mesh index, 4x4 float64 matrix to the
    model's frame) for every node with a mesh, in depth-first order."""

    meshes: tuple[ObjMesh | None, ...]
    placements: tuple[tuple[int, np.ndarray], ...]
    materials: tuple[GltfMaterial, ...]
    images: tuple[Callable[[], bytes], ...]  # each image's encoded bytes, read when used
    camera: GltfCamera | None
    warnings: tuple[str, ...]


def is_gltf_file(name: str | Path) -> bool:
    return Path(name).suffix.lower() in GLTF_SUFFIXES


class _Reader:
    """One file's JSON document and buffers; errors name the file and the JSON path."""

    def __init__(self, path: Path, read_file: Callable[[str, str], bytes]) -> None:
        self.path = path
        self.read_file = read_file  # (relative name, JSON path) -> bytes, or SceneError
        self.doc: dict = {}
        self.bin: memoryview | None = None  # a view: the chunk is not copied
        self.buffers: dict[int, bytes | memoryview] = {}
        self.warnings: list[str] = []
        self.size = 0  # the bytes of the .gltf or .glb file
        self.held: int | None = None  # ... and of the buffers it has (zeros), once counted

    def error(self, where: str | None, message: str) -> SceneError:
        return SceneError(self.path, where, message)

    def warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    # -- the document -----------------------------------------------------------------------

    def document(self, data: bytes) -> None:
        text = data
        if data[:4] == _GLB_MAGIC:
            text = self.glb(data)
        try:
            doc = json.loads(text)
        except RecursionError:
            raise self.error(None, "JSON nested too deeply") from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise self.error(None, f"not glTF JSON: {str(exc)[:120]}") from None
        if not isinstance(doc, dict):
            raise self.error(None, "expected a JSON object at the top level")
        self.doc = doc
        asset = self.table(doc.get("asset"), "asset")
        version = asset.get("version")
        if not isinstance(version, str) or not version.startswith("2."):
            raise self.error("asset.version", f"expected glTF 2.x, got {_shown(version)}")
        required = self.items(doc, "extensionsRequired")
        for name in required:
            if name in _GEOMETRY_EXTENSIONS:
                raise self.error("extensionsRequired", f"{_shown(name)} compresses the "
                                 "geometry, which clray does not read")
        for name in [*required, *self.items(doc, "extensionsUsed")]:
            if name not in SUPPORTED_EXTENSIONS and name not in _GEOMETRY_EXTENSIONS:
                self.warn(f"extension {_shown(name)} is not modelled (ignored)")

    def glb(self, data: bytes) -> bytes:
        """The JSON chunk of a .glb; its BIN chunk kept as buffer 0's data."""
        if len(data) < 20:
            raise self.error(None, f"truncated .glb: {plural(len(data), 'byte')}, less than "
                             "a header and a chunk")
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise self.error(None, f".glb version {version} (expected 2)")
        if length > len(data):
            raise self.error(None, f"truncated .glb: the header gives {length} bytes, the "
                             f"file has {len(data)}")
        if length < len(data):
            # The chunks end at the header's length (the whole .glb's, by the specification):
            # bytes after it, padding a tool added say, are not the model's.
            self.warn(f"ignored: {plural(len(data) - length, 'byte')} past the length the "
                      f".glb header gives ({length})")
        chunks: list[tuple[int, bytes]] = []
        at = 12
        while at < length:
            if at + 8 > length:
                raise self.error(None, f"truncated .glb: chunk header at byte {at}")
            size, kind = struct.unpack_from("<II", data, at)
            if at + 8 + size > length:
                raise self.error(None, f"truncated .glb: chunk at byte {at} of {size} bytes "
                                 f"runs past the end ({length})")
            chunks.append((kind, memoryview(data)[at + 8 : at + 8 + size]))
            at += 8 + size
        if not chunks or chunks[0][0] != _CHUNK_JSON:
            raise self.error(None, ".glb: the first chunk must be JSON")
        if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN:
            self.bin = chunks[1][1]
        return bytes(chunks[0][1])

    # -- checked JSON values ----------------------------------------------------------------

    def table(self, value: Any, where: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(where, f"expected a JSON object, got {_shown(value)}")
        return value

    def items(self, parent: dict, name: str, where: str | None = None) -> list:
        value = parent.get(name, [])
        if not isinstance(value, list):
            raise self.error(where or name, f"expected an array, got {_shown(value)}")
        return value

    def entry(self, kind: str, index: Any, where: str) -> tuple[dict, str]:
        """(the object doc[kind][index], its path), the index checked."""
        array = self.items(self.doc, kind)
        if not _is_int(index) or not 0 <= index < len(array):
            raise self.error(where, f"{_shown(index)} is not an index into {kind} "
                             f"({plural(len(array), 'entry', 'entries')})")
        return self.table(array[index], f"{kind}[{index}]"), f"{kind}[{index}]"

    def integer(self, obj: dict, name: str, where: str, default: int | None = None,
                low: int = 0) -> int:
        value = obj.get(name, default)
        if not _is_int(value) or value < low:
            raise self.error(f"{where}.{name}", f"expected an integer >= {low}, got "
                             f"{_shown(value)}")
        return value

    def numbers(self, obj: dict, name: str, where: str, default: list[float],
                low: float = -math.inf, high: float = math.inf) -> list[float]:
        value = obj.get(name, default)
        if (not isinstance(value, list) or len(value) != len(default)
                or not all(_is_number(x) and low <= x <= high for x in value)):
            shown = f"[{low:g}, {high:g}]" if math.isfinite(low) else "finite numbers"
            raise self.error(f"{where}.{name}", f"expected {len(default)} numbers in {shown}, "
                             f"got {_shown(value)}")
        return [float(x) for x in value]

    def number(self, obj: dict, name: str, where: str, default: float, low: float = 0.0,
               high: float = math.inf) -> float:
        value = obj.get(name, default)
        if not _is_number(value) or not low <= value <= high:
            raise self.error(f"{where}.{name}", f"expected a number in [{low:g}, {high:g}], "
                             f"got {_shown(value)}")
        return float(value)

    # -- buffers and accessors ----------------------------------------------------------------

    def buffer(self, index: int, where: str) -> bytes | memoryview:
        if index in self.buffers:
            return self.buffers[index]
        spec, path = self.entry("buffers", index, where)
        length = self.integer(spec, "byteLength", path, low=1)
        if "uri" in spec:
            data = self.uri(spec["uri"], f"{path}.uri")
        elif index == 0 and self.bin is not None:
            data = self.bin
        else:
            raise self.error(path, "no uri, and not the .glb's binary chunk")
        if len(data) < length:
            raise self.error(path, f"byteLength {length}, but {plural(len(data), 'byte')} "
                             "could be read")
        self.buffers[index] = data
        return data

    def uri(self, uri: Any, where: str) -> bytes:
        """A data: URI's bytes, or a file's relative to the glTF file."""
        if not isinstance(uri, str):
            raise self.error(where, f"expected a string, got {_shown(uri)}")
        if uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma or not head.endswith(";base64"):
                raise self.error(where, "a data: URI must be base64 (data:...;base64,...)")
            try:
                return base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError):
                raise self.error(where, "data: URI is not valid base64") from None
        name = unquote(uri)
        if ":" in name.split("/")[0] or name.startswith("/"):
            raise self.error(where, f"{_shown(uri[:80])}: only relative file names and data: "
                             "URIs are read")
        return self.read_file(name, where)

    def view(self, index: Any, where: str) -> tuple[bytes | memoryview, int, int, int | None]:
        """(buffer, offset, length, byteStride) of a buffer view."""
        spec, path = self.entry("bufferViews", index, where)
        data = self.buffer(self.integer(spec, "buffer", path), f"{path}.buffer")
        offset = self.integer(spec, "byteOffset", path, 0)
        length = self.integer(spec, "byteLength", path, low=1)
        if offset + length > len(data):
            raise self.error(path, f"bytes {offset} to {offset + length} run past the end "
                             f"of its buffer ({plural(len(data), 'byte')})")
        stride = self.integer(spec, "byteStride", path, 4) if "byteStride" in spec else None
        if stride is not None and not (4 <= stride <= 252 and stride % 4 == 0):
            raise self.error(f"{path}.byteStride", f"expected a multiple of 4 from 4 to 252, "
                             f"got {stride}")
        return data, offset, length, stride

    def accessor(self, index: Any, where: str, widths: tuple[str, ...]) -> np.ndarray:
        """An accessor's elements as a (count, width) array (float64 for floats and normalised
        integers, int64 otherwise), every value checked to lie within its buffer view."""
        spec, path = self.entry("accessors", index, where)
        kind = spec.get("type")
        if kind not in widths:
            raise self.error(f"{path}.type", f"expected {' or '.join(widths)} here, got "
                             f"{_shown(kind)}")
        component = spec.get("componentType")
        if not _is_int(component) or component not in _COMPONENTS:
            raise self.error(f"{path}.componentType", f"expected one of "
                             f"{', '.join(map(str, _COMPONENTS))}, got {_shown(component)}")
        dtype = np.dtype("<" + _COMPONENTS[component])
        width = _WIDTHS[kind]
        count = self.integer(spec, "count", path, low=1)
        normalized = spec.get("normalized", False) is True
        if "bufferView" in spec:
            values = self.strided(spec, path, dtype, width, count)
        else:
            if count > _MAX_ELEMENTS:
                raise self.error(f"{path}.count", f"{count} is over the limit of "
                                 f"{_MAX_ELEMENTS} for an accessor without a buffer view")
            self.zeros(count * width * dtype.itemsize, path)
            values = np.zeros((count, width), dtype=dtype)
        if "sparse" in spec:
            values = self.sparse(spec["sparse"], f"{path}.sparse", values, dtype)
        if dtype.kind == "f":
            out = values.astype(np.float64)
            if not np.all(np.isfinite(out)):
                raise self.error(path, "holds a value that is not finite")
            return out
        if normalized:  # integers standing for [0, 1] or [-1, 1]
            top = float(np.iinfo(dtype).max)
            return np.maximum(values.astype(np.float64) / top, -1.0)
        return values.astype(np.int64)

    def zeros(self, size: int, path: str) -> None:
        """An accessor without a buffer view (zeros, or sparse) is charged as if its zeros
        were written out: at most the bytes of the file and of the buffers it has, and at
        most L.MAX_BINARY_MESH_BYTES. A 689-byte file of 100 M zeros took 4.8 GB and 24 s.
        A buffer counts once read (its byteLength then holds), not by the byteLength it
        declares, which a small file could make anything; one that cannot be read counts
        none: an unused buffer may be missing, and a used one fails where it is used. Counted
        once for all the file's accessors."""
        if self.held is None:
            self.held = self.size
            for i in range(len(self.items(self.doc, "buffers"))):
                spec, where = self.entry("buffers", i, f"buffers[{i}]")
                if "uri" not in spec and i == 0 and self.bin is not None:
                    continue  # the .glb's binary chunk: in the file's bytes already
                try:
                    self.buffer(i, where)
                except SceneError:
                    continue
                self.held += self.integer(spec, "byteLength", where, low=1)
        bound = min(self.held, L.MAX_BINARY_MESH_BYTES)
        if size > bound:
            raise self.error(path, f"{size} bytes of elements without a buffer view, over "
                             f"the {bound} bytes of the file and its buffers (an accessor's "
                             "zeros may be at most as large as the file)")

    def strided(self, spec: dict, path: str, dtype: np.dtype, width: int, count: int
                ) -> np.ndarray:
        if "bufferView" not in spec:  # a sparse accessor's indices and values need one
            raise self.error(f"{path}.bufferView", "missing required key")
        data, offset, length, stride = self.view(spec["bufferView"], f"{path}.bufferView")
        start = self.integer(spec, "byteOffset", path, 0)
        element = dtype.itemsize * width
        if stride is not None and stride < element:
            # Elements would overlap: the glTF 2.0 specification requires a stride of at
            # least the element's size (a stride of 4 for float VEC3 ended in "every
            # triangle has zero area").
            raise self.error(f"bufferViews[{spec['bufferView']}].byteStride",
                             f"{stride} is less than the {element} bytes of {path}'s elements")
        step = element if stride is None else stride
        end = start + (count - 1) * step + element
        if end > length:
            raise self.error(path, f"{count} elements of {element} bytes every {step} from "
                             f"byte {start} run past its buffer view ({length} bytes)")
        return np.ndarray((count, width), dtype=dtype, buffer=data, offset=offset + start,
                          strides=(step, dtype.itemsize)).copy()

    def sparse(self, value: Any, path: str, values: np.ndarray, dtype: np.dtype) -> np.ndarray:
        sparse = self.table(value, path)
        n = self.integer(sparse, "count", path, low=1)
        if n > len(values):
            raise self.error(f"{path}.count", f"{n} is more than the accessor's "
                             f"{len(values)} elements")
        indices = self.table(sparse.get("indices"), f"{path}.indices")
        index_type = indices.get("componentType")
        if not _is_int(index_type) or index_type not in (5121, 5123, 5125):
            raise self.error(f"{path}.indices.componentType", f"expected 5121, 5123 or 5125, "
                             f"got {_shown(index_type)}")
        where = self.strided(indices, f"{path}.indices",
                             np.dtype("<" + _COMPONENTS[index_type]), 1, n)[:, 0]
        if np.any(where >= len(values)):
            raise self.error(f"{path}.indices", f"an index is not below the accessor's "
                             f"{len(values)} elements")
        replaced = self.strided(self.table(sparse.get("values"), f"{path}.values"),
                                f"{path}.values", dtype, values.shape[1], n)
        values = values.copy()
        values[where] = replaced
        return values

    # -- meshes -------------------------------------------------------------------------------

    def declared(self, used: list[int]) -> None:
        """The vertices and triangles the meshes `used` declare, counted from the JSON against
        the limits for all meshes (L.MAX_MESH_VERTICES, L.MAX_TRIANGLES) before any array is
        built: each primitive's arrays are its own (float64) copies, so two accessors of
        fifty million zeros, or one buffer view read by many primitives, would fill memory
        before the triangles were counted. A primitive the reader refuses or leaves out is
        not counted here (mesh() says what is wrong with it)."""
        vertices = triangles = 0
        for m in used:
            spec, path = self.entry("meshes", m, "nodes[].mesh")
            for j, value in enumerate(self.items(spec, "primitives", f"{path}.primitives")):
                where = f"{path}.primitives[{j}]"
                primitive = self.table(value, where)
                mode = primitive.get("mode", 4)
                attributes = primitive.get("attributes")
                if (not _is_int(mode) or not 4 <= mode <= 6 or not isinstance(attributes, dict)
                        or "POSITION" not in attributes):
                    continue
                apath = f"{where}.attributes"
                n = self.count(attributes["POSITION"], f"{apath}.POSITION")
                for name in ("NORMAL", "TEXCOORD_0", "COLOR_0"):
                    if name in attributes:
                        k = self.count(attributes[name], f"{apath}.{name}")
                        if k != n:  # as attribute() says it, before k elements are made
                            raise self.error(f"{apath}.{name}", f"{k} elements for "
                                             f"{plural(n, 'position')}")
                corners = (self.count(primitive["indices"], f"{where}.indices")
                           if "indices" in primitive else n)
                vertices += n
                triangles += corners // 3 if mode == 4 else max(corners - 2, 0)
                if vertices > L.MAX_MESH_VERTICES or triangles > L.MAX_TRIANGLES:
                    raise self.error(where, f"the file's meshes declare {vertices} vertices "
                                     f"and {triangles} triangles up to here, over the limit "
                                     f"of {L.MAX_MESH_VERTICES} vertices and "
                                     f"{L.MAX_TRIANGLES} triangles for all meshes")
        fits_host_memory(self.path, triangles)

    def count(self, index: Any, where: str) -> int:
        """An accessor's declared element count."""
        spec, path = self.entry("accessors", index, where)
        return self.integer(spec, "count", path, low=1)

    def mesh(self, index: int) -> ObjMesh | None:
        spec, path = self.entry("meshes", index, "nodes[].mesh")
        parts = []
        for j, value in enumerate(self.items(spec, "primitives", f"{path}.primitives")):
            part = self.primitive(self.table(value, f"{path}.primitives[{j}]"),
                                  f"{path}.primitives[{j}]")
            if part is None:
                continue
            if not len(part["faces"]):
                self.warn("primitives of fewer than three indices are not drawn (no whole "
                          "triangle)")
                continue
            parts.append(part)
        if "weights" in spec:
            self.warn("morph targets are not modelled (meshes render in their base shape)")
        return _merged(parts) if parts else None

    def primitive(self, spec: dict, path: str) -> dict | None:
        mode = spec.get("mode", 4)
        if not _is_int(mode) or not 0 <= mode <= 6:
            raise self.error(f"{path}.mode", f"expected 0 to 6, got {_shown(mode)}")
        if mode < 4:
            self.warn(f"primitives of mode {_MODES[mode]} are not drawn (only triangles, "
                      "strips and fans are)")
            return None
        if "targets" in spec:
            self.warn("morph targets are not modelled (meshes render in their base shape)")
        attributes = self.table(spec.get("attributes"), f"{path}.attributes")
        if "POSITION" not in attributes:
            raise self.error(f"{path}.attributes", "no POSITION")
        apath = f"{path}.attributes"
        vertices = self.accessor(attributes["POSITION"], f"{apath}.POSITION", ("VEC3",))
        if np.max(np.abs(vertices)) > MAX_MAGNITUDE:
            raise self.error(f"{apath}.POSITION", f"a position beyond {MAX_MAGNITUDE:g}")
        n = len(vertices)
        part: dict[str, Any] = {"vertices": vertices}
        if "NORMAL" in attributes:
            normals = self.attribute(attributes, "NORMAL", apath, ("VEC3",), n)
            # Zero normals (exporters write them for degenerate faces) leave the mesh flat.
            part["normals"] = unit(normals) if np.all(np.any(normals != 0, axis=1)) else None
        if "TEXCOORD_0" in attributes:
            uv = self.attribute(attributes, "TEXCOORD_0", apath, ("VEC2",), n)
            part["uvs"] = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])  # glTF's v runs down
        if "COLOR_0" in attributes:
            color = self.attribute(attributes, "COLOR_0", apath, ("VEC3", "VEC4"), n)
            part["colors"] = np.clip(color[:, :3], 0.0, 1.0)  # linear, as glTF has them
        if any(name.startswith(("JOINTS_", "WEIGHTS_")) for name in attributes):
            self.warn("skins are not modelled (meshes render in their bind pose)")
        if "indices" in spec:
            indices = self.accessor(spec["indices"], f"{path}.indices", ("SCALAR",))[:, 0]
            if indices.dtype.kind == "f":
                raise self.error(f"{path}.indices", "expected an accessor of unsigned integers")
            if np.any((indices < 0) | (indices >= n)):
                bad = int(indices[(indices < 0) | (indices >= n)][0])
                raise self.error(f"{path}.indices", f"index {bad} out of range "
                                 f"({plural(n, 'vertex', 'vertices')})")
        else:
            indices = np.arange(n, dtype=np.int64)
        part["faces"] = _triangles(indices, mode)
        material = spec.get("material", -1)
        if material != -1:
            self.entry("materials", material, f"{path}.material")
        part["material"] = material
        return part

    def attribute(self, attributes: dict, name: str, path: str, widths: tuple[str, ...],
                  n: int) -> np.ndarray:
        values = self.accessor(attributes[name], f"{path}.{name}", widths)
        if len(values) != n:
            raise self.error(f"{path}.{name}", f"{len(values)} elements for "
                             f"{plural(n, 'position')}")
        return values

    # -- materials ----------------------------------------------------------------------------

    def material(self, index: int) -> GltfMaterial:
        spec, path = self.entry("materials", index, "materials")
        pbr = self.table(spec.get("pbrMetallicRoughness", {}), f"{path}.pbrMetallicRoughness")
        ppath = f"{path}.pbrMetallicRoughness"
        base = self.numbers(pbr, "baseColorFactor", ppath, [1.0] * 4, 0.0, 1.0)
        blend = spec.get("alphaMode", "OPAQUE")
        if blend == "MASK":
            self.warn("alphaMode MASK is not modelled (the faces render opaque)")
        emission = self.numbers(spec, "emissiveFactor", path, [0.0] * 3, 0.0, 1.0)
        extensions = self.table(spec.get("extensions", {}), f"{path}.extensions")
        if "KHR_materials_emissive_strength" in extensions:
            strength = self.number(self.table(extensions["KHR_materials_emissive_strength"],
                                              f"{path}.extensions"), "emissiveStrength",
                                   f"{path}.extensions.KHR_materials_emissive_strength", 1.0)
            emission = [min(e * strength, 1e6) for e in emission]
        for name in ("normalTexture", "occlusionTexture", "emissiveTexture"):
            if name in spec:
                self.warn(f"{name} is not modelled (ignored)")
        if "metallicRoughnessTexture" in pbr:
            self.warn("metallicRoughnessTexture is not modelled (the factors are used)")
        texture = None
        if "baseColorTexture" in pbr:
            texture = self.texture(pbr["baseColorTexture"], f"{ppath}.baseColorTexture")
        name = spec.get("name")
        return GltfMaterial(
            name=name if isinstance(name, str) else f"material {index}",
            color=(base[0], base[1], base[2]),
            alpha=base[3] if blend == "BLEND" else 1.0,
            metallic=self.number(pbr, "metallicFactor", ppath, 1.0, 0.0, 1.0),
            roughness=self.number(pbr, "roughnessFactor", ppath, 1.0, 0.0, 1.0),
            emission=(emission[0], emission[1], emission[2]),
            texture=texture,
        )

    def texture(self, value: Any, path: str) -> int | None:
        info = self.table(value, path)
        if info.get("texCoord", 0) != 0:
            self.warn("base colour textures on TEXCOORD_1 and above are not modelled")
            return None
        texture, tpath = self.entry("textures", info.get("index"), f"{path}.index")
        if "source" not in texture:
            self.warn(f"{tpath}: no source image in a format clray reads (the material keeps "
                      "its colour)")
            return None
        self.entry("images", texture["source"], f"{tpath}.source")  # the index checked
        return int(texture["source"])

    def image(self, index: int) -> Callable[[], bytes]:
        """The image's bytes, read when a material needs them (SceneError if they cannot be)."""
        spec, path = self.entry("images", index, "images")

        def read() -> bytes:
            if "uri" in spec:
                return self.uri(spec["uri"], f"{path}.uri")
            if "bufferView" in spec:
                data, offset, length, _ = self.view(spec["bufferView"], f"{path}.bufferView")
                return bytes(data[offset : offset + length])
            raise self.error(path, "neither uri nor bufferView")

        return read

    # -- the node hierarchy -------------------------------------------------------------------

    def roots(self) -> list:
        scenes = self.items(self.doc, "scenes")
        if "scene" in self.doc or scenes:
            spec, path = self.entry("scenes", self.doc.get("scene", 0), "scene")
            return self.items(spec, "nodes", f"{path}.nodes")
        # No scene: every node that is no other's child is a root.
        nodes = self.items(self.doc, "nodes")
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])
                    if _is_int(c)}
        return [i for i in range(len(nodes)) if i not in children]

    def walk(self) -> list[tuple[int, dict, np.ndarray]]:
        """(node index, node, 4x4 matrix to the model's frame) depth-first from the roots."""
        out: list[tuple[int, dict, np.ndarray]] = []
        seen: set[int] = set()
        stack = [(index, np.eye(4), "scenes[].nodes") for index in reversed(self.roots())]
        while stack:
            index, parent, where = stack.pop()
            node, path = self.entry("nodes", index, where)
            if index in seen:
                raise self.error(path, "reached twice in the hierarchy (a node has one parent "
                                 "and is not its own ancestor)")
            seen.add(index)
            if len(seen) > _MAX_NODES:
                raise self.error("nodes", f"over {_MAX_NODES} nodes")
            matrix = parent @ self.local(node, path)
            out.append((index, node, matrix))
            if "skin" in node:
                self.warn("skins are not modelled (meshes render in their bind pose)")
            children = self.items(node, "children", f"{path}.children")
            stack.extend((c, matrix, f"{path}.children") for c in reversed(children))
        return out

    def local(self, node: dict, path: str) -> np.ndarray:
        """The node's matrix: `matrix` (column-major), or translation x rotation x scale."""
        if "matrix" in node:
            matrix = np.array(self.numbers(node, "matrix", path, [0.0] * 16)).reshape(4, 4).T
            if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
                raise self.error(f"{path}.matrix", "not affine (its last row, the 4th, 8th, "
                                 "12th and 16th numbers, must be 0 0 0 1)")
            return matrix
        t = self.numbers(node, "translation", path, [0.0] * 3)
        x, y, z, w = self.numbers(node, "rotation", path, [0.0, 0.0, 0.0, 1.0], -1.0, 1.0)
        s = self.numbers(node, "scale", path, [1.0] * 3)
        q = math.sqrt(x * x + y * y + z * z + w * w)
        if q == 0:
            raise self.error(f"{path}.rotation", "a zero quaternion")
        x, y, z, w = x / q, y / q, z / q, w / q
        rotation = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        out = np.eye(4)
        out[:3, :3] = rotation * np.array(s)
        out[:3, 3] = t
        return out

    def camera(self, index: Any, matrix: np.ndarray, path: str) -> GltfCamera:
        spec, cpath = self.entry("cameras", index, f"{path}.camera")
        kind = spec.get("type")
        if kind not in ("perspective", "orthographic"):
            raise self.error(f"{cpath}.type", f"expected perspective or orthographic, got "
                             f"{_shown(kind)}")
        lens = self.table(spec.get(kind), f"{cpath}.{kind}")
        a = matrix[:3, :3]
        position = matrix[:3, 3]
        forward, up = unit(a @ [0.0, 0.0, -1.0]), unit(a @ [0.0, 1.0, 0.0])
        if not (np.any(forward) and np.any(up)) or abs(float(forward @ up)) > 0.999:
            raise self.error(path, "the camera's node squashes its view directions")
        aspect = None
        if kind == "perspective":
            if "yfov" not in lens:
                raise self.error(f"{cpath}.perspective.yfov", "missing required key")
            vfov = math.degrees(self.number(lens, "yfov", f"{cpath}.perspective", 1.0, 1e-6,
                                            math.pi - 1e-6))
            if "aspectRatio" in lens:
                aspect = self.number(lens, "aspectRatio", f"{cpath}.perspective", 1.0, 1e-3,
                                     1e3)
            height = None
        else:
            ymag = self.number(lens, "ymag", f"{cpath}.orthographic", 1.0, 1e-12, 1e30)
            xmag = self.number(lens, "xmag", f"{cpath}.orthographic", ymag, 1e-12, 1e30)
            vfov, height, aspect = None, 2.0 * ymag * float(np.linalg.norm(a[:, 1])), xmag / ymag
        return GltfCamera(_vec(position), _vec(position + forward), _vec(up), vfov, height,
                          aspect, f"{path}.camera")


def read_gltf(data: bytes, path: Path, read_file: Callable[[str, str], bytes]) -> GltfModel:
    """A .gltf or .glb file's model. read_file(name, JSON path) reads a buffer or image file
    relative to the glTF file (raising a SceneError where it cannot)."""
    r = _Reader(path, read_file)
    r.size = len(data)
    r.document(data)
    if r.items(r.doc, "animations"):
        r.warn("animations are not played (the model renders as the file places it)")
    placements: list[tuple[int, np.ndarray]] = []
    camera = None
    for index, node, matrix in r.walk():
        if "mesh" in node:
            r.entry("meshes", node["mesh"], f"nodes[{index}].mesh")
            placements.append((int(node["mesh"]), matrix))
        if "camera" in node and camera is None:
            camera = r.camera(node["camera"], matrix, f"nodes[{index}]")
    used = sorted({m for m, _ in placements})
    r.declared(used)
    meshes: list[ObjMesh | None] = [None] * len(r.items(r.doc, "meshes"))
    for m in used:
        meshes[m] = r.mesh(m)
    materials = tuple(r.material(i) for i in range(len(r.items(r.doc, "materials"))))
    images = tuple(r.image(i) for i in range(len(r.items(r.doc, "images"))))
    return GltfModel(tuple(meshes), tuple(placements), materials, images, camera,
                     tuple(r.warnings))


def read_gltf_camera(data: bytes, path: Path) -> GltfCamera | None:
    """The file's first camera (None without one), its buffers left unread."""
    r = _Reader(path, lambda name, where: b"")
    r.document(data)
    for index, node, matrix in r.walk():
        if "camera" in node:
            return r.camera(node["camera"], matrix, f"nodes[{index}]")
    return None


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    """(F, 3) corners of a primitive's triangles, strips and fans wound as OpenGL's rules."""
    if mode == 4:
        return indices[: len(indices) // 3 * 3].reshape(-1, 3)
    n = len(indices) - 2
    if n <= 0:
        return np.zeros((0, 3), dtype=np.int64)
    k = np.arange(n)
    if mode == 5:  # every other triangle's first two corners swapped: all wound alike
        odd = k % 2 == 1
        a = np.where(odd, indices[k + 1], indices[k])
        b = np.where(odd, indices[k], indices[k + 1])
        return np.column_stack([a, b, indices[k + 2]])
    return np.column_stack([np.full(n, indices[0]), indices[k + 1], indices[k + 2]])


def flat_corners(vertices: np.ndarray, faces: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corners, faces, normals) of a mesh given a vertex for each face's corner, each with
    its face's unit normal: vertices[corners] are the new vertices, and any per-vertex array
    is taken so too. A mesh without normals joined to one with them shades flat so (glTF
    asks for flat normals where NORMAL is missing); a shared vertex has no one face normal.
    A degenerate face's normal is +z: it is never hit, and vertex normals may not be zero."""
    corners = faces.reshape(-1).astype(np.int64)
    v = vertices[faces].astype(np.float64)
    normals = unit(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))
    normals[~np.any(normals != 0, axis=1)] = (0.0, 0.0, 1.0)
    return (corners, np.arange(len(corners), dtype=np.int64).reshape(-1, 3),
            np.repeat(normals, 3, axis=0))


def _merged(parts: list[dict]) -> ObjMesh:
    """One mesh of a glTF mesh's primitives: normals where any primitive has them (its face
    normals, flat_corners, for a primitive without), uvs and colours where any has (zero uvs
    elsewhere: only a textured material reads them; white, which tints nothing, for
    colours)."""
    if len(parts) == 1:  # most meshes: nothing to join
        p = parts[0]
        groups = np.full(len(p["faces"]), p["material"], dtype=np.int64)
        return ObjMesh(p["vertices"], p["faces"].astype(np.int64), p.get("normals"),
                       p.get("uvs"), (), groups, colors=p.get("colors"))
    if any(p.get("normals") is not None for p in parts):
        parts = [p if p.get("normals") is not None else _flat(p) for p in parts]
    starts = np.cumsum([0] + [len(p["vertices"]) for p in parts])
    vertices = np.concatenate([p["vertices"] for p in parts])
    faces = np.concatenate([p["faces"] + s for p, s in zip(parts, starts, strict=False)])
    groups = np.concatenate([np.full(len(p["faces"]), p["material"], dtype=np.int64)
                             for p in parts])

    def joined(name: str, width: int, fill: float | None) -> np.ndarray | None:
        have = [p.get(name) is not None for p in parts]
        if not all(have) and not (fill is not None and any(have)):
            return None
        return np.concatenate([p[name] if p.get(name) is not None
                               else np.full((len(p["vertices"]), width), fill) for p in parts])

    return ObjMesh(vertices, faces.astype(np.int64), joined("normals", 3, None),
                   joined("uvs", 2, 0.0), (), groups, colors=joined("colors", 3, 1.0))


def _flat(part: dict) -> dict:
    """A primitive (primitive()'s dict) given a vertex a face corner, with its face normal."""
    corners, faces, normals = flat_corners(part["vertices"], part["faces"])
    flat = {name: value[corners] for name, value in part.items()
            if name in ("vertices", "uvs", "colors") and value is not None}
    return {**part, **flat, "faces": faces, "normals": normals}


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    # The bound alone, which NaN and the infinities fail too: JSON's integers have no bound, and
    # math.isfinite raises on one past a float's range, where the comparison is exact.
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and abs(value) <= MAX_MAGNITUDE)


def _vec(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _shown(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, bytes) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
