"""A scene made for a mesh file (`clray render model.obj`, `clray scene model.ply`).

The scene is built as scene data (the dict a TOML file parses to), so that what `clray scene`
writes is exactly what `clray render` renders: a camera framing the mesh's bounding sphere
from the chosen view, a key and a fill light (directional, so they light any size of model
alike) plus the ambient light, the file's own materials (or a plain grey where it has none),
and optionally a ground plane under the model. docs/cli.md (A mesh file) describes it.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from clray.errors import SceneError
from clray.host_memory import CHUNK_ROWS, by_chunks, small_pages
from clray.scene.assets import MESH_SUFFIXES, meshes_read_once
from clray.scene.emitters import has_emissive_faces
from clray.scene.files import UnreadableFile, open_regular, read_regular
from clray.scene.gltf import GLTF_SUFFIXES, GltfCamera, read_gltf_camera
from clray.scene.limits import MAX_IMAGE_SIZE, MAX_MAGNITUDE, MIN_LENGTH, mesh_bytes_limit
from clray.scene.load import scene_from_dict
from clray.scene.model import Instance, Mesh, Scene
from clray.scene.parse_camera import parse_camera
from clray.scene.parse_transform import parse_transform
from clray.scene.values import Values, file_name
from clray.vectors import bounds, unit

# For help and messages: "mesh file (.obj, .ply, .npz, .gltf, .glb)".
MESH_FILE = f"mesh file ({', '.join(MESH_SUFFIXES)})"
# Unit directions from the model's centre to the camera, and the camera's up.
DEFAULT_VIEW = "three-quarter"
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # 45 degrees round from the front, 25 degrees up: the usual three-quarter view (unit
    # length: the camera stands at the framing's distance).
    "three-quarter": ((math.cos(math.radians(25)) * math.sqrt(0.5), math.sin(math.radians(25)),
                       math.cos(math.radians(25)) * math.sqrt(0.5)), (0.0, 1.0, 0.0)),
    "front": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "side": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    "iso": ((math.sqrt(1 / 3),) * 3, (0.0, 1.0, 0.0)),
}
# --up: the rotation that turns the named model axis to +y, the up of VIEWS (each a proper
# rotation, det +1, so the winding and normals stay as they are). Z-up is the scanners' and
# CAD's convention; with it the model's -y side faces the front view, as in Blender.
DEFAULT_UP = "y"
UP_ROTATIONS: dict[str, tuple[tuple[int, int, int], ...]] = {
    "y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "-y": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "-z": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "x": ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    "-x": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
}
VFOV = 35.0
# The image size of the automatic scene where neither -W/-H nor a glTF camera sets it.
DEFAULT_SIZE = (640, 480)
# The bounding sphere's radius over the half-extent of the view's narrower side: a little room
# round it.
MARGIN = 1.05
# The bounding radius below which, over the centre's distance from the origin (largest
# coordinate), the camera's float64 position and look_at no longer resolve the model: such a
# model is moved to the origin (see RADIUS_RANGE).
RESOLVED_RADIUS = 1e-10
# Bounding radii the automatic scene frames as they are. Outside, the model is moved to the
# origin and scaled by a power of 2 (exact) to a radius near 1: the float32 triangle test
# multiplies three lengths (scale.py), whose product leaves float32's range for models near
# 1e13 or 1e-13, and rendered nothing; 2^+-32 keeps those products 1e9 inside it.
RADIUS_RANGE = (2.0 ** -32, 2.0 ** 32)
# The powers of 2 a transform may scale by (its singular values at least MIN_LENGTH, its
# entries at most MAX_MAGNITUDE): 2^-99 brings the largest radius a mesh file may hold
# (coordinates within 1e30: sqrt(3) x 1e30) to 2.7, and 2^99 any radius from 2^-131 up into
# RADIUS_RANGE. A model smaller than that (or too small for its distance from the origin: the
# offset too is at most MAX_MAGNITUDE) is refused, naming the file.
SHRINK_EXPONENTS = (math.ceil(math.log2(MIN_LENGTH)), math.floor(math.log2(MAX_MAGNITUDE)))
# A triangle whose cross product is at most this much of its two edges' lengths' product has
# no area that a render could show (its corners are one point or on one line).
FLAT_TRIANGLE = 1e-12
# A model thinner than this much of its radius along an axis is flat: edge-on, it is under a
# pixel thick even 16384 pixels high (its radius spans about 1/2.2 of the frame).
FLAT_MODEL = 1e-4
# The view that faces a model flat along x, y or z.
FACING_VIEW = ("side", "top", "front")
# The ground plane's distance under the model's lowest point, over the model's radius: in its
# plane, a flat model (a terrain) and the ground hit at the same distance, and the ground hid
# it; 1e-3 is many float32 steps of a camera-relative distance, and invisible as a gap.
GROUND_GAP = 1e-3
# The ambient light: dim, as files often give Ka = 1 (exporters' default) or Ka = Kd.
AMBIENT = 0.12
MODEL_MATERIAL = {"color": [0.8, 0.8, 0.8], "ambient": 1.0, "diffuse": 0.85,
                  "specular": 0.25, "shininess": 40.0}
GROUND_MATERIAL = {"color": [0.6, 0.6, 0.6], "ambient": 1.0, "diffuse": 0.85}


def is_mesh_file(path: Path) -> bool:
    return path.suffix.lower() in MESH_SUFFIXES


@small_pages
def model_scene_data(path: Path, view: str = DEFAULT_VIEW, ground: bool = False,
                     up: str = DEFAULT_UP, width: int | None = None,
                     height: int | None = None, turntable: int | None = None) -> dict:
    """Scene data for the mesh file `path` (relative names are relative to the working
    directory, and written so); `up` names the model's axis that points up; `width` and
    `height` the image's (default 640 x 480, or a glTF camera's aspect), which the camera
    frames the model in. A glTF file's own camera replaces `view`. `turntable`: an
    animation of that many frames (at least 2) in which the model turns once about the
    vertical through its centre (_turntable)."""
    name = path.as_posix()
    probe = _probe_scene(path, name)
    toward, view_up = (np.array(v) for v in VIEWS[view])
    model, rotation, vertices = _turned_model(probe, up)
    found = probe_camera(path)
    size = (_file_size(found, width, height) if found is not None
            else (width or DEFAULT_SIZE[0], height or DEFAULT_SIZE[1]))
    # The half-angle of the view's narrower side: a portrait image is narrower than its 35
    # degrees high, and a distance from the vertical angle cropped the model's sides.
    half = math.atan(math.tan(math.radians(VFOV) / 2.0) * min(1.0, size[0] / size[1]))
    center, radius, lo, hi = _bounds(vertices)  # radius > 0: some triangle has an area
    matrix, offset = _model_placement(path, rotation, center, radius, half)
    transform = None
    if up != DEFAULT_UP or offset.any() or not np.array_equal(matrix, rotation):
        transform, matrix, offset = _written_transform(matrix, offset)
        # Framed from the vertices as the written (rounded) transform places them.
        vertices = model @ matrix.T + offset
        _check_placement(path, transform, vertices)
        center, radius, lo, hi = _bounds(vertices)
    distance = MARGIN * radius / math.sin(half)
    if np.max(np.abs(center)) + distance > MAX_MAGNITUDE:
        raise SceneError(path, None, f"the automatic camera cannot frame a model this large "
                         f"(it would stand beyond {MAX_MAGNITUDE:g}); write a scene file")
    if found is not None:  # a glTF file's own camera, turned and moved as the model is
        camera = _checked_file_camera(path, found, matrix, offset)
        toward = unit(np.array(camera["position"]) - np.array(camera["look_at"]))
        view_up = np.array(camera["up"])
    else:
        camera = {"position": _plain(center + distance * toward), "look_at": _plain(center),
                  "up": _plain(view_up), "vfov": VFOV}
        _warn_edge_on(name, view, toward, hi - lo, radius)
    obj: dict[str, Any] = {"type": "mesh", "file": name}
    if transform is not None:
        obj["transform"] = {"matrix": transform}
    data: dict[str, Any] = {
        "render": {"width": size[0], "height": size[1], "background": [0.05, 0.05, 0.07],
                   "ambient": [AMBIENT] * 3, "max_depth": 4},
        "camera": camera,
        "materials": {},
        "lights": _model_lights(toward, view_up),
        "objects": [obj],
    }
    if all(m.face_materials is None for m in _meshes(probe)):  # the file brings none
        data["materials"]["model"] = _model_material(probe)
        obj["material"] = "model"
    if ground:
        data["materials"]["ground"] = GROUND_MATERIAL
        data["objects"].append(_ground_plane(center, lo, radius))
    if turntable is not None:
        if has_emissive_faces(probe):
            raise SceneError(path, None, "has emissive faces, which light the scene only "
                             "from its own meshes: a turntable's model is a group, whose "
                             "faces would glow but light nothing (write a scene file)")
        _turntable(data, center, turntable)
    return data


def _turntable(data: dict, center: np.ndarray, frames: int) -> None:
    """Makes the model (data's first object) a group placed by one instance whose rotation
    about y a track keys, a whole turn over `frames` frames (frame `frames` would be frame
    0 again), the rest of the scene still. An instance's transform places its group without
    moving the group's triangles, so the frames share one packing and the model's BVH, built
    once (docs/distributed.md); a mesh object's own keyed transform would be packed afresh
    each frame. The group holds the model moved to put its centre at the origin, where the
    instance's rotation turns it, and the instance's translation puts the centre back."""
    if frames < 2:
        raise ValueError(f"a turntable needs at least 2 frames, got {frames}")
    model = data["objects"][0]
    placement = np.array(model.get("transform", {}).get("matrix", np.eye(4).tolist()))
    placement[:3, 3] -= center
    model["transform"] = {"matrix": [_plain(row) for row in placement]}
    data["objects"][0] = {"type": "instance", "group": "model",
                          "transform": {"rotate": [0.0, 0.0, 0.0], "translate": _plain(center)}}
    data["groups"] = {"model": {"objects": [model]}}
    # Linear written out: an [animation] interpolation edited in would not change the turn's
    # even speed.
    data["animation"] = {"frames": frames, "tracks": [{
        "key": "objects[0].transform.rotate", "interpolation": "linear",
        "frames": [0, frames - 1],
        "values": [[0.0, 0.0, 0.0], [0.0, 360.0 * (frames - 1) / frames, 0.0]]}]}


def _probe_scene(path: Path, name: str) -> Scene:
    """The scene of the mesh file alone (a placeholder camera), which the automatic scene is
    made from: SceneError, naming the file, where it cannot be read or has no triangle with
    an area."""
    try:
        # Opened first, so that a file that cannot be opened (or is over its kind's limit) is
        # said as a scene file that cannot be read is.
        open_regular(path, mesh_bytes_limit(path.suffix.lower()))[0].close()
    except UnreadableFile as exc:
        raise SceneError(path, None, f"cannot read mesh file: {exc}") from None
    try:
        probe = scene_from_dict({"camera": {"position": [0, 0, 1], "look_at": [0, 0, 0]},
                                 "objects": [{"type": "mesh", "file": name}]})
    except SceneError as err:
        if err.file is not None:  # an error inside the mesh file names it already
            raise
        # Not a scene file's key (the probe's): what the file holds, and where in it (a .npz's
        # array, "faces[3]") where the key goes on past the probe's object and file name.
        inside = _probe_key(name)
        key = err.key[len(inside):] if err.key and err.key.startswith(inside) else None
        raise SceneError(path, key, err.message) from None
    _refuse_zero_area(path, probe)
    return probe


def _turned_model(probe: Scene, up: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's vertices where the file places them, the rotation that turns its `up` axis
    to y, and the vertices so turned."""
    meshes = _placed_meshes(probe)
    rotation = np.array(UP_ROTATIONS[up], dtype=np.float64)
    # One mesh's vertices as they are: a joined copy of a 2.6 M-vertex model was 63 MB of
    # fresh memory.
    model = meshes[0] if len(meshes) == 1 else np.concatenate(meshes)
    # einsum, not `model @ rotation.T`: numpy's matmul of millions of rows by a 3 x 3 took
    # 1.3 s for a 2.6 M-vertex model, einsum 0.18 s, the same numbers for these rotations
    # (each row a coordinate, signed); the default up needs no turn at all.
    vertices = model if up == DEFAULT_UP else np.einsum("ij,kj->ik", model, rotation)
    return model, rotation, vertices


def _model_placement(path: Path, rotation: np.ndarray, center: np.ndarray, radius: float,
                     half: float) -> tuple[np.ndarray, np.ndarray]:
    """The model's placement x -> matrix x + offset: its turn to the chosen up (bounds
    `center` and `radius` once turned, `half` the view's half-angle), scaled and moved to the
    origin where the camera could not frame it as it stands."""
    distance = MARGIN * radius / math.sin(half)
    reach = float(np.max(np.abs(center)))
    if (not RADIUS_RANGE[0] <= radius <= RADIUS_RANGE[1] or radius < RESOLVED_RADIUS * reach
            or reach + distance > MAX_MAGNITUDE / 2):
        # Moved to the origin and scaled by a power of 2, exact (the transform's offset too),
        # so that `clray scene` writes the numbers that render; the float64 vertices keep
        # what the file resolves. This also keeps a model with coordinates near 1e30 (valid)
        # framed by a camera within the scene's limit (half of it: room for rounding).
        shrink = _shrink(path, radius, reach)
        return shrink * rotation, -shrink * center
    return rotation, np.zeros(3)


def _written_transform(matrix: np.ndarray, offset: np.ndarray
                       ) -> tuple[list[list[float]], np.ndarray, np.ndarray]:
    """The object's transform table for the placement, and the placement as it reads back
    from the written numbers (its matrix and offset)."""
    transform = [[*_plain(matrix[i]), *_plain(offset[i:i + 1])] for i in range(3)]
    transform.append([0.0, 0.0, 0.0, 1.0])
    written = np.array(transform)
    return transform, written[:3, :3], written[:3, 3]


def _checked_file_camera(path: Path, found: GltfCamera, matrix: np.ndarray,
                         offset: np.ndarray) -> dict[str, Any]:
    """The glTF camera's table placed as the model is, SceneError naming the file and its
    node where the scene cannot take it."""
    camera = _file_camera(found, matrix, offset)
    try:
        # Checked here, so that a camera the scene cannot take (a node placing it beyond
        # 1e30) names the file and its node, not a [camera] key the user never wrote.
        parse_camera(camera, Values(None))
    except SceneError as err:
        raise SceneError(path, found.where, f"as the automatic scene's {err.key}: "
                         f"{err.message}") from None
    return camera


def _model_lights(toward: np.ndarray, up: np.ndarray) -> list[dict[str, Any]]:
    """The key and fill lights for a camera in the unit direction `toward` from the model's
    centre, `up` its up: the key from above the camera and to its left, the dimmer fill from
    nearly level and to its right."""
    right = unit(np.cross(-toward, up))
    true_up = np.cross(right, -toward)
    key = unit(toward + 0.8 * true_up - 0.6 * right)
    fill = unit(toward + 0.2 * true_up + 0.9 * right)
    return [{"type": "directional", "direction": _plain(-key), "color": [0.85] * 3},
            {"type": "directional", "direction": _plain(-fill), "color": [0.35] * 3}]


def _model_material(probe: Scene) -> dict[str, Any]:
    """The material for a model whose file brings none."""
    if any(m.colors is not None for m in _meshes(probe)):
        # Vertex colours multiply the material's: white shows them as the file has them.
        return {**MODEL_MATERIAL, "color": [1.0, 1.0, 1.0]}
    return MODEL_MATERIAL


def _ground_plane(center: np.ndarray, lo: np.ndarray, radius: float) -> dict[str, Any]:
    """The ground plane's object, just under the model's bounding box."""
    point = center.copy()
    point[1] = lo[1] - GROUND_GAP * radius
    return {"type": "plane", "point": _plain(point), "normal": [0.0, 1.0, 0.0],
            "material": "ground"}


def load_model_scene(path: Path, view: str = DEFAULT_VIEW, ground: bool = False,
                     up: str = DEFAULT_UP, width: int | None = None,
                     height: int | None = None) -> Scene:
    with meshes_read_once():  # framing the model and loading its scene read the file once
        scene = scene_from_dict(model_scene_data(path, view, ground, up, width, height))
    # The loader's warnings about the mesh begin with its key in the made scene
    # (`objects[0].file: NAME: `), a key the user never wrote: told as `NAME: `. Set as the
    # loader sets `checked`: the scene is frozen, and replace() would make an unchecked copy.
    inside = _probe_key(path.as_posix())
    told = tuple(f"{file_name(path.as_posix())}: {w[len(inside):]}" if w.startswith(inside)
                 else w for w in scene.warnings)
    object.__setattr__(scene, "warnings", told)
    return scene


def _probe_key(name: str) -> str:
    """How the loader's messages about the made scene's mesh begin: its key and file name."""
    return f"objects[0].file: {file_name(name)}: "


def _shrink(path: Path, radius: float, reach: float) -> float:
    """The power of 2 that scales a model of this bounding radius, its centre `reach` from
    the origin (largest coordinate), to a radius near 1 about the origin, within what a
    transform may hold: 2^SHRINK_EXPONENTS, and an offset (shrink x centre) of at most
    MAX_MAGNITUDE. SceneError, naming the file, where the model would still be smaller than
    RADIUS_RANGE: the float32 triangle test would render nothing. (The radius is 0 where its
    square left float64, under 1e-154: _refuse_zero_area has found an area.)"""
    exponent = -round(math.log2(radius)) if radius > 0.0 else SHRINK_EXPONENTS[1]
    if reach > 0.0:
        exponent = min(exponent, math.floor(math.log2(MAX_MAGNITUDE) - math.log2(reach)))
    shrink = 2.0 ** min(max(exponent, SHRINK_EXPONENTS[0]), SHRINK_EXPONENTS[1])
    if shrink * radius < RADIUS_RANGE[0]:
        size = f"{radius:.3g}" if radius > 0.0 else "under 1e-154"
        raise SceneError(path, None, f"the automatic scene cannot frame a model this small "
                         f"(radius {size}, {reach:.3g} from the origin): it scales a "
                         f"model by at most 2^{SHRINK_EXPONENTS[1]} and moves it by at most "
                         f"{MAX_MAGNITUDE:g}; scale the model up, or write a scene file")
    return shrink


def _check_placement(path: Path, transform: list[list[float]], vertices: np.ndarray) -> None:
    """SceneError naming the model file where the transform the automatic scene writes, or
    the vertices it places, are beyond the scene's limits: loading the scene would name its
    objects[0].transform, a key the user never wrote."""
    try:
        parse_transform({"matrix": transform}, "transform", Values(None))
    except SceneError as err:
        raise SceneError(path, None, f"the automatic scene cannot place this model (its "
                         f"{err.key}: {err.message}); write a scene file") from None
    if not np.all(np.abs(vertices) <= MAX_MAGNITUDE):  # NaN too
        raise SceneError(path, None, f"the automatic scene cannot place this model (it would "
                         f"move vertices beyond {MAX_MAGNITUDE:g}); write a scene file")


def _refuse_zero_area(path: Path, probe: Scene) -> None:
    """SceneError where no triangle of the file has an area: the render would be empty."""
    for mesh in _meshes(probe):
        for start in range(0, len(mesh.faces), CHUNK_ROWS):
            corners = mesh.vertices[mesh.faces[start:start + CHUNK_ROWS]].astype(np.float64)
            e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
            # Scaled by the largest edge component first, so that no square leaves float64.
            peak = np.maximum(np.abs(e1).max(axis=1), np.abs(e2).max(axis=1))
            peak[peak == 0] = 1.0
            e1, e2 = e1 / peak[:, None], e2 / peak[:, None]
            cross = np.cross(e1, e2)
            area2 = np.einsum("ij,ij->i", cross, cross)
            lengths2 = np.einsum("ij,ij->i", e1, e1) * np.einsum("ij,ij->i", e2, e2)
            if np.any(area2 > FLAT_TRIANGLE ** 2 * lengths2):
                return
    raise SceneError(path, None, "every triangle has zero area (its corners are one point or "
                     "on one line): nothing to render")


def _warn_edge_on(name: str, view: str, toward: np.ndarray, extent: np.ndarray,
                  radius: float) -> None:
    """A warning where the model is flat in a plane that holds the view direction (and the
    camera, which looks at its centre): seen edge-on, it renders as nothing."""
    for axis in range(3):
        if extent[axis] <= FLAT_MODEL * radius and toward[axis] == 0.0:
            warnings.warn(f"{name}: the model is flat along {'xyz'[axis]} and --view {view} "
                          f"sees it edge-on, as nothing; try --view {FACING_VIEW[axis]}",
                          stacklevel=3)
            return


def _meshes(scene: Scene) -> list[Mesh]:
    """The scene's meshes and its instances' (a glTF file's mesh placed by several nodes)."""
    return [m for obj in scene.objects
            for m in ((obj,) if isinstance(obj, Mesh) else obj.group.objects
                      if isinstance(obj, Instance) else ()) if isinstance(m, Mesh)]


def _placed_meshes(scene: Scene) -> list[np.ndarray]:
    """The vertices of every mesh that its faces use, where the scene places them."""
    out = []
    for obj in scene.objects:
        if isinstance(obj, Mesh):
            out.append(_used_vertices(obj))
        elif isinstance(obj, Instance):
            a, t = obj.matrix[:, :3], obj.matrix[:, 3]
            out += [_used_vertices(m) @ a.T + t for m in obj.group.objects
                    if isinstance(m, Mesh)]
    return out


def _used_vertices(mesh: Mesh) -> np.ndarray:
    """The mesh's vertices that a face uses: an OBJ file's points and `l` lines keep vertices
    that nothing draws, and the camera framed them (a line to (100, 100, 0) beside a triangle
    at the origin looked at (50, 50, 0)). The array itself, not a copy, where all are used."""
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[mesh.faces.reshape(-1)] = True
    return mesh.vertices if used.all() else mesh.vertices[used]


def probe_camera(path: Path) -> GltfCamera | None:
    """A glTF file's first camera (None for other files, and glTF files without one)."""
    if path.suffix.lower() not in GLTF_SUFFIXES:
        return None
    # The probe's scene has read the file already: it can be read again, and only its JSON.
    try:
        return read_gltf_camera(read_regular(path, mesh_bytes_limit(path.suffix.lower())), path)
    except UnreadableFile as exc:
        raise SceneError(path, None, f"cannot read mesh file: {exc}") from None


def _file_camera(found: GltfCamera, matrix: np.ndarray, offset: np.ndarray) -> dict[str, Any]:
    """The camera table of a glTF camera placed by x -> matrix x + offset."""
    position = matrix @ np.array(found.position) + offset
    look_at = matrix @ np.array(found.look_at) + offset
    camera: dict[str, Any] = {"position": _plain(position), "look_at": _plain(look_at),
                              "up": _plain(unit(matrix @ np.array(found.up)))}
    if found.vfov is not None:
        # In full, as _plain writes: the reader's largest yfov, pi - 1e-6, is 179.99994
        # degrees, which 6 digits rounded to 180, outside (0, 180).
        camera["vfov"] = float(found.vfov)
    else:
        scale = float(np.linalg.norm(matrix @ np.array(found.up)) /
                      np.linalg.norm(found.up))
        camera.update(type="orthographic", height=float(found.height * scale))
    return camera


def _file_size(found: GltfCamera, width: int | None, height: int | None) -> tuple[int, int]:
    """The image size for a glTF camera: as given, else the camera's aspect ratio on the
    side given (or a width of 640)."""
    aspect = found.aspect if found.aspect is not None else DEFAULT_SIZE[0] / DEFAULT_SIZE[1]
    if width is None and height is not None:
        return min(max(round(height * aspect), 1), MAX_IMAGE_SIZE), height
    width = width or DEFAULT_SIZE[0]
    return width, height or min(max(round(width / aspect), 1), MAX_IMAGE_SIZE)


def _bounds(vertices: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """(centre of the bounding box, radius of the sphere about it, the box's low and high
    corners)."""
    lo, hi = bounds(vertices)
    center = (lo + hi) / 2.0
    # The largest square's root is the largest length (a rounded root is monotonic). A chunk
    # of vertices at a time on every core: the differences of them all were three float64
    # arrays of fresh memory.
    farthest = np.zeros(-(-len(vertices) // CHUNK_ROWS))

    def reach(part: slice) -> None:
        d = vertices[part] - center
        farthest[part.start // CHUNK_ROWS] = (
            d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]).max()
    by_chunks(len(vertices), reach)
    return center, float(np.sqrt(farthest.max(initial=0.0))), lo, hi


def _plain(v: np.ndarray) -> list[float]:
    # Plain floats, which to_toml writes as repr does (the shortest digits that read back to
    # the same float): the TOML loads to exactly these numbers. Rounded to 6 significant
    # digits, the camera of a 0.01-unit model 4e6 from the origin stood half a unit off.
    return [float(x) for x in np.asarray(v, dtype=np.float64).tolist()]


# TOML basic strings escape the quote, the backslash and every control character (U+0000 to
# U+001F and DEL, U+007F); comments may hold none but the tab. JSON's escapes are not TOML's:
# json.dumps leaves DEL as it is and writes a character beyond U+FFFF as a surrogate pair of
# \u escapes, which TOML refuses.
_STRING_ESCAPES = {**{c: f"\\u{c:04X}" for c in (*range(0x20), 0x7F)},
                   ord('"'): '\\"', ord("\\"): "\\\\", ord("\b"): "\\b", ord("\t"): "\\t",
                   ord("\n"): "\\n", ord("\f"): "\\f", ord("\r"): "\\r"}
_COMMENT_ESCAPES = {c: f"\\u{c:04X}" for c in (*range(0x20), 0x7F) if c != ord("\t")}


def toml_string(text: str) -> str:
    """`text` as a TOML basic string, every other character as it is (UTF-8 in the file).
    UnicodeEncodeError for a lone surrogate (a file name that is not UTF-8, as Python decodes
    one): no TOML file holds it."""
    text.encode("utf-8")
    return '"' + text.translate(_STRING_ESCAPES) + '"'


def to_toml(data: dict, header: str = "") -> str:
    """Scene data of model_scene_data as TOML: top-level tables, materials and groups as
    sub-tables, lights, objects and an animation's tracks as arrays of tables; `header` as
    comment lines, each control character in it written as a \\uXXXX escape (a comment may
    not hold one)."""
    lines = [f"# {line.translate(_COMMENT_ESCAPES)}" for line in header.split("\n")
             if header]
    for section, value in data.items():
        if isinstance(value, list):
            for item in value:
                lines += ["", f"[[{section}]]", *_pairs(item)]
        elif section in ("materials", "groups"):
            for name, spec in value.items():
                lines += ["", f"[{section}.{name}]", *_pairs(spec)]
        elif section == "animation":
            lines += ["", "[animation]", *_pairs({k: x for k, x in value.items()
                                                  if k != "tracks"})]
            for track in value.get("tracks", []):
                lines += ["", "[[animation.tracks]]", *_pairs(track)]
        else:
            lines += ["", f"[{section}]", *_pairs(value)]
    return "\n".join(lines).lstrip("\n") + "\n"


def _pairs(table: dict) -> list[str]:
    return [f"{key} = {_value(v)}" for key, v in table.items()]


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):  # an inline table: the mesh's transform
        return "{" + ", ".join(f"{key} = {_value(x)}" for key, x in v.items()) + "}"
    return repr(v)
