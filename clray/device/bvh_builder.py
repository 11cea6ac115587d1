"""The binned-SAH build of clray.accel.bvh on an OpenCL device (kernels/bvh_build.cl): the same
splits and bounds, so the same tree.

The host build runs level by level because numpy wants whole-array passes; a kernel can instead
run the plain recursive build, one subtree per work-item. The top few levels, where there are
fewer nodes than cores, are split one level per launch (one work-item per node) until there are
enough subtrees to keep every core busy.

Nodes go to 2N - 1 slots, each subtree's to a range of its own: a subtree over primitives
[s, s + c) gets the 2c - 2 slots from 2s + 1 for the nodes below it (as many as they could ever
need), so no work-item waits for another's subtree size, and its nodes are written as a pair of
children at a time (kernels/bvh_build.cl, process): the layout of Bvh.pairs, which the collapse
into the wide tree reads as it is. The tree is renumbered depth-first on the host where asked.

The kernels repeat the host build's arithmetic operation for operation (float32 binning, float64
costs, no contraction into fma), so both builds give the same tree.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pyopencl as cl

from clray.accel.bvh import (
    N_BINS,
    SAH_PACKET,
    TRAVERSAL_COST,
    Bvh,
    build_bvh,
    checked_bounds,
)
from clray.device.buffers import read_only_buffer
from clray.device.context import has_fp64
from clray.device.layout import BINARY_NODE, BUILD_PRIM, BUILD_TASK
from clray.device.program import (
    build_cached,
    cache_folder_errors,
    device_build_options,
    is_oclgrind,
    kernel_source,
)
from clray.host_memory import by_chunks

# Subtrees per compute unit before the per-subtree kernel takes over: enough that one large
# subtree does not leave the other cores idle at the end.
_TASKS_PER_UNIT = 8
# Work-items of the rounding pass, each over a contiguous run of primitives.
_ROUND_ITEMS = 256
# A lopsided tree (each split peeling off a few primitives) never reaches that many subtrees:
# past this many one-level launches its remaining subtrees are built as they are.
_MAX_LEVEL_LAUNCHES = 24
BUILD_FILE = "bvh_build.cl"
_FLOAT_PRIM = np.dtype((np.void, 32))


def build_options() -> list[str]:
    """The host build's constants, so that the kernels cost and bin as it does."""
    return [f"-DN_BINS={N_BINS}", f"-DTRAVERSAL_COST={float(TRAVERSAL_COST)!r}",
            f"-DSAH_PACKET={SAH_PACKET}"]


def build_bvh_on(queue: cl.CommandQueue, lo: np.ndarray, hi: np.ndarray,
                 max_leaf_size: int = 4, *, largest_leaf: int | None = None,
                 pairs: bool = False) -> Bvh:
    """clray.accel.bvh.build_bvh's tree, built on the queue's device where it can be (float64,
    int slot indices: supports), several times faster than the host build; else on the host.

    pairs: a device build's tree is left in its own layout (Bvh.pairs), for
    clray.accel.wide.collapse, without the pass that renumbers it depth-first."""
    return build_bvh_from(queue, [lo, hi], max_leaf_size, largest_leaf=largest_leaf,
                          pairs=pairs)


def build_bvh_from(queue: cl.CommandQueue, bounds: list[np.ndarray], max_leaf_size: int = 4,
                   *, largest_leaf: int | None = None, pairs: bool = False,
                   values_checked: bool = False, consume: bool = False) -> Bvh:
    """build_bvh_on's tree from `bounds` = [lo, hi], a list this call empties: where the
    caller holds the arrays nowhere else, the device build frees them once its kernels have
    their copies, before its own buffers fill (a mesh's float bounds, 24 B a triangle, are
    the pack's largest arrays beside them: docs/scale.md).
    values_checked: as for clray.accel.bvh.checked_bounds. consume: the build may reorder
    bounds made by float_prims, working in their records (build); else they are left as
    they were."""
    lo, hi, largest = checked_bounds(*bounds, max_leaf_size, largest_leaf, values_checked)
    bounds.clear()
    n = lo.shape[0]
    if n > max_leaf_size and supports(queue.device, n, lo.itemsize):
        bounds += [lo, hi]
        del lo, hi
        return build(queue, bounds, max_leaf_size, largest, not pairs, consume=consume)
    return build_bvh(lo, hi, max_leaf_size, largest_leaf=largest)


