"""The oracle's scene traversal (kernels/bvh.h), by brute force: every ray against every
primitive, closest_hit with the kernels' tie rule, and the transmission of shadow rays."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clray.accel.prim_refs import PRIM_TRIANGLE
from clray.reference.intersect import INTERSECT, intersect_triangle
from clray.reference.shading import SHAPE_SURFACE
from clray.reference.texture import MaterialTable
from clray.scene.check import check_scene
from clray.scene.model import (
    Cone,
    Cylinder,
    Instance,
    Mesh,
    Plane,
    Scene,
    SceneObject,
    Sphere,
    Spheres,
    Triangle,
)
from clray.shapes import SHAPES
from clray.vectors import safe_normalize

# Ties in t go to the earlier type in this order, then to the earlier object in the scene: the
# kernels' type codes (clray.accel.prim_refs, Shape.prim). Triangles (loose and mesh),
# intersected as one batch, come after the shapes of TIE_ORDER with smaller codes and before
# those of AFTER_TRIANGLES.
TIE_ORDER: tuple[type, ...] = (Plane, *(shape.model for shape in
                                        sorted(SHAPES, key=lambda shape: shape.prim)))
AFTER_TRIANGLES: tuple[type, ...] = tuple(shape.model for shape in SHAPES
                                          if shape.prim > PRIM_TRIANGLE)
# Rays x triangles handled per numpy step: bounds memory to a few tens of MB.
_TRIANGLE_BATCH = 1 << 17
# Crossings whose t differ by at most this, relative to t, tie (docs/rendering.md): 64 roundings,
# gamma(64) in float64 as the kernels' double build has it.
TIE_TOLERANCE = 64 * (np.finfo(np.float64).eps / 2) / (1 - 64 * np.finfo(np.float64).eps / 2)


def _tie_floor(best_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """A later primitive's t must be below this to beat best_t: nearer by more than a tie."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(best_t),
                        best_t - TIE_TOLERANCE * np.maximum(best_t, np.abs(t)), np.inf)


class SceneHit(NamedTuple):
    """Closest hits of N rays. On a miss: t = inf, normals and uv zero, indices -1."""

    t: np.ndarray  # (N,)
    # (N, 3) geometric normal n_g, outward / as given (-d for a degenerate triangle), not flipped
    normal: np.ndarray
    shading_normal: np.ndarray  # (N, 3) n_g, or the blended vertex normals; not flipped
    uv: np.ndarray  # (N, 2) texture coordinates
    obj: np.ndarray  # (N,) index into scene.objects
    face: np.ndarray  # (N,) triangle index within a mesh (0 for a Triangle object), else -1
    material: np.ndarray  # (N,) index into scene.materials
    tint: np.ndarray  # (N, 3) blended vertex colours (Mesh.colors), ones elsewhere
    # (N,) v runs pole to pole or rim to rim (a sphere; a cylinder's or cone's side): the
    # kernels' v_ends_apart, which image_texel clamps rather than wraps at v's ends
    ends_apart: np.ndarray


class _Nearest(NamedTuple):
    """Per ray, the nearest crossing so far: a shape (index into Geometry.shapes, and the
    face it hit) or a triangle (index, and its barycentrics b1, b2), -1 for neither."""

    t: np.ndarray
    shape: np.ndarray
    part: np.ndarray
    triangle: np.ndarray
    b: np.ndarray


def _expanded(spheres: Spheres) -> list[Sphere]:
    return [Sphere(tuple(c), float(r), int(m)) for c, r, m in
            zip(spheres.centers.tolist(), spheres.radii.tolist(), spheres.materials.tolist(),
                strict=True)]


