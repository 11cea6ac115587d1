"""The binned-SAH build of clray.accel.bvh as OpenCL kernels: the same splits and bounds.

The host build runs level by level because numpy wants whole-array passes; a kernel can instead
run the plain recursive build, one subtree per work-item. The top few levels, where there are
fewer nodes than cores, are split one level per launch (one work-item per node) until there are
enough subtrees to keep every core busy.

Every node is written at its position in a padded depth-first layout: a subtree over c
primitives gets 2c - 1 slots (as many as its nodes could ever need), so a node's position
depends only on its ancestors' splits and no work-item waits for another's subtree size.
Dropping the unused slots, in order, leaves exactly the depth-first layout.

The kernels repeat the host build's arithmetic operation for operation (float32 binning, float64
costs, no contraction into fma), so both builds give the same tree.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pyopencl as cl

from clray.accel.bvh import SAH_PACKET, TRAVERSAL_COST
from clray.device.context import has_fp64
from clray.device.layout import BVH_NODE

# Device-side twins of the structs below; Task's float4s set its 16-byte alignment.
_PRIM = np.dtype([("lo", "<f4", (4,)), ("hi", "<f4", (4,)), ("c", "<f4", (4,))])
_TASK = np.dtype([("lo", "<f4", (4,)), ("hi", "<f4", (4,)), ("clo", "<f4", (4,)),
                  ("chi", "<f4", (4,)), ("start", "<i4"), ("count", "<i4"), ("pos", "<i4"),
                  ("flip", "<i4")])

# Subtrees per compute unit before the per-subtree kernel takes over: enough that one large
# subtree does not leave the other cores idle at the end.
_TASKS_PER_UNIT = 8
# Work-items of the rounding pass, each over a contiguous run of primitives.
_ROUND_ITEMS = 256
# A lopsided tree (each split peeling off a few primitives) never reaches that many subtrees:
# past this many one-level launches its remaining subtrees are built as they are.
_MAX_LEVEL_LAUNCHES = 24

_SOURCE = r"""
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
// The host build rounds every product and sum on its own; a fused multiply-add would not.
#pragma OPENCL FP_CONTRACT OFF

#define N_BINS 16
// TRAVERSAL_COST and SAH_PACKET come from clray.accel.bvh, as build options.
// Pending subtrees of one work-item: the larger child is deferred and the smaller one built
// first, so each deferred entry at least halves the count and 64 covers any int count.
#define STACK 64

// Vectors, so a primitive is three aligned loads; the id rides in the centroid's w.
typedef struct { float4 lo, hi, c; } Prim;
// `flip`: which of the two primitive buffers holds the task's primitives. Each split moves
// them to the other one, so a stable partition is one pass and needs no copy back.
typedef struct { float4 lo, hi, clo, chi; int start, count, pos, flip; } Task;
typedef struct { float lo[3]; int first; float hi[3]; int count; } Node;
typedef struct {
    int count[N_BINS];
    float4 lo[N_BINS], hi[N_BINS], clo[N_BINS], chi[N_BINS];
} Bins;


// Float32 values one step towards -inf (down) or +inf (up) where `need` is set. Integer
// arithmetic on the bits and selects, four lanes at once: about half the values need the step,
// at random, and branching on that costs several times the rest of the pass.
static float4 step_down(float4 f, int4 need) {
    int4 bits = as_int4(f);
    int4 stepped = bits + select((int4)(-1), (int4)(1), f < 0.0f);
    stepped = select(stepped, (int4)(0x80000001), f == 0.0f);
    return as_float4(select(bits, stepped, need));
}

static float4 step_up(float4 f, int4 need) {
    int4 bits = as_int4(f);
    int4 stepped = bits + select((int4)(1), (int4)(-1), f < 0.0f);
    stepped = select(stepped, (int4)(1), f == 0.0f);
    return as_float4(select(bits, stepped, need));
}

__kernel void round_prims(__global const double *lo, __global const double *hi,
                          __global Prim *prims, int n, int chunk) {
    int end = min(n, (int)(get_global_id(0) + 1) * chunk);
    for (int i = get_global_id(0) * chunk; i < end; i++) {
        double4 a = (double4)(vload3(i, lo), 0.0), b = (double4)(vload3(i, hi), 0.0);
        // Nearest, then one step outwards where that went inwards: the host's rounding.
        float4 fa = convert_float4(a), fb = convert_float4(b);
        Prim p;
        p.lo = step_down(fa, convert_int4(convert_double4(fa) > a));
        p.hi = step_up(fb, convert_int4(convert_double4(fb) < b));
        p.c = convert_float4(0.5 * (a + b));
        p.c.w = as_float(i);
        prims[i] = p;
    }
}

