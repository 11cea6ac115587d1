// The binned-SAH BVH build of clray/accel/bvh.py on the device (clray/device/bvh_builder.py
// launches it): the same splits and bounds, so the same tree. Its records (BuildPrim,
// BuildTask, BinaryNode) are in clray_types.h.
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
// The host build rounds every product and sum on its own; a fused multiply-add would not.
#pragma OPENCL FP_CONTRACT OFF

#include "clray_types.h"

// N_BINS, TRAVERSAL_COST and SAH_PACKET come from clray.accel.bvh, as build options.
// Pending subtrees of one work-item: the larger child is deferred and the smaller one built
// first, so each deferred entry at least halves the count and 64 covers any int count.
#define STACK 64

// Componentwise minimum and maximum of bounds and centroids, which are never NaN (the host
// checks the bounds: clray.accel.bvh.checked_bounds) but start at +-INFINITY in empty bins: a
// compare and select, one instruction on x86 (minps), where fmin's NaN rules took three and
// OpenCL leaves min() undefined for infinities. The host build's np.minimum gives the same.
static float4 lesser(float4 a, float4 b) { return select(b, a, a < b); }
static float4 greater(float4 a, float4 b) { return select(b, a, a > b); }

// Primitives from which fill_bins alternates two sets of bins; below it, clearing and merging
// the second set cost more than the overlap saves.
#define TWO_SETS_FROM 64

typedef struct {
    int count[N_BINS];
    float4 lo[N_BINS], hi[N_BINS], clo[N_BINS], chi[N_BINS];
} Bins;


#ifdef FLOAT_BOUNDS
// Float bounds (a mesh's triangles, whose corners are floats) are their own rounding, and the
// centroid, 0.5 (lo + hi) in double, is found from them again wherever it is needed: a
// primitive is its bounds alone, the index in lo.w (its bin of the moment in hi.w: add_to_bin),
// 32 bytes where BuildPrim takes 48 (every level of the build reads and writes each primitive).
typedef struct {
    float4 lo, hi;
} Prim;

static float4 centroid(Prim p) {
    float4 c = convert_float4(0.5 * (convert_double4(p.lo) + convert_double4(p.hi)));
    return (float4)(c.xyz, 0.0f);
}

static int prim_index(Prim p) { return as_int(p.lo.w); }

// By vload3 with the fourth lane set: Oclgrind took floats loaded one by one into a vector
// for uninitialised.
__kernel void round_prims_float(__global const float *lo, __global const float *hi,
                                __global Prim *prims, int n, int chunk) {
    int end = min(n, (int)(get_global_id(0) + 1) * chunk);
    for (int i = get_global_id(0) * chunk; i < end; i++) {
        Prim p;
        // + 0.0f: every zero +0.0, as in round_prims.
        p.lo = (float4)(vload3(i, lo) + 0.0f, as_float(i));
        p.hi = (float4)(vload3(i, hi) + 0.0f, 0.0f);
        prims[i] = p;
    }
}
#else
typedef BuildPrim Prim;

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

static float4 centroid(Prim p) { return (float4)(p.c.xyz, 0.0f); }

static int prim_index(Prim p) { return as_int(p.c.w); }

// Nearest, then one step outwards where that went inwards: the host's rounding.
__kernel void round_prims(__global const double *lo, __global const double *hi,
                          __global Prim *prims, int n, int chunk) {
    int end = min(n, (int)(get_global_id(0) + 1) * chunk);
    for (int i = get_global_id(0) * chunk; i < end; i++) {
        // Element by element, not vload3: a 3-vector's fourth (padding) lane is undefined,
        // and Oclgrind tracks it into the whole double4 built from it.
        double4 a = (double4)(lo[3 * i], lo[3 * i + 1], lo[3 * i + 2], 0.0);
        double4 b = (double4)(hi[3 * i], hi[3 * i + 1], hi[3 * i + 2], 0.0);
        float4 fa = convert_float4(a), fb = convert_float4(b);
        Prim p;
        // + 0.0f makes every zero +0.0 (-0.0 + 0.0 is +0.0), as the host build does
        // (clray/accel/bvh.py, _round_out): -0.0 and +0.0 compare equal, so which one lesser or
        // greater keeps depends on the order of the reduction, which is not the host's here.
        // With no -0.0 in, both builds give the same bytes. After the steps: the one up from
        // -2^-149 gives -0.0.
        p.lo = step_down(fa, convert_int4(convert_double4(fa) > a)) + 0.0f;
        p.hi = step_up(fb, convert_int4(convert_double4(fb) < b)) + 0.0f;
        p.c = convert_float4(0.5 * (a + b)) + 0.0f;
        p.c.w = as_float(i);
        prims[i] = p;
    }
}
#endif