class Geometry:
    """A scene's (or a group's) objects flattened in tie order: shapes one by one, triangles
    as arrays, instances last with their group's geometry."""

    def __init__(self, objects: tuple[SceneObject, ...]) -> None:
        # A `spheres` array is that many Sphere objects at its place in the scene order.
        indexed = [(i, sphere) for i, ob in enumerate(objects)
                   for sphere in (_expanded(ob) if isinstance(ob, Spheres) else (ob,))]
        # Instances after every other shape (ties go to the scene's own shapes first), each
        # with its group's geometry, built once per group.
        groups: dict[int, Geometry] = {}
        self.instances: list[_Placement] = []
        for i, ob in enumerate(objects):
            if isinstance(ob, Instance):
                if id(ob.group) not in groups:
                    groups[id(ob.group)] = Geometry(ob.group.objects)
                self.instances.append(_Placement(i, ob, groups[id(ob.group)],
                                                 np.linalg.inv(ob.matrix[:, :3])))
        # Stable sort: within a type, scene order is kept.
        self.shapes: list[tuple[int, SceneObject]] = sorted(
            ((i, ob) for i, ob in indexed if type(ob) in INTERSECT),
            key=lambda item: TIE_ORDER.index(type(item[1])),
        )
        self._flatten_triangles(indexed)

    def _flatten_triangles(self, indexed: list[tuple[int, SceneObject]]) -> None:
        """Loose triangles and mesh faces as (T, 3, ...) arrays, with their object, face and
        material; NaN vertex normals / uvs mark triangles without them, white vertex colours
        those without colours."""
        # Each list starts with an empty block so that a scene without triangles concatenates.
        verts, normals, uvs = [np.zeros((0, 3, 3))], [np.zeros((0, 3, 3))], [np.zeros((0, 3, 2))]
        tints = [np.zeros((0, 3, 3))]
        obj, face, mat = ([np.zeros(0, dtype=np.int64)] for _ in range(3))
        for i, ob in indexed:
            if isinstance(ob, Triangle):
                tri = np.asarray(ob.vertices, dtype=np.float64)[None]
                verts.append(tri)
                normals.append(np.full((1, 3, 3), np.nan))
                uvs.append(np.full((1, 3, 2), np.nan))
                tints.append(np.ones((1, 3, 3)))
                faces = np.zeros(1, dtype=np.int64)
            elif isinstance(ob, Mesh):
                f = np.asarray(ob.faces, dtype=np.int64)
                verts.append(np.asarray(ob.vertices, dtype=np.float64)[f])
                nrm = np.full((len(f), 3, 3), np.nan) if ob.normals is None else ob.normals[f]
                uv = np.full((len(f), 3, 2), np.nan) if ob.uvs is None else ob.uvs[f]
                normals.append(np.asarray(nrm, dtype=np.float64))
                uvs.append(np.asarray(uv, dtype=np.float64))
                tints.append(np.ones((len(f), 3, 3)) if ob.colors is None
                             else np.asarray(ob.colors, dtype=np.float64)[f])
                faces = np.arange(len(f), dtype=np.int64)
            else:
                continue
            obj.append(np.full(len(faces), i, dtype=np.int64))
            face.append(faces)
            if isinstance(ob, Mesh) and ob.face_materials is not None:
                mat.append(np.asarray(ob.face_materials, dtype=np.int64))
            else:
                mat.append(np.full(len(faces), ob.material, dtype=np.int64))
        self.tri_v = np.concatenate(verts)
        self.tri_n = np.concatenate(normals)
        self.tri_uv = np.concatenate(uvs)
        self.tri_tint = np.concatenate(tints)
        self.tri_obj = np.concatenate(obj)
        self.tri_face = np.concatenate(face)
        self.tri_mat = np.concatenate(mat)

    def _triangle_batches(self, n_rays: int) -> list[slice]:
        size = max(1, _TRIANGLE_BATCH // max(n_rays, 1))
        return [slice(start, start + size) for start in range(0, len(self.tri_v), size)]

    def closest_hit(self, o: np.ndarray, d: np.ndarray) -> SceneHit:
        """The nearest hit at t > 0 of each ray, ties by docs/rendering.md."""
        nearest = self._nearest(o, d)
        hit = self._hit_record(nearest, o, d)
        for placement in self.instances:
            hit = placement.nearer(hit, o, d)
        return hit

    def _nearest(self, o: np.ndarray, d: np.ndarray) -> _Nearest:
        n = len(o)
        best_t = np.full(n, np.inf)
        best_shape = np.full(n, -1, dtype=np.int64)
        best_part = np.zeros(n, dtype=np.int64)
        best_tri = np.full(n, -1, dtype=np.int64)
        best_b = np.zeros((n, 2))
        nearest = _Nearest(best_t, best_shape, best_part, best_tri, best_b)
        self._nearest_shapes(o, d, nearest, after_triangles=False)
        self._nearest_triangles(o, d, nearest)
        self._nearest_shapes(o, d, nearest, after_triangles=True)
        return nearest

    def _nearest_shapes(self, o: np.ndarray, d: np.ndarray, nearest: _Nearest,
                        after_triangles: bool) -> None:
        """The shapes' crossings into `nearest`: those of TIE_ORDER before the triangles, or
        those of AFTER_TRIANGLES."""
        best_t, best_shape, best_part = nearest.t, nearest.shape, nearest.part
        for k, (_, ob) in enumerate(self.shapes):
            if (type(ob) in AFTER_TRIANGLES) != after_triangles:
                continue
            for t, part in INTERSECT[type(ob)](ob, o, d):
                # Shapes come in tie order: a later one wins only when nearer beyond a tie.
                better = (t > 0.0) & (t < _tie_floor(best_t, t))
                best_t[better] = t[better]
                best_shape[better] = k
                best_part[better] = part[better]
                nearest.triangle[better] = -1

    def _nearest_triangles(self, o: np.ndarray, d: np.ndarray, nearest: _Nearest) -> None:
        n = len(o)
        best_t, best_shape, best_tri, best_b = (nearest.t, nearest.shape, nearest.triangle,
                                                nearest.b)
        rows = np.arange(n)
        for batch in self._triangle_batches(n):
            t, b1, b2 = intersect_triangle(self.tri_v[batch], o, d)
            # The first (in file order) of the triangles that tie with the batch's nearest.
            closest = t.min(axis=1, keepdims=True)
            j = np.argmax(t <= closest + TIE_TOLERANCE * closest, axis=1)
            tj = t[rows, j]
            better = tj < _tie_floor(best_t, tj)
            best_t[better] = tj[better]
            best_shape[better] = -1
            best_tri[better] = batch.start + j[better]
            best_b[better] = np.stack([b1[rows, j], b2[rows, j]], axis=-1)[better]

    def _hit_record(self, nearest: _Nearest, o: np.ndarray, d: np.ndarray) -> SceneHit:
        """Normals, uv, object and material at the nearest crossings."""
        n = len(o)
        p = o + np.where(np.isfinite(nearest.t), nearest.t, 0.0)[:, None] * d
        normal = np.zeros((n, 3))
        shading = np.zeros((n, 3))
        uv = np.zeros((n, 2))
        obj = np.full(n, -1, dtype=np.int64)
        face = np.full(n, -1, dtype=np.int64)
        material = np.full(n, -1, dtype=np.int64)
        tint = np.ones((n, 3))
        ends_apart = np.zeros(n, dtype=bool)
        for k, (i, ob) in enumerate(self.shapes):
            m = nearest.shape == k
            if m.any():
                normal[m], uv[m] = SHAPE_SURFACE[type(ob)](ob, p[m], nearest.part[m])
                if isinstance(ob, Sphere):
                    ends_apart[m] = True
                elif isinstance(ob, Cylinder | Cone):
                    ends_apart[m] = nearest.part[m] == 0
                shading[m] = normal[m]
                obj[m], material[m] = i, ob.material
        m = nearest.triangle >= 0
        if m.any():
            tri = nearest.triangle[m]
            b1, b2 = nearest.b[m, 0], nearest.b[m, 1]
            bary = np.stack([1.0 - b1 - b2, b1, b2], axis=-1)[:, :, None]
            v = self.tri_v[tri]
            winding = safe_normalize(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))
            # A degenerate triangle (zero cross product) has no normal: it faces the ray, as
            # in kernels/triangle.h (triangle_surface).
            facing = (np.linalg.norm(winding, axis=-1) > 0.0)[:, None]
            normal[m] = np.where(facing, winding, -d[m])
            smooth = np.sum(bary * self.tri_n[tri], axis=1)
            # Without vertex normals (NaN) or where they cancel out, shade with n_g.
            usable = (np.linalg.norm(smooth, axis=-1) > 0.0)[:, None]
            shading[m] = np.where(usable, safe_normalize(smooth), normal[m])
            blended_uv = np.sum(bary * self.tri_uv[tri], axis=1)
            uv[m] = np.where(np.isnan(blended_uv), np.stack([b1, b2], axis=-1), blended_uv)
            obj[m], face[m], material[m] = self.tri_obj[tri], self.tri_face[tri], self.tri_mat[tri]
            tint[m] = np.sum(bary * self.tri_tint[tri], axis=1)
        return SceneHit(nearest.t, normal, shading, uv, obj, face, material, tint, ends_apart)

    def transmission(
        self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, filters: np.ndarray
    ) -> np.ndarray:
        """Product of filters[material] over every surface crossing with 0 < t < tmax."""
        n = len(o)
        out = np.ones((n, 3))
        for _, ob in self.shapes:
            for t, _ in INTERSECT[type(ob)](ob, o, d):
                crossed = (t > 0.0) & (t < tmax)
                out[crossed] *= filters[ob.material]
        for batch in self._triangle_batches(n):
            t, _, _ = intersect_triangle(self.tri_v[batch], o, d)
            crossed = t < tmax[:, None]  # misses are inf, and t > 0 already holds
            tri_filters = filters[self.tri_mat[batch]]
            out *= np.prod(np.where(crossed[:, :, None], tri_filters[None], 1.0), axis=1)
        for placement in self.instances:
            inst = placement.instance
            mine = filters if inst.material is None else np.broadcast_to(
                filters[inst.material], filters.shape)
            out *= placement.group.transmission(*placement.to_group(o, d), tmax, mine)
        return out