// Bounds and centroid bounds of prims[start, start + count) into t.
static void bound(__global const Prim *prims, int start, int count, Task *t) {
    float4 lo = (float4)(INFINITY), hi = (float4)(-INFINITY), clo = lo, chi = hi;
    for (int i = start; i < start + count; i++) {
        Prim p = prims[i];
        float4 c = (float4)(p.c.xyz, 0.0f);
        lo = fmin(lo, p.lo);
        hi = fmax(hi, p.hi);
        clo = fmin(clo, c);
        chi = fmax(chi, c);
    }
    t->lo = lo; t->hi = hi; t->clo = clo; t->chi = chi;
    t->start = start; t->count = count;
}

__kernel void root_task(__global const Prim *prims, int n, __global Task *root) {
    Task t;
    bound(prims, 0, n, &t);
    t.pos = 0;
    t.flip = 0;
    *root = t;
}

static double half_area(float4 lo, float4 hi) {
    double ex = fmax((double)hi.x - (double)lo.x, 0.0);
    double ey = fmax((double)hi.y - (double)lo.y, 0.0);
    double ez = fmax((double)hi.z - (double)lo.z, 0.0);
    return ex * ey + ey * ez + ez * ex;
}

// Packet tests of a leaf of n primitives: the SAH's leaf cost, as the host's bvh.packets.
static int packets(int n) { return (n + SAH_PACKET - 1) / SAH_PACKET; }

static int bin_of(float c, float cmin, float scale) {
    return clamp((int)((c - cmin) * scale), 0, N_BINS - 1);
}

static float along(float4 v, int axis) { return axis == 0 ? v.x : axis == 1 ? v.y : v.z; }

static void fill_bins(Bins *bins, __global const Prim *src, int start, int count, int axis,
                      float cmin, float scale) {
    for (int k = 0; k < N_BINS; k++) {
        bins->count[k] = 0;
        bins->lo[k] = bins->clo[k] = (float4)(INFINITY);
        bins->hi[k] = bins->chi[k] = (float4)(-INFINITY);
    }
    for (int i = start; i < start + count; i++) {
        Prim p = src[i];
        int b = bin_of(along(p.c, axis), cmin, scale);
        float4 c = (float4)(p.c.xyz, 0.0f);
        bins->count[b]++;
        bins->lo[b] = fmin(bins->lo[b], p.lo);
        bins->hi[b] = fmax(bins->hi[b], p.hi);
        bins->clo[b] = fmin(bins->clo[b], c);
        bins->chi[b] = fmax(bins->chi[b], c);
    }
}

// The bin to split after, from prefix and suffix unions, costed as the host costs it.
static int best_split(const Bins *bins, int count, double *best_cost) {
    double a_right[N_BINS - 1];
    float4 lo = (float4)(INFINITY), hi = (float4)(-INFINITY);
    for (int k = N_BINS - 1; k > 0; k--) {
        lo = fmin(lo, bins->lo[k]);
        hi = fmax(hi, bins->hi[k]);
        a_right[k - 1] = half_area(lo, hi);
    }
    lo = (float4)(INFINITY);
    hi = (float4)(-INFINITY);
    int n_left = 0, best = 0;
    *best_cost = INFINITY;
    for (int k = 0; k < N_BINS - 1; k++) {
        lo = fmin(lo, bins->lo[k]);
        hi = fmax(hi, bins->hi[k]);
        n_left += bins->count[k];
        int n_right = count - n_left;
        double cost = n_left == 0 || n_right == 0 ? INFINITY
            : half_area(lo, hi) * (double)packets(n_left)
                + a_right[k] * (double)packets(n_right);
        if (cost < *best_cost) {
            *best_cost = cost;
            best = k;
        }
    }
    return best;
}