// Bounds and centroid bounds of prims[start, start + count) into t.
static void bound(__global const Prim *prims, int start, int count, BuildTask *t) {
    float4 lo = (float4)(INFINITY), hi = (float4)(-INFINITY), clo = lo, chi = hi;
    for (int i = start; i < start + count; i++) {
        Prim p = prims[i];
        float4 c = centroid(p);
        lo = lesser(lo, p.lo);
        hi = greater(hi, p.hi);
        clo = lesser(clo, c);
        chi = greater(chi, c);
    }
    t->lo = lo; t->hi = hi; t->clo = clo; t->chi = chi;
    t->start = start; t->count = count;
    t->pad0 = 0;  // written, so that a task is copied with no uninitialised word
}

__kernel void root_task(__global const Prim *prims, int n, __global BuildTask *root) {
    BuildTask t;
    bound(prims, 0, n, &t);
    t.pos = 0;
    *root = t;
}

static double half_area(float4 lo, float4 hi) {
    double ex = fmax((double)hi.x - (double)lo.x, 0.0);
    double ey = fmax((double)hi.y - (double)lo.y, 0.0);
    double ez = fmax((double)hi.z - (double)lo.z, 0.0);
    return ex * ey + ey * ez + ez * ex;
}

static double half_perimeter(float4 lo, float4 hi) {
    double ex = fmax((double)hi.x - (double)lo.x, 0.0);
    double ey = fmax((double)hi.y - (double)lo.y, 0.0);
    double ez = fmax((double)hi.z - (double)lo.z, 0.0);
    return ex + ey + ez;
}

// The SAH's measure of a box: its half area, or its length in a node of no area (the host's
// _sah_choice says why).
static double measure(float4 lo, float4 hi, bool by_length) {
    return by_length ? half_perimeter(lo, hi) : half_area(lo, hi);
}

// Packet tests of a leaf of n primitives: the SAH's leaf cost, as the host's bvh.packets.
static int packets(int n) { return (n + SAH_PACKET - 1) / SAH_PACKET; }

static int bin_of(float c, float cmin, float scale) {
    return clamp((int)((c - cmin) * scale), 0, N_BINS - 1);
}

static float along(float4 v, int axis) { return axis == 0 ? v.x : axis == 1 ? v.y : v.z; }

static void clear_bins(Bins *bins) {
    for (int k = 0; k < N_BINS; k++) {
        bins->count[k] = 0;
        bins->lo[k] = bins->clo[k] = (float4)(INFINITY);
        bins->hi[k] = bins->chi[k] = (float4)(-INFINITY);
    }
}

// The primitive's bin is also kept in its hi.w (unused otherwise, and overwritten on every
// level), for the partition that follows to read instead of finding it again (a third of
// the partition's instructions).
static void add_to_bin(Bins *bins, __global Prim *at, int b, Prim p, float4 c) {
    at->hi.w = as_float(b);
    bins->count[b]++;
    bins->lo[b] = lesser(bins->lo[b], p.lo);
    bins->hi[b] = greater(bins->hi[b], p.hi);
    bins->clo[b] = lesser(bins->clo[b], c);
    bins->chi[b] = greater(bins->chi[b], c);
}

