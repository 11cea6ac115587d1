"""The files a scene names (textures, environment images, meshes, sphere arrays), read once each
and counted against the limits that all of them share.

Files are known by (device, inode): a scene naming one texture or mesh a thousand times must
not decode it a thousand times, nor count it against the texel limit more than once. The
budgets (texels, triangles, bulk spheres) are what is left of clray.scene.limits' totals.
"""

from __future__ import annotations

import dataclasses
import io
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from clray.errors import SceneError, plural
from clray.host_memory import fits_host_memory, loading
from clray.scene import limits as L
from clray.scene.colour import srgb_decode
from clray.scene.files import (
    UnreadableFile,
    kept_parse,
    open_regular,
    parses_kept,
    read_at_most,
)
from clray.scene.gltf import GLTF_SUFFIXES, GltfModel, read_gltf
from clray.scene.mesh_data import mesh_arrays
from clray.scene.mtl import MtlLibrary, parse_mtl
from clray.scene.obj import ObjMesh, parse_obj
from clray.scene.ply import read_ply
from clray.scene.texture import TextureError, check_size, read_texture
from clray.scene.values import Values, file_name, show

# What a `spheres` object's .npz may hold (a .npy holds centers, or centers and radii).
SPHERE_ARRAYS = ("centers", "radii", "material_index")
# A mesh `file` by its suffix: read by mesh_file, or (.gltf, .glb) by gltf_model. Any other
# is refused by name: read as OBJ, an STL or an image only gave "mesh has no faces".
MESH_SUFFIXES = (".obj", ".ply", ".npz", *GLTF_SUFFIXES)
_DECODE_SLICE = 1 << 20  # texel values decoded from sRGB at a time
# The meshes read within meshes_read_once(), which every Assets made there shares.
_SHARED_MESHES: ContextVar[dict | None] = ContextVar("clray_shared_meshes", default=None)


@contextmanager
def meshes_read_once() -> Iterator[None]:
    """Scenes loaded within it read each mesh file once between them: the automatic scene of a
    model file loads it to frame it, then as the scene (for a 5 M-triangle PLY, half the
    load). Meshes only: a mesh file's warnings travel with the mesh (ObjMesh.warnings), so
    the second scene takes them too, which a texture's or a glTF file's would miss."""
    token = _SHARED_MESHES.set({})
    try:
        yield
    finally:
        _SHARED_MESHES.reset(token)


