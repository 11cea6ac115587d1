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
from clray.accel.bvh import BINARY_NODE, TRAVERSAL_COST, Bvh
from clray.host_memory import aligned_empty, by_chunks
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
# Binary nodes as opaque 32-byte items: numpy takes and copies those far faster than structs.
_OPAQUE = np.dtype((np.void, BINARY_NODE.itemsize))
# The leaf section of each primitive kind that has one of its own; any other kind: 2.
_SECTION = {P.PRIM_TRIANGLE: 0, SPHERE.prim: 1}
# The most primitives of each section a leaf's count can describe: triangle packets fill the
# int32's bits above LEAF_TRIANGLE_SHIFT short of the sign (a negative count is an instance's
# marker to the kernels), sphere packets and other primitives a field of LEAF_FIELD_MASK each.
_SECTION_MOST = ((np.iinfo(np.int32).max >> LEAF_TRIANGLE_SHIFT) * PACKET_WIDTH,
                 LEAF_FIELD_MASK * PACKET_WIDTH, LEAF_FIELD_MASK)


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


def collapse(bvh: Bvh, refs: np.ndarray | int, width: int,
             fold_packets: int | None = None) -> WideBvh:
    """Wide BVH of `width` children per node from a binary `bvh` over primitives whose
    references (PRIM_* << PRIM_TYPE_SHIFT | index) are `refs[i]` for build input i (`refs + i`
    where refs is an int: a run of one kind's primitives, as a mesh alone's are).
    `fold_packets`: the folding bound (None: FOLD_PACKETS). The collapse reads only the nodes
    it reaches from the root, so `bvh` may be in the device build's layout (Bvh.pairs)."""
    if width not in BVH_WIDTHS:
        raise ValueError(f"BVH width must be 4 or 8, got {width}")
    dtype = bvh_node_dtype(width)
    if bvh.nodes.size == 0:
        return WideBvh(np.zeros(0, dtype), np.zeros(0, np.int32), width, 1)
    order_refs = _refs_in_order(refs, bvh.order)
    kinds = _Kinds(order_refs >> P.PRIM_TYPE_SHIFT)
    nodes = bvh.nodes.view(_OPAQUE)
    levels = _levels(nodes, width, bvh.pairs)
    # Per child slot: its binary node (-1 none) and that node's first and count fields.
    slots, first, count = (np.concatenate([lv[f] for lv in levels]) for f in range(3))
    level_rows = np.cumsum([0] + [lv[0].shape[0] for lv in levels])
    del levels
    keep = _fold(slots, first, count, kinds,
                 FOLD_PACKETS if fold_packets is None else fold_packets)
    if keep is not None:
        slots, first, count = slots[keep], first[keep], count[keep]
        level_rows = np.concatenate([[0], np.cumsum(keep)])[level_rows]
    n_wide = slots.shape[0]

    used = slots >= 0
    is_inner = used & (count == 0)
    is_leaf = used & ~is_inner
    # Wide nodes are numbered level by level, children in slot order: the k-th inner slot (row-
    # major) is wide node k + 1.
    child = np.full(slots.shape, -1, dtype=np.int32)
    child[is_inner] = np.arange(1, int(is_inner.sum()) + 1)
    leaf_first, leaf_count, prim_refs = _lay_out_leaves(
        first[is_leaf].astype(np.int64), count[is_leaf].astype(np.int64), order_refs, kinds)
    child[is_leaf] = leaf_first
    packed_count = np.zeros(slots.shape, dtype=np.int32)
    packed_count[is_leaf] = leaf_count

    # The node records as rows of 8 lanes-wide fields: 6 bound fields, then child and count.
    # The bounds are each slot's binary node's (a folded slot keeps its node's box), NaN in an
    # unused lane. Each node is aligned to its own size, which a cache line of any size
    # divides: a CPU device reads the nodes in place (clray/device/buffers.py).
    rows = aligned_empty((n_wide, 8, width), np.float32, dtype.itemsize)

    def lay_out_boxes(part: slice) -> None:
        boxes = nodes.take(np.where(used[part], slots[part], 0)).view(BINARY_NODE)
        rows[part, 0:3] = boxes["lo"].transpose(0, 2, 1)
        rows[part, 3:6] = boxes["hi"].transpose(0, 2, 1)
        rows[part, 0:6].transpose(0, 2, 1)[~used[part]] = np.nan
    by_chunks(n_wide, lay_out_boxes, row_items=width)
    rows[:, 6].view(np.int32)[...] = child
    rows[:, 7].view(np.int32)[...] = packed_count
    nodes = rows.reshape(n_wide, -1).view(dtype).ravel()
    return WideBvh(nodes, prim_refs, width, _stack_size(child, is_inner, used, level_rows))


