"""Scene model (+ BVH) -> PackedScene: numpy arrays in the layouts of layout.py.

Positions are made camera-relative in float64 before they are rounded to float32, so a scene
authored far from the origin keeps its precision near the eye.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from clray.accel.bvh import build_bvh
from clray.device import layout as L
from clray.device.program import KernelConfig
from clray.scene import model as M
from clray.scene.scale import needs_fp64_spheres


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
    vertices: np.ndarray  # (V, 4) float32
    normals: np.ndarray  # (V, 4) float32, or empty
    uvs: np.ndarray  # (V, 2) float32, or empty
    nodes: np.ndarray
    prim_refs: np.ndarray  # int32
    materials: np.ndarray
    textures: np.ndarray
    texels: np.ndarray  # (T, 4) float32
    lights: np.ndarray
    config: KernelConfig
    bvh_s: float  # host time to build the BVH

    def device_bytes(self) -> dict[str, int]:
        names = ("planes", "spheres", "boxes", "cylinders", "cones", "triangles", "vertices",
                 "normals", "uvs", "nodes", "prim_refs", "materials", "textures", "texels",
                 "lights")
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


def pack_scene(scene: M.Scene, *, width: int, height: int, spp: int, max_depth: int,
               seed: int, precision: str = "float", **variants: object) -> PackedScene:
    """`variants` are extra KernelConfig fields (study switches, build options)."""
    eye = np.asarray(scene.camera.position, dtype=np.float64)

    def rel(p: tuple | np.ndarray) -> np.ndarray:
        return np.asarray(p, dtype=np.float64) - eye

    kinds: dict[type, list] = {t: [] for t in (M.Sphere, M.Plane, M.Box, M.Cylinder, M.Cone)}
    tri_vertices: list[np.ndarray] = []
    tri_faces: list[np.ndarray] = []
    tri_normals: list[np.ndarray | None] = []
    tri_uvs: list[np.ndarray | None] = []
    tri_material: list[int] = []
    for obj in scene.objects:
        if isinstance(obj, M.Triangle):
            tri_vertices.append(np.asarray(obj.vertices, dtype=np.float64))
            tri_faces.append(np.array([[0, 1, 2]]))
            tri_normals.append(None)
            tri_uvs.append(None)
            tri_material.append(obj.material)
        elif isinstance(obj, M.Mesh):
            tri_vertices.append(obj.vertices)
            tri_faces.append(obj.faces)
            tri_normals.append(obj.normals)
            tri_uvs.append(obj.uvs)
            tri_material.append(obj.material)
        else:
            kinds[type(obj)].append(obj)

    planes = _records(L.PLANE, len(kinds[M.Plane]))
    for i, o in enumerate(kinds[M.Plane]):
        n = np.asarray(o.normal, dtype=np.float64)
        # The plane's point nearest the eye is the best-conditioned point to store; its
        # texture coordinates keep (u, v) anchored at the point the scene gave.
        nearest = n * np.dot(rel(o.point), n)
        e1, e2 = texture_frame(n)
        shift = nearest - rel(o.point)
        planes[i]["point"] = _f4(nearest, np.dot(shift, e1))
        planes[i]["normal"] = _f4(n, np.dot(shift, e2))
        planes[i]["material"] = o.material

    lo_list: list[np.ndarray] = []
    hi_list: list[np.ndarray] = []
    ref_list: list[np.ndarray] = []

    def add_bounds(kind: int, lo: np.ndarray, hi: np.ndarray) -> None:
        lo_list.append(lo)
        hi_list.append(hi)
        ref_list.append((kind << L.PRIM_TYPE_SHIFT) | np.arange(len(lo), dtype=np.int64))

    spheres = _records(L.SPHERE, len(kinds[M.Sphere]))
    for i, o in enumerate(kinds[M.Sphere]):
        spheres[i]["center_radius"] = _f4(rel(o.center), o.radius)
        spheres[i]["material"] = o.material
    if len(spheres):
        cr = spheres["center_radius"].astype(np.float64)
        add_bounds(L.PRIM_SPHERE, cr[:, :3] - cr[:, 3:], cr[:, :3] + cr[:, 3:])

    boxes = _records(L.BOX, len(kinds[M.Box]))
    for i, o in enumerate(kinds[M.Box]):
        boxes[i]["lo"] = _f4(rel(o.min))
        boxes[i]["hi"] = _f4(rel(o.max))
        boxes[i]["material"] = o.material
    if len(boxes):
        add_bounds(L.PRIM_BOX, boxes["lo"][:, :3].astype(np.float64),
                   boxes["hi"][:, :3].astype(np.float64))

    cylinders = _records(L.CYLINDER, len(kinds[M.Cylinder]))
    cyl_lo, cyl_hi = [], []
    for i, o in enumerate(kinds[M.Cylinder]):
        cylinders[i]["base_radius"] = _f4(rel(o.base), o.radius)
        cylinders[i]["axis_height"] = _f4(o.axis, o.height)
        cylinders[i]["material"] = o.material
        cylinders[i]["capped"] = int(o.capped)
        base = cylinders[i]["base_radius"][:3].astype(np.float64)
        axis = cylinders[i]["axis_height"][:3].astype(np.float64)
        top = base + axis * float(cylinders[i]["axis_height"][3])
        ext = _disc_extent(axis, float(cylinders[i]["base_radius"][3]))
        cyl_lo.append(np.minimum(base, top) - ext)
        cyl_hi.append(np.maximum(base, top) + ext)
    if cyl_lo:
        add_bounds(L.PRIM_CYLINDER, np.array(cyl_lo), np.array(cyl_hi))

    cones = _records(L.CONE, len(kinds[M.Cone]))
    cone_lo, cone_hi = [], []
    for i, o in enumerate(kinds[M.Cone]):
        cones[i]["apex_tan"] = _f4(rel(o.apex), np.tan(np.radians(o.angle)))
        cones[i]["axis_height"] = _f4(o.axis, o.height)
        cones[i]["material"] = o.material
        cones[i]["capped"] = int(o.capped)
        apex = cones[i]["apex_tan"][:3].astype(np.float64)
        axis = cones[i]["axis_height"][:3].astype(np.float64)
        length = float(cones[i]["axis_height"][3])
        base = apex + axis * length
        ext = _disc_extent(axis, length * float(cones[i]["apex_tan"][3]))
        cone_lo.append(np.minimum(apex, base - ext))
        cone_hi.append(np.maximum(apex, base + ext))
    if cone_lo:
        add_bounds(L.PRIM_CONE, np.array(cone_lo), np.array(cone_hi))

    has_normals = any(n is not None for n in tri_normals)
    has_uvs = any(u is not None for u in tri_uvs)
    if tri_vertices:
        counts = [len(v) for v in tri_vertices]
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        positions = np.concatenate(tri_vertices) - eye
        vertices = np.zeros((len(positions), 4), dtype=np.float32)
        vertices[:, :3] = positions
        faces = np.concatenate([f + off for f, off in zip(tri_faces, offsets, strict=True)])
        flags = []
        for f, mat, n, u in zip(tri_faces, tri_material, tri_normals, tri_uvs, strict=True):
            bits = mat | (L.TRIANGLE_SMOOTH if n is not None else 0)
            bits |= L.TRIANGLE_UV if u is not None else 0
            flags.append(np.full(len(f), bits, dtype=np.int64))
        triangles = _records(L.TRIANGLE, len(faces))
        triangles["v0"], triangles["v1"], triangles["v2"] = faces.T
        triangles["material"] = np.concatenate(flags)
        corners = vertices[faces, :3].astype(np.float64)
        add_bounds(L.PRIM_TRIANGLE, corners.min(axis=1), corners.max(axis=1))
    else:
        vertices = np.zeros((0, 4), dtype=np.float32)
        triangles = _records(L.TRIANGLE, 0)
    normals = np.zeros((len(vertices) if has_normals else 0, 4), dtype=np.float32)
    uvs = np.zeros((len(vertices) if has_uvs else 0, 2), dtype=np.float32)
    if tri_vertices:
        for v, off, n, u in zip(tri_vertices, offsets, tri_normals, tri_uvs, strict=True):
            if n is not None:
                normals[off:off + len(v), :3] = n
                normals[off:off + len(v), 3] = 1.0
            if u is not None:
                uvs[off:off + len(v)] = u

    start = time.perf_counter()
    if lo_list:
        bvh = build_bvh(np.concatenate(lo_list), np.concatenate(hi_list))
        prim_refs = np.concatenate(ref_list)[bvh.order].astype(np.int32)
        nodes = bvh.nodes
    else:
        prim_refs = np.zeros(0, dtype=np.int32)
        nodes = _records(L.BVH_NODE, 0)
    bvh_s = time.perf_counter() - start

    texture_records, texel_chunks, texel_count = [], [], 0
    materials = _records(L.MATERIAL, len(scene.materials))
    for i, m in enumerate(scene.materials):
        rec = materials[i]
        rec["color"] = _f4(m.color)
        for key in ("ambient", "diffuse", "specular", "shininess", "reflect", "transmit", "ior"):
            rec[key] = getattr(m, key)
        rec["texture"] = L.TEXTURE_NONE
        if m.texture is not None:
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

    lights = _records(L.LIGHT, len(scene.lights))
    for i, light in enumerate(scene.lights):
        lights[i]["color"] = _f4(light.color)
        if isinstance(light, M.PointLight):
            lights[i]["kind"] = L.LIGHT_POINT
            lights[i]["position"] = _f4(rel(light.position))
            lights[i]["attenuation"] = _f4(light.attenuation)
        else:
            lights[i]["kind"] = L.LIGHT_DIRECTIONAL
            lights[i]["position"] = _f4(light.direction)

    forward, right, up, half_w, half_h = scene.camera.basis(width, height)
    camera = np.zeros(1, dtype=L.CAMERA)
    camera[0]["position"] = 0.0
    camera[0]["forward"] = _f4(forward)
    camera[0]["right"] = _f4(right * half_w)
    camera[0]["up"] = _f4(up * half_h)
    camera[0]["world"] = _f4(eye)

    params = np.zeros(1, dtype=L.PARAMS)
    p = params[0]
    p["background"] = _f4(scene.render.background)
    p["ambient"] = _f4(scene.render.ambient)
    p["width"], p["height"], p["spp"], p["max_depth"] = width, height, spp, max_depth
    p["seed"] = seed
    p["n_planes"], p["n_lights"] = len(planes), len(lights)
    p["bvh_root_count"] = len(prim_refs)

    any_reflect = any(m.reflect > 0 for m in scene.materials)
    any_transmit = any(m.transmit > 0 for m in scene.materials)
    config = KernelConfig(
        has_planes=len(planes) > 0,
        has_spheres=len(spheres) > 0,
        has_boxes=len(boxes) > 0,
        has_cylinders=len(cylinders) > 0,
        has_cones=len(cones) > 0,
        has_triangles=len(triangles) > 0,
        has_vertex_normals=has_normals,
        has_vertex_uvs=has_uvs,
        has_textures=len(textures) > 0,
        has_refraction=any_transmit and max_depth > 0,
        max_depth=max_depth if (any_reflect or any_transmit) else 0,
        precision=precision,
        **{"fp64_spheres": len(spheres) > 0 and needs_fp64_spheres(scene), **variants},
    )
    return PackedScene(camera, params, planes, spheres, boxes, cylinders, cones, triangles,
                       vertices, normals, uvs, nodes, prim_refs, materials, textures, texels,
                       lights, config, bvh_s)
