"""Scene model (+ BVH) -> PackedScene: numpy arrays in the layouts of layout.py.

Positions are made camera-relative in float64 before they are rounded to float32, so a scene
authored far from the origin keeps its precision near the eye.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clray.accel.bvh import build_bvh
from clray.accel.wide import PACKET_WIDTH, WideBvh, collapse
from clray.device import layout as L
from clray.device.program import KernelConfig
from clray.scene import model as M
from clray.scene.scale import needs_fp64_spheres

# Primitive count from which pack_scene builds the BVH on the device when given a queue.
DEVICE_BUILD_MIN = 20000


@dataclass(frozen=True)
class PackedScene:
    camera: np.ndarray  # one CAMERA record
    params: np.ndarray  # one PARAMS record
    planes: np.ndarray
    spheres: np.ndarray
    boxes: np.ndarray
    cylinders: np.ndarray
    cones: np.ndarray
    triangles: np.ndarray
    triangle_packets: np.ndarray  # TRIANGLE_PACKET per PACKET_WIDTH slots of prim_refs
    sphere_packets: np.ndarray  # SPHERE_PACKET likewise (spheres only)
    # Empty: shading reads a triangle's corners from its packet (the same float32 numbers), so
    # the device keeps no vertex positions; the kernels still take the argument.
    vertices: np.ndarray  # (0, 4) float32
    normals: np.ndarray  # (V, 4) float32, or empty
    uvs: np.ndarray  # (V, 2) float32, or empty
    nodes: np.ndarray  # layout.bvh_node_dtype(config.bvh_width), root first
    prim_refs: np.ndarray  # int32, leaves laid out as clray.accel.wide describes
    materials: np.ndarray
    textures: np.ndarray
    texels: np.ndarray  # (T, 4) float32
    lights: np.ndarray
    config: KernelConfig
    bvh_s: float  # host time to build the BVH

    def device_bytes(self) -> dict[str, int]:
        names = ("planes", "spheres", "boxes", "cylinders", "cones", "triangles",
                 "triangle_packets", "sphere_packets", "vertices", "normals", "uvs", "nodes",
                 "prim_refs", "materials", "textures", "texels", "lights")
        return {name: int(getattr(self, name).nbytes) for name in names}


def _f4(v: np.ndarray | tuple, w: float = 0.0) -> np.ndarray:
    return np.array([*np.asarray(v, dtype=np.float64), w], dtype=np.float32)


def _records(dtype: np.dtype, n: int) -> np.ndarray:
    return np.zeros(n, dtype=dtype)


def _disc_extent(axis: np.ndarray, radius: float) -> np.ndarray:
    """Half-extent per world axis of a disc of this radius across unit `axis`."""
    return radius * np.sqrt(np.clip(1.0 - axis * axis, 0.0, 1.0))


def texture_frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """frame(a) of docs/rendering.md, as kernels/real.h computes it."""
    h = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, h)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


class _Bounded:
    """Bounds and references of the primitives that go into the BVH, kind by kind."""

    def __init__(self) -> None:
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.refs: list[np.ndarray] = []

    def add(self, kind: int, lo: np.ndarray, hi: np.ndarray) -> None:
        self.lo.append(lo)
        self.hi.append(hi)
        self.refs.append((kind << L.PRIM_TYPE_SHIFT) | np.arange(len(lo), dtype=np.int64))


@dataclass(frozen=True)
class _Triangles:
    triangles: np.ndarray
    vertices: np.ndarray  # (V, 4) float32, camera-relative
    normals: np.ndarray
    uvs: np.ndarray


def _pack_planes(objs: list[M.Plane], eye: np.ndarray) -> np.ndarray:
    planes = _records(L.PLANE, len(objs))
    for i, o in enumerate(objs):
        n = np.asarray(o.normal, dtype=np.float64)
        # The plane's point nearest the eye is the best-conditioned point to store; its
        # texture coordinates keep (u, v) anchored at the point the scene gave.
        point = np.asarray(o.point, dtype=np.float64) - eye
        nearest = n * np.dot(point, n)
        e1, e2 = texture_frame(n)
        shift = nearest - point
        planes[i]["point"] = _f4(nearest, np.dot(shift, e1))
        planes[i]["normal"] = _f4(n, np.dot(shift, e2))
        planes[i]["material"] = o.material
    return planes


def _pack_spheres(objs: list[M.Sphere | M.Spheres], eye: np.ndarray,
                  bounded: _Bounded) -> np.ndarray:
    """Sphere objects and `spheres` arrays, in scene order: one record per sphere."""
    blocks = [(o.centers, o.radii, o.materials) if isinstance(o, M.Spheres) else
              ([o.center], [o.radius], [o.material]) for o in objs]
    centers, radii, materials = (
        np.concatenate([np.asarray(b[k], dtype=dtype).reshape(shape) for b in blocks])
        if blocks else np.zeros((0, *shape[1:]), dtype=dtype)
        for k, dtype, shape in ((0, np.float64, (-1, 3)), (1, np.float64, (-1,)),
                                (2, np.int32, (-1,))))
    spheres = _records(L.SPHERE, len(centers))
    spheres["center_radius"][:, :3] = centers - eye
    spheres["center_radius"][:, 3] = radii
    spheres["material"] = materials
    if len(spheres):
        cr = spheres["center_radius"].astype(np.float64)
        bounded.add(L.PRIM_SPHERE, cr[:, :3] - cr[:, 3:], cr[:, :3] + cr[:, 3:])
    return spheres


def _pack_boxes(objs: list[M.Box], eye: np.ndarray, bounded: _Bounded) -> np.ndarray:
    boxes = _records(L.BOX, len(objs))
    for i, o in enumerate(objs):
        boxes[i]["lo"] = _f4(np.asarray(o.min) - eye)
        boxes[i]["hi"] = _f4(np.asarray(o.max) - eye)
        boxes[i]["material"] = o.material
    if len(boxes):
        bounded.add(L.PRIM_BOX, boxes["lo"][:, :3].astype(np.float64),
                    boxes["hi"][:, :3].astype(np.float64))
    return boxes


def _pack_cylinders(objs: list[M.Cylinder], eye: np.ndarray, bounded: _Bounded) -> np.ndarray:
    cylinders = _records(L.CYLINDER, len(objs))
    lo, hi = [], []
    for i, o in enumerate(objs):
        rec = cylinders[i]
        rec["base_radius"] = _f4(np.asarray(o.base) - eye, o.radius)
        rec["axis_height"] = _f4(o.axis, o.height)
        rec["material"] = o.material
        rec["capped"] = int(o.capped)
        # Bounds of the stored (float32) shape, so they hold what the kernel intersects.
        base = rec["base_radius"][:3].astype(np.float64)
        axis = rec["axis_height"][:3].astype(np.float64)
        top = base + axis * float(rec["axis_height"][3])
        ext = _disc_extent(axis, float(rec["base_radius"][3]))
        lo.append(np.minimum(base, top) - ext)
        hi.append(np.maximum(base, top) + ext)
    if lo:
        bounded.add(L.PRIM_CYLINDER, np.array(lo), np.array(hi))
    return cylinders


def _pack_cones(objs: list[M.Cone], eye: np.ndarray, bounded: _Bounded) -> np.ndarray:
    cones = _records(L.CONE, len(objs))
    lo, hi = [], []
    for i, o in enumerate(objs):
        rec = cones[i]
        rec["apex_tan"] = _f4(np.asarray(o.apex) - eye, np.tan(np.radians(o.angle)))
        rec["axis_height"] = _f4(o.axis, o.height)
        rec["material"] = o.material
        rec["capped"] = int(o.capped)
        apex = rec["apex_tan"][:3].astype(np.float64)
        axis = rec["axis_height"][:3].astype(np.float64)
        length = float(rec["axis_height"][3])
        base = apex + axis * length
        ext = _disc_extent(axis, length * float(rec["apex_tan"][3]))
        lo.append(np.minimum(apex, base - ext))
        hi.append(np.maximum(apex, base + ext))
    if lo:
        bounded.add(L.PRIM_CONE, np.array(lo), np.array(hi))
    return cones


def _pack_triangles(objs: list[M.Triangle | M.Mesh], eye: np.ndarray,
                    bounded: _Bounded) -> _Triangles:
    """Loose triangles and meshes as one indexed triangle list over shared vertex arrays."""
    if not objs:
        empty = np.zeros((0, 4), dtype=np.float32)
        return _Triangles(_records(L.TRIANGLE, 0), empty, empty.copy(),
                          np.zeros((0, 2), np.float32))
    sources = []  # (vertices, faces, normals, uvs, material) per object
    for obj in objs:
        if isinstance(obj, M.Triangle):
            sources.append((np.asarray(obj.vertices, dtype=np.float64), np.array([[0, 1, 2]]),
                            None, None, obj.material))
        else:
            sources.append((obj.vertices, obj.faces, obj.normals, obj.uvs, obj.material))
    counts = [len(src[0]) for src in sources]
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_vertices = int(sum(counts))
    vertices = np.zeros((n_vertices, 4), dtype=np.float32)
    vertices[:, :3] = np.concatenate([src[0] for src in sources]) - eye
    has_normals = any(src[2] is not None for src in sources)
    has_uvs = any(src[3] is not None for src in sources)
    normals = np.zeros((n_vertices if has_normals else 0, 4), dtype=np.float32)
    uvs = np.zeros((n_vertices if has_uvs else 0, 2), dtype=np.float32)
    faces, flags = [], []
    for (v, f, n, u, material), off in zip(sources, offsets, strict=True):
        faces.append(f + off)
        bits = material | (L.TRIANGLE_SMOOTH if n is not None else 0)
        bits |= L.TRIANGLE_UV if u is not None else 0
        flags.append(np.full(len(f), bits, dtype=np.int64))
        if n is not None:
            normals[off:off + len(v), :3] = n
            normals[off:off + len(v), 3] = 1.0
        if u is not None:
            uvs[off:off + len(v)] = u
    all_faces = np.concatenate(faces)
    triangles = _records(L.TRIANGLE, len(all_faces))
    triangles["v0"], triangles["v1"], triangles["v2"] = all_faces.T
    triangles["material"] = np.concatenate(flags)
    # Corner by corner: elementwise minima of three (F, 3) arrays take a tenth of the time of
    # a reduction over the middle axis of (F, 3, 3), and float32 minima widened are the same
    # numbers as float64 minima of the widened corners.
    c0, c1, c2 = (vertices[all_faces[:, k], :3] for k in range(3))
    lo = np.minimum(np.minimum(c0, c1), c2).astype(np.float64)
    hi = np.maximum(np.maximum(c0, c1), c2).astype(np.float64)
    bounded.add(L.PRIM_TRIANGLE, lo, hi)
    return _Triangles(triangles, vertices, normals, uvs)


def _pack_bvh(bounded: _Bounded, width: int,
              queue: cl.CommandQueue | None) -> tuple[WideBvh, float]:
    """The wide BVH over every bounded primitive, and the seconds it took."""
    start = time.perf_counter()
    if bounded.lo:
        lo, hi = np.concatenate(bounded.lo), np.concatenate(bounded.hi)
        # Below DEVICE_BUILD_MIN primitives the host build takes milliseconds, less than
        # fetching the device build's program from the cache.
        binary = build_bvh(lo, hi, queue=queue if len(lo) >= DEVICE_BUILD_MIN else None)
        wide = collapse(binary, np.concatenate(bounded.refs), width)
    else:
        wide = collapse(build_bvh(np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(0), width)
    return wide, time.perf_counter() - start


def _triangle_packets(prim_refs: np.ndarray, tris: _Triangles) -> np.ndarray:
    """One TrianglePacket per PACKET_WIDTH slots of prim_refs: the corners of the slots'
    triangles, coordinate by coordinate, NaN in slots that hold no triangle."""
    if len(tris.triangles) == 0:
        return _records(L.TRIANGLE_PACKET, 0)
    slots = prim_refs.reshape(-1, PACKET_WIDTH)
    is_tri = (slots >= 0) & ((slots >> L.PRIM_TYPE_SHIFT) == L.PRIM_TRIANGLE)
    faces = tris.triangles[["v0", "v1", "v2"]].view(np.int32).reshape(-1, 4)[:, :3]
    # (packet, lane, corner, axis), then the record's order: corner, axis, lane.
    corners = tris.vertices[faces[np.where(is_tri, slots & L.PRIM_INDEX_MASK, 0)], :3]
    corners[~is_tri] = np.nan
    packed = np.ascontiguousarray(corners.transpose(0, 2, 3, 1)).reshape(len(slots), -1)
    return packed.view(L.TRIANGLE_PACKET).ravel()


def _sphere_packets(prim_refs: np.ndarray, spheres: np.ndarray) -> np.ndarray:
    """One SpherePacket per PACKET_WIDTH slots of prim_refs, NaN where a slot holds no sphere."""
    if len(spheres) == 0:
        return _records(L.SPHERE_PACKET, 0)
    slots = prim_refs.reshape(-1, PACKET_WIDTH).astype(np.int64)
    is_sphere = (slots >= 0) & ((slots >> L.PRIM_TYPE_SHIFT) == L.PRIM_SPHERE)
    cr = spheres["center_radius"][np.where(is_sphere, slots & L.PRIM_INDEX_MASK, 0)]
    packets = _records(L.SPHERE_PACKET, len(slots))
    for axis, name in enumerate(("x", "y", "z", "radius")):
        packets[name] = np.where(is_sphere, cr[..., axis], np.nan)
    return packets


def _pack_materials(materials: list[M.Material]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(materials, textures, texels): image texels of every texture in one array."""
    texture_records, texel_chunks, texel_count = [], [], 0
    records = _records(L.MATERIAL, len(materials))
    for i, m in enumerate(materials):
        rec = records[i]
        rec["color"] = _f4(m.color)
        for key in ("ambient", "diffuse", "specular", "shininess", "reflect", "transmit", "ior"):
            rec[key] = getattr(m, key)
        rec["texture"] = L.TEXTURE_NONE
        rec["fresnel"] = int(m.fresnel)
        if m.texture is None:
            continue
        tex = np.zeros((), dtype=L.TEXTURE)
        tex["color2"] = _f4(m.texture.color2)
        tex["size"] = m.texture.size
        tex["repeat_u"], tex["repeat_v"] = m.texture.repeat
        tex["blend"] = m.texture.blend
        if m.texture.kind == "checker":
            tex["kind"] = L.TEXTURE_CHECKER
        else:
            img = np.asarray(m.texture.image, dtype=np.float32)
            tex["kind"] = L.TEXTURE_IMAGE
            tex["texel_offset"] = texel_count
            tex["height"], tex["width"] = img.shape[:2]
            rgba = np.zeros((img.shape[0] * img.shape[1], 4), dtype=np.float32)
            rgba[:, :3] = img.reshape(-1, 3)
            texel_chunks.append(rgba)
            texel_count += len(rgba)
        rec["texture"] = len(texture_records)
        texture_records.append(tex)
    textures = np.array(texture_records, dtype=L.TEXTURE)
    texels = (np.concatenate(texel_chunks) if texel_chunks
              else np.zeros((0, 4), dtype=np.float32))
    return records, textures, texels