// Child task over bins [from, to].
static void bin_child(Task *c, const Bins *bins, int from, int to, int start) {
    c->lo = c->clo = (float4)(INFINITY);
    c->hi = c->chi = (float4)(-INFINITY);
    c->count = 0;
    for (int k = from; k <= to; k++) {
        c->lo = fmin(c->lo, bins->lo[k]);
        c->hi = fmax(c->hi, bins->hi[k]);
        c->clo = fmin(c->clo, bins->clo[k]);
        c->chi = fmax(c->chi, bins->chi[k]);
        c->count += bins->count[k];
    }
    c->start = start;
}

static void write_node(__global Node *nodes, __global uchar *used, const Task *t, int first,
                       int count) {
    Node nd;
    nd.lo[0] = t->lo.x; nd.lo[1] = t->lo.y; nd.lo[2] = t->lo.z;
    nd.hi[0] = t->hi.x; nd.hi[1] = t->hi.y; nd.hi[2] = t->hi.z;
    nd.first = first;
    nd.count = count;
    nodes[t->pos] = nd;
    used[t->pos] = 1;
}

static void write_leaf(const Task *t, __global const Prim *src, __global Node *nodes,
                       __global uchar *used, __global int *order) {
    write_node(nodes, used, t, t->start, t->count);
    for (int i = t->start; i < t->start + t->count; i++) order[i] = as_int(src[i].c.w);
}

// Writes the task's node. Returns 0 for a leaf, or 1 after stably partitioning its primitives
// (left side first) into the other buffer and filling in the two child tasks.
static int process(const Task *t, __global Prim *buf0, __global Prim *buf1,
                   __global Node *nodes, __global uchar *used, __global int *order,
                   int max_leaf, int sah_max_leaf, Task *left, Task *right) {
    __global Prim *src = t->flip ? buf1 : buf0, *dst = t->flip ? buf0 : buf1;
    int start = t->start, count = t->count;
    if (count <= max_leaf) {
        write_leaf(t, src, nodes, used, order);
        return 0;
    }
    float ext[3] = {t->chi.x - t->clo.x, t->chi.y - t->clo.y, t->chi.z - t->clo.z};
    int axis = 0;
    if (ext[1] > ext[axis]) axis = 1;
    if (ext[2] > ext[axis]) axis = 2;
    float cmin = axis == 0 ? t->clo.x : axis == 1 ? t->clo.y : t->clo.z;
    float scale = (float)(N_BINS / (double)ext[axis]);
    // Coincident centroids (or a reciprocal that overflows): split at the median instead.
    if (!(isfinite(scale) && scale > 0.0f)) {
        if (count <= sah_max_leaf) {
            write_leaf(t, src, nodes, used, order);
            return 0;
        }
        for (int i = start; i < start + count; i++) dst[i] = src[i];
        bound(dst, start, count / 2, left);
        bound(dst, start + count / 2, count - count / 2, right);
    } else {
        Bins bins;
        fill_bins(&bins, src, start, count, axis, cmin, scale);
        double best_cost;
        int best = best_split(&bins, count, &best_cost);
        double a_node = half_area(t->lo, t->hi);
        if (count <= sah_max_leaf
            && TRAVERSAL_COST * a_node + best_cost >= (double)packets(count) * a_node) {
            write_leaf(t, src, nodes, used, order);
            return 0;
        }
        bin_child(left, &bins, 0, best, start);
        bin_child(right, &bins, best + 1, N_BINS - 1, start + left->count);
        int il = start, ir = right->start;
        for (int i = start; i < start + count; i++) {
            Prim p = src[i];
            if (bin_of(along(p.c, axis), cmin, scale) > best) dst[ir++] = p;
            else dst[il++] = p;
        }
    }
    int nl = left->count;
    write_node(nodes, used, t, t->pos + 2 * nl, 0);
    left->pos = t->pos + 1;
    right->pos = t->pos + 2 * nl;
    left->flip = right->flip = !t->flip;
    return 1;
}

// One level: every task split once, its children (count -1: none) to out[2g], out[2g + 1].
__kernel void split_level(__global const Task *in, __global Task *out, __global Prim *buf0,
                          __global Prim *buf1, __global Node *nodes, __global uchar *used,
                          __global int *order, int max_leaf, int sah_max_leaf) {
    int g = get_global_id(0);
    Task t = in[g], l, r;
    if (!process(&t, buf0, buf1, nodes, used, order, max_leaf, sah_max_leaf, &l, &r)) {
        l.count = -1;
        r.count = -1;
    }
    out[2 * g] = l;
    out[2 * g + 1] = r;
}

