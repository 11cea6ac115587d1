"""Scene model (+ BVH) -> PackedScene: numpy arrays in the layouts of layout.py.

Positions are made camera-relative in float64 before they are rounded to float32, so a scene
authored far from the origin keeps its precision near the eye.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, make_dataclass, replace

import numpy as np
import pyopencl as cl

from clray.accel.bvh import TRAVERSAL_COST, build_bvh, rounded_out, within_float32
from clray.accel.wide import (
    LEAF_FIELD_MASK,
    PACKET_WIDTH,
    WideBvh,
    collapse,
    fill_nodes,
    refit,
    tree_cost,
)
from clray.device import layout as L
from clray.device.bvh_builder import build_bvh_from, float_prims
from clray.device.context import opencl_errors
from clray.device.program import KernelConfig
from clray.host_memory import CHUNK_ROWS, aligned_empty, by_chunks, small_pages, trim_heap
from clray.knobs import DEFAULT_TUNING, Tuning
from clray.lights import LIGHT_OF, LIGHTS
from clray.scene import model as M
from clray.scene.emitters import scene_lights
from clray.scene.scale import needs_fp64_spheres
from clray.shapes import SHAPE_OF, SHAPES
from clray.shapes.shape import Shape, f4
from clray.shapes.sphere import SPHERE
from clray.vectors import frame_helper

# Primitive count from which pack_scene builds the BVH on the device when given a queue.
DEVICE_BUILD_MIN = 20000


def _device_bytes(self: PackedScene) -> dict[str, int]:
    """Bytes of each scene buffer on the device, in layout.SCENE_BUFFERS' order."""
    return {name: int(array.nbytes) for name, array in self.buffers().items()}


def _triangle_count(self: PackedScene) -> int:
    """The triangles of the scene and its groups (the Triangle records or material words are
    one a slot of prim_refs, the packets' padding slots included)."""
    # References from PRIM_TRIANGLE << PRIM_TYPE_SHIFT up to the next kind's, a chunk at a time:
    # temporaries of the whole prim_refs took 31 MiB at 5.24 M triangles, above the pack's peak.
    first = L.PRIM_TRIANGLE << L.PRIM_TYPE_SHIFT
    count = 0
    for at in range(0, len(self.prim_refs), CHUNK_ROWS):
        part = self.prim_refs[at:at + CHUNK_ROWS]
        count += int(np.count_nonzero((part >= first) & (part < first + (1 << L.PRIM_TYPE_SHIFT))))
    return count


def _buffers(self: PackedScene) -> dict[str, np.ndarray]:
    """The scene's buffers by name, in the kernels' parameter order (layout.SCENE_BUFFERS)."""
    return {b.name: getattr(self, b.name) for b in L.SCENE_BUFFERS}


# One numpy array per layout.SCENE_BUFFERS entry (a field of that name, in that order), then
# the build switches, the host time the BVH build took and the performance knobs it was packed
# with (clray.tuning; the launches follow them too). Made from the list, so a new buffer is one
# entry there.
PackedScene = make_dataclass(
    "PackedScene",
    [*((b.name, np.ndarray) for b in L.SCENE_BUFFERS), ("config", KernelConfig),
     ("bvh_s", float), ("tuning", Tuning, field(default=DEFAULT_TUNING))],
    frozen=True,
    namespace={"device_bytes": _device_bytes, "buffers": _buffers,
               "triangle_count": _triangle_count,
               "__doc__": "A scene packed for the kernels: layout.SCENE_BUFFERS' arrays by "
                          "name, the KernelConfig and bvh_s (host seconds of the BVH build, "
                          "or of its refit at another eye)."},
)
PackedScene.__module__ = __name__  # pickled by reference: a Dask worker finds it here


def _records(dtype: np.dtype, n: int) -> np.ndarray:
    return np.zeros(n, dtype=dtype)


def texture_frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """frame(a) of docs/rendering.md, as kernels/real.h computes it."""
    e1 = np.cross(a, frame_helper(a))
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