def _pack_lights(lights: list[M.Light], eye: np.ndarray) -> np.ndarray:
    records = _records(L.LIGHT, len(lights))
    for i, light in enumerate(lights):
        rec = records[i]
        rec["color"] = _f4(light.color)
        if isinstance(light, M.PointLight | M.SpotLight):
            rec["kind"] = L.LIGHT_POINT
            rec["position"] = _f4(np.asarray(light.position) - eye)
            rec["attenuation"] = _f4(light.attenuation)
            if isinstance(light, M.SpotLight):
                inner = light.angle if light.inner_angle is None else light.inner_angle
                rec["kind"] = L.LIGHT_SPOT
                rec["axis_u"] = _f4(light.direction, math.cos(math.radians(light.angle)))
                rec["axis_v"] = _f4((0.0, 0.0, 0.0), math.cos(math.radians(inner)))
        elif isinstance(light, M.RectLight):
            rec["kind"] = L.LIGHT_RECT
            rec["position"] = _f4(np.asarray(light.corner) - eye)
            rec["axis_u"], rec["axis_v"] = _f4(light.u), _f4(light.v)
            rec["color"] = _f4(light.color, M.rect_area(light.u, light.v))
        elif isinstance(light, M.DiscLight):
            rec["kind"] = L.LIGHT_DISC
            rec["position"] = _f4(np.asarray(light.center) - eye, light.radius)
            rec["axis_u"] = _f4(light.normal)
            rec["color"] = _f4(light.color, math.pi * light.radius**2)
        elif isinstance(light, M.SphereLight):
            rec["kind"] = L.LIGHT_SPHERE
            rec["position"] = _f4(np.asarray(light.center) - eye, light.radius)
        else:
            rec["kind"] = L.LIGHT_DIRECTIONAL
            rec["position"] = _f4(light.direction)
    return records