def _refs_in_order(refs: np.ndarray | int, order: np.ndarray) -> np.ndarray:
    """refs[order]. A mesh alone numbers its references as its primitives, refs[i] = refs[0] +
    i: then a sum, where a gather in tree order (random access, 0.3 s for 5 M) would do."""
    if isinstance(refs, int):
        return np.add(order, refs, dtype=np.int32)
    if refs.size and refs[-1] - refs[0] == refs.size - 1 and np.all(np.diff(refs) == 1):
        return order.astype(refs.dtype) + refs[0]
    return refs[order]


class _Kinds:
    """The primitive kind of each slot of the build's `order`. A mesh alone has one kind, whose
    count in a leaf is the leaf's count: the prefix sums of a kind are made only for mixed
    primitives, and only when asked."""

    def __init__(self, kind: np.ndarray) -> None:
        self.kind = kind
        self.only = int(kind[0]) if kind.size and kind.min() == kind.max() else None
        self._sums: dict[int, np.ndarray] = {}

    def leaf_total(self, k: int, first: np.ndarray, count: np.ndarray, total: np.ndarray
                   ) -> np.ndarray:
        """Primitives of kind k in each row's runs order[first:first + count] (count 0 for a
        slot that is not a leaf); `total`: each row's count, all kinds."""
        if self.only is not None:
            return total if k == self.only else np.zeros_like(total)
        if k not in self._sums:
            self._sums[k] = np.concatenate([[0], np.cumsum(self.kind == k)])
        first = np.where(count > 0, first, 0)
        return (self._sums[k][first + count] - self._sums[k][first]).sum(axis=1)


# A wide level: per child slot (m, width), its binary node (-1 none) and that node's first and
# count fields (0 where none), int32.
_Level = tuple[np.ndarray, np.ndarray, np.ndarray]


def _levels(nodes: np.ndarray, width: int, pairs: bool) -> list[_Level]:
    """The wide tree level by level. `nodes`: the binary nodes as opaque records; pairs:
    Bvh.pairs."""
    root = nodes[:1].view(BINARY_NODE)
    if root["count"][0] > 0:
        # A leaf root still needs a wide node above it: its one child is the root itself.
        level = tuple(np.zeros((1, width), dtype=np.int32) for _ in range(3))
        level[0][0, 1:] = -1
        level[1][0, 0], level[2][0, 0] = root["first"][0], root["count"][0]
        levels = [level]
    else:
        levels = [_open_children(np.zeros(1, np.int64), root["first"].astype(np.int64), nodes,
                                 width, pairs)]
    while True:
        slots, first, count = levels[-1]
        inner = (slots >= 0) & (count == 0)
        if not inner.any():
            return levels
        levels.append(_open_children(slots[inner].astype(np.int64),
                                     first[inner].astype(np.int64), nodes, width, pairs))


def _open_children(parents: np.ndarray, first: np.ndarray, nodes: np.ndarray, width: int,
                   pairs: bool) -> _Level:
    """The level of wide nodes grown from binary inner nodes `parents` (with `first` their
    nodes' field: Bvh's two layouts). Each node grows alone: chunks of them on every core."""
    m = parents.size
    level = (np.full((m, width), -1, dtype=np.int32), np.zeros((m, width), dtype=np.int32),
             np.zeros((m, width), dtype=np.int32))

    def grow(part: slice) -> None:
        mine = tuple(field[part] for field in level)
        rows = np.arange(part.stop - part.start)
        # An inner child's half area and length (clray.accel.bvh._sah_choice), -1 for a leaf
        # or none. Length orders children of no area (segments), which area alone would tie:
        # the first of them opened each time, the node would grow down one side.
        area = np.full((rows.size, width), -1.0)
        length = np.full((rows.size, width), -1.0)
        left, right = _children(parents[part], first[part], pairs)
        _place(mine, area, length, rows, 0, left, nodes)
        _place(mine, area, length, rows, 1, right, nodes)
        for filled in range(2, width):
            k = np.argmax(area, axis=1)
            flat = area[rows, k] == 0
            k[flat] = np.argmax(np.where(area[flat] == 0, length[flat], -1.0), axis=1)
            open_rows = rows[area[rows, k] >= 0]
            if open_rows.size == 0:
                break
            k = k[open_rows]
            left, right = _children(mine[0][open_rows, k].astype(np.int64),
                                    mine[1][open_rows, k].astype(np.int64), pairs)
            _place(mine, area, length, open_rows, k, left, nodes)
            _place(mine, area, length, open_rows, filled, right, nodes)
    by_chunks(m, grow, row_items=width)
    return level