class Assets:
    """The files of one scene, relative to `base`; errors through `values` name the key."""

    def __init__(self, values: Values, base: Path) -> None:
        self.values = values
        self.base = base
        self.warnings: list[str] = []
        self.textures: dict[tuple[int, int], tuple[np.ndarray, bool]] = {}
        # By id() of the stored texels: (those texels, kept alive here so that their id is not
        # another array's while this holds it, as a glTF file's could be once decoded; their
        # linear values).
        self.decoded_textures: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # Texels read_image had kept, by id() likewise: (the texels, kept alive here, and the
        # path and kind that kept_parse knows them by). Only these are kept decoded too.
        self.kept_images: dict[int, tuple[np.ndarray, Path, str]] = {}
        shared = _SHARED_MESHES.get()
        self.meshes: dict[tuple[int, int], ObjMesh] = {} if shared is None else shared
        self.models: dict[tuple[int, int], GltfModel] = {}  # glTF files
        self.mesh_warned: set[tuple[int, int]] = set()  # mesh files whose warnings are taken
        # MTL libraries by (device, inode): (the library, its identity).
        self.libraries: dict[tuple[int, int], MtlLibrary] = {}
        self.texels_left = L.MAX_TEXELS
        self.triangles_left = L.MAX_TRIANGLES
        self.spheres_left = L.MAX_BULK_SPHERES

    def sharing_files(self) -> Assets:
        """Fresh budgets over the same files already read: a keyframe's scene does not read a
        mesh or texture again."""
        other = Assets(self.values, self.base)
        other.textures, other.meshes, other.models = self.textures, self.meshes, self.models
        other.decoded_textures, other.kept_images = self.decoded_textures, self.kept_images
        return other

    def open_file(
        self, value: Any, key: str, max_bytes: int, written: str | None = None
    ) -> tuple[BinaryIO, tuple[int, int]]:
        """(open binary stream, (device, inode)) of a mesh or texture file. `written`: its
        name as the file that refers to it writes it (an MTL file's map_Kd, which `value`
        joins to that file's folder), which messages name; else `value`."""
        name = self.values.string(value, key)
        try:
            stream, info = open_regular(self.base / name, max_bytes)
        except UnreadableFile as exc:
            raise self.values.error(key, f"{exc}: {file_name(written or name)}") from None
        return stream, (info.st_dev, info.st_ino)

    # -- images ---------------------------------------------------------------------------

    def image(self, name: str, key: str, written: str | None = None
              ) -> tuple[np.ndarray, bool]:
        """(texels as stored, scaled to [0, 1]; whether the file has more than 8 bits).
        `written`: the name that messages give it, as for open_file."""
        stream, identity = self.open_file(name, key, L.MAX_TEXTURE_BYTES, written)
        shown = file_name(written or name)
        with stream:
            if identity in self.textures:
                return self.textures[identity]
            try:
                texels, deep, warned = self.read_image(lambda: stream, self.base / name,
                                                       "image")
            except TextureError as exc:
                raise self.values.error(key, f"cannot read image {shown}: {exc}") from None
        self.warnings.extend(f"{key}: image {shown}: {w}" for w in warned)
        self.textures[identity] = (texels, deep)
        return texels, deep

    def read_image(self, stream: Callable[[], BinaryIO], path: Path, kind: str
                   ) -> tuple[np.ndarray, bool, tuple[str, ...]]:
        """read_texture of stream() (the image that `path` holds as `kind`), within the
        texels left, which it takes; TextureError if not. An animation's frames decode the
        kept bytes once between them (kept_parse), each checking and counting the texels
        against its own scene's limit, as the decode does, and taking the warnings."""
        texels, deep, warned = kept_parse(path, kind, lambda: _read_only_texture(
            stream(), self.texels_left))
        height, width, _ = texels.shape
        check_size((width, height), self.texels_left)
        self.texels_left -= width * height
        if parses_kept():
            # decoded() keeps the texels decoded from sRGB beside them. (Not otherwise: a
            # glTF file's texels, once decoded, are not held.)
            self.kept_images[id(texels)] = (texels, path, kind)
        return texels, deep, warned

    def texels(self, value: Any, key: str) -> np.ndarray:
        """Linear texels given as an (H, W, 3) array (from Python), within the texel limits."""
        # The limits by the shape alone, before any pass over (or copy of) the values.
        texels = self.values.shaped_array(value, key, (None, None, 3))
        height, width, _ = texels.shape
        side = L.MAX_TEXTURE_SIDE
        if not 0 < min(height, width) <= max(height, width) <= side:
            raise self.values.error(key, f"must be at least 1 and at most {side} texels a side, "
                                    f"got {width}x{height}")
        if width * height > self.texels_left:
            raise self.values.error(key, f"{width}x{height} texels is over what is left "
                                    f"({self.texels_left}) of the limit of {L.MAX_TEXELS}")
        texels = self.values.array(texels, key, (None, None, 3))
        if not np.all((texels >= 0) & (texels <= 1)):
            raise self.values.error(key, "must be linear values in [0, 1]")
        self.texels_left -= width * height
        # A copy always (np.ascontiguousarray would return the caller's own float32 array,
        # which the caller could then change under the checked scene).
        return np.array(texels, dtype=np.float32, order="C")

    def decoded(self, texels: np.ndarray) -> np.ndarray:
        """`texels` decoded from sRGB to linear, once per file however often it is named (and
        once for an animation's frames, where read_image had them kept)."""
        if id(texels) not in self.decoded_textures:
            kept = self.kept_images.get(id(texels))
            if kept is None:
                linear = _srgb_decoded(texels)
            else:
                _, path, kind = kept
                linear = kept_parse(path, f"{kind}, decoded from sRGB",
                                    lambda: _srgb_decoded(texels))
            self.decoded_textures[id(texels)] = (texels, linear)
        return self.decoded_textures[id(texels)][1]

    # -- meshes ---------------------------------------------------------------------------

    def mesh_file(self, name: Any, key: str) -> ObjMesh:
        """A mesh from an OBJ or PLY file, or a .npz of arrays."""
        suffix = Path(self.values.string(name, key)).suffix.lower()
        if suffix not in MESH_SUFFIXES:
            expected = ", ".join(MESH_SUFFIXES[:-1]) + f" or {MESH_SUFFIXES[-1]}"
            raise self.values.error(key, f"{file_name(name)}: unknown mesh file type "
                                    f"{show(suffix) if suffix else '(no suffix)'} (use "
                                    f"{expected})")
        limit = L.mesh_bytes_limit(suffix)
        stream, identity = self.open_file(name, key, limit)
        with stream, loading(self.base / name):
            if identity not in self.meshes:

                def parse() -> ObjMesh:
                    try:
                        data = read_at_most(stream, limit)
                    except UnreadableFile as exc:
                        raise self.values.error(key, f"{exc}: {file_name(name)}") from None
                    if suffix == ".npz":
                        return read_only(self.npz_mesh(data, key, name))
                    if suffix == ".ply":
                        return read_only(self.ply_mesh(data, key, name))
                    mesh = parse_obj(data, self.base / name)
                    # Its triangles are known once parsed: refused before the BVH is built.
                    fits_host_memory(self.base / name, len(mesh.faces))
                    return read_only(mesh)

                # An animation's frames parse the file's kept bytes once between them.
                self.meshes[identity] = kept_parse(self.base / name, "mesh", parse)
        mesh = self.meshes[identity]
        # Each scene takes a file's warnings once, whether or not it read the file itself.
        if mesh.warnings and identity not in self.mesh_warned:
            self.mesh_warned.add(identity)
            self.warnings.extend(f"{key}: {file_name(name)}: {w}" for w in mesh.warnings)
        return mesh

    def gltf_model(self, name: Any, key: str) -> tuple[GltfModel, tuple[int, int]]:
        """A .gltf or .glb file's model (clray.scene.gltf), read once, with its identity; the
        buffers and images it names are relative to it."""
        # A .glb's and a .bin's arrays are numpy views, as a binary PLY's; a .gltf is JSON.
        limit = L.mesh_bytes_limit(Path(str(name)).suffix.lower())
        stream, identity = self.open_file(name, key, limit)
        with stream, loading(self.base / name):
            if identity not in self.models:
                # An animation's frames parse the file's kept bytes (and its buffers') once
                # between them; each scene takes its warnings.
                model = kept_parse(self.base / name, "glTF",
                                   lambda: self.read_gltf_model(stream, limit, name, key))
                self.warnings.extend(f"{key}: {file_name(name)}: {w}" for w in model.warnings)
                self.models[identity] = model
        return self.models[identity], identity

    def read_gltf_model(self, stream: BinaryIO, limit: int, name: Any, key: str
                        ) -> GltfModel:
        """gltf_model's reading of the file and of the buffer and image files it names, its
        arrays read-only."""
        try:
            data = read_at_most(stream, limit)
        except UnreadableFile as exc:
            raise self.values.error(key, f"{exc}: {file_name(name)}") from None
        path = self.base / name
        # The buffer and image files by (device, inode), each read once (25 `buffers`
        # naming one .bin were 25 copies of it), and together within the limit of
        # one file, as a .glb's binary chunk is.
        files: dict[tuple[int, int], bytes] = {}
        left = L.MAX_BINARY_MESH_BYTES

        def read_file(relative: str, where: str) -> bytes:
            nonlocal left
            try:
                stream, info = open_regular(path.parent / relative,
                                            L.MAX_BINARY_MESH_BYTES)
                with stream:
                    identity = (info.st_dev, info.st_ino)
                    if identity not in files:
                        if info.st_size > left:
                            raise UnreadableFile(
                                f"{info.st_size} bytes is over what is left ({left}) "
                                f"of the limit of {L.MAX_BINARY_MESH_BYTES} bytes for "
                                "a glTF file's buffer and image files together")
                        files[identity] = read_at_most(stream, left)
                        left -= len(files[identity])
                    return files[identity]
            except UnreadableFile as exc:
                raise SceneError(path, where, f"cannot read {file_name(relative)}: "
                                 f"{exc}") from None

        model = read_gltf(data, path, read_file)
        for mesh in model.meshes:
            if mesh is not None:
                read_only(mesh)
        for _, matrix in model.placements:
            matrix.flags.writeable = False
        return model

    def ply_mesh(self, data: bytes, key: str, name: str) -> ObjMesh:
        ply = read_ply(data, self.base / name)
        if ply.colors is None:
            return ply.mesh
        # Scanners and MeshLab write display (sRGB) colours, as 8-bit images hold.
        return dataclasses.replace(ply.mesh, colors=srgb_decode(ply.colors))

    def material_library(self, path: Path, where: str, written: str
                         ) -> tuple[MtlLibrary, tuple[int, int]] | None:
        """An MTL file (relative to the scene's folder) read once, with its identity; None,
        with a warning naming `where`, if it cannot be read. `written`: its name as the OBJ's
        mtllib writes it, which messages name (its base name alone may be another file's)."""
        try:
            stream, info = open_regular(self.base / path, L.MAX_SCENE_BYTES)
            with stream:
                identity = (info.st_dev, info.st_ino)
                if identity not in self.libraries:
                    shown = f"{where}: {file_name(written)}"

                    def parse() -> MtlLibrary:
                        data = read_at_most(stream, L.MAX_SCENE_BYTES)
                        return parse_mtl(data, self.base / path, shown)

                    # An animation's frames parse the kept bytes once between them: by
                    # `shown` too, which the warnings name. Nothing changes a library read.
                    self.libraries[identity] = kept_parse(self.base / path, f"MTL {shown}",
                                                          parse)
                    self.warnings.extend(self.libraries[identity].warnings)
        except UnreadableFile as exc:
            self.warnings.append(f"{where}: cannot read material library "
                                 f"{file_name(written)}: {exc} (its faces take the default "
                                 "material)")
            return None
        return self.libraries[identity], identity

    def npz_mesh(self, data: bytes, key: str, name: str) -> ObjMesh:
        """A mesh from a .npz of arrays: vertices (V, 3), faces (F, 3, 0-based), and optionally
        normals (V, 3) and uvs (V, 2); checked as inline arrays are."""
        try:
            headers = npz_headers(data, L.mesh_bytes_limit(".npz"))
        except ValueError as exc:
            raise self.values.error(key, f"cannot read {file_name(name)}: {exc}") from None
        known = ("vertices", "faces", "normals", "uvs", "colors")
        unknown = sorted(set(headers) - set(known))
        if unknown or "vertices" not in headers or "faces" not in headers:
            raise self.values.error(
                key, f"{file_name(name)} holds {', '.join(sorted(headers)) or 'nothing'} "
                f"(expected vertices, faces and optionally normals, uvs, colors)")
        # From the header, before the faces are inflated (parse_mesh counts them again).
        triangles = headers["faces"][0] if headers["faces"] else 0
        self.fits_triangles(triangles, key)
        fits_host_memory(self.base / name, triangles)
        try:
            arrays = npz_arrays(data)
        except ValueError as exc:
            raise self.values.error(key, f"cannot read {file_name(name)}: {exc}") from None
        # Errors name the array.
        return mesh_arrays(self.values, arrays, f"{key}: {file_name(name)}: ")

    def fits_triangles(self, count: int, key: str) -> None:
        """Whether `count` more triangles fit the limit for all meshes: a SceneError if not."""
        if count > self.triangles_left:
            raise self.values.error(
                key, f"{plural(count, 'triangle')} is over what is left ({self.triangles_left}) of "
                f"the limit of {L.MAX_TRIANGLES} triangles for all meshes"
            )

    def take_triangles(self, count: int, key: str) -> None:
        """Count a mesh's triangles against the limit for all meshes."""
        self.fits_triangles(count, key)
        self.triangles_left -= count

    # -- sphere arrays --------------------------------------------------------------------

    def sphere_file(self, value: Any, fkey: str) -> dict[str, Any]:
        """The arrays of a `spheres` object's .npy or .npz file, by name."""
        v = self.values
        name = v.string(value, fkey)
        suffix = Path(name).suffix.lower()
        if suffix not in (".npy", ".npz"):
            raise v.error(fkey, f"expected a .npy or .npz file, got {file_name(name)}")
        stream, _ = self.open_file(name, fkey, L.MAX_ARRAY_BYTES)
        with stream:
            try:
                data = read_at_most(stream, L.MAX_ARRAY_BYTES)
                if suffix == ".npy":
                    return self.npy_spheres(npy_array(data), fkey, name)
                unknown = sorted(set(npz_headers(data, L.MAX_ARRAY_BYTES)) - set(SPHERE_ARRAYS))
                if unknown:
                    raise v.error(fkey, f"{file_name(name)} holds {', '.join(unknown)} "
                                  f"(expected {', '.join(SPHERE_ARRAYS)})")
                return npz_arrays(data)
            except (UnreadableFile, ValueError) as exc:
                raise v.error(fkey, f"cannot read {file_name(name)}: {exc}") from None

    def npy_spheres(self, array: np.ndarray, key: str, name: str) -> dict[str, Any]:
        """A .npy of spheres: (N, 3) centers, or (N, 4) centers and radii."""
        if array.ndim != 2 or array.shape[1] not in (3, 4):
            raise self.values.error(key, f"{file_name(name)}: expected an (N, 3) or (N, 4) "
                                    f"array, got shape {array.shape}")
        if array.shape[1] == 3:
            return {"centers": array}
        return {"centers": array[:, :3], "radii": array[:, 3]}

    def take_spheres(self, count: int, key: str) -> None:
        """Count a `spheres` object's spheres against the limit for all of them."""
        if count > self.spheres_left:
            raise self.values.error(
                key, f"{plural(count, 'sphere')} is over what is left ({self.spheres_left}) of the "
                f"limit of {L.MAX_BULK_SPHERES} spheres for all spheres objects")
        self.spheres_left -= count