def _pack_camera(camera: M.Camera, eye: np.ndarray, width: int, height: int) -> np.ndarray:
    forward, right, up, half_w, half_h = camera.basis(width, height)
    record = np.zeros(1, dtype=L.CAMERA)
    record[0]["position"] = 0.0
    record[0]["forward"] = _f4(forward)
    record[0]["right"] = _f4(right * half_w)
    record[0]["up"] = _f4(up * half_h)
    record[0]["world"] = _f4(eye)
    if camera.aperture > 0:
        focus = camera.focus_distance
        if focus is None:
            focus = float(np.linalg.norm(np.subtract(camera.look_at, camera.position)))
        radius = camera.aperture / 2.0
        record[0]["lens_u"] = _f4(right * radius, 1.0 / focus)
        record[0]["lens_v"] = _f4(up * radius)
    return record


def _pack_background(background: M.Vec3 | M.Background, params: np.ndarray,
                     texels: np.ndarray) -> np.ndarray:
    """Fill the params' background fields; the texels with an environment image appended."""
    p = params[0]
    if not isinstance(background, M.Background):
        p["background"] = _f4(background)
        return texels
    if background.kind == "gradient":
        p["background"] = _f4(background.bottom)
        p["background_top"] = _f4(background.top)
        return texels
    img = np.asarray(background.image, dtype=np.float32)
    rgba = np.zeros((img.shape[0] * img.shape[1], 4), dtype=np.float32)
    rgba[:, :3] = img.reshape(-1, 3)
    p["background_texels"] = len(texels)
    p["background_height"], p["background_width"] = img.shape[:2]
    return np.concatenate([texels, rgba])


