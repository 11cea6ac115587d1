"""Small glTF 2.0 files written for the tests and the fuzz harness: a document with its
buffer built from numpy arrays, saved as .glb or as .gltf with a data: URI or a .bin beside it.
"""

from __future__ import annotations

import base64
import io
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

FLOAT, USHORT, UINT = 5126, 5123, 5125


class Builder:
    """A glTF document and one binary buffer, arrays appended as accessors."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {"asset": {"version": "2.0"}, "scene": 0,
                                    "scenes": [{"nodes": []}], "nodes": [], "meshes": [],
                                    "accessors": [], "bufferViews": [], "buffers": []}
        self.blob = bytearray()

    def view(self, data: bytes) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.blob),
                                        "byteLength": len(data)})
        self.blob += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str) -> int:
        array = np.asarray(array)
        component = {np.dtype("float32"): FLOAT, np.dtype("uint16"): USHORT,
                     np.dtype("uint32"): UINT}[array.dtype]
        spec: dict[str, Any] = {"bufferView": self.view(array.tobytes()),
                                "componentType": component, "count": len(array), "type": kind}
        if kind == "VEC3" and component == FLOAT:
            spec["min"], spec["max"] = array.min(0).tolist(), array.max(0).tolist()
        self.doc["accessors"].append(spec)
        return len(self.doc["accessors"]) - 1

    def mesh(self, vertices: np.ndarray, faces: np.ndarray, material: int | None = None,
             uvs: np.ndarray | None = None, normals: np.ndarray | None = None,
             colors: np.ndarray | None = None, mode: int | None = None) -> int:
        attributes = {"POSITION": self.accessor(np.asarray(vertices, np.float32), "VEC3")}
        if uvs is not None:
            attributes["TEXCOORD_0"] = self.accessor(np.asarray(uvs, np.float32), "VEC2")
        if normals is not None:
            attributes["NORMAL"] = self.accessor(np.asarray(normals, np.float32), "VEC3")
        if colors is not None:
            attributes["COLOR_0"] = self.accessor(np.asarray(colors, np.float32), "VEC3")
        primitive: dict[str, Any] = {
            "attributes": attributes,
            "indices": self.accessor(np.asarray(faces, np.uint16).reshape(-1), "SCALAR")}
        if material is not None:
            primitive["material"] = material
        if mode is not None:
            primitive["mode"] = mode
        self.doc["meshes"].append({"primitives": [primitive]})
        return len(self.doc["meshes"]) - 1

    def node(self, root: bool = True, **spec: Any) -> int:
        self.doc["nodes"].append(spec)
        index = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def image(self, texels: np.ndarray) -> int:
        """An sRGB PNG of (H, W, 3) uint8 texels in the buffer, and a texture of it."""
        from PIL import Image

        png = io.BytesIO()
        Image.fromarray(texels).save(png, format="PNG")
        self.doc.setdefault("images", []).append({"bufferView": self.view(png.getvalue()),
                                                  "mimeType": "image/png"})
        self.doc.setdefault("textures", []).append({"source": len(self.doc["images"]) - 1})
        return len(self.doc["textures"]) - 1

    def material(self, **spec: Any) -> int:
        self.doc.setdefault("materials", []).append(spec)
        return len(self.doc["materials"]) - 1

    def document(self, uri: str | None) -> dict:
        doc = json.loads(json.dumps(self.doc))
        doc["buffers"] = [{"byteLength": len(self.blob)}]
        if uri is not None:
            doc["buffers"][0]["uri"] = uri
        return doc

    def glb(self) -> bytes:
        return glb_bytes(self.document(None), bytes(self.blob))

    def gltf(self) -> bytes:
        """The .gltf with its buffer in a data: URI."""
        uri = "data:application/octet-stream;base64," + base64.b64encode(self.blob).decode()
        return json.dumps(self.document(uri)).encode()

    def save(self, path: Path) -> Path:
        """As .glb, or .gltf with a .bin of the same stem beside it."""
        if path.suffix == ".glb":
            path.write_bytes(self.glb())
        else:
            path.with_suffix(".bin").write_bytes(bytes(self.blob))
            path.write_text(json.dumps(self.document(path.with_suffix(".bin").name)))
        return path


def glb_bytes(doc: dict, blob: bytes) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


CUBE_VERTICES = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)],
                         dtype=np.float64)
CUBE_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def instanced_cubes() -> Builder:
    """A unit cube mesh placed by three nodes (an instanced mesh) under a parent node that
    translates, and a second mesh (one triangle) placed once by a TRS node."""
    b = Builder()
    red = b.material(pbrMetallicRoughness={"baseColorFactor": [1, 0, 0, 1],
                                           "metallicFactor": 0.0, "roughnessFactor": 0.5})
    cube = b.mesh(CUBE_VERTICES, CUBE_FACES, red)
    tri = b.mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    kids = [b.node(root=False, mesh=cube, translation=[3.0 * i, 0, 0]) for i in range(3)]
    b.node(children=kids, translation=[0, 10, 0])
    b.node(mesh=tri, translation=[0, 0, -5], rotation=[0, 0, 0.7071067811865476,
                                                       0.7071067811865476], scale=[2, 2, 2])
    return b