class _Bounded:
    """Bounds and references of the primitives that go into a BVH, kind by kind, with the
    owner of each: 0 for the scene, g + 1 for group g (each owner gets its own BVH).

    References are int32 (prim_refs' type: a kind and an index fit it) and owners are kept as
    runs, an owner per object and its primitive count: for 5 M triangles, int64 references and
    an owner a primitive took 80 MiB beside the bounds."""

    def __init__(self) -> None:
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        # Each kind's references, or the first of them where they run on from it (refs + i):
        # an array of 4 B a primitive is made only where groups or kinds are joined, or after
        # the build (collapse), not beside the device build's primitives (21 MiB at 5.24 M).
        self.refs: list[np.ndarray | int] = []
        self.owners: list[np.ndarray] = []  # runs: an owner per object...
        self.sizes: list[np.ndarray] = []  # ...and its primitives
        # Whether each kind's bounds were made from checked values (checked_bounds).
        self.checked: list[bool] = []

    def add(self, kind: int, lo: np.ndarray, hi: np.ndarray, owners: np.ndarray,
            sizes: np.ndarray, checked: bool = False) -> None:
        """Primitives of one kind; `owners` (one per object) own `sizes` of them each.
        checked: the bounds are minima and maxima of values known to be finite and within
        float32's range (clray.accel.bvh.checked_bounds's values_checked)."""
        self.checked.append(checked)
        self.lo.append(lo)
        self.hi.append(hi)
        self.refs.append(int(kind) << L.PRIM_TYPE_SHIFT)
        self.owners.append(np.asarray(owners, dtype=np.int64))
        self.sizes.append(np.asarray(sizes, dtype=np.int64))

    def owned_by(self, owner: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | int]:
        """(lo, hi, refs) of one owner's primitives; refs as collapse takes them (an array, or
        the first of a run)."""
        if not self.lo:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
        if len(self.lo) > 1:
            # Joined once: a scene with groups asks once per owner.
            self.refs = [_ref_array(refs, len(lo)) for refs, lo in zip(self.refs, self.lo,
                                                                        strict=True)]
            self.lo, self.hi, self.refs, self.owners, self.sizes = (
                [np.concatenate(part)] for part in (self.lo, self.hi, self.refs, self.owners,
                                                    self.sizes))
            self.checked = [all(self.checked)]
        lo, hi, refs = self.lo[0], self.hi[0], self.refs[0]
        runs = self.owners[0] == owner
        if runs.all():
            return lo, hi, refs
        mine = np.repeat(runs, self.sizes[0])
        return lo[mine], hi[mine], _ref_array(refs, len(lo))[mine]

    def take(self, owner: int) -> list:
        """[lo, hi, refs] of the last owner built: this _Bounded lets go of its arrays, so
        that _build_wide can free the bounds before the collapse."""
        prims = list(self.owned_by(owner))
        self.lo, self.hi, self.refs, self.owners, self.sizes = [], [], [], [], []
        self.checked = []
        return prims

    def kind_bounds(self, code: int) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float32 of the primitives of one kind, by their index, as the builds take
        them (clray.accel.bvh.rounded_out); empty where the kind has none. Before owned_by:
        each kind as added (once a kind), its references still the first of its run."""
        for lo, hi, refs in zip(self.lo, self.hi, self.refs, strict=True):
            if not isinstance(refs, int):
                raise ValueError("kind_bounds: the kinds are joined already (owned_by)")
            if refs >> L.PRIM_TYPE_SHIFT == code:
                return rounded_out(lo, hi)
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)

    def values_checked(self) -> bool:
        """Every kind's bounds made from checked values (add's `checked`)."""
        return bool(self.checked) and all(self.checked)


def _ref_array(refs: np.ndarray | int, n: int) -> np.ndarray:
    """n references as an array: `refs` itself, or the run from the first reference `refs`."""
    return refs + np.arange(n, dtype=np.int32) if isinstance(refs, int) else refs


@dataclass(frozen=True)
class _Placed:
    """Objects of one kind, each with the origin its coordinates are stored relative to (the
    eye for the scene's objects, 0 for a group's, which stay in the group's frame) and its
    owner (as in _Bounded)."""

    objects: list
    origins: np.ndarray  # (n, 3) float64
    owners: np.ndarray  # (n,) int64


@dataclass(frozen=True)
class _Faces:
    """The scene's triangles in its order, as (v0, v1, v2, material word) records: written out
    (F, 4) with `word` None, or, where the scene's triangles are one mesh of one material, the
    mesh's own int32 faces (F, 3) and that word: no copy of them (16 B a triangle) beside the
    mesh through the BVH build."""

    corners: np.ndarray  # int32, vertex indices in the first three columns
    word: int | None = None

    def __len__(self) -> int:
        return len(self.corners)

    def take(self, index: np.ndarray) -> np.ndarray:
        """The records of triangles `index`, shaped index.shape + (4,)."""
        if self.word is None:
            return np.take(self.corners, index, axis=0)
        records = np.empty((*index.shape, 4), dtype=np.int32)
        records[..., :3] = np.take(self.corners, index, axis=0)
        records[..., 3] = self.word
        return records


@dataclass(frozen=True)
class _Positions:
    """The triangles' camera-relative float32 vertex positions, taken corner by corner: the
    sources' vertices made relative (_relative_vertices: (V, 4) float32, w unused), or a mesh
    alone's own vertices and its origin, made relative as they are taken, in float64 and then
    rounded as _relative_vertices rounds them: the same numbers with no array of them all
    beside the packets (40 MiB of the pack's peak at 5.24 M triangles, for 0.03 s)."""

    vertices: np.ndarray
    origin: np.ndarray | None = None  # None: `vertices` are already relative

    def __len__(self) -> int:
        return len(self.vertices)

    def take(self, index: np.ndarray) -> np.ndarray:
        """The positions of vertices `index`, shaped index.shape + (3,) or (4,) float32."""
        taken = np.take(self.vertices, index, axis=0)
        if self.origin is None:
            return taken
        relative = np.empty(taken.shape, np.float32)
        return np.subtract(taken, self.origin, out=relative, casting="unsafe")


@dataclass(frozen=True)
class _Triangles:
    faces: _Faces  # the scene's triangles, in its order
    positions: _Positions
    normals: np.ndarray
    uvs: np.ndarray
    colors: np.ndarray  # (V, 4) float32 linear rgb, w unused; (0, 4) without vertex colours
    # The device's material words one a slot (int32) where it keeps no TRIANGLE records
    # (_in_slot_order), or the one word every triangle has; else empty.
    material_words: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    one_material: bool = False  # material_words is the one word of every triangle
    # The device's TRIANGLE records one a slot (_in_slot_order), where it keeps them.
    triangles: np.ndarray = field(default_factory=lambda: _records(L.TRIANGLE, 0))


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
        planes[i]["point"] = f4(nearest, np.dot(shift, e1))
        planes[i]["normal"] = f4(n, np.dot(shift, e2))
        planes[i]["material"] = o.material
    return planes


def _pack_shape(shape: Shape, objs: _Placed, bounded: _Bounded) -> np.ndarray:
    """One shape's records (clray.shapes), their bounds added to the BVH's input."""
    records, lo, hi = shape.pack(objs.objects, objs.origins)
    if len(records):
        sizes = [shape.primitives(obj) for obj in objs.objects]
        bounded.add(shape.prim, lo, hi, objs.owners, sizes)
    return records


def _triangle_sources(objs: _Placed) -> list[tuple]:
    """(vertices, faces, normals, uvs, material or one per face) of each loose triangle and
    mesh, in the scene's order: the mesh's own arrays."""
    sources = []
    for obj in objs.objects:
        if isinstance(obj, M.Triangle):
            sources.append((np.asarray(obj.vertices, dtype=np.float64), np.array([[0, 1, 2]]),
                            None, None, obj.material))
        else:
            material = obj.material if obj.face_materials is None else obj.face_materials
            sources.append((obj.vertices, obj.faces, obj.normals, obj.uvs, material))
    return sources


def _vertex_offsets(sources: list[tuple]) -> np.ndarray:
    """Each source's first row in the shared vertex arrays."""
    return np.concatenate([[0], np.cumsum([len(src[0]) for src in sources])[:-1]]).astype(np.int64)


def _pack_triangles(objs: _Placed, sources: list[tuple], bounded: _Bounded) -> _Faces:
    """Loose triangles and meshes (`sources`: _triangle_sources) as one indexed triangle list
    over shared vertex arrays, their bounds, taken from the camera-relative vertices
    (_relative_vertices), added to the BVH's input. The vertices are let go before the BVH
    build, the pack's highest stage (16 B a vertex: 40 MiB at 5.24 M triangles,
    docs/scale.md); the packets take them again (_vertex_arrays: a mesh alone's own vertices,
    made relative as they are taken, or the vertices of several made again)."""
    if not objs.objects:
        return _Faces(np.zeros((0, 4), np.int32))
    tints = [getattr(obj, "colors", None) for obj in objs.objects]
    faces = _scene_faces(sources, _vertex_offsets(sources), tints)
    vertices = _relative_vertices(objs, sources)
    lo, hi = _triangle_bounds(vertices, faces.corners)
    # Every vertex finite: then so is every triangle's box, and lo <= hi by construction. Two
    # passes over the vertices spare the BVH build's three over six bounds a triangle.
    bounded.add(L.PRIM_TRIANGLE, lo, hi, objs.owners, [len(src[1]) for src in sources],
                checked=within_float32(vertices))
    return faces


def _relative_vertices(objs: _Placed, sources: list[tuple]) -> np.ndarray:
    """(V, 4) float32: the sources' vertices relative to each one's origin (the eye, or 0 in
    a group), made relative in float64 and then rounded, a chunk at a time: no float64 copy
    of every vertex beside the float32 ones."""
    vertices = np.zeros((int(sum(len(src[0]) for src in sources)), 4), dtype=np.float32)
    for (v, *_), origin, off in zip(sources, objs.origins, _vertex_offsets(sources),
                                    strict=True):
        def relative(part: slice, v: np.ndarray = v, origin: np.ndarray = origin,
                     off: int = off) -> None:
            vertices[off + part.start:off + part.stop, :3] = v[part] - origin
        by_chunks(len(v), relative)
    return vertices


def _vertex_arrays(objs: _Placed, sources: list[tuple], faces: _Faces) -> _Triangles:
    """The triangles with their vertex arrays: camera-relative positions (as _pack_triangles
    made them for the bounds), normals, uvs and colours."""
    if not objs.objects:
        empty = np.zeros((0, 4), dtype=np.float32)
        return _Triangles(faces, _Positions(empty), empty.copy(), np.zeros((0, 2), np.float32),
                          empty.copy())
    positions = _positions(objs, sources)
    offsets = _vertex_offsets(sources)
    n_vertices = len(positions)
    has_normals = any(src[2] is not None for src in sources)
    has_uvs = any(src[3] is not None for src in sources)
    normals = np.zeros((n_vertices if has_normals else 0, 4), dtype=np.float32)
    uvs = np.zeros((n_vertices if has_uvs else 0, 2), dtype=np.float32)
    tints = [getattr(obj, "colors", None) for obj in objs.objects]
    colors = np.zeros((n_vertices if any(c is not None for c in tints) else 0, 4), np.float32)
    for (v, _, n, u, _), off, c in zip(sources, offsets, tints, strict=True):
        if c is not None:
            colors[off:off + len(v), :3] = c
        if n is not None:
            normals[off:off + len(v), :3] = n
            normals[off:off + len(v), 3] = 1.0
        if u is not None:
            uvs[off:off + len(v)] = u
    return _Triangles(faces, positions, normals, uvs, colors)


def _positions(objs: _Placed, sources: list[tuple]) -> _Positions:
    """The triangles' camera-relative positions: a mesh alone's made relative as they are
    taken, several sources' made relative together (_relative_vertices)."""
    if len(sources) == 1:
        return _Positions(sources[0][0], objs.origins[0])
    return _Positions(_relative_vertices(objs, sources))


def _scene_faces(sources: list[tuple], offsets: np.ndarray, tints: list) -> _Faces:
    """The sources' triangles as _Faces: one mesh of one material keeps its int32 faces;
    otherwise the records are written source by source (no joined face list beside them)."""
    words = [material | (L.TRIANGLE_SMOOTH if n is not None else 0)
             | (L.TRIANGLE_UV if u is not None else 0) | (L.TRIANGLE_COLOR if c is not None else 0)
             for (_, _, n, u, material), c in zip(sources, tints, strict=True)]
    faces = sources[0][1]
    if len(sources) == 1 and np.ndim(words[0]) == 0 and faces.dtype == np.int32 \
            and faces.flags.c_contiguous:
        return _Faces(faces, int(words[0]))
    rows = np.empty((sum(len(src[1]) for src in sources), 4), dtype=np.int32)
    start = 0
    for (_, f, *_), off, word in zip(sources, offsets, words, strict=True):
        rows[start:start + len(f), :3] = f + off if off else f
        rows[start:start + len(f), 3] = word
        start += len(f)
    return _Faces(rows)


def _triangle_bounds(vertices: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (F, 3) float32 of the triangles whose vertex indices are the first three
    columns of `corners` (F, 3 or 4) int32: views of the device build's primitive records
    (bvh_builder.float_prims), which a build over these triangles alone takes as they are: no
    bounds beside its primitives (24 B a triangle) and no pass that copies them in.

    Corner by corner: elementwise minima of three (F, 4) arrays take a tenth of the time of a
    reduction over the middle axis of (F, 3, 3), and float32 minima widened are the same
    numbers as float64 minima of the widened corners. Whole rows taken (np.take along axis
    0), not vertices[index, :3]: numpy's fancy index with a slice is four times slower. The
    bounds stay float32 (the BVH builds take them as the same numbers as their float64 copies
    would be). A chunk of triangles at a time: the corners of them all took 48 B a triangle
    beside the bounds."""
    lo, hi = float_prims(len(corners))

    def bound(part: slice) -> None:
        c0, c1, c2 = (np.take(vertices, corners[part, k], axis=0) for k in range(3))
        # + 0: every zero +0.0, as the builds' own rounding passes make them (a device build
        # that consumes these records has none): -0.0 and +0.0 compare equal, so which one a
        # minimum or maximum keeps depends on the reduction's order, and the builds' differ.
        hi[part] = np.maximum(np.maximum(c0, c1), c2)[:, :3] + np.float32(0)
        lo[part] = np.minimum(np.minimum(c0, c1, out=c0), c2, out=c0)[:, :3] + np.float32(0)
    by_chunks(len(corners), bound, row_items=4)
    return lo, hi


def _build_wide(prims: list[np.ndarray], width: int, queue: cl.CommandQueue | None,
                tuning: Tuning, one_per_leaf: bool = False,
                values_checked: bool = False) -> WideBvh:
    """prims: [lo, hi, refs], emptied here: where the caller holds the arrays nowhere else
    (_Bounded.take), the bounds (24 B a triangle) are freed once the device build has copied
    them (build_bvh_from), or the host build is done, before the collapse. one_per_leaf:
    every leaf holds one primitive, so each one's box is a lane of its parent's vector slab
    test (the scene's tree where it holds instances). values_checked: _Bounded's."""
    refs = prims.pop()
    # Below DEVICE_BUILD_MIN primitives the host build takes milliseconds, less than fetching
    # the device build's program from the cache.
    # The device build compiles the default traversal cost in: another one builds on the host.
    leaves = ({"max_leaf_size": 1, "largest_leaf": 1} if one_per_leaf else
              {"max_leaf_size": tuning.max_leaf_size, "largest_leaf": tuning.largest_leaf})
    on_device = (queue is not None and len(prims[0]) >= DEVICE_BUILD_MIN
                 and tuning.traversal_cost == TRAVERSAL_COST)
    if on_device:
        with opencl_errors(queue.device, "the device BVH build failed"):
            binary = build_bvh_from(queue, prims, **leaves, pairs=True,
                                    values_checked=values_checked, consume=True)
    else:
        binary = build_bvh(*prims, traversal_cost=tuning.traversal_cost, **leaves)
        prims.clear()
    return collapse(binary, refs, width, tuning.fold_packets)


# Relative widening of an instance's bounds in the scene's frame: its matrices are rounded to
# float32, so the kernel's group-frame hits can land that much outside the exact image of the
# group's bounds.
_INSTANCE_BOUND_SLACK = 1e-5


def _pack_instances(instances: list[M.Instance], group_of: np.ndarray,
                    group_bounds: list[tuple[np.ndarray, np.ndarray]], eye: np.ndarray,
                    bounded: _Bounded) -> np.ndarray:
    """INSTANCE records (to_object in the packed, camera-relative frame; roots left for the
    caller), their bounds added to the scene's BVH input (the records do not keep them: an
    instance's box is its lane's in the scene tree, kernels/clray_types.h). group_of: each
    one's group index. All instances at once: a thousand cost a few milliseconds."""
    records = _records(L.INSTANCE, len(instances))
    if not instances:
        return records
    to_world = np.array([inst.matrix for inst in instances], dtype=np.float64)
    to_world[:, :, 3] -= eye
    linear_inverse = np.linalg.inv(to_world[:, :, :3])
    records["to_object"] = np.concatenate(
        [linear_inverse, -(linear_inverse @ to_world[:, :, 3:])], axis=2)
    records["material"] = [-1 if inst.material is None else inst.material for inst in instances]
    # The eight corners of each group's box, mapped by each instance's transform.
    lo = np.array([b[0] for b in group_bounds])[group_of]
    hi = np.array([b[1] for b in group_bounds])[group_of]
    pick = (np.arange(8)[:, None] >> np.arange(3)) & 1  # (8, 3): which corner takes hi
    corners = np.where(pick[None], hi[:, None], lo[:, None])  # (N, 8, 3)
    placed = np.einsum("nij,nkj->nki", to_world[:, :, :3], corners) + to_world[:, None, :, 3]
    plo, phi = placed.min(axis=1), placed.max(axis=1)
    slack = _INSTANCE_BOUND_SLACK * (np.abs(placed).max(axis=(1, 2)) + (phi - plo).max(axis=1))
    plo, phi = plo - slack[:, None], phi + slack[:, None]
    bounded.add(L.PRIM_INSTANCE,
                np.nextafter(plo.astype(np.float32), np.float32(-np.inf)).astype(np.float64),
                np.nextafter(phi.astype(np.float32), np.float32(np.inf)).astype(np.float64),
                [0], [len(instances)])
    return records


def _instance_lanes(wide: WideBvh) -> WideBvh:
    """The scene's tree with each leaf that holds one instance alone made an instance lane of
    its node (child: the instance's index, count ENTER_INSTANCE; the lane's box is the
    instance's, kernels/clray_types.h) and its slots dropped: no leaf of four slots, and no
    second test of the box the node's vector test has just passed."""
    nodes = wide.nodes.copy()
    child, count = nodes["child"], nodes["count"]
    refs = wide.prim_refs
    alone = count == 1  # one primitive outside the packets
    alone[alone] = (refs[child[alone]] >> L.PRIM_TYPE_SHIFT) == L.PRIM_INSTANCE
    if not alone.any():
        return wide
    dropped = np.zeros(len(refs) // PACKET_WIDTH, dtype=bool)
    dropped[child[alone] // PACKET_WIDTH] = True
    child[alone] = refs[child[alone]] & L.PRIM_INDEX_MASK
    count[alone] = L.ENTER_INSTANCE
    # Leaves start at multiples of PACKET_WIDTH: each moves down by the slots dropped before it.
    kept_before = np.cumsum(~dropped) - ~dropped
    leaf = count > 0
    child[leaf] = kept_before[child[leaf] // PACKET_WIDTH] * PACKET_WIDTH
    prim_refs = refs.reshape(-1, PACKET_WIDTH)[~dropped].ravel()
    return WideBvh(nodes, prim_refs, wide.width, wide.stack_size)


def _append(nodes: np.ndarray, wide: WideBvh, node_offset: int, slot_offset: int) -> None:
    """Writes a tree's nodes into `nodes` (its rows of the scene's joined nodes) with their
    children renumbered for its place there: inner children by node_offset, leaves by
    slot_offset."""
    nodes[...] = wide.nodes
    inner = (nodes["count"] == 0) & (nodes["child"] >= 0)
    nodes["child"] += np.where(inner, node_offset, np.where(nodes["count"] > 0, slot_offset, 0))


def _pack_bvh(bounded: _Bounded, n_groups: int, instances: list[M.Instance],
              group_of: np.ndarray, eye: np.ndarray, width: int,
              queue: cl.CommandQueue | None, tuning: Tuning
              ) -> tuple[WideBvh, np.ndarray, list[tuple[np.ndarray, np.ndarray]], int, float]:
    """The wide BVH of the scene's bounded primitives and instances, each group's BVH appended
    after it, the INSTANCE records, each group's box, the groups' slots (the first of
    prim_refs, before the scene's) and the seconds it took."""
    start = time.perf_counter()
    group_trees, group_bounds = [], []
    for g in range(n_groups):
        lo, hi, refs = bounded.owned_by(g + 1)
        group_trees.append(_build_wide([lo, hi, refs], width, queue, tuning,
                                       values_checked=bounded.values_checked()))
        group_bounds.append((lo.min(axis=0), hi.max(axis=0)))
    # The scene's tree comes first (its root is node 0): the groups' roots are known after it.
    records = _pack_instances(instances, group_of, group_bounds, eye, bounded)
    values_checked = bounded.values_checked()
    prims = bounded.take(0)
    # Where instances are most of the scene's tree, one primitive a leaf; a large mesh of the
    # scene's own beside a few instances keeps its packed leaves.
    one_per_leaf = bool(instances) and 2 * len(instances) >= len(prims[0])
    wide = _build_wide(prims, width, queue, tuning, one_per_leaf=one_per_leaf,
                       values_checked=values_checked)
    if not instances:
        return wide, records, group_bounds, 0, time.perf_counter() - start
    wide = _instance_lanes(wide)
    if one_per_leaf:
        wide = fill_nodes(wide)
    # Nodes: the scene's tree first, then each group's. Slots: the groups' first, so that the
    # scene's leaves of instances come last and need no packets (_slot_triangles).
    slot_offsets = np.cumsum([0] + [len(tree.prim_refs) for tree in group_trees])
    node_offsets = np.cumsum([0, len(wide.nodes)] + [len(tree.nodes) for tree in group_trees])
    # Allocated aligned to a node's size, as the collapse allocates a tree's: a CPU device
    # reads them in place (clray/device/buffers.py), where joined by np.concatenate they
    # were copied for the render.
    dtype = wide.nodes.dtype
    nodes = aligned_empty((int(node_offsets[-1]),), dtype, dtype.itemsize)
    _append(nodes[:len(wide.nodes)], wide, 0, int(slot_offsets[-1]))
    for tree, slot_offset, first, end in zip(group_trees, slot_offsets[:-1], node_offsets[1:-1],
                                             node_offsets[2:], strict=True):
        _append(nodes[first:end], tree, int(first), int(slot_offset))
    records["root"] = node_offsets[1:-1].astype(np.int64)[group_of]
    # At a leaf the walk pushes the leaf's instances (an instance lane is pushed as a node's
    # child), then one LEAVE_INSTANCE entry and the group's walk above it.
    leaf = wide.nodes["count"] > 0
    per_leaf = int(np.max(wide.nodes["count"][leaf] & LEAF_FIELD_MASK, initial=0))
    stack_size = (wide.stack_size + per_leaf + 1 +
                  max(tree.stack_size for tree in group_trees))
    prim_refs = np.concatenate([*(tree.prim_refs for tree in group_trees), wide.prim_refs])
    return (WideBvh(nodes, prim_refs, width, stack_size), records, group_bounds,
            int(slot_offsets[-1]), time.perf_counter() - start)


def _packet_slots(prim_refs: np.ndarray, prim: int) -> tuple[np.ndarray, np.ndarray]:
    """prim_refs as packets of PACKET_WIDTH slots, through the last packet that holds a
    primitive of kind `prim` (the kernel reads none past it), and which slots hold one."""
    slots = prim_refs.reshape(-1, PACKET_WIDTH)
    is_kind = (slots >= 0) & ((slots >> L.PRIM_TYPE_SHIFT) == prim)
    used = _through_last(is_kind)
    return slots[:used], is_kind[:used]


def _through_last(is_kind: np.ndarray) -> int:
    """Packets up to and including the last one with a lane of the kind (rows of is_kind)."""
    holding = np.flatnonzero(is_kind.any(axis=1))
    return int(holding[-1]) + 1 if len(holding) else 0


def _slot_triangles(prim_refs: np.ndarray, tris: _Triangles) -> tuple[np.ndarray, _Triangles]:
    """The triangle packets, one per PACKET_WIDTH slots of prim_refs through the last packet
    that holds a triangle (the kernel reads none past it), and the triangles as the device
    keeps them (_in_slot_order).

    A chunk of packets at a time: each slot's (v0, v1, v2, material) record is taken (one take
    of 16-byte rows, not three of a strided field), its corners go into the packet, and the
    record is kept (the slot's material word alone where the device keeps no more). Records of
    every slot at once took 16 B a slot beside the packets, at the pack's peak."""
    slots, is_tri = _packet_slots(prim_refs, L.PRIM_TRIANGLE)
    used = len(slots)
    whole = bool(len(tris.normals) or len(tris.uvs) or len(tris.colors))
    # A mesh of one material (_Faces.word) keeps its one word: nothing a slot to keep.
    one_word = None if whole else tris.faces.word
    kept = (None if one_word is not None else
            np.empty((used, PACKET_WIDTH, 4) if whole else (used, PACKET_WIDTH), np.int32))
    packets = np.empty((used, 3, 3, PACKET_WIDTH), dtype=np.float32)

    def gather(part: slice) -> None:
        records = _packets_of(packets, part, slots[part], is_tri[part], tris.faces,
                              tris.positions, whole=kept is not None)
        if kept is not None:
            kept[part] = records if whole else records[..., 3]
    by_chunks(used, gather, row_items=PACKET_WIDTH)
    packets = packets.reshape(used, -1).view(L.TRIANGLE_PACKET).ravel()
    if one_word is not None:
        return packets, _Triangles(tris.faces, tris.positions, tris.normals, tris.uvs,
                                   tris.colors, np.array([one_word], dtype=np.int32),
                                   one_material=True)
    return packets, _in_slot_order(kept, is_tri, tris)


def _packets_of(packets: np.ndarray, part: slice, slots: np.ndarray, is_tri: np.ndarray,
                faces: _Faces, positions: _Positions, whole: bool) -> np.ndarray:
    """Writes packets[part] (packets, 3 corners, 3 axes, PACKET_WIDTH) from those packets'
    `slots` of prim_refs: each triangle slot's corners, NaN in the lanes of a packet that are
    not triangles. Returns the slots' face records (whole: with their material words), zero
    where a slot is not a triangle."""
    index = np.where(is_tri, slots & L.PRIM_INDEX_MASK, 0)
    records = faces.take(index) if whole else np.take(faces.corners, index, axis=0)
    records[~is_tri] = 0
    # Corner by corner, whole vertex rows taken (np.take along axis 0: a fancy index with a
    # slice is several times slower), then the packet's order: corner, axis, lane.
    for k in range(3):
        packets[part, k] = positions.take(records[:, :, k])[..., :3].transpose(0, 2, 1)
    partial = part.start + np.flatnonzero(~is_tri.all(axis=1))
    packets[partial] = np.where(is_tri[partial - part.start, None, None, :], packets[partial],
                                np.nan)
    return records


def _fill_packets(packets: np.ndarray, prim_refs: np.ndarray, faces: _Faces,
                  positions: _Positions, first: int = 0) -> None:
    """The triangle packets (TRIANGLE_PACKET records) from packet `first` on written again in
    place from `faces` and `positions` for the slots of prim_refs they were made for
    (_slot_triangles)."""
    slots, is_tri = _packet_slots(prim_refs[first * PACKET_WIDTH:], L.PRIM_TRIANGLE)
    corners = packets[first:first + len(slots)].view(np.float32).reshape(
        len(slots), 3, 3, PACKET_WIDTH)
    by_chunks(len(slots), lambda part: _packets_of(corners, part, slots[part], is_tri[part],
                                                   faces, positions, whole=False),
              row_items=PACKET_WIDTH)


def _slot_bounds(prim_refs: np.ndarray, triangle_packets: np.ndarray, bounded: _Bounded,
                 first: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (slots, 3) float32 of each slot's primitive from packet `first` on: a
    triangle's from its packet's corners (the numbers _triangle_bounds takes from the same
    positions), any other kind's from `bounded` (its shapes and instances); +inf and -inf
    where a slot holds none, and before packet `first`."""
    lo = np.full((len(prim_refs), 3), np.inf, dtype=np.float32)
    hi = np.full((len(prim_refs), 3), -np.inf, dtype=np.float32)
    kind = np.where(prim_refs >= 0, prim_refs >> L.PRIM_TYPE_SHIFT, -1)
    kind[:first * PACKET_WIDTH] = -1
    index = prim_refs & L.PRIM_INDEX_MASK
    corners = triangle_packets.view(np.float32).reshape(-1, 3, 3, PACKET_WIDTH)[first:]
    start = first * PACKET_WIDTH
    is_tri = (kind[start:start + corners.shape[0] * PACKET_WIDTH] == L.PRIM_TRIANGLE)[:, None]

    def bound(part: slice) -> None:
        # Elementwise over the three corners (a reduction over their axis is several times
        # slower), then a row a slot; + 0 as _triangle_bounds makes every zero +0.0.
        c = corners[part]
        mine = slice(part.start * PACKET_WIDTH, part.stop * PACKET_WIDTH)
        rows = slice(start + mine.start, start + mine.stop)
        for out, pick, empty in ((lo, np.minimum, np.inf), (hi, np.maximum, -np.inf)):
            slots = pick(pick(c[:, 0], c[:, 1]), c[:, 2]).transpose(0, 2, 1).reshape(-1, 3)
            out[rows] = np.where(is_tri[mine], slots + np.float32(0), np.float32(empty))
    by_chunks(corners.shape[0], bound, row_items=PACKET_WIDTH)
    for code in {int(r) >> L.PRIM_TYPE_SHIFT for r in bounded.refs}:
        kind_lo, kind_hi = bounded.kind_bounds(code)
        mine = np.flatnonzero(kind == code)
        lo[mine], hi[mine] = kind_lo[index[mine]], kind_hi[index[mine]]
    return lo, hi


def _in_slot_order(kept: np.ndarray, is_tri: np.ndarray, tris: _Triangles) -> _Triangles:
    """The device's triangle records and vertex arrays from `kept`, the slots' records
    (packets, PACKET_WIDTH, 4), or their material words (packets, PACKET_WIDTH) where the
    triangles have no vertex normals, uvs or colours: the records one a slot, as the kernels
    read them (a hit's part is its slot), and the vertex normals, uvs and colours renumbered
    in the order the slots use them. A ray's hit then reads a record and vertices near its
    neighbours' instead of wherever the file put them: on the 327,680-triangle bumpy mesh,
    1 spp, this took a third of the render kernel's cache misses to memory
    (docs/acceleration.md). The same numbers, so the same images.

    Without vertex normals, uvs and colours the kernels read nothing of a record but its
    material word (kernels/scene.h: HAS_VERTEX_ATTRIBUTES, set by the switches that these
    arrays' sizes set), so the device keeps the words alone: 4 bytes a slot instead of 16;
    and where every triangle's word is the same (a model of one material), that word alone
    (KernelConfig.has_one_triangle_material)."""
    normals, uvs, colors = tris.normals, tris.uvs, tris.colors
    if kept.ndim == 2:
        words = kept.ravel()
        if is_tri.any():
            first = words[np.argmax(is_tri.ravel())]
            if not np.any((kept != first) & is_tri):
                return _Triangles(tris.faces, tris.positions, normals, uvs, colors,
                                  np.array([first], dtype=np.int32), one_material=True)
        return _Triangles(tris.faces, tris.positions, normals, uvs, colors, words)
    # Each vertex keyed by a slot that uses it (numpy's assignment keeps one of them: any is
    # near the others), unused vertices last; the new numbering sorts the keys.
    key = np.full(len(tris.positions), kept.shape[0] * PACKET_WIDTH, dtype=np.int64)
    uses = kept[..., :3]
    key[uses[is_tri].ravel()] = np.repeat(np.flatnonzero(is_tri.ravel()), 3)
    order = np.argsort(key, kind="stable")
    renumber = np.empty(len(order), dtype=np.int32)
    renumber[order] = np.arange(len(order), dtype=np.int32)
    kept[..., :3] = np.where(is_tri[..., None], renumber[uses], 0)
    normals, uvs, colors = (a[order] if len(a) else a for a in (normals, uvs, colors))
    triangles = kept.reshape(-1, 4).view(L.TRIANGLE).ravel()
    return _Triangles(tris.faces, tris.positions, normals, uvs, colors, triangles=triangles)


def _sphere_packets(prim_refs: np.ndarray, spheres: np.ndarray) -> np.ndarray:
    """One SpherePacket per PACKET_WIDTH slots of prim_refs, NaN where a slot holds no sphere."""
    if len(spheres) == 0:
        return _records(L.SPHERE_PACKET, 0)
    slots, is_sphere = _packet_slots(prim_refs, SPHERE.prim)
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
        rec["color"] = f4(m.color)
        for key in ("ambient", "diffuse", "specular", "shininess", "reflect", "transmit", "ior"):
            rec[key] = getattr(m, key)
        rec["texture"] = L.TEXTURE_NONE
        rec["fresnel"] = int(m.fresnel)
        rec["emission"] = f4(m.emission)
        if m.texture is None:
            continue
        tex = np.zeros((), dtype=L.TEXTURE)
        tex["color2"] = f4(m.texture.color2)
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


def _pack_lights(lights: tuple[M.Light, ...], eye: np.ndarray) -> np.ndarray:
    """The lights' records, the n_lights the kernels loop over, then the parts a light's
    samples pick among (a mesh light's faces), which only their light's record points to."""
    kinds = [LIGHT_OF[type(light)] for light in lights]
    counts = [kind.parts(light) if kind.parts else 0
              for kind, light in zip(kinds, lights, strict=True)]
    records = _records(L.LIGHT, len(lights) + sum(counts))
    first = len(lights)
    for i, (kind, light, count) in enumerate(zip(kinds, lights, counts, strict=True)):
        records[i]["kind"] = kind.code
        records[i]["color"] = f4(light.color)  # w: an area light's area, from its fields
        kind.fields(records[i], light, eye)
        if count:
            records[i]["pad0"], records[i]["pad1"] = first, count
            kind.part_fields(records[first:first + count], light, eye)
            first += count
    return records


def _pack_camera(camera: M.Camera, eye: np.ndarray, width: int, height: int) -> np.ndarray:
    forward, right, up, half_w, half_h = camera.basis(width, height)
    record = np.zeros(1, dtype=L.CAMERA)
    record[0]["position"] = 0.0
    record[0]["forward"] = f4(forward)
    record[0]["right"] = f4(right * half_w)
    record[0]["up"] = f4(up * half_h)
    record[0]["world"] = f4(eye)
    if camera.aperture > 0:
        focus = camera.focus_distance
        if focus is None:
            focus = float(np.linalg.norm(np.subtract(camera.look_at, camera.position)))
        radius = camera.aperture / 2.0
        record[0]["lens_u"] = f4(right * radius, 1.0 / focus)
        record[0]["lens_v"] = f4(up * radius)
    return record


def _pack_background(background: M.Vec3 | M.Background, params: np.ndarray,
                     texels: np.ndarray) -> np.ndarray:
    """Fill the params' background fields; the texels with an environment image appended."""
    p = params[0]
    if not isinstance(background, M.Background):
        p["background"] = f4(background)
        return texels
    if background.kind == "gradient":
        p["background"] = f4(background.bottom)
        p["background_top"] = f4(background.top)
        return texels
    img = np.asarray(background.image, dtype=np.float32)
    rgba = np.zeros((img.shape[0] * img.shape[1], 4), dtype=np.float32)
    rgba[:, :3] = img.reshape(-1, 3)
    p["background_texels"] = len(texels)
    p["background_height"], p["background_width"] = img.shape[:2]
    return np.concatenate([texels, rgba])


def _by_kind(objects: tuple[M.SceneObject, ...], groups: list[M.Group], eye: np.ndarray
             ) -> dict[type, _Placed]:
    """The scene's objects (stored relative to the eye) and then each group's (in its own
    frame), sorted by the array they pack into: Plane, each shape's model (a `spheres` array
    with Sphere), Triangle (with Mesh)."""
    owned = [(obj, eye, 0) for obj in objects if not isinstance(obj, M.Instance)]
    owned += [(obj, np.zeros(3), g + 1) for g, group in enumerate(groups) for obj in group.objects]
    array_of = {M.Mesh: M.Triangle, **{t: shape.model for t, shape in SHAPE_OF.items()}}
    kinds = {}
    for kind in (M.Plane, *(shape.model for shape in SHAPES), M.Triangle):
        mine = [item for item in owned if array_of.get(type(item[0]), type(item[0])) is kind]
        kinds[kind] = _Placed([item[0] for item in mine],
                              np.array([item[1] for item in mine]).reshape(-1, 3),
                              np.array([item[2] for item in mine], dtype=np.int64))
    return kinds


def _groups_of(instances: list[M.Instance]) -> tuple[list[M.Group], np.ndarray]:
    """The groups the instances place, by identity in order of first use, and each instance's
    index among them."""
    groups: dict[int, M.Group] = {}
    for inst in instances:
        groups.setdefault(id(inst.group), inst.group)
    index = {key: g for g, key in enumerate(groups)}
    return list(groups.values()), np.array([index[id(inst.group)] for inst in instances],
                                           dtype=np.int64)


def _scene_switches(scene: M.Scene, lights: tuple[M.Light, ...],
                    max_depth: int) -> dict[str, object]:
    """The KernelConfig switches that follow from the materials, lights, camera and
    background (the geometry's follow from the packed arrays)."""
    any_reflect = any(m.reflect > 0 for m in scene.materials)
    any_transmit = any(m.transmit > 0 for m in scene.materials)
    background = scene.render.background
    background_kind = background.kind if isinstance(background, M.Background) else None
    return {
        "has_transmission": any_transmit,
        "has_refraction": any_transmit and max_depth > 0,
        **_light_switches(lights),
        "has_fresnel": max_depth > 0 and any(m.fresnel and m.transmit > 0
                                             for m in scene.materials),
        "has_thin_lens": scene.camera.aperture > 0,
        "has_orthographic": scene.camera.type == "orthographic",
        "has_background_gradient": background_kind == "gradient",
        "has_background_image": background_kind == "image",
        "max_depth": max_depth if (any_reflect or any_transmit) else 0,
    }


def _light_switches(lights: tuple[M.Light, ...]) -> dict[str, bool]:
    """The lights' KernelConfig switches: each kind's own (has_spot_lights) and has_area_lights,
    on where a light of the scene needs them."""
    kinds = {LIGHT_OF[type(light)] for light in lights}
    switches = {kind.switch: False for kind in LIGHTS if kind.switch}
    switches.update({kind.switch: True for kind in kinds if kind.switch})
    switches["has_area_lights"] = any(kind.area for kind in kinds)
    return switches


def _stack_size_option(stack_size: int) -> int:
    """The tree's stack need rounded up to a multiple of 16, so most scenes share a build."""
    return max(16, -(-stack_size // 16) * 16)


# A refitted scene tree (instances or shapes moved, clray.sequence) whose cost a ray
# (wide.tree_cost) has grown past this many times the tree's as built is not used: the frame is
# packed afresh. A rigid turn or slide of a few instances stays well within it, while instances
# that have changed places can make every inner box span the scene. Each frame's tree so costs
# at most 1.5 times frame 0's as built, or is built for that frame; either way it is a function
# of frame 0 and the frame alone, so the images do not depend on which frames a run renders.
REFIT_COST_LIMIT = 1.5


@dataclass(eq=False)
class SceneGeometry:
    """A scene's objects packed at an eye: the arrays that pack_scene joins to the scene's
    materials, lights and camera. pack_geometry makes it at frame 0 of an animation whose
    frames share a packing (clray.sequence); pack_scene(geometry=...) moves it to another
    frame's eye, instances' places and planes' and shapes' values (_moved_to): their records
    are made again there, and the scene's tree keeps its shape with each box made again from
    them (wide.refit), instead of a new build; the groups' trees, in their own frames, are
    kept as they are. Moving it writes over its arrays in place (the triangle packets and the
    nodes, the largest, among them), so a PackedScene made from it is good until the next
    move: it is the geometry of the last frame moved to, and holds nothing beside what that
    frame's PackedScene holds but the triangles' faces, which each move takes the corners
    through."""

    eye: np.ndarray  # float64, what the positions are relative to; NaN while being moved
    placements: np.ndarray  # float64 (instances, 3, 4): the instances' matrices
    group_of: np.ndarray  # each instance's group (_groups_of)
    planes: np.ndarray
    shapes: dict[str, np.ndarray]  # each shape's records by its buffer's name
    tris: _Triangles  # in slot order (_slot_triangles), without the positions
    triangle_packets: np.ndarray
    sphere_packets: np.ndarray
    wide: WideBvh  # the scene's tree, then each group's
    instances: np.ndarray  # INSTANCE records
    group_bounds: list[tuple[np.ndarray, np.ndarray]]  # each group's box, in its frame
    # The groups' packets, before the scene's: in the groups' own frames, where no move
    # changes them.
    group_packets: int
    # Seconds of BVH work (the build, then each refit) that no PackedScene has reported yet.
    bvh_s: float
    bvh_width: int
    tuning: Tuning
    # The scene tree's wide.tree_cost as built (None until the first move: a still render
    # never needs it), and as last refitted.
    built_cost: float | None = None
    cost: float = 0.0


@dataclass(frozen=True)
class _AtEye:
    """What a scene's objects give at an eye before any BVH: the instances and the groups they
    place, the objects by kind (relative to the eye, a group's in its own frame), the planes'
    and shapes' records, and the bounded primitives so far (pack_geometry's and _moved_to's
    first steps)."""

    instances: list[M.Instance]
    groups: list[M.Group]
    group_of: np.ndarray
    kinds: dict[type, _Placed]
    bounded: _Bounded
    planes: np.ndarray
    shapes: dict[str, np.ndarray]


def _at(scene: M.Scene, eye: np.ndarray) -> _AtEye:
    """The scene's objects at `eye` (_AtEye)."""
    instances = [obj for obj in scene.objects if isinstance(obj, M.Instance)]
    groups, group_of = _groups_of(instances)
    kinds = _by_kind(scene.objects, groups, eye)
    bounded = _Bounded()
    planes = _pack_planes(kinds[M.Plane].objects, eye)
    shapes = {shape.buffer: _pack_shape(shape, kinds[shape.model], bounded) for shape in SHAPES}
    return _AtEye(instances, groups, group_of, kinds, bounded, planes, shapes)


@small_pages
def pack_geometry(scene: M.Scene, *, bvh_width: int = 8, queue: cl.CommandQueue | None = None,
                  tuning: Tuning = DEFAULT_TUNING) -> SceneGeometry:
    """The scene's objects packed at its eye, with their BVH (pack_scene's arguments)."""
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    at = _at(scene, eye)
    kinds = at.kinds
    sources = _triangle_sources(kinds[M.Triangle])
    faces = _pack_triangles(kinds[M.Triangle], sources, at.bounded)
    wide, instance_records, group_bounds, group_slots, bvh_s = _pack_bvh(
        at.bounded, len(at.groups), at.instances, at.group_of, eye, bvh_width, queue, tuning)
    # The build's and the collapse's temporaries, freed: their heap pages go back before
    # the packets take their place.
    trim_heap()
    tris = _vertex_arrays(kinds[M.Triangle], sources, faces)
    if len(tris.faces):
        triangle_packets, tris = _slot_triangles(wide.prim_refs, tris)
    else:
        triangle_packets = _records(L.TRIANGLE_PACKET, 0)
    sphere_packets = _sphere_packets(wide.prim_refs, at.shapes[SPHERE.buffer])
    # The positions are in the packets: kept, they would be frame 0's for a whole sequence.
    tris = replace(tris, positions=_Positions(np.zeros((0, 4), np.float32)))
    return SceneGeometry(eye, _placements(at.instances), at.group_of, at.planes, at.shapes, tris,
                         triangle_packets, sphere_packets, wide, instance_records, group_bounds,
                         group_slots // PACKET_WIDTH, bvh_s, bvh_width, tuning)


def _placements(instances: list[M.Instance]) -> np.ndarray:
    """The instances' matrices, (instances, 3, 4) float64: where a move finds them."""
    return np.array([inst.matrix for inst in instances], dtype=np.float64).reshape(-1, 3, 4)


def _same_primitives(geometry: SceneGeometry, at: _AtEye, sources: list[tuple]) -> bool:
    """Whether the objects of `at` (their triangles' `sources`) pack into as many planes,
    shapes of each kind and triangles as `geometry` holds, with instances of the same groups:
    the slots of its tree are theirs. Which triangles, and where in their groups' frames, is
    the caller's word (pack_scene's `geometry`)."""
    return (len(at.planes) == len(geometry.planes)
            and all(len(at.shapes[b]) == len(geometry.shapes[b]) for b in geometry.shapes)
            and sum(len(source[1]) for source in sources) == len(geometry.tris.faces)
            and np.array_equal(at.group_of, geometry.group_of))


def _moved_to(geometry: SceneGeometry, scene: M.Scene) -> SceneGeometry | None:
    """`geometry`, made of the same primitives as `scene`'s, moved to `scene`'s eye, its
    instances' places and its planes' and shapes' values: in place, and returned; None, and
    nothing moved, where `scene` has other primitives (_same_primitives). Everything that
    depends on them is made again as pack_geometry makes it (planes, shapes, instances, the
    scene's own triangle packets; the groups' are in their own frames), but the BVH, which
    is refitted: the boxes a build of that shape would have, its cost in geometry.cost. The
    image is a fresh pack's but where a ray meets two primitives at one distance: a tree of
    another shape may take the other one."""
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    at = _at(scene, eye)
    triangles = at.kinds[M.Triangle]
    sources = _triangle_sources(triangles)
    if not _same_primitives(geometry, at, sources):
        return None
    placements = _placements(at.instances)
    if (np.array_equal(eye, geometry.eye) and np.array_equal(placements, geometry.placements)
            and at.planes.tobytes() == geometry.planes.tobytes()
            and all(at.shapes[b].tobytes() == geometry.shapes[b].tobytes()
                    for b in geometry.shapes)):
        return geometry
    # Until the move is done, no eye: a move that fails part way leaves arrays of two eyes,
    # which no later frame at the old eye may take as they are.
    geometry.eye = np.full(3, np.nan)
    geometry.planes, geometry.shapes = at.planes, at.shapes
    roots = geometry.instances["root"]
    geometry.instances = _pack_instances(at.instances, at.group_of, geometry.group_bounds, eye,
                                         at.bounded)
    geometry.instances["root"] = roots
    prim_refs = geometry.wide.prim_refs
    # The groups' packets are in their own frames: no move changes them.
    first = geometry.group_packets
    if len(geometry.triangle_packets) > first:
        _fill_packets(geometry.triangle_packets, prim_refs, geometry.tris.faces,
                      _positions(triangles, sources), first)
    geometry.sphere_packets = _sphere_packets(prim_refs, at.shapes[SPHERE.buffer])
    start = time.perf_counter()
    nodes, traversal_cost = geometry.wide.nodes, geometry.tuning.traversal_cost
    if geometry.built_cost is None:  # the first move: the tree is still the build's
        geometry.built_cost = tree_cost(nodes, traversal_cost)
    refit(nodes, *_slot_bounds(prim_refs, geometry.triangle_packets, at.bounded, first),
          *at.bounded.kind_bounds(L.PRIM_INSTANCE))
    geometry.cost = tree_cost(nodes, traversal_cost)
    geometry.eye, geometry.placements = eye, placements
    geometry.bvh_s += time.perf_counter() - start
    return geometry


@small_pages
def pack_scene(scene: M.Scene, *, width: int, height: int, spp: int, max_depth: int,
               seed: int, min_weight: float = 0.0, precision: str = "float",
               bvh_width: int = 8, queue: cl.CommandQueue | None = None,
               tuning: Tuning = DEFAULT_TUNING, geometry: SceneGeometry | None = None,
               **variants: object) -> PackedScene:
    """`bvh_width`: children per BVH node (4 or 8; clray.device.policy.bvh_width_for picks
    one per device). `queue`: build large BVHs on its device (the same tree as the host
    build). `tuning`: the other knobs of the BVH build, and of the launches (kept in the
    PackedScene). `geometry`: this scene's objects as pack_geometry packed them at another
    frame of its animation (with this bvh_width and tuning: ValueError if not), whose meshes,
    triangles and groups are this scene's, moved to this scene's eye, instances' places and
    planes' and shapes' values instead of packed afresh; packed afresh where the frames'
    primitives differ in number or the refitted tree's cost has grown past REFIT_COST_LIMIT.
    `variants` are extra KernelConfig fields (study switches, options)."""
    if geometry is None:
        geometry = pack_geometry(scene, bvh_width=bvh_width, queue=queue, tuning=tuning)
    elif (geometry.bvh_width, geometry.tuning) != (bvh_width, tuning):
        raise ValueError("pack_scene: the geometry was packed with another BVH width or tuning")
    else:
        moved = _moved_to(geometry, scene)
        # built_cost is None only before the first move, while cost is still 0.
        if moved is None or moved.cost > REFIT_COST_LIMIT * (moved.built_cost or 0.0):
            fresh = pack_geometry(scene, bvh_width=bvh_width, queue=queue, tuning=tuning)
            fresh.bvh_s += geometry.bvh_s  # a refit's time, spent too
            geometry.bvh_s = 0.0
            moved = fresh
        geometry = moved
    planes, shapes, tris, wide = geometry.planes, geometry.shapes, geometry.tris, geometry.wide
    eye = geometry.eye
    bvh_s, geometry.bvh_s = geometry.bvh_s, 0.0
    materials, textures, texels = _pack_materials(scene.materials)
    every_light = scene_lights(scene)  # its emissive faces found once, for both uses
    lights = _pack_lights(every_light, eye)
    camera = _pack_camera(scene.camera, eye, width, height)

    params = np.zeros(1, dtype=L.PARAMS)
    p = params[0]
    texels = _pack_background(scene.render.background, params, texels)
    p["ambient"] = f4(scene.render.ambient)
    p["width"], p["height"], p["spp"], p["max_depth"] = width, height, spp, max_depth
    p["seed"], p["min_weight"] = seed, min_weight
    p["n_planes"], p["n_lights"] = len(planes), len(every_light)
    p["n_nodes"] = len(wide.nodes)

    config = KernelConfig(
        has_planes=len(planes) > 0,
        **{shape.switch: len(shapes[shape.buffer]) > 0 for shape in SHAPES},
        has_triangles=len(geometry.triangle_packets) > 0,
        has_vertex_normals=len(tris.normals) > 0,
        has_vertex_uvs=len(tris.uvs) > 0,
        has_vertex_colors=len(tris.colors) > 0,
        has_one_triangle_material=tris.one_material,
        has_textures=len(textures) > 0,
        has_instances=len(geometry.instances) > 0,
        **_scene_switches(scene, every_light, max_depth),
        bvh_width=bvh_width,
        bvh_stack_size=_stack_size_option(wide.stack_size),
        precision=precision,
        **{"fp64_spheres": len(shapes[SPHERE.buffer]) > 0 and needs_fp64_spheres(scene),
           **variants},
    )
    return PackedScene(camera=camera, params=params, planes=planes, **shapes,
                       triangles=tris.triangles, triangle_materials=tris.material_words,
                       triangle_packets=geometry.triangle_packets,
                       sphere_packets=geometry.sphere_packets,
                       normals=tris.normals, uvs=tris.uvs, colors=tris.colors,
                       nodes=wide.nodes,
                       prim_refs=wide.prim_refs, materials=materials, textures=textures,
                       texels=texels, lights=lights, instances=geometry.instances,
                       config=config, bvh_s=bvh_s, tuning=tuning)