class _Placement(NamedTuple):
    """An instance (objects[index]) with its group's geometry and the inverse of its matrix's
    linear part."""

    index: int
    instance: Instance
    group: Geometry
    inverse: np.ndarray

    def to_group(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays in the group's frame: d is mapped, not normalised, so t stays the same."""
        return (o - self.instance.matrix[:, 3]) @ self.inverse.T, d @ self.inverse.T

    def nearer(self, hit: SceneHit, o: np.ndarray, d: np.ndarray) -> SceneHit:
        """`hit` with this instance's hits where they are nearer beyond a tie. Normals go back
        by the inverse transpose of the instance's matrix (instance_normal in the kernels)."""
        local = self.group.closest_hit(*self.to_group(o, d))
        better = (local.t > 0.0) & (local.t < _tie_floor(hit.t, local.t))
        if not better.any():
            return hit
        t, normal, shading, uv, obj, face, material, tint, ends_apart = (
            np.array(field) for field in hit)
        t[better] = local.t[better]
        normal[better] = safe_normalize(local.normal[better] @ self.inverse)
        shading[better] = safe_normalize(local.shading_normal[better] @ self.inverse)
        uv[better] = local.uv[better]
        obj[better] = self.index
        face[better] = local.face[better]
        replaced = self.instance.material
        material[better] = local.material[better] if replaced is None else replaced
        tint[better] = local.tint[better]
        ends_apart[better] = local.ends_apart[better]
        return SceneHit(t, normal, shading, uv, obj, face, material, tint, ends_apart)


def intersect_scene(scene: Scene, origins: np.ndarray, directions: np.ndarray) -> SceneHit:
    """Closest hit (t > 0, ties by docs/rendering.md) of each ray with the scene's objects
    (the scene checked and normalised as render() takes it)."""
    scene = check_scene(scene)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return Geometry(scene.objects).closest_hit(o, d)


def transmission(
    scene: Scene, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float
) -> np.ndarray:
    """(N, 3): the product of transmit * colour over every surface crossing with 0 < t < tmax
    (the scene checked and normalised as render() takes it)."""
    scene = check_scene(scene)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(o),))
    filters = MaterialTable(scene.materials).filter
    return Geometry(scene.objects).transmission(o, d, tmax, filters)