def _children(node: np.ndarray, first: np.ndarray, pairs: bool) -> tuple[np.ndarray, np.ndarray]:
    """Left and right children of inner nodes: depth-first, the left child is the next node and
    `first` the right one; in pairs, `first` is the left child and the right one follows."""
    return (first, first + 1) if pairs else (node + 1, first)


def _place(level: _Level, area: np.ndarray, length: np.ndarray, rows: np.ndarray,
           col: np.ndarray | int, node: np.ndarray, nodes: np.ndarray) -> None:
    """Binary nodes `node` into child slots (rows, col) of `level`, with their half areas and
    lengths (-1 for a leaf)."""
    taken = nodes.take(node).view(BINARY_NODE)
    level[0][rows, col] = node
    level[1][rows, col] = taken["first"]
    level[2][rows, col] = taken["count"]
    ext = np.maximum(taken["hi"].astype(np.float64) - taken["lo"], 0)
    half_area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    inner = taken["count"] == 0
    area[rows, col] = np.where(inner, half_area, -1.0)
    length[rows, col] = np.where(inner, ext[:, 0] + ext[:, 1] + ext[:, 2], -1.0)


def _fold(slots: np.ndarray, first: np.ndarray, count: np.ndarray, kinds: _Kinds,
          fold_packets: int) -> np.ndarray | None:
    """Folds each wide node (row of `slots`) of leaves only that one leaf of at most
    `fold_packets` packet tests would cover into that leaf: its parent's slot, in `first` and
    `count`, becomes a leaf over its leaves' primitives, which are contiguous (a subtree's
    are). Returns the rows to keep, or None where none folds. A folded node was never opened,
    so the collapse above it opened the same nodes as it would have with the leaf in its
    place."""
    used = slots >= 0
    is_inner = used & (count == 0)
    leaf = used & ~is_inner
    n = np.where(leaf, count, 0).astype(np.int64)
    total = n.sum(axis=1)
    tri, sph, inst = (kinds.leaf_total(k, first, n, total)
                      for k in (P.PRIM_TRIANGLE, SPHERE.prim, P.PRIM_INSTANCE))
    tests = -(-tri // PACKET_WIDTH) - (-sph // PACKET_WIDTH) + (total - tri - sph)
    # Wide node k + 1 grew from the k-th inner slot; the root (row 0) stays. Nodes over
    # instances stay: their boxes are lanes of one vector test, where a leaf would test each.
    fold = ~is_inner.any(axis=1) & (tests <= fold_packets) & (inst == 0)
    fold[0] = False
    if not fold.any():
        return None
    parent = np.flatnonzero(is_inner)[fold[1:]]
    start = np.where(leaf, first, np.iinfo(np.int32).max).min(axis=1)
    first.reshape(-1)[parent] = start[fold]
    count.reshape(-1)[parent] = total[fold]
    return ~fold


def _lay_out_leaves(first: np.ndarray, count: np.ndarray, order_refs: np.ndarray,
                    kinds: _Kinds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each leaf's refs in its sections (triangle packets, sphere packets, others), each in
    build order: (start slot, packed count, prim_refs)."""
    n_leaves = first.size
    if kinds.only is not None:
        # One section, at the start of each leaf: slots are ranks within the leaf.
        section = _SECTION.get(kinds.only, 2)
        sizes = [count if s == section else np.zeros(n_leaves, np.int64) for s in range(3)]
    else:
        offsets = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
        position = np.arange(int(count.sum()))
        refs = order_refs[np.repeat(first - offsets, count) + position]
        sizes, position = _sections(refs, count, offsets)
    tri_packets = -(-sizes[0] // PACKET_WIDTH)
    sphere_packets = -(-sizes[1] // PACKET_WIDTH)
    for size, name, most in zip(sizes, ("triangles", "spheres", "other primitives"),
                                _SECTION_MOST, strict=True):
        if size.size and size.max() > most:
            raise ValueError(f"a leaf of {int(size.max())} {name} exceeds {most}, the most "
                             f"its count field holds: build with a smaller largest_leaf")
    padded = -(-((tri_packets + sphere_packets) * PACKET_WIDTH + sizes[2]) // PACKET_WIDTH)
    start = np.concatenate([[0], np.cumsum(padded * PACKET_WIDTH)[:-1]]).astype(np.int64)
    prim_refs = np.full(int(padded.sum()) * PACKET_WIDTH, NO_REF, dtype=np.int32)
    if kinds.only is not None:
        prim_refs[_slots_in_build_order(start, first, count)] = order_refs
    else:
        prim_refs[np.repeat(start - offsets, count) + position] = refs
    packed = ((tri_packets << LEAF_TRIANGLE_SHIFT) | (sphere_packets << LEAF_SPHERE_SHIFT)
              | sizes[2])
    return start, packed, prim_refs


def _slots_in_build_order(start: np.ndarray, first: np.ndarray, count: np.ndarray
                          ) -> np.ndarray:
    """The slot of each primitive of the build's order, where the leaves, each starting at
    slot `start` with its primitives order[first:first + count] in their order, hold every
    primitive once: the leaves taken by their first primitive, so the primitives come in
    the build's order and its refs are read once in sequence. One int32 array (slots fit):
    gathering each leaf's refs and scattering them would take an int64 index a primitive
    for each, four such arrays in all (docs/scale.md)."""
    by_first = np.argsort(first)
    slots = np.repeat((start - first)[by_first].astype(np.int32), count[by_first])
    slots += np.arange(len(slots), dtype=np.int32)
    return slots


def _sections(refs: np.ndarray, count: np.ndarray, offsets: np.ndarray
              ) -> tuple[list[np.ndarray], np.ndarray]:
    """Mixed leaves: each section's size per leaf, and each ref's slot from its leaf's start
    (section start plus its rank in the section, in build order) plus its leaf's offset in
    `refs` (which the caller's scatter subtracts again)."""
    n_leaves = count.size
    leaf = np.repeat(np.arange(n_leaves), count)
    kind = refs >> P.PRIM_TYPE_SHIFT
    section = np.where(kind == P.PRIM_TRIANGLE, 0, np.where(kind == SPHERE.prim, 1, 2))
    sizes, ranks = [], np.zeros(refs.size, dtype=np.int64)
    for sec in range(3):
        member = section == sec
        running = np.cumsum(member) - member
        if refs.size:
            ranks[member] = (running - running[offsets][leaf])[member]
        sizes.append(np.bincount(leaf[member], minlength=n_leaves).astype(np.int64))
    tri_slots = -(-sizes[0] // PACKET_WIDTH) * PACKET_WIDTH
    sphere_slots = -(-sizes[1] // PACKET_WIDTH) * PACKET_WIDTH
    section_start = np.stack([np.zeros(n_leaves, np.int64), tri_slots,
                              tri_slots + sphere_slots])
    return sizes, offsets[leaf] + section_start[section, leaf] + ranks


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


def fill_nodes(wide: WideBvh) -> WideBvh:
    """The same tree with fewer, fuller nodes: where a node has room, an inner child's lanes
    move up into it (the child goes; the boxes stay the same), and inner children whose lanes
    fit in one node together are merged (their parent's lane gets the union of their boxes).
    For a tree of one primitive a leaf (the scene's tree over instances, clray/device/pack.py),
    whose greedy collapse above leaves many nodes of two or three children where a balanced
    binary tree's depth is not a multiple of log2(width): each lane there is an instance's
    record-sized share of node bytes. A Python loop over the nodes: for trees of thousands."""
    if wide.nodes.size == 0:
        return wide
    lanes = _lanes(wide)
    _fill(lanes, 0, wide.width)
    return _laid_out(lanes, wide.width, wide.prim_refs)


# A node's used lanes, as fill_nodes works on them: (bounds: lo xyz, hi xyz; child; count).
_Lane = tuple[np.ndarray, int, int]
_BOUND_FIELDS = ("lo_x", "lo_y", "lo_z", "hi_x", "hi_y", "hi_z")


def _lanes(wide: WideBvh) -> list[list[_Lane]]:
    """Each node's used lanes."""
    box = np.stack([wide.nodes[f] for f in _BOUND_FIELDS], axis=-1).astype(np.float64)
    child, count = wide.nodes["child"], wide.nodes["count"]
    return [[(box[i, k], int(child[i, k]), int(count[i, k])) for k in range(wide.width)
             if child[i, k] >= 0] for i in range(wide.nodes.size)]


def _inner(lane: _Lane) -> bool:
    return lane[2] == 0


def _fill(lanes: list[list[_Lane]], i: int, width: int) -> None:
    """Node i's subtree filled: its children's first, then moves and merges at i until none
    is left."""
    for lane in lanes[i]:
        if _inner(lane):
            _fill(lanes, lane[1], width)
    while _move_up(lanes, i, width) or _merge(lanes, i, width):
        pass


def _move_up(lanes: list[list[_Lane]], i: int, width: int) -> bool:
    """Moves the lanes of node i's smallest inner child that fits in the room left up into
    it; False where none fits."""
    for k, lane in sorted(enumerate(lanes[i]), key=lambda kl: len(lanes[kl[1][1]])
                          if _inner(kl[1]) else width + 1):
        if _inner(lane) and len(lanes[i]) - 1 + len(lanes[lane[1]]) <= width:
            lanes[i][k:k + 1] = lanes[lane[1]]
            return True
    return False


def _merge(lanes: list[list[_Lane]], i: int, width: int) -> bool:
    """Merges two of node i's inner children whose lanes fit in one node, the smallest
    first; False where no two fit."""
    kids = sorted((k for k, lane in enumerate(lanes[i]) if _inner(lane)),
                  key=lambda k: len(lanes[lanes[i][k][1]]))
    for a, b in itertools.combinations(kids, 2):
        na, nb = lanes[i][a][1], lanes[i][b][1]
        if len(lanes[na]) + len(lanes[nb]) <= width:
            lanes[na] = lanes[na] + lanes[nb]
            joined = np.concatenate([np.minimum(lanes[i][a][0][:3], lanes[i][b][0][:3]),
                                     np.maximum(lanes[i][a][0][3:], lanes[i][b][0][3:])])
            lanes[i][a] = (joined, na, 0)
            del lanes[i][b]
            return True
    return False


def _laid_out(lanes: list[list[_Lane]], width: int, prim_refs: np.ndarray) -> WideBvh:
    """The nodes the root still reaches, numbered breadth first from it and laid out: empty
    lanes have NaN bounds, child -1 and count 0, as the collapse leaves them."""
    order, at = [0], 0
    while at < len(order):
        order.extend(lane[1] for lane in lanes[order[at]] if _inner(lane))
        at += 1
    number = {old: new for new, old in enumerate(order)}
    bounds = np.full((len(order), 6, width), np.nan, dtype=np.float32)
    kids = np.full((len(order), width), -1, dtype=np.int32)
    counts = np.zeros((len(order), width), dtype=np.int32)
    pushed = np.zeros(len(order), dtype=np.int64)
    for new, old in enumerate(order):
        for k, (b, c, n) in enumerate(lanes[old]):
            bounds[new, :, k] = b
            kids[new, k] = number[c] if n == 0 else c
            counts[new, k] = n
            if n == 0:
                # The stack bound as _stack_size counts it.
                pushed[number[c]] = pushed[new] + len(lanes[old]) - 1
    nodes = np.zeros(len(order), dtype=bvh_node_dtype(width))
    for f, field in enumerate(_BOUND_FIELDS):
        nodes[field] = bounds[:, f]
    nodes["child"], nodes["count"] = kids, counts
    used = np.array([len(lanes[old]) for old in order])
    return WideBvh(nodes, prim_refs, width, int((pushed + used - 1).max()) + 1)


def _leaf_packets(count: np.ndarray) -> np.ndarray:
    """The triangle and sphere packets of each leaf `count` field."""
    return (count >> LEAF_TRIANGLE_SHIFT) + ((count >> LEAF_SPHERE_SHIFT) & LEAF_FIELD_MASK)


def leaf_slots(count: np.ndarray) -> np.ndarray:
    """The slots of prim_refs each leaf `count` field spans: its triangle and sphere packets'
    PACKET_WIDTH slots each, then its other primitives one slot each."""
    return PACKET_WIDTH * _leaf_packets(count) + (count & LEAF_FIELD_MASK)


def _reached_levels(nodes: np.ndarray) -> list[np.ndarray]:
    """The nodes the root (node 0) reaches, level by level from the root's: a group's tree,
    reached through an instance lane, is not among them."""
    child, count = nodes["child"], nodes["count"]
    inner = (count == 0) & (child >= 0)
    levels = [np.zeros(1, dtype=np.int64)]
    while True:
        below = child[levels[-1]][inner[levels[-1]]]
        if not below.size:
            return levels
        levels.append(below.astype(np.int64))


def tree_cost(nodes: np.ndarray, traversal_cost: float = TRAVERSAL_COST) -> float:
    """The expected cost of a ray's walk through the tree whose root is node 0, relative to
    its root's box (the surface-area heuristic, as clray.accel.bvh.sah_cost gives it for a
    binary tree): each lane's box area times its cost, a node visit for an inner lane or an
    instance's (its group's tree is not counted), a test a packet or other primitive for a
    leaf's, over the root's area. A refitted tree (refit) against the same tree as built says
    how far the refit has let its boxes grow: the figure a build minimises. 0 for a tree
    without nodes or with a root box of no area."""
    if nodes.size == 0:
        return 0.0
    reached = nodes[np.concatenate(_reached_levels(nodes))]
    child, count = reached["child"], reached["count"].astype(np.int64)
    e = np.stack([reached[f"hi_{a}"].astype(np.float64) - reached[f"lo_{a}"] for a in "xyz"])
    area = np.where(child >= 0, e[0] * e[1] + e[1] * e[2] + e[2] * e[0], 0.0)
    # A leaf's tests: a packet test each, and one for each other primitive.
    cost = np.where(count > 0, _leaf_packets(count) + (count & LEAF_FIELD_MASK), traversal_cost)
    lo = [np.nanmin(nodes[0][f"lo_{a}"].astype(np.float64)) for a in "xyz"]
    hi = [np.nanmax(nodes[0][f"hi_{a}"].astype(np.float64)) for a in "xyz"]
    root = sum((hi[i] - lo[i]) * (hi[j] - lo[j]) for i, j in ((0, 1), (1, 2), (2, 0)))
    return float((cost * area).sum() / root) if root > 0 else 0.0


def refit(nodes: np.ndarray, slot_lo: np.ndarray, slot_hi: np.ndarray,
          instance_lo: np.ndarray, instance_hi: np.ndarray) -> None:
    """Makes again, in place, every box of the tree whose root is node 0 from its primitives'
    boxes: `slot_lo`, `slot_hi` (slots, 3) float32, one a slot of prim_refs (+inf and -inf
    where a slot is empty), and `instance_lo`, `instance_hi` (instances, 3) for the lanes
    that hold an instance (a negative count, ENTER_INSTANCE: kernels/clray_types.h). The
    tree keeps its shape, and each box is again the union of the boxes below it, as the
    collapse made them: where the primitives have moved together (the same scene at another
    eye, clray/device/pack.py), the tree a build would give, or one of the same quality.
    Nodes the root does not reach (a group's tree, in the group's own frame) are left as
    they are.

    Level by level from the deepest: a lane's box is its leaf's slots' union (one reduceat
    over all the leaves), its instance's box, or the union of its child node's lanes."""
    if nodes.size == 0:
        return
    child, count = nodes["child"], nodes["count"]
    inner = (count == 0) & (child >= 0)
    levels = _reached_levels(nodes)
    reached = np.concatenate(levels)
    # The records as rows of 8 lanes-wide fields (collapse's layout): lo xyz, hi xyz, child,
    # count. Boxes are written through this view, in place.
    rows = nodes.view(np.float32).reshape(len(nodes), 8, -1)
    lo, hi = slice(0, 3), slice(3, 6)

    node, lane = np.nonzero(count[reached] > 0)
    node = reached[node]
    if node.size:
        starts = child[node, lane].astype(np.int64)
        # One extra empty slot: a leaf that ends at the last slot ends at a valid index.
        ends = np.stack([starts, starts + leaf_slots(count[node, lane])], axis=1).ravel()
        for fields, slots, empty, union in ((lo, slot_lo, np.inf, np.minimum),
                                            (hi, slot_hi, -np.inf, np.maximum)):
            padded = np.concatenate([slots, np.full((1, 3), empty, np.float32)])
            rows[node, fields, lane] = union.reduceat(padded, ends, axis=0)[::2]
    node, lane = np.nonzero(count[reached] < 0)
    node = reached[node]
    rows[node, lo, lane] = instance_lo[child[node, lane]]
    rows[node, hi, lane] = instance_hi[child[node, lane]]

    for level in reversed(levels[:-1]):
        node, lane = np.nonzero(inner[level])
        node = level[node]
        below = child[node, lane]
        # An unused lane's box is NaN: fmin and fmax pass over it.
        rows[node, lo, lane] = np.fmin.reduce(rows[below, lo], axis=2)
        rows[node, hi, lane] = np.fmax.reduce(rows[below, hi], axis=2)
