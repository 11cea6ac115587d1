"""Binary BVH -> wide BVH (kernels/clray_types.h: BvhNode) with leaves laid out for packets.

A wide node holds up to `width` children (4 or 8) with their bounds stored axis by axis, so the
kernel tests all of a node's children with one vector slab test. Each wide node is grown from a
binary node by opening its child of largest surface area until it has `width` children or only
leaves are left: the greedy collapse of Wald et al. 2008 ("Getting rid of packets") that Embree
uses. The binary tree is SAH-built, so the wide tree inherits its partition.

A wide node below the root whose children are all leaves, and which would hold FOLD_PACKETS
packet tests or fewer as one leaf, is folded into its parent as that leaf: choosing among a few
packets is not worth a node visit (about a packet test) and a node's bytes. The SAH decided
those splits for a binary node; in the wide tree each such split costs a whole wide node.

Leaves are re-laid out in `prim_refs` for the kernel's packets: a leaf's triangles come first, in
groups of PACKET_WIDTH (the last group padded with NO_REF), then its spheres likewise, then its
other primitives. Every leaf starts at a multiple of PACKET_WIDTH, so slot // PACKET_WIDTH indexes
the packet arrays, and a child's `count` holds the three section sizes: triangle packets <<
LEAF_TRIANGLE_SHIFT | sphere packets << LEAF_SPHERE_SHIFT | others.

Everything is numpy over one wide level at a time: the Python loop runs per level and per
opened child (at most width - 2 per level), never per node.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from clray.accel import prim_refs as P
from clray.accel.bvh import Bvh
from clray.knobs import KNOBS
from clray.shapes.sphere import SPHERE

PACKET_WIDTH = 4
LEAF_TRIANGLE_SHIFT = 16
LEAF_SPHERE_SHIFT = 8
LEAF_FIELD_MASK = 0xFF
NO_REF = -1
# The node widths the kernels are built for (-DBVH_WIDTH).
BVH_WIDTHS = (4, 8)
# A node of leaves only that one leaf of this many packet tests (triangle packets, sphere
# packets, other primitives one each) would cover is folded into that leaf. A tunable knob
# (clray.tuning): its default comes from the knob table.
FOLD_PACKETS = KNOBS["fold_packets"].default


def bvh_node_dtype(width: int) -> np.dtype:
    """A wide node (kernels/clray_types.h's BvhNode for -DBVH_WIDTH=width): its children's
    bounds axis by axis, then each child's index and count."""
    lane_f = ("<f4", (width,))
    lane_i = ("<i4", (width,))
    return np.dtype([*[(f"{side}_{axis}", *lane_f) for side in ("lo", "hi") for axis in "xyz"],
                     ("child", *lane_i), ("count", *lane_i)])


@dataclass(frozen=True)
class WideBvh:
    """`nodes` in bvh_node_dtype(width), root first; `prim_refs` as laid out above.

    `stack_size` bounds the kernels' traversal stack for this tree: the most entries a
    closest-hit or shadow walk can hold at once.
    """

    nodes: np.ndarray
    prim_refs: np.ndarray
    width: int
    stack_size: int


def collapse(bvh: Bvh, refs: np.ndarray, width: int,
             fold_packets: int | None = None) -> WideBvh:
    """Wide BVH of `width` children per node from a binary `bvh` over primitives whose
    references (PRIM_* << PRIM_TYPE_SHIFT | index) are `refs[i]` for build input i.
    `fold_packets`: the folding bound (None: FOLD_PACKETS)."""
    if width not in BVH_WIDTHS:
        raise ValueError(f"BVH width must be 4 or 8, got {width}")
    dtype = bvh_node_dtype(width)
    b = bvh.nodes
    if b.size == 0:
        return WideBvh(np.zeros(0, dtype), np.zeros(0, np.int32), width, 1)
    count = b["count"].astype(np.int64)
    first = b["first"].astype(np.int64)
    # Bounds as one (nodes + 1, 6) array whose last row, NaN, is what slot -1 reads.
    bounds = np.full((b.size + 1, 6), np.nan, dtype=np.float32)
    bounds[:-1, :3] = b["lo"]
    bounds[:-1, 3:] = b["hi"]
    ext = np.maximum(bounds[:-1, 3:].astype(np.float64) - bounds[:-1, :3], 0)
    half_area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    # The area of each node that can be opened (an inner node), -1 otherwise and for slot -1.
    open_area = np.append(np.where(count == 0, half_area, -1.0), -1.0)

    order_refs = refs[bvh.order].astype(np.int64)
    levels = _levels(first, open_area, count[0] > 0, width)
    fold = _foldable(np.concatenate(levels), first, count, open_area, order_refs,
                     FOLD_PACKETS if fold_packets is None else fold_packets)
    if fold is not None:
        # Each folded node's binary node becomes one leaf over its leaves' primitives, which
        # are contiguous (a subtree's are). It was never opened, so the collapse above it
        # opens the same nodes as before.
        node, fold_first, fold_count = fold
        first, count, open_area = first.copy(), count.copy(), open_area.copy()
        first[node], count[node], open_area[node] = fold_first, fold_count, -1.0
        levels = _levels(first, open_area, count[0] > 0, width)
    slots = np.concatenate(levels)  # binary node per child slot, -1 for none
    n_wide = slots.shape[0]

    used = slots >= 0
    is_inner = open_area[slots] >= 0
    is_leaf = used & ~is_inner
    # Wide nodes are numbered level by level, children in slot order: the k-th inner slot (row-
    # major) is wide node k + 1.
    child = np.full(slots.shape, -1, dtype=np.int32)
    child[is_inner] = np.arange(1, int(is_inner.sum()) + 1)
    leaf_first, leaf_count, prim_refs = _lay_out_leaves(
        first[slots[is_leaf]], count[slots[is_leaf]], order_refs)
    child[is_leaf] = leaf_first
    packed_count = np.zeros(slots.shape, dtype=np.int32)
    packed_count[is_leaf] = leaf_count

    # The node records as rows of 8 lanes-wide fields: 6 bound fields, then child and count.
    rows = np.empty((n_wide, 8, width), dtype=np.float32)
    rows[:, :6] = bounds[slots].transpose(0, 2, 1)
    rows[:, 6].view(np.int32)[...] = child
    rows[:, 7].view(np.int32)[...] = packed_count
    nodes = rows.reshape(n_wide, -1).view(dtype).ravel()
    level_rows = np.cumsum([0] + [lv.shape[0] for lv in levels])
    return WideBvh(nodes, prim_refs, width, _stack_size(child, is_inner, used, level_rows))


def _levels(first: np.ndarray, open_area: np.ndarray, leaf_root: bool,
            width: int) -> list[np.ndarray]:
    """The wide tree level by level: (m, width) binary node per child slot, -1 for none."""
    # A leaf root still needs a wide node above it: its one child is the root itself.
    if leaf_root:
        levels = [np.array([[0] + [-1] * (width - 1)])]
    else:
        levels = [_open_children(np.array([0]), first, open_area, width)]
    while True:
        inner = levels[-1][open_area[levels[-1]] >= 0]
        if inner.size == 0:
            break
        levels.append(_open_children(inner, first, open_area, width))
    return levels


def _foldable(slots: np.ndarray, first: np.ndarray, count: np.ndarray, open_area: np.ndarray,
              order_refs: np.ndarray, fold_packets: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The wide nodes (rows of `slots`) to fold into one leaf, as (binary node, first, count)
    of that leaf, or None."""
    used = slots >= 0
    is_inner = open_area[slots] >= 0
    leaf = used & ~is_inner
    # Primitives of each kind per leaf slot, from prefix sums over the leaves' references.
    kind = order_refs >> P.PRIM_TYPE_SHIFT
    sums = [np.concatenate([[0], np.cumsum(kind == k)])
            for k in (P.PRIM_TRIANGLE, SPHERE.prim, P.PRIM_INSTANCE)]
    lo = np.where(leaf, first[slots], 0)
    n = np.where(leaf, count[slots], 0)
    tri, sph, inst = ((s[lo + n] - s[lo]).sum(axis=1) for s in sums)
    total = n.sum(axis=1)
    tests = -(-tri // PACKET_WIDTH) - (-sph // PACKET_WIDTH) + (total - tri - sph)
    # Wide node k + 1 grew from the k-th inner slot; the root (row 0) stays. Nodes over
    # instances stay: their boxes are lanes of one vector test, where a leaf would test each.
    fold = ~is_inner.any(axis=1) & (tests <= fold_packets) & (inst == 0)
    fold[0] = False
    if not fold.any():
        return None
    node = slots[is_inner][fold[1:]]
    start = np.where(leaf, first[slots], np.iinfo(np.int64).max).min(axis=1)
    return node, start[fold], total[fold]


def _open_children(parents: np.ndarray, first: np.ndarray, open_area: np.ndarray,
                   width: int) -> np.ndarray:
    """(m, width) child slots of the wide nodes grown from binary inner nodes `parents`."""
    m = parents.size
    rows = np.arange(m)
    slots = np.full((m, width), -1, dtype=np.int64)
    slots[:, 0] = parents + 1  # depth-first layout: the left child is the next node
    slots[:, 1] = first[parents]
    for filled in range(2, width):
        area = open_area[slots]
        k = np.argmax(area, axis=1)
        open_rows = rows[area[rows, k] >= 0]
        if open_rows.size == 0:
            break
        opened = slots[open_rows, k[open_rows]]
        slots[open_rows, k[open_rows]] = opened + 1
        slots[open_rows, filled] = first[opened]
    return slots


def _lay_out_leaves(first: np.ndarray, count: np.ndarray,
                    order_refs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each leaf's refs in its sections (triangle packets, sphere packets, others), each in
    build order: (start slot, packed count, prim_refs)."""
    n_leaves = first.size
    leaf = np.repeat(np.arange(n_leaves), count)
    offsets = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    refs = order_refs[np.repeat(first - offsets, count) + np.arange(count.sum())]
    kind = refs >> P.PRIM_TYPE_SHIFT
    section = np.where(kind == P.PRIM_TRIANGLE, 0, np.where(kind == SPHERE.prim, 1, 2))
    sizes, ranks = [], np.zeros(refs.size, dtype=np.int64)
    for sec in range(3):
        member = section == sec
        if not member.any():  # a mesh alone has triangles only: nothing to rank
            sizes.append(np.zeros(n_leaves, dtype=np.int64))
            continue
        running = np.cumsum(member) - member
        if refs.size:
            ranks[member] = (running - running[offsets][leaf])[member]
        sizes.append(np.bincount(leaf[member], minlength=n_leaves).astype(np.int64))
    tri_packets = -(-sizes[0] // PACKET_WIDTH)
    sphere_packets = -(-sizes[1] // PACKET_WIDTH)
    if np.any(sizes[2] > LEAF_FIELD_MASK) or np.any(sphere_packets > LEAF_FIELD_MASK):
        raise ValueError(f"a leaf holds more than {LEAF_FIELD_MASK} of one section")
    section_start = np.stack([np.zeros(n_leaves, np.int64), tri_packets * PACKET_WIDTH,
                              (tri_packets + sphere_packets) * PACKET_WIDTH])
    size = section_start[2] + sizes[2]
    padded = -(-size // PACKET_WIDTH) * PACKET_WIDTH
    start = np.concatenate([[0], np.cumsum(padded)[:-1]]).astype(np.int64)
    prim_refs = np.full(int(padded.sum()), NO_REF, dtype=np.int32)
    prim_refs[start[leaf] + section_start[section, leaf] + ranks] = refs
    packed = ((tri_packets << LEAF_TRIANGLE_SHIFT) | (sphere_packets << LEAF_SPHERE_SHIFT)
              | sizes[2])
    return start, packed, prim_refs


def _stack_size(child: np.ndarray, is_inner: np.ndarray, used: np.ndarray,
                level_rows: np.ndarray) -> int:
    """Most stack entries a walk can hold: a walk at a node has pushed, per ancestor, all but
    one of its children, and pushes all but one of the node's own (plus one for the pop)."""
    pushed = np.zeros(child.shape[0], dtype=np.int64)
    extra = used.sum(axis=1) - 1
    for lo, hi in itertools.pairwise(level_rows):
        kids = child[lo:hi]
        inner = is_inner[lo:hi]
        pushed[kids[inner]] = np.repeat(pushed[lo:hi] + extra[lo:hi], inner.sum(axis=1))
    return int((pushed + extra).max()) + 1