def _read_only_texture(stream: BinaryIO, texels_left: int
                       ) -> tuple[np.ndarray, bool, tuple[str, ...]]:
    """read_texture's answer, its texels read-only: shared by the scenes that name the file
    (an animation's frames, kept_parse), which pack copies of them."""
    texels, deep, warned = read_texture(stream, texels_left)
    texels.flags.writeable = False
    return texels, deep, tuple(warned)


def _srgb_decoded(texels: np.ndarray) -> np.ndarray:
    """`texels` decoded from sRGB to linear, a new read-only array (see _read_only_texture)."""
    # In float64, a slice at a time: the whole of a texture at the texel limit would take
    # several GiB of float64 temporaries.
    flat = texels.reshape(-1)
    linear = np.empty_like(flat)
    for start in range(0, flat.size, _DECODE_SLICE):
        part = flat[start : start + _DECODE_SLICE].astype(np.float64)
        linear[start : start + _DECODE_SLICE] = srgb_decode(part)
    linear = linear.reshape(texels.shape)
    linear.flags.writeable = False
    return linear


def read_only(mesh: ObjMesh) -> ObjMesh:
    """`mesh`, its arrays made read-only: a mesh read once is shared by the scenes that name
    its file (an animation's frames, clray.scene.files.kept_parse), which copy what they
    change."""
    for array in (mesh.vertices, mesh.faces, mesh.normals, mesh.uvs, mesh.face_groups,
                  mesh.colors):
        if array is not None:
            array.flags.writeable = False
    return mesh


