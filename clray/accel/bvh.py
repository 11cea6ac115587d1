"""Primitive bounds -> flat binary BVH node array (BINARY_NODE; clray.accel.wide collapses it
into the wide tree the kernels walk).

The builder is binned SAH, run level by level: every node of one tree level is binned, costed and
partitioned by the same handful of numpy calls, so the Python overhead is per level (a few dozen),
not per node (hundreds of thousands for a large mesh). The breadth-first tree it grows is then
renumbered into the depth-first layout the kernels walk.

All bound arithmetic is done on the primitives' bounds rounded outwards to float32 once, at the
start. Rounding is monotonic, so a node's min/max of rounded bounds equals the rounding of its
float64 min/max: node bounds hold the float64 geometry exactly, as the double build needs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from clray.knobs import KNOBS

# SAH bins along the axis of largest centroid extent. 16 is where binned SAH stops gaining
# quality for its cost (Wald 2007, "On fast construction of SAH-based BVHs").
N_BINS = 16
# Largest leaf SAH may choose; bigger nodes are split regardless of cost, so leaf sizes stay
# bounded (kernels loop over a leaf's primitives) even for duplicate or coincident primitives.
# A tunable knob (clray.tuning): its default comes from the knob table.
SAH_MAX_LEAF = KNOBS["largest_leaf"].default
# Primitives one leaf test covers: the kernels test a leaf's triangles and spheres in packets
# of four (clray.accel.wide.PACKET_WIDTH), at the cost of about one, so a leaf costs its packet
# count, ceil(n / 4), and a split that cuts 8 primitives into 4 + 4 beats one into 3 + 5.
SAH_PACKET = 4
# Cost of one node visit relative to one packet test: a tunable knob (clray.tuning), whose table
# records why its default is 1.5 (benchmarks/README.md, What did not pay).
TRAVERSAL_COST = KNOBS["traversal_cost"].default
# Nodes of at most this many primitives are always leaves (a tunable knob too).
MAX_LEAF_SIZE = KNOBS["max_leaf_size"].default

_F32_MAX = float(np.finfo(np.float32).max)
# Rows of bounds compared at a time: a temporary of this size is reused, not one of every row.
_CHECK_ROWS = 1 << 16

# A node of the binary tree: its bounds, and for an inner node (count 0) its right child's index,
# for a leaf its first slot in `order` and its primitive count. kernels/clray_types.h's
# BinaryNode (the device build writes it too).
BINARY_NODE = np.dtype([("lo", "<f4", (3,)), ("first", "<i4"), ("hi", "<f4", (3,)),
                        ("count", "<i4")])


@dataclass(frozen=True)
class Bvh:
    """Depth-first flattened BVH: `nodes` in BINARY_NODE, leaves index into `order`.

    An inner node's left child is the next node and its `first` is the right child's index,
    with count 0. A leaf's primitives are `order[first:first + count]`, and `order[k]` is an
    index into the primitives given to `build_bvh`.

    pairs: the device build's own layout instead (clray.device.bvh_builder), root first: an inner
    node's `first` is its left child and the right child follows it; slots no node reached are
    uninitialised, so only a walk from the root (clray.accel.wide.collapse) may read them.
    """

    nodes: np.ndarray
    order: np.ndarray
    pairs: bool = False


def max_leaf_count(max_leaf_size: int) -> int:
    """The largest leaf `build_bvh(..., max_leaf_size)` can produce."""
    return max(max_leaf_size, SAH_MAX_LEAF)


def packets(count: np.ndarray) -> np.ndarray:
    """Packet tests of leaves of `count` primitives: the SAH's leaf cost."""
    return -(-count // SAH_PACKET)


def sah_cost(nodes: np.ndarray, traversal_cost: float = TRAVERSAL_COST) -> float:
    """SAH cost of a built tree (node visits at `traversal_cost`, leaves at their packet count)
    relative to the root's area: the build-quality figure, lower is better. The root needs an
    area."""
    e = (nodes["hi"].astype(np.float64) - nodes["lo"]).clip(min=0)
    area = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    count = nodes["count"].astype(np.int64)
    return float((np.where(count > 0, packets(count), traversal_cost) * area).sum() / area[0])


def checked_bounds(lo: np.ndarray, hi: np.ndarray, max_leaf_size: int,
                   largest_leaf: int | None, values_checked: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """build_bvh's arguments checked (ValueError names the bad one): the bounds as float64,
    or float32 where both are (a mesh's: the same numbers at half the bytes, uncopied), and
    the largest leaf. values_checked: the caller made the bounds from values it checked
    (finite, within float32's range) as minima and maxima, so lo <= hi holds by construction
    and the scans of every value, the check's whole cost, are skipped."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    if not lo.dtype == hi.dtype == np.float32:
        lo, hi = lo.astype(np.float64, copy=False), hi.astype(np.float64, copy=False)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape:
        raise ValueError(f"bounds must both have shape (N, 3), got {lo.shape} and {hi.shape}")
    if max_leaf_size < 1:
        raise ValueError(f"max_leaf_size must be at least 1, got {max_leaf_size}")
    largest = max_leaf_count(max_leaf_size) if largest_leaf is None else largest_leaf
    if largest < max_leaf_size:
        raise ValueError(f"largest_leaf {largest} is below max_leaf_size {max_leaf_size}")
    if lo.size and not values_checked:
        _check_values(lo, hi)
    return lo, hi, largest


def _check_values(lo: np.ndarray, hi: np.ndarray) -> None:
    """Every bound finite and within float32's range, and lo <= hi. By reductions, not a
    boolean array the size of the bounds, whose first touch of fresh memory would cost more
    than the comparisons (docs/scale.md). A NaN fails lo <= hi; once lo <= hi holds,
    every value lies between lo's minimum and hi's maximum, so those two bound the range:
    three passes over the bounds where a minimum and a maximum of each took five."""
    ordered = all(np.all(lo[at:at + _CHECK_ROWS] <= hi[at:at + _CHECK_ROWS])
                  for at in range(0, len(lo), _CHECK_ROWS))
    if ordered and lo.min() >= -_F32_MAX and hi.max() <= _F32_MAX:
        return
    if not (within_float32(lo) and within_float32(hi)):
        i = _first_row(lo, hi, lambda a, b: ~(_within_rows(a) & _within_rows(b)))
        raise ValueError(f"primitive {i}'s bounds must be finite and within float32 range: "
                         f"{_row_text(lo, hi, i)}")
    i = _first_row(lo, hi, lambda a, b: (a > b).any(axis=1))
    raise ValueError(f"primitive {i}'s bounds have lo > hi: {_row_text(lo, hi, i)}")


def _within_rows(a: np.ndarray) -> np.ndarray:
    """Which rows' values are all finite and within float32's range."""
    return ((a >= -_F32_MAX) & (a <= _F32_MAX)).all(axis=1)


def _first_row(lo: np.ndarray, hi: np.ndarray,
               bad: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> int:
    """Index of the first row for which bad(lo rows, hi rows) holds, a block of rows at a
    time; the caller knows there is one."""
    for at in range(0, len(lo), _CHECK_ROWS):
        rows = np.flatnonzero(bad(lo[at:at + _CHECK_ROWS], hi[at:at + _CHECK_ROWS]))
        if rows.size:
            return at + int(rows[0])
    raise AssertionError("no bad row")


def _row_text(lo: np.ndarray, hi: np.ndarray, i: int) -> str:
    return (f"lo ({', '.join(str(v) for v in lo[i])}), "
            f"hi ({', '.join(str(v) for v in hi[i])})")


def within_float32(a: np.ndarray) -> bool:
    """Every value finite and within float32's range (a NaN makes the minimum and maximum
    NaN, which fail both tests): values that minima and maxima may be taken of for bounds
    that checked_bounds need not scan (its values_checked)."""
    return bool(a.min() >= -_F32_MAX) and bool(a.max() <= _F32_MAX)


def build_bvh(lo: np.ndarray, hi: np.ndarray, max_leaf_size: int = MAX_LEAF_SIZE, *,
              largest_leaf: int | None = None, traversal_cost: float = TRAVERSAL_COST) -> Bvh:
    """Build a BVH over N primitives with bounds `lo`, `hi` of shape (N, 3) (float64, or
    float32 for both: the same tree as their float64 copies).

    Nodes of at most `max_leaf_size` primitives are always leaves; nodes of up to
    `largest_leaf` (default `max_leaf_count(max_leaf_size)`) are leaves when SAH says a split
    would not pay; `traversal_cost` is the SAH's cost of a node visit against one packet
    test. clray.device.bvh_builder builds the same tree on an OpenCL device (with the default
    traversal cost, which it compiles in).
    """
    lo, hi, largest = checked_bounds(lo, hi, max_leaf_size, largest_leaf)
    if lo.shape[0] == 0:
        return Bvh(np.zeros(0, dtype=BINARY_NODE), np.zeros(0, dtype=np.int32))
    return _Builder(_round_out(lo, hi), max_leaf_size, largest, traversal_cost).run()


def rounded_out(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds as float32, each rounded to nearest and then one step outwards where that went
    inwards, every zero +0.0: the boxes every build takes (and a refit, clray.accel.wide.refit,
    again). -0.0 and +0.0 compare equal, so which one a minimum or maximum keeps depends on the
    reduction's order, which differs between the builds; with no -0.0 in, all give the same
    bytes (kernels/bvh_build.cl, round_prims). + 0 after the rounding: nextafter up from
    -2^-149 gives -0.0."""
    lo32 = lo.astype(np.float32)
    hi32 = hi.astype(np.float32)
    return (np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32) + np.float32(0),
            np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32) + np.float32(0))