// Neighbours in a node's order are near in space and often share a bin: alternate primitives
// go to two sets of bins, so one's updates need not wait for the other's, then the sets are
// merged (minima, maxima and counts: the same bins in any order).
static void fill_bins(Bins *bins, __global Prim *src, int start, int count, int axis,
                      float cmin, float scale) {
    clear_bins(bins);
    int i = start, end = start + count;
    if (count >= TWO_SETS_FROM) {
        Bins odd;
        clear_bins(&odd);
        for (; i + 1 < end; i += 2) {
            Prim p = src[i], q = src[i + 1];
            float4 cp = centroid(p), cq = centroid(q);
            add_to_bin(bins, src + i, bin_of(along(cp, axis), cmin, scale), p, cp);
            add_to_bin(&odd, src + i + 1, bin_of(along(cq, axis), cmin, scale), q, cq);
        }
        for (int k = 0; k < N_BINS; k++) {
            bins->count[k] += odd.count[k];
            bins->lo[k] = lesser(bins->lo[k], odd.lo[k]);
            bins->hi[k] = greater(bins->hi[k], odd.hi[k]);
            bins->clo[k] = lesser(bins->clo[k], odd.clo[k]);
            bins->chi[k] = greater(bins->chi[k], odd.chi[k]);
        }
    }
    for (; i < end; i++) {
        Prim p = src[i];
        float4 c = centroid(p);
        add_to_bin(bins, src + i, bin_of(along(c, axis), cmin, scale), p, c);
    }
}

// The bin to split after, from prefix and suffix unions, costed as the host costs it. An empty
// bin changes neither union nor count: its suffix area is the next bin's, and a split after it
// costs exactly what the split after the last non-empty bin before it did, which the strict
// comparison keeps. Skipping them leaves the choice as it was; small nodes, most of a tree,
// leave most of their bins empty.
static int best_split(const Bins *bins, int count, bool by_length, double *best_cost) {
    double a_right[N_BINS - 1];
    float4 lo = (float4)(INFINITY), hi = (float4)(-INFINITY);
    for (int k = N_BINS - 1; k > 0; k--) {
        if (bins->count[k] == 0 && k < N_BINS - 1) {
            a_right[k - 1] = a_right[k];
            continue;
        }
        lo = lesser(lo, bins->lo[k]);
        hi = greater(hi, bins->hi[k]);
        a_right[k - 1] = measure(lo, hi, by_length);
    }
    lo = (float4)(INFINITY);
    hi = (float4)(-INFINITY);
    int n_left = 0, best = 0;
    *best_cost = INFINITY;
    for (int k = 0; k < N_BINS - 1; k++) {
        if (bins->count[k] == 0) continue;
        lo = lesser(lo, bins->lo[k]);
        hi = greater(hi, bins->hi[k]);
        n_left += bins->count[k];
        int n_right = count - n_left;
        double cost = n_left == 0 || n_right == 0 ? INFINITY
            : measure(lo, hi, by_length) * (double)packets(n_left)
                + a_right[k] * (double)packets(n_right);
        if (cost < *best_cost) {
            *best_cost = cost;
            best = k;
        }
    }
    return best;
}

// Child task over bins [from, to].
static void bin_child(BuildTask *c, const Bins *bins, int from, int to, int start) {
    c->lo = c->clo = (float4)(INFINITY);
    c->hi = c->chi = (float4)(-INFINITY);
    c->count = 0;
    for (int k = from; k <= to; k++) {
        c->lo = lesser(c->lo, bins->lo[k]);
        c->hi = greater(c->hi, bins->hi[k]);
        c->clo = lesser(c->clo, bins->clo[k]);
        c->chi = greater(c->chi, bins->chi[k]);
        c->count += bins->count[k];
    }
    c->start = start;
    c->pad0 = 0;  // written, so that a task is copied with no uninitialised word
}

static void write_node(__global BinaryNode *nodes, const BuildTask *t, int first, int count) {
    BinaryNode nd;
    nd.lo[0] = t->lo.x; nd.lo[1] = t->lo.y; nd.lo[2] = t->lo.z;
    nd.hi[0] = t->hi.x; nd.hi[1] = t->hi.y; nd.hi[2] = t->hi.z;
    nd.first = first;
    nd.count = count;
    nodes[t->pos] = nd;
}

static void write_leaf(const BuildTask *t, __global const Prim *src,
                       __global BinaryNode *nodes, __global int *order) {
    write_node(nodes, t, t->start, t->count);
    for (int i = t->start; i < t->start + t->count; i++) order[i] = prim_index(src[i]);
}