# -- numpy files --------------------------------------------------------------------------
# np.load picks a file's kind by its first bytes, whatever its name: a .npy named .npz gives an
# array, a .npz named .npy a mapping. These read one kind each, and refuse the other.

_NPY_MAGIC = b"\x93NUMPY"


def npy_array(data: bytes) -> np.ndarray:
    """The array of a .npy file's bytes; ValueError if they are not one."""
    if not data.startswith(_NPY_MAGIC):
        raise ValueError("not a .npy file (it lacks numpy's header)")
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, EOFError) as exc:
        raise ValueError(str(exc)) from None


def npz_headers(data: bytes, max_bytes: int) -> dict[str, tuple[int, ...]]:
    """Each array's shape in a .npz file's bytes, from its .npy header alone; ValueError if
    they are not a .npz, or if its arrays would take more than `max_bytes` once inflated: a
    compressed .npz of a few megabytes can hold gigabytes of zeros."""
    total = 0
    shapes = {}
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            for member in archive.infolist():
                with archive.open(member) as stream:
                    shape, dtype = _npy_header(stream)
                shapes[member.filename.removesuffix(".npy")] = shape
                total += int(np.prod(shape, dtype=object)) * dtype.itemsize
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError) as exc:
        raise ValueError(f"not a .npz file ({exc})") from None
    if total > max_bytes:
        raise ValueError(f"its arrays take {total} bytes inflated, over the limit of "
                         f"{max_bytes}")
    return shapes


def _npy_header(stream: BinaryIO) -> tuple[tuple[int, ...], np.dtype]:
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
    else:
        shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
    return shape, dtype


def npz_arrays(data: bytes) -> dict[str, np.ndarray]:
    """A .npz file's arrays by name, once npz_headers has checked their size."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
            return {n: loaded[n] for n in loaded.files}
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(str(exc)) from None