// Each task's whole subtree.
__kernel void build_subtrees(__global const Task *tasks, __global Prim *buf0,
                             __global Prim *buf1, __global Node *nodes,
                             __global uchar *used, __global int *order, int max_leaf,
                             int sah_max_leaf) {
    Task stack[STACK];
    int sp = 0;
    Task cur = tasks[get_global_id(0)], l, r;
    for (;;) {
        if (process(&cur, buf0, buf1, nodes, used, order, max_leaf, sah_max_leaf, &l, &r)) {
            if (l.count >= r.count) {
                stack[sp++] = l;
                cur = r;
            } else {
                stack[sp++] = r;
                cur = l;
            }
        } else if (sp > 0) {
            cur = stack[--sp];
        } else {
            break;
        }
    }
}
"""


def supports(device: cl.Device, n: int) -> bool:
    """The kernels cost splits in float64, as the host build does, and index node slots
    (2N - 1 of them) with ints."""
    return has_fp64(device) and 2 * n - 1 <= np.iinfo(np.int32).max


@cache
def _kernels(context: cl.Context) -> dict[str, cl.Kernel]:
    # Kernel objects are kept: pyopencl makes a new one on every attribute access.
    program = cl.Program(context, _SOURCE).build(
        options=[f"-DTRAVERSAL_COST={float(TRAVERSAL_COST)!r}", f"-DSAH_PACKET={SAH_PACKET}"])
    return {k.function_name: k for k in program.all_kernels()}


def build(queue: cl.CommandQueue, lo: np.ndarray, hi: np.ndarray, max_leaf: int,
          sah_max_leaf: int) -> tuple[np.ndarray, np.ndarray]:
    """(nodes, order) for N primitives with float64 bounds `lo`, `hi` (N, 3), N > max_leaf."""
    n = lo.shape[0]
    slots = 2 * n - 1
    kernels = _kernels(queue.context)
    # Every buffer lives in numpy memory: a CPU device then works in place, and numpy reuses
    # freed memory where a fresh device allocation page-faults in all over again each build.
    lo_buf = _host_buffer(queue, np.ascontiguousarray(lo))
    hi_buf = _host_buffer(queue, np.ascontiguousarray(hi))
    prims = [np.empty(n, dtype=_PRIM), np.empty(n, dtype=_PRIM)]
    padded = np.empty(slots, dtype=BVH_NODE)
    used = np.zeros(slots, dtype=np.uint8)
    order = np.empty(n, dtype=np.int32)
    root = np.empty(1, dtype=_TASK)
    bufs = [_host_buffer(queue, a) for a in (*prims, padded, used, order, root)]
    chunk = -(-n // _ROUND_ITEMS)
    kernels["round_prims"](queue, (-(-n // chunk),), (1,), lo_buf, hi_buf, bufs[0],
                           np.int32(n), np.int32(chunk))
    kernels["root_task"](queue, (1,), (1,), bufs[0], np.int32(n), bufs[5])
    shared = (*bufs[:5], np.int32(max_leaf), np.int32(sah_max_leaf))

    tasks = _split_levels(queue, kernels["split_level"], bufs[5], shared)
    if tasks.size:
        kernels["build_subtrees"](queue, (tasks.size,), (1,), _host_buffer(queue, tasks),
                                  *shared)
    for buf, array in zip(bufs[2:5], (padded, used, order), strict=True):
        _sync(queue, buf, array)
    return _compact(padded, used.view(bool)), order


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
        out = np.empty(2 * m, dtype=_TASK)
        out_buf = _host_buffer(queue, out)
        split_level(queue, (m,), (1,), in_buf, out_buf, *shared)
        _sync(queue, out_buf, out)
        tasks = out[out["count"] >= 0]
        if not 0 < tasks.size < enough:
            break
        in_buf = _host_buffer(queue, tasks)
        m = tasks.size
    return tasks


def _compact(padded: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Drop the unused slots; inner nodes' `first` goes from padded to compact positions."""
    index = np.cumsum(used, dtype=np.int32) - 1
    # Whole records as opaque 32-byte items: numpy copies those far faster than structs.
    nodes = np.compress(used, padded.view(np.dtype((np.void, BVH_NODE.itemsize)))).view(BVH_NODE)
    first = nodes["first"]
    np.copyto(first, index[first], where=nodes["count"] == 0)
    return nodes