def _stack_size_option(stack_size: int) -> int:
    """The tree's stack need rounded up to a multiple of 16, so most scenes share a build."""
    return max(16, -(-stack_size // 16) * 16)


def pack_scene(scene: M.Scene, *, width: int, height: int, spp: int, max_depth: int,
               seed: int, min_weight: float = 0.0, precision: str = "float",
               bvh_width: int = 8, queue: cl.CommandQueue | None = None,
               **variants: object) -> PackedScene:
    """`bvh_width`: children per BVH node (4 or 8; clray.device.program.bvh_width_for picks
    one per device). `queue`: build large BVHs on its device (the same tree as the host
    build). `variants` are extra KernelConfig fields (study switches, options)."""
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    kinds: dict[type, list] = {t: [] for t in (M.Sphere, M.Plane, M.Box, M.Cylinder, M.Cone)}
    triangle_objs = []
    for obj in scene.objects:
        if isinstance(obj, M.Triangle | M.Mesh):
            triangle_objs.append(obj)
        else:
            kinds[M.Sphere if isinstance(obj, M.Spheres) else type(obj)].append(obj)

    bounded = _Bounded()
    planes = _pack_planes(kinds[M.Plane], eye)
    spheres = _pack_spheres(kinds[M.Sphere], eye, bounded)
    boxes = _pack_boxes(kinds[M.Box], eye, bounded)
    cylinders = _pack_cylinders(kinds[M.Cylinder], eye, bounded)
    cones = _pack_cones(kinds[M.Cone], eye, bounded)
    tris = _pack_triangles(triangle_objs, eye, bounded)
    wide, bvh_s = _pack_bvh(bounded, bvh_width, queue)
    triangle_packets = _triangle_packets(wide.prim_refs, tris)
    sphere_packets = _sphere_packets(wide.prim_refs, spheres)
    materials, textures, texels = _pack_materials(scene.materials)
    lights = _pack_lights(scene.lights, eye)
    camera = _pack_camera(scene.camera, eye, width, height)

    params = np.zeros(1, dtype=L.PARAMS)
    p = params[0]
    texels = _pack_background(scene.render.background, params, texels)
    p["ambient"] = _f4(scene.render.ambient)
    p["width"], p["height"], p["spp"], p["max_depth"] = width, height, spp, max_depth
    p["seed"], p["min_weight"] = seed, min_weight
    p["n_planes"], p["n_lights"] = len(planes), len(lights)
    p["bvh_root_count"] = len(wide.prim_refs)

    any_reflect = any(m.reflect > 0 for m in scene.materials)
    any_transmit = any(m.transmit > 0 for m in scene.materials)
    background = scene.render.background
    background_kind = background.kind if isinstance(background, M.Background) else None
    config = KernelConfig(
        has_planes=len(planes) > 0,
        has_spheres=len(spheres) > 0,
        has_boxes=len(boxes) > 0,
        has_cylinders=len(cylinders) > 0,
        has_cones=len(cones) > 0,
        has_triangles=len(tris.triangles) > 0,
        has_vertex_normals=len(tris.normals) > 0,
        has_vertex_uvs=len(tris.uvs) > 0,
        has_textures=len(textures) > 0,
        has_transmission=any_transmit,
        has_refraction=any_transmit and max_depth > 0,
        has_spot_lights=any(isinstance(x, M.SpotLight) for x in scene.lights),
        has_area_lights=any(isinstance(x, M.AreaLight) for x in scene.lights),
        has_fresnel=max_depth > 0 and any(m.fresnel and m.transmit > 0 for m in scene.materials),
        has_thin_lens=scene.camera.aperture > 0,
        has_orthographic=scene.camera.type == "orthographic",
        has_background_gradient=background_kind == "gradient",
        has_background_image=background_kind == "image",
        max_depth=max_depth if (any_reflect or any_transmit) else 0,
        bvh_width=bvh_width,
        bvh_stack_size=_stack_size_option(wide.stack_size),
        precision=precision,
        **{"fp64_spheres": len(spheres) > 0 and needs_fp64_spheres(scene), **variants},
    )
    return PackedScene(camera, params, planes, spheres, boxes, cylinders, cones,
                       tris.triangles, triangle_packets, sphere_packets,
                       np.zeros((0, 4), dtype=np.float32),
                       tris.normals, tris.uvs, wide.nodes, wide.prim_refs, materials, textures,
                       texels, lights, config, bvh_s)