def _round_out(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(9, N) float32 rows: lo xyz, hi xyz rounded outwards, then centroids (for binning only)."""
    prim = np.empty((9, lo.shape[0]), dtype=np.float32)
    prim[0:3], prim[3:6] = rounded_out(lo.T, hi.T)
    # Summed in float64 whatever the bounds' type, as the device build does; every zero +0.0,
    # as rounded_out makes the bounds'.
    prim[6:9] = (0.5 * np.add(lo.T, hi.T, dtype=np.float64)).astype(np.float32) + np.float32(0)
    return prim


def _half_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half surface area of boxes with corners along the last axis; empty boxes give 0."""
    e = np.maximum(hi.astype(np.float64) - lo, 0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _half_perimeter(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sum of the edge lengths along the three axes of boxes with corners along the last
    axis: a segment's length; empty boxes give 0."""
    e = np.maximum(hi.astype(np.float64) - lo, 0)
    return e[..., 0] + e[..., 1] + e[..., 2]


def _segment_ranks(counts: np.ndarray, offsets: np.ndarray,
                   total: int) -> tuple[np.ndarray, np.ndarray]:
    """Segment id of each of `total` slots and its rank within the segment."""
    seg = np.repeat(np.arange(counts.size), counts)
    return seg, np.arange(total) - offsets[seg]


def _take_columns(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a[:, index], a row at a time: numpy's two-dimensional fancy indexing is several times
    slower than one-dimensional takes."""
    out = np.empty((a.shape[0], index.size), dtype=a.dtype)
    for row, dest in zip(a, out, strict=True):
        row.take(index, out=dest)
    return out


class _Active(NamedTuple):
    """The nodes of one level that still need splitting, in slot order."""

    node: np.ndarray  # breadth-first node id
    bounds: np.ndarray  # (m, 6) float32 lo xyz, hi xyz
    cbounds: np.ndarray  # (m, 6) float32 bounds of the centroids
    start: np.ndarray  # first slot in `order`
    count: np.ndarray


class _Builder:
    """One build. Breadth-first: each level holds the nodes still to be split (the active
    nodes) and their primitives, contiguous per node, in `ids` and the columns of `prim`."""

    def __init__(self, prim: np.ndarray, max_leaf_size: int, largest_leaf: int,
                 traversal_cost: float) -> None:
        self.max_leaf = max_leaf_size
        self.sah_leaf = largest_leaf
        self.traversal_cost = traversal_cost
        n = prim.shape[1]
        self.order = np.empty(n, dtype=np.int32)
        # Per breadth-first node, appended one level at a time; ids are positions in the
        # concatenation, so each level's nodes have consecutive ids.
        self.bounds: list[np.ndarray] = []  # (k, 6) float32
        self.start: list[np.ndarray] = []  # first slot in `order`
        self.count: list[np.ndarray] = []
        self.left: list[np.ndarray] = []  # left child id, -1 for a leaf
        self.n_nodes = 0
        self.ids = np.arange(n, dtype=np.int32)
        self.prim = prim

    def _add_nodes(self, bounds: np.ndarray, start: np.ndarray, count: np.ndarray) -> np.ndarray:
        k = count.size
        node_ids = np.arange(self.n_nodes, self.n_nodes + k)
        self.bounds.append(bounds)
        self.start.append(start)
        self.count.append(count)
        self.left.append(np.full(k, -1, dtype=np.int64))
        self.n_nodes += k
        return node_ids

    def run(self) -> Bvh:
        n = self.ids.size
        root_bounds = np.concatenate([self.prim[0:3].min(axis=1), self.prim[3:6].max(axis=1)])
        node = self._add_nodes(root_bounds[None, :], np.zeros(1, np.int64), np.full(1, n))
        cbounds = np.concatenate([self.prim[6:9].min(axis=1), self.prim[6:9].max(axis=1)])[None]
        if n <= self.max_leaf:
            self.order[:] = self.ids
        else:
            active = _Active(node, root_bounds[None, :], cbounds, np.zeros(1, np.int64),
                             np.full(1, n))
            while active is not None:
                active = self._level(active)
        return self._flatten()

    def _level(self, active: _Active) -> _Active | None:
        """Split every active node once; returns the next level's active nodes."""
        node, bounds, cbounds, start, count = active
        m = count.size
        p = self.ids.size
        offsets = np.zeros(m, dtype=np.int64)
        np.cumsum(count[:-1], out=offsets[1:])
        seg, rank = _segment_ranks(count, offsets, p)
        b, binnable, bins = self._bins(cbounds, seg, m)
        best, leaf = self._sah_choice(bounds, count, binnable, *bins)

        # Partition: stable within each side, left side first, so the final `order` lists the
        # leaves' primitives in depth-first order and a subtree's primitives are contiguous.
        split_bin = np.where(binnable, best, 0)
        median = count // 2
        right = np.where(binnable[seg], b > split_bin[seg], rank >= median[seg])
        is_left = ~right
        left_upto = np.cumsum(is_left)
        left_before = left_upto - is_left
        left_rank = left_before - left_before[offsets][seg]
        n_left_node = left_upto[offsets + count - 1] - left_before[offsets]
        within = np.where(right, rank - left_rank, left_rank)  # rank within the child

        # Primitives of nodes that stay leaves go to `order` at their node's slots.
        leaf_slot = leaf[seg]
        self.order[(start[seg] + rank)[leaf_slot]] = self.ids[leaf_slot]

        # Children of split nodes, left then right per parent, so they keep their parents' slot
        # order; their primitives are scattered straight into a compact child-major array.
        split = ~leaf
        if not split.any():
            return None
        split_index = np.cumsum(split) - 1
        ch_count = np.stack([n_left_node[split], count[split] - n_left_node[split]], 1).ravel()
        ch_start = np.repeat(start[split], 2)
        ch_start[1::2] += n_left_node[split]
        ch_offset = np.zeros(ch_count.size, dtype=np.int64)
        np.cumsum(ch_count[:-1], out=ch_offset[1:])
        split_slot = ~leaf_slot
        child = (2 * split_index[seg] + right)[split_slot]
        src = np.empty(child.size, dtype=np.intp)
        src[ch_offset[child] + within[split_slot]] = np.flatnonzero(split_slot)
        ids = self.ids.take(src)
        prim = _take_columns(self.prim, src)
        ch_bounds = np.concatenate([
            np.minimum.reduceat(prim[0:3], ch_offset, axis=1),
            np.maximum.reduceat(prim[3:6], ch_offset, axis=1),
            np.minimum.reduceat(prim[6:9], ch_offset, axis=1),
            np.maximum.reduceat(prim[6:9], ch_offset, axis=1),
        ]).T
        parents = self.left[-1]
        first_id = self.n_nodes - parents.size
        ch_node = self._add_nodes(ch_bounds[:, :6], ch_start, ch_count)
        parents[node[split] - first_id] = ch_node[0::2]

        # Small children are leaves at once; the rest carry on with their primitives compacted.
        small = ch_count <= self.max_leaf
        if small.any():
            ch_seg, ch_rank = _segment_ranks(ch_count, ch_offset, src.size)
            small_slot = small[ch_seg]
            self.order[(ch_start[ch_seg] + ch_rank)[small_slot]] = ids[small_slot]
            keep = np.flatnonzero(~small_slot)
            ids = ids.take(keep)
            prim = _take_columns(prim, keep)
        self.ids = ids
        self.prim = prim
        go = ~small
        if not go.any():
            return None
        return _Active(ch_node[go], ch_bounds[go, :6], ch_bounds[go, 6:], ch_start[go],
                       ch_count[go])

    def _bins(self, cbounds: np.ndarray, seg: np.ndarray, m: int
              ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Bin the `m` active nodes' primitives by centroid along each node's axis of largest
        centroid extent: (each primitive's bin, which nodes could be binned, and per node and
        bin the primitive count and the bounds' low and high corners)."""
        prim = self.prim
        p = self.ids.size
        # Float32, as the device build finds them: centroids near float32's limits may span
        # more than it holds, an extent of inf, whose node is not binned (below). Its bins,
        # inf * 0 = NaN cast and clipped, are never read.
        with np.errstate(over="ignore"):
            extent = cbounds[:, 3:] - cbounds[:, :3]
        axis = np.argmax(extent, axis=1)
        rows = np.arange(m)
        cmin = cbounds[rows, axis]
        cext = extent[rows, axis].astype(np.float64)
        with np.errstate(divide="ignore", over="ignore"):
            scale = (N_BINS / cext).astype(np.float32)
        # Coincident centroids (or an extent so small its reciprocal overflows) leave nothing to
        # bin: those nodes are split at the median of their (arbitrary) order instead.
        binnable = np.isfinite(scale) & (scale > 0)
        scale[~binnable] = 0
        c = prim.ravel().take((6 + axis)[seg] * p + np.arange(p))
        with np.errstate(over="ignore", invalid="ignore"):
            b = ((c - cmin[seg]) * scale[seg]).astype(np.int64)
        np.clip(b, 0, N_BINS - 1, out=b)
        key = seg * N_BINS + b
        bin_count = np.bincount(key, minlength=m * N_BINS).reshape(m, N_BINS)
        bin_lo = np.full((3, m * N_BINS), np.inf, dtype=np.float32)
        bin_hi = np.full((3, m * N_BINS), -np.inf, dtype=np.float32)
        for d in range(3):
            np.minimum.at(bin_lo[d], key, prim[d])
            np.maximum.at(bin_hi[d], key, prim[3 + d])
        bin_lo = bin_lo.reshape(3, m, N_BINS).transpose(1, 2, 0)
        bin_hi = bin_hi.reshape(3, m, N_BINS).transpose(1, 2, 0)
        return b, binnable, (bin_count, bin_lo, bin_hi)

    def _sah_choice(self, bounds: np.ndarray, count: np.ndarray, binnable: np.ndarray,
                    bin_count: np.ndarray, bin_lo: np.ndarray, bin_hi: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """(each node's best split bin, whether it stays a leaf) by the surface area
        heuristic.

        A node whose box has no area (its primitives lie on a segment parallel to an axis, or
        at a point) is costed by length instead: every candidate there has zero area, so area
        would tie them all and each split would peel off the first bin. A ray meets a segment
        with a chance in proportion to its length (Cauchy-Crofton), as it meets a box in
        proportion to its area, so length is the same heuristic one dimension down."""
        a_node = _half_area(bounds[:, :3], bounds[:, 3:])
        by_length = (a_node == 0)[:, None]
        # SAH cost of splitting after bin k (k = 0 .. N_BINS-2), from prefix and suffix unions.
        n_left = np.cumsum(bin_count, axis=1)[:, :-1]
        n_right = count[:, None] - n_left
        left_lo = np.minimum.accumulate(bin_lo, axis=1)[:, :-1]
        left_hi = np.maximum.accumulate(bin_hi, axis=1)[:, :-1]
        right_lo = np.minimum.accumulate(bin_lo[:, ::-1], axis=1)[:, -2::-1]
        right_hi = np.maximum.accumulate(bin_hi[:, ::-1], axis=1)[:, -2::-1]
        a_left = np.where(by_length, _half_perimeter(left_lo, left_hi),
                          _half_area(left_lo, left_hi))
        a_right = np.where(by_length, _half_perimeter(right_lo, right_hi),
                           _half_area(right_lo, right_hi))
        cost = a_left * packets(n_left) + a_right * packets(n_right)
        cost[(n_left == 0) | (n_right == 0)] = np.inf
        best = np.argmin(cost, axis=1)
        best_cost = cost[np.arange(count.size), best]
        a_node = np.where(by_length[:, 0], _half_perimeter(bounds[:, :3], bounds[:, 3:]), a_node)
        # Compared multiplied through by the node's area (or length), so point nodes need no
        # care.
        sah_leaf = ((self.traversal_cost * a_node + best_cost >= packets(count) * a_node)
                    | ~binnable)
        return best, sah_leaf & (count <= self.sah_leaf)

    def _flatten(self) -> Bvh:
        """Renumber the breadth-first tree depth-first: subtree sizes bottom-up, then each
        node's index top-down (left child next, right child after the left subtree)."""
        bounds = np.concatenate(self.bounds)
        start = np.concatenate(self.start)
        count = np.concatenate(self.count)
        left = np.concatenate(self.left)
        n = count.size
        inner = np.flatnonzero(left >= 0)
        # Inner nodes per breadth-first level: ids are consecutive within a level, so each level
        # is a slice of the sorted `inner`.
        level_ends = np.cumsum([c.size for c in self.count])
        levels = np.split(inner, np.searchsorted(inner, level_ends[:-1]))
        # A child's id is larger than its parent's, so bottom-up every child's size is final
        # before its parent's is summed, and top-down every parent's index is set before its
        # children's.
        size = np.ones(n, dtype=np.int64)
        for lv in reversed(levels):
            size[lv] += size[left[lv]] + size[left[lv] + 1]
        dfs = np.zeros(n, dtype=np.int64)
        for lv in levels:
            dfs[left[lv]] = dfs[lv] + 1
            dfs[left[lv] + 1] = dfs[lv] + 1 + size[left[lv]]
        nodes = np.zeros(n, dtype=BINARY_NODE)
        nodes["lo"][dfs] = bounds[:, :3]
        nodes["hi"][dfs] = bounds[:, 3:]
        is_leaf = left < 0
        nodes["count"][dfs] = np.where(is_leaf, count, 0)
        right_dfs = dfs[np.where(is_leaf, 0, left + 1)]
        nodes["first"][dfs] = np.where(is_leaf, start, right_dfs)
        return Bvh(nodes, self.order)