// The task's primitives [start, start + count) stably partitioned in place, the nl whose bin
// (hi.w) is at most `best` first. The smaller side waits in `stash` while the other is
// compacted towards its end of the range (forwards for the left side, backwards for the
// right), then is copied in after it: at most count / 2 primitives, at stash[start / 2 ..],
// which no other task's range reaches (floor(s / 2) + floor(c / 2) <= floor((s + c) / 2)), so
// the stash is half the primitives where a second buffer of them all took twice that.
static void partition(__global Prim *prims, __global Prim *stash, int start, int count,
                      int nl, int best) {
    __global Prim *wait = stash + start / 2;
    int end = start + count, k = 0;
    if (count - nl <= nl) {
        int il = start;
        for (int i = start; i < end; i++) {
            Prim p = prims[i];
            if (as_int(p.hi.w) > best) wait[k++] = p;
            else prims[il++] = p;
        }
        for (int j = 0; j < k; j++) prims[il + j] = wait[j];
    } else {
        int ir = end;
        for (int i = end - 1; i >= start; i--) {
            Prim p = prims[i];
            if (as_int(p.hi.w) > best) prims[--ir] = p;
            else wait[k++] = p;
        }
        for (int j = 0; j < k; j++) prims[start + j] = wait[k - 1 - j];
    }
}

// Writes the task's node. Returns 0 for a leaf, or 1 after stably partitioning its primitives
// (left side first, in place) and filling in the two child tasks, whose nodes are a
// pair of slots (left, then right: the node's `first` is the left one). A task over primitives
// [s, s + c) has slots 2s + 1 .. 2s + 2c - 2 for the nodes below it (at most 2c - 2): split
// after nl primitives, its children's ranges are those of [s, s + nl) and [s + nl, s + c), and
// the two slots between them, 2(s + nl) - 1 and 2(s + nl), are the pair's. That is where
// split_level puts it (next 0); build_subtrees instead takes pairs in turn from the start of its
// task's range (*next), so a subtree's nodes are written together, not strewn over its range.
static int process(const BuildTask *t, __global Prim *prims, __global Prim *stash,
                   __global BinaryNode *nodes, __global int *order, int max_leaf,
                   int sah_max_leaf, int *next, BuildTask *left, BuildTask *right) {
    int start = t->start, count = t->count;
    if (count <= max_leaf) {
        write_leaf(t, prims, nodes, order);
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
            write_leaf(t, prims, nodes, order);
            return 0;
        }
        bound(prims, start, count / 2, left);
        bound(prims, start + count / 2, count - count / 2, right);
    } else {
        Bins bins;
        fill_bins(&bins, prims, start, count, axis, cmin, scale);
        double a_node = half_area(t->lo, t->hi);
        bool by_length = a_node == 0.0;
        if (by_length) a_node = half_perimeter(t->lo, t->hi);
        double best_cost;
        int best = best_split(&bins, count, by_length, &best_cost);
        if (count <= sah_max_leaf
            && TRAVERSAL_COST * a_node + best_cost >= (double)packets(count) * a_node) {
            write_leaf(t, prims, nodes, order);
            return 0;
        }
        bin_child(left, &bins, 0, best, start);
        bin_child(right, &bins, best + 1, N_BINS - 1, start + left->count);
        partition(prims, stash, start, count, left->count, best);
    }
    int kids = next ? (*next += 2) - 2 : 2 * (start + left->count) - 1;
    write_node(nodes, t, kids, 0);
    left->pos = kids;
    right->pos = kids + 1;
    return 1;
}

// One level: every task split once, its children (count -1: none) to out[2g], out[2g + 1].
__kernel void split_level(__global const BuildTask *in, __global BuildTask *out,
                          __global Prim *prims, __global Prim *stash,
                          __global BinaryNode *nodes, __global int *order, int max_leaf,
                          int sah_max_leaf) {
    int g = get_global_id(0);
    BuildTask t = in[g], l, r;
    if (!process(&t, prims, stash, nodes, order, max_leaf, sah_max_leaf, 0, &l, &r)) {
        l.count = -1;
        r.count = -1;
    }
    out[2 * g] = l;
    out[2 * g + 1] = r;
}

// Each task's whole subtree, its nodes in the pairs of slots from the start of its range on.
__kernel void build_subtrees(__global const BuildTask *tasks, __global Prim *prims,
                             __global Prim *stash, __global BinaryNode *nodes,
                             __global int *order, int max_leaf, int sah_max_leaf) {
    BuildTask stack[STACK];
    int sp = 0;
    BuildTask cur = tasks[get_global_id(0)], l, r;
    int next = 2 * cur.start + 1;
    for (;;) {
        if (process(&cur, prims, stash, nodes, order, max_leaf, sah_max_leaf, &next, &l, &r)) {
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