def float_prims(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): (n, 3) float32 views, for the caller to fill with n primitives' bounds, of
    records laid out as the device build's float primitives (kernels/bvh_build.cl, Prim under
    FLOAT_BOUNDS: lo, the index, hi, a spare word). A device build allowed to consume bounds
    that are these views whole (build_bvh_from's consume) takes their records as its first
    primitive buffer (_prims_of), on every device but Oclgrind: no copy of the bounds and no
    pass that rounds them in, but the build partitions them in place, so their rows come back
    reordered on a device that works in host memory. Any other build copies them, and any
    other use sees plain bounds. The caller writes every zero as +0.0, as the rounding passes
    do (consumed records have none), for the host build's bytes. The index and spare words
    are written a chunk at a time on every core: their first touch of the records' fresh
    memory (32 B a primitive) is most of the time this takes."""
    records = np.empty((n, 8), dtype=np.float32)

    def number(part: slice) -> None:
        records[part, 3] = np.arange(part.start, part.stop, dtype=np.int32).view(np.float32)
        records[part, 7] = 0.0
    by_chunks(n, number)
    return records[:, 0:3], records[:, 4:7]


def _prims_of(lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """The float primitive records whose whole lo and hi columns `lo` and `hi` are
    (float_prims), as the build's records; else None."""
    records = lo.base
    if (records is None or hi.base is not records or records.dtype != np.float32
            or records.shape != (len(lo), 8) or not records.flags.c_contiguous
            or lo.ctypes.data != records.ctypes.data
            or hi.ctypes.data != records.ctypes.data + 16):
        return None
    return records.view(_FLOAT_PRIM).reshape(len(lo))


def supports(device: cl.Device, n: int, bound_bytes: int = 8) -> bool:
    """The kernels cost splits in float64, as the host build does, and index node slots
    (2N - 1 of them) with ints; every buffer of the build fits the device's largest allocation
    (CL_DEVICE_MAX_MEM_ALLOC_SIZE, a quarter of its memory on PoCL and NVIDIA) and all of
    them its memory. Where they do not, the host builds the same tree, slower. bound_bytes:
    of one coordinate of the bounds (8 for float64, 4 for float32)."""
    sizes = build_buffer_bytes(n, bound_bytes)
    return (has_fp64(device) and 2 * n - 1 <= np.iinfo(np.int32).max
            and max(sizes.values()) <= device.max_mem_alloc_size
            and sum(sizes.values()) <= device.global_mem_size)


def build_buffer_bytes(n: int, bound_bytes: int = 8) -> dict[str, int]:
    """Bytes of each buffer build() makes for n primitives with bounds of `bound_bytes` a
    coordinate."""
    slots = 2 * n - 1
    prim = _prim_dtype(bound_bytes).itemsize
    return {"lo": 3 * bound_bytes * n, "hi": 3 * bound_bytes * n, "prims": prim * n,
            "prims_stash": prim * _stash_count(n), "nodes": BINARY_NODE.itemsize * slots,
            "order": 4 * n}


def _stash_count(n: int) -> int:
    """Primitives the partition's stash holds: the smaller side of any split, n // 2 at most
    (one where that is none: an empty buffer is not a buffer)."""
    return max(n // 2, 1)


def _prim_dtype(bound_bytes: int) -> np.dtype:
    """The build's primitive record: for float bounds their own rounding, the bounds alone
    (kernels/bvh_build.cl, Prim under FLOAT_BOUNDS: 32 bytes), else BuildPrim (48)."""
    return _FLOAT_PRIM if bound_bytes == 4 else BUILD_PRIM


@cache
def _kernels(context: cl.Context, float_bounds: bool) -> dict[str, cl.Kernel]:
    # Kernel objects are kept: pyopencl makes a new one on every attribute access.
    options = build_options() + list(device_build_options(context.devices[0]))
    program = build_cached(cl.Program(context, kernel_source(BUILD_FILE)),
                           options + (["-DFLOAT_BOUNDS"] if float_bounds else []))
    with cache_folder_errors():
        return {k.function_name: k for k in program.all_kernels()}


def build(queue: cl.CommandQueue, bounds: list[np.ndarray], max_leaf: int,
          sah_max_leaf: int, depth_first: bool = True, *, consume: bool = False) -> Bvh:
    """The tree over N primitives with float64 or float32 bounds [lo, hi] (N, 3), N >
    max_leaf: depth-first, or in the build's own layout (Bvh.pairs). `bounds` is emptied
    and, where `consume`, may be reordered (build_bvh_from)."""
    lo, hi = bounds
    bounds.clear()
    n, bound_bytes = lo.shape[0], lo.itemsize
    slots = 2 * n - 1
    float_bounds = lo.dtype == np.float32
    kernels = _kernels(queue.context, float_bounds)
    # Every buffer lives in numpy memory: a CPU device then works in place, and numpy reuses
    # freed memory where a fresh device allocation page-faults in all over again each build.
    # Records the caller filled (float_prims) and lets the build consume are the first
    # primitive buffer: a USE_HOST_PTR buffer's contents are its host memory's at creation,
    # which a CPU device then reads and partitions in place and a GPU copies once, so the
    # bounds need no second copy beside the records. Not on Oclgrind, which takes such
    # contents for uninitialised: there they are bounds like any others.
    given = (_prims_of(lo, hi) if consume and float_bounds and not is_oclgrind(queue.device)
             else None)
    # The primitives, partitioned in place, and the stash of the smaller side of a split
    # (kernels/bvh_build.cl, partition): half as many.
    prims = [np.empty(n, dtype=_prim_dtype(bound_bytes)) if given is None else given,
             np.empty(_stash_count(n), dtype=_prim_dtype(bound_bytes))]
    # Uninitialised: the pages a subtree's range does not reach are never touched.
    nodes = np.empty(slots, dtype=BINARY_NODE)
    order = np.empty(n, dtype=np.int32)
    root = np.empty(1, dtype=BUILD_TASK)
    bufs = [_host_buffer(queue, a) for a in (*prims, nodes, order, root)]
    if given is None:
        _round_in(queue, kernels, lo, hi, bufs[0])
    del lo, hi, given
    kernels["root_task"](queue, (1,), (1,), bufs[0], np.int32(n), bufs[4])
    shared = (*bufs[:4], np.int32(max_leaf), np.int32(sah_max_leaf))

    tasks = _split_levels(queue, kernels["split_level"], bufs[4], shared)
    if tasks.size:
        kernels["build_subtrees"](queue, (tasks.size,), (1,),
                                  read_only_buffer(queue.context, tasks), *shared)
    for buf, array in zip(bufs[2:4], (nodes, order), strict=True):
        _sync(queue, buf, array)
    return Bvh(_depth_first(nodes), order) if depth_first else Bvh(nodes, order, pairs=True)


def _round_in(queue: cl.CommandQueue, kernels: dict[str, cl.Kernel], lo: np.ndarray,
              hi: np.ndarray, prims: cl.Buffer) -> None:
    """The bounds as the build's primitive records, rounded outwards where they are float64.
    Read in place where the device can (read_only_buffer): a copy of them was 24 B a triangle
    more of fresh memory. Done before returning, so that the caller may free them."""
    n = len(lo)
    lo_buf = read_only_buffer(queue.context, lo)
    hi_buf = read_only_buffer(queue.context, hi)
    chunk = -(-n // _ROUND_ITEMS)
    round_prims = kernels["round_prims_float" if lo.dtype == np.float32 else "round_prims"]
    round_prims(queue, (-(-n // chunk),), (1,), lo_buf, hi_buf, prims, np.int32(n),
                np.int32(chunk)).wait()
    lo_buf.release()
    hi_buf.release()


def _host_buffer(queue: cl.CommandQueue, array: np.ndarray) -> cl.Buffer:
    return cl.Buffer(queue.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR,
                     hostbuf=array)


def _sync(queue: cl.CommandQueue, buf: cl.Buffer, array: np.ndarray) -> None:
    """Make the device's writes to `buf` visible in `array`, its host memory: mapping does
    that (a no-op on a CPU device), and unmapping hands the memory back."""
    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, array.shape,
                                      array.dtype, is_blocking=True)
    mapped.base.release(queue)


def _split_levels(queue: cl.CommandQueue, split_level: cl.Kernel, root_buf: cl.Buffer,
                  shared: tuple) -> np.ndarray:
    """Split the top levels one launch each; returns the subtrees left to build."""
    enough = _TASKS_PER_UNIT * queue.device.max_compute_units
    in_buf, m = root_buf, 1
    for _ in range(_MAX_LEVEL_LAUNCHES):
        out = np.empty(2 * m, dtype=BUILD_TASK)
        out_buf = _host_buffer(queue, out)
        split_level(queue, (m,), (1,), in_buf, out_buf, *shared)
        _sync(queue, out_buf, out)
        tasks = out[out["count"] >= 0]
        if not 0 < tasks.size < enough:
            break
        in_buf = read_only_buffer(queue.context, tasks)
        m = tasks.size
    return tasks


def _depth_first(nodes: np.ndarray) -> np.ndarray:
    """The build's tree (Bvh.pairs) renumbered depth-first, a level at a time from the root:
    subtree sizes bottom-up, then each node's position top-down (left child next, right child
    after the left subtree)."""
    levels = [np.zeros(1, dtype=np.int64)]  # slots, level by level; children in pairs
    inner = []  # which of a level's nodes are inner: the next level holds their children
    while True:
        inner.append(nodes["count"][levels[-1]] == 0)
        if not inner[-1].any():
            break
        first = nodes["first"][levels[-1][inner[-1]]].astype(np.int64)
        levels.append(np.stack([first, first + 1], axis=1).ravel())
    size = [np.ones(level.size, dtype=np.int64) for level in levels]
    for k in range(len(levels) - 2, -1, -1):
        size[k][inner[k]] += size[k + 1].reshape(-1, 2).sum(axis=1)
    position = [np.zeros(1, dtype=np.int64)]
    for k in range(1, len(levels)):
        parent = position[k - 1][inner[k - 1]]
        left_size = size[k].reshape(-1, 2)[:, 0]
        position.append(np.stack([parent + 1, parent + 1 + left_size], axis=1).ravel())
    opaque = np.dtype((np.void, BINARY_NODE.itemsize))
    out = np.empty(int(size[0][0]), dtype=BINARY_NODE)
    out.view(opaque)[np.concatenate(position)] = nodes.view(opaque)[np.concatenate(levels)]
    for k in range(len(levels) - 1):
        out["first"][position[k][inner[k]]] = position[k + 1].reshape(-1, 2)[:, 1]
    return out
