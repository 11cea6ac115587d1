// Sample packets (TRAVERSAL_SAMPLE_PACKET): PACKET_LANES rays of one pixel's samples walk the
// wide BVH together, one ray per vector lane (docs/acceleration.md, Sample packets). A child
// is visited if any active lane crosses its box, nearest first for the packet; each lane keeps
// its own t and hit, and tests shapes with the single-ray formulas written lane-wise, so each
// lane finds the hit the single-ray walk finds, but for one case: where three or more
// crossings lie within two tie widths of each other (bvh.h: TIE_ROUNDINGS), which one wins can
// depend on the order the leaves are visited in (a tie is not transitive), and the packet's
// order is not the lane's own. A subtree or leaf that at most PACKET_MIN_LANES lanes reach is
// walked ray by ray by the single-ray code (bvh.h).
#ifndef CLRAY_PACKET_H
#define CLRAY_PACKET_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shapes.h"
#include "bvh.h"

#if SAMPLE_PACKETS
// consider_hit on every lane of `crossed`, for one shape (ref, part) crossed at t: the same
// comparisons, with selects.
HOT void consider_lanes(PacketHit* h, MASKP crossed, REALP t, int ref, int part, REALP b1,
                        REALP b2) {
    MASKP take = crossed & (t > (REAL)0) & (t < REAL_INF);
    MASKP none = h->ref < (MASKP)(0);
    // GREATER for consider_hit's fmax: the same wherever h->t is a number (it always is).
    REALP tol = none ? (REALP)(0) : (REALP)(tie_gamma()) * GREATER(t, h->t);
    take &= none | (t < h->t - tol) | ((t <= h->t + tol) & ((MASKP)(ref) < h->ref));
    h->t = take ? t : h->t;
    h->ref = take ? (MASKP)(ref) : h->ref;
    h->part = take ? (MASKP)(part) : h->part;
    h->b1 = take ? b1 : h->b1;
    h->b2 = take ? b2 : h->b2;
}

// How far each lane's hit may still be replaced: its t plus consider_lanes's tie reach.
DEFINE_TIE_REACH(HOT, REALP, tie_reach_lanes)

#if HAS_PLANES
// consider_planes on every lane of `lanes`, each crossing through consider_hit's rules
// (consider_lanes).
HOT void consider_planes_lanes(const SceneRefs* s, const RayPacket* p, MASKP lanes,
                               PacketHit* h) {
    for (int i = 0; i < s->n_planes; ++i) {
        REALP t;
        MASKP crossed = lanes & plane_lanes(s->planes + i, p, &t);
        if (lane_mask(crossed)) {
            consider_lanes(h, crossed, t, (PRIM_PLANE << PRIM_TYPE_SHIFT) | i, 0, (REALP)(0),
                           (REALP)(0));
        }
    }
}
#endif

// One axis of node_children's slab test (bvh.h), for one box against every lane.
DEFINE_SLAB_AXIS(REALP, SIGNS_P, slab_axis_lanes)

// Where each lane enters box c of a node, within [0, tmax]; crossed lanes in *crossed.
HOT REALP box_lanes(const __global BvhNode* node, int c, const RayPacket* p, REALP tmax,
                    MASKP* crossed) {
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    REALP t0 = (REALP)(0), t1 = tmax;
    slab_axis_lanes((REALP)(TO_REAL(node->lo_x[c])), (REALP)(TO_REAL(node->hi_x[c])), p->ox,
                    p->ix, widen, &t0, &t1);
    slab_axis_lanes((REALP)(TO_REAL(node->lo_y[c])), (REALP)(TO_REAL(node->hi_y[c])), p->oy,
                    p->iy, widen, &t0, &t1);
    slab_axis_lanes((REALP)(TO_REAL(node->lo_z[c])), (REALP)(TO_REAL(node->hi_z[c])), p->oz,
                    p->iz, widen, &t0, &t1);
    *crossed = t0 <= t1;
    return t0;
}

// The packet's active rays as intervals, so that one vector test bounds a node's boxes against
// all of them (node_children_interval): along each axis the lanes' origins lie in [olo, ohi] and
// their reciprocal directions in [ilo, ihi]. An axis bounds the test only where every lane's
// reciprocal is finite and of one sign (sign +1 or -1); elsewhere (lanes on both sides of a
// direction parallel to the axis) its sign is 0.
typedef struct {
    REAL olo[3], ohi[3], ilo[3], ihi[3];
    int sign[3];
    REAL origin_size;  // the largest magnitude of an origin's coordinate (shapes_interval)
} PacketBounds;

// The twelve extremes are reduced together, not one by one: each vector's lanes are first
// folded to eight, then pairs of vectors share each step's shuffles (FOLD_PAIRS), so that one
// minimum instruction works for two or four of them at once.
#ifdef USE_DOUBLE
typedef double8 REAL8;
#else
typedef float8 REAL8;
#endif
#if PACKET_LANES == 16
#define TO_EIGHT(v, HALF) HALF(v)
#elif PACKET_LANES == 8
#define TO_EIGHT(v, HALF) (v)
#else
#define TO_EIGHT(v, HALF) ((REAL8)((v), (v)))
#endif
// Lanes 0..7 of a and of b folded to four each by PICK: a's at lanes 0, 1, 4, 5, b's at 2, 3,
// 6, 7 (shuffles within each half of the vector, one instruction each on x86).
#define FOLD_PAIRS(a, b, PICK) \
    PICK((REAL8)((a).s02, (b).s02, (a).s46, (b).s46), (REAL8)((a).s13, (b).s13, (a).s57, (b).s57))

// The least lane of each of a, b, c and d, in that order.
HOT REAL4 least_of_four(REAL8 a, REAL8 b, REAL8 c, REAL8 d) {
    REAL8 ab = FOLD_PAIRS(a, b, LESSER), cd = FOLD_PAIRS(c, d, LESSER);
    REAL8 e = FOLD_PAIRS(ab, cd, LESSER);
    return LESSER(e.lo, e.hi);
}

// The greatest lane of each of a, b, c and d, in that order.
HOT REAL4 greatest_of_four(REAL8 a, REAL8 b, REAL8 c, REAL8 d) {
    REAL8 ab = FOLD_PAIRS(a, b, GREATER), cd = FOLD_PAIRS(c, d, GREATER);
    REAL8 e = FOLD_PAIRS(ab, cd, GREATER);
    return GREATER(e.lo, e.hi);
}

HOT int axis_sign(REAL ilo, REAL ihi) {
    bool positive = ilo > (REAL)0 && ihi < REAL_INF;
    bool negative = ihi < (REAL)0 && ilo > -REAL_INF;
    return positive ? 1 : (negative ? -1 : 0);
}

HOT PacketBounds packet_bounds(const RayPacket* p, int bits) {
    MASKP active = lanes_of(bits);
    // Origins and reciprocals, x, y, z each; lanes outside `bits` (a packet's lanes mostly all
    // take part) as +inf for the least and -inf for the greatest.
    REALP low[6] = {p->ox, p->oy, p->oz, p->ix, p->iy, p->iz};
    REALP high[6] = {p->ox, p->oy, p->oz, p->ix, p->iy, p->iz};
    if (bits != ALL_LANES) {
        for (int k = 0; k < 6; ++k) {
            low[k] = active ? low[k] : (REALP)(REAL_INF);
            high[k] = active ? high[k] : (REALP)(-REAL_INF);
        }
    }
#ifdef PORTABLE_REDUCTIONS
    // Oclgrind 21.10 crashes on FOLD_PAIRS' two-vector shuffles: one extreme at a time there.
    REAL4 lo = (REAL4)(min_lanes(low[0]), min_lanes(low[1]), min_lanes(low[2]), min_lanes(low[3]));
    REAL4 lo_rest = (REAL4)(min_lanes(low[4]), min_lanes(low[5]), 0, 0);
    REAL4 hi =
        (REAL4)(max_lanes(high[0]), max_lanes(high[1]), max_lanes(high[2]), max_lanes(high[3]));
    REAL4 hi_rest = (REAL4)(max_lanes(high[4]), max_lanes(high[5]), 0, 0);
#else
    REAL8 l[6], h[6];
    for (int k = 0; k < 6; ++k) {
        l[k] = TO_EIGHT(low[k], MIN_OF_HALVES);
        h[k] = TO_EIGHT(high[k], MAX_OF_HALVES);
    }
    REAL4 lo = least_of_four(l[0], l[1], l[2], l[3]);
    REAL4 lo_rest = least_of_four(l[4], l[5], l[4], l[5]);
    REAL4 hi = greatest_of_four(h[0], h[1], h[2], h[3]);
    REAL4 hi_rest = greatest_of_four(h[4], h[5], h[4], h[5]);
#endif
    PacketBounds b;
    b.olo[0] = lo.x;
    b.olo[1] = lo.y;
    b.olo[2] = lo.z;
    b.ilo[0] = lo.w;
    b.ilo[1] = lo_rest.x;
    b.ilo[2] = lo_rest.y;
    b.ohi[0] = hi.x;
    b.ohi[1] = hi.y;
    b.ohi[2] = hi.z;
    b.ihi[0] = hi.w;
    b.ihi[1] = hi_rest.x;
    b.ihi[2] = hi_rest.y;
    for (int axis = 0; axis < 3; ++axis) b.sign[axis] = axis_sign(b.ilo[axis], b.ihi[axis]);
    REAL4 size = fmax(fabs(lo), fabs(hi));  // x, y, z: the origins' (w: a reciprocal's)
    b.origin_size = fmax(fmax(size.x, size.y), size.z);
    // The reductions pass NaNs by: a lane with one bounds nothing. (x != x, not isnan: PoCL's
    // vector isnan tests the bits in integer lanes, several instructions a vector.)
    MASKP nan = (p->ox != p->ox) | (p->oy != p->oy) | (p->oz != p->oz) | (p->ix != p->ix) |
                (p->iy != p->iy) | (p->iz != p->iz);
    if (lane_mask(active & nan)) b.sign[0] = b.sign[1] = b.sign[2] = 0;
    return b;
}

// One axis of node_children_interval: slab_axis_lanes's near and far bounds, as low and as high
// as any lane's can be. For a lane whose reciprocal is positive its near plane is lo and its far
// plane hi (negative: the other way round), so its near t is (plane - o) * inv for o and inv in
// their intervals: smallest at the origin's far bound, times the reciprocal's low bound where
// the difference is positive and its high bound where it is negative; the far t likewise at the
// other ends. Rounding is monotonic, so each lane's rounded t lies within the rounded bounds.
HOT void slab_axis_interval(REALW lo, REALW hi, const PacketBounds* b, int axis, REAL widen,
                            REALW* t0, REALW* t1) {
    int sign = b->sign[axis];
    if (sign == 0) return;
    REALW near_plane = sign > 0 ? lo : hi, far_plane = sign > 0 ? hi : lo;
    REAL near_o = sign > 0 ? b->ohi[axis] : b->olo[axis];
    REAL far_o = sign > 0 ? b->olo[axis] : b->ohi[axis];
    REALW an = near_plane - (REALW)(near_o), af = far_plane - (REALW)(far_o);
    REALW near = an * (an >= (REALW)(0) ? (REALW)(b->ilo[axis]) : (REALW)(b->ihi[axis]));
    REALW far = af * (af >= (REALW)(0) ? (REALW)(b->ihi[axis]) : (REALW)(b->ilo[axis])) * widen;
    *t0 = near > *t0 ? near : *t0;
    *t1 = far < *t1 ? far : *t1;
}

// The children of a node that some lane may cross within [0, tmax] (tmax: the largest of the
// lanes'), as bits: node_children's one vector test for all children, on the packet's
// intervals. A child whose bit is clear no lane crosses (box_lanes would find none).
HOT int node_children_interval(const __global BvhNode* node, const PacketBounds* b, REAL tmax) {
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    REALW t0 = (REALW)(0), t1 = (REALW)(tmax);
    slab_axis_interval(TO_REALW(VLOADW(0, node->lo_x)), TO_REALW(VLOADW(0, node->hi_x)), b, 0,
                       widen, &t0, &t1);
    slab_axis_interval(TO_REALW(VLOADW(0, node->lo_y)), TO_REALW(VLOADW(0, node->hi_y)), b, 1,
                       widen, &t0, &t1);
    slab_axis_interval(TO_REALW(VLOADW(0, node->lo_z)), TO_REALW(VLOADW(0, node->hi_z)), b, 2,
                       widen, &t0, &t1);
    INTW used = VLOADW(0, node->child) >= 0;
    return lane_bits(MASK_TO_INTW(t0 <= t1) & used);
}

// A leaf packet's PACKET_WIDTH shapes in a node's vector: the upper half of an 8-wide one
// repeats the lower, and its bits are dropped.
HOT REALW shape_vector(REAL4 v) {
#if BVH_WIDTH == 8
    return (REALW)(v, v);
#else
    return v;
#endif
}

// The shapes of a leaf packet that some lane may cross within [0, tmax], as bits: their boxes
// (lo, hi) against the packet's intervals, node_children_interval's test. The shapes' own tests
// round, so a box grows by 2^-12 of its coordinates' and the origins' magnitude, far more than
// their rounding can move a crossing (a few ulps of that magnitude): a shape left out is one
// that no lane's test would report. A margin that overflows (or a NaN) keeps the shape in: the
// slab test's selects then leave its [t0, t1] as it was.
HOT int shapes_interval(REAL4 lo_x, REAL4 hi_x, REAL4 lo_y, REAL4 hi_y, REAL4 lo_z, REAL4 hi_z,
                        const PacketBounds* b, REAL tmax) {
    REAL4 size = GREATER(GREATER(GREATER(fabs(lo_x), fabs(hi_x)), GREATER(fabs(lo_y), fabs(hi_y))),
                         GREATER(fabs(lo_z), fabs(hi_z)));
    REAL4 margin = (size + b->origin_size) * REAL_C(0x1p-12);
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    REALW t0 = (REALW)(0), t1 = (REALW)(tmax);
    slab_axis_interval(shape_vector(lo_x - margin), shape_vector(hi_x + margin), b, 0, widen,
                       &t0, &t1);
    slab_axis_interval(shape_vector(lo_y - margin), shape_vector(hi_y + margin), b, 1, widen,
                       &t0, &t1);
    slab_axis_interval(shape_vector(lo_z - margin), shape_vector(hi_z + margin), b, 2, widen,
                       &t0, &t1);
    return lane_bits(MASK_TO_INTW(t0 <= t1)) & ((1 << PACKET_WIDTH) - 1);
}

#if HAS_BVH && !HAS_INSTANCES
#if TRIANGLE_LANES
// shapes_interval for a triangle packet: each triangle's box of its corners.
HOT int triangles_interval(const __global TrianglePacket* pk, const PacketBounds* b, REAL tmax) {
    REAL4 x0 = TO_REAL4(vload4(0, pk->x0)), x1 = TO_REAL4(vload4(0, pk->x1)),
          x2 = TO_REAL4(vload4(0, pk->x2));
    REAL4 y0 = TO_REAL4(vload4(0, pk->y0)), y1 = TO_REAL4(vload4(0, pk->y1)),
          y2 = TO_REAL4(vload4(0, pk->y2));
    REAL4 z0 = TO_REAL4(vload4(0, pk->z0)), z1 = TO_REAL4(vload4(0, pk->z1)),
          z2 = TO_REAL4(vload4(0, pk->z2));
    return shapes_interval(LESSER(LESSER(x0, x1), x2), GREATER(GREATER(x0, x1), x2),
                           LESSER(LESSER(y0, y1), y2), GREATER(GREATER(y0, y1), y2),
                           LESSER(LESSER(z0, z1), z2), GREATER(GREATER(z0, z1), z2), b, tmax);
}
#endif

#if SPHERE_LANES
// shapes_interval for a sphere packet: each sphere's box, its centre +- its radius.
HOT int spheres_interval(const __global SpherePacket* pk, const PacketBounds* b, REAL tmax) {
    REAL4 x = TO_REAL4(vload4(0, pk->x)), y = TO_REAL4(vload4(0, pk->y)),
          z = TO_REAL4(vload4(0, pk->z)), r = fabs(TO_REAL4(vload4(0, pk->radius)));
    return shapes_interval(x - r, x + r, y - r, y + r, z - r, z + r, b, tmax);
}
#endif

// Whether a leaf holds shapes that have no lane-wise test: its other primitives, and the
// packets of the study variants' formulas.
HOT bool leaf_ray_by_ray(int count) {
    bool ray_by_ray = (count & LEAF_FIELD_MASK) > 0;
#if !TRIANGLE_LANES
    ray_by_ray |= section_packets(count, PRIM_TRIANGLE) > 0;
#endif
#if !SPHERE_LANES
    ray_by_ray |= section_packets(count, PRIM_SPHERE) > 0;
#endif
    return ray_by_ray;
}

// Closest hits of the lanes `bits` in a leaf: its triangles and spheres lane-wise (those that
// shapes_interval leaves in, on the packet's intervals b), its other shapes (and the study
// variants' formulas) ray by ray, as leaf_closest has them.
HOT void leaf_closest_lanes(const SceneRefs* s, int slot, int count, const RayLanes* rays,
                            const RayPacket* p, const PacketBounds* b, int bits, PacketHit* h) {
    MASKP lanes = lanes_of(bits);
    int tri_packets = section_packets(count, PRIM_TRIANGLE);
    int sphere_packets = section_packets(count, PRIM_SPHERE);
    if (leaf_ray_by_ray(count) || popcount(bits) <= PACKET_MIN_LANES) {
        HitLanes hits;
        store_hits(h, &hits);
        for (int rest = bits; rest; rest &= rest - 1) {
            int j = lowest_bit(rest);
            Ray r = ray_from_lanes(rays, j);
            Hit hit = hit_of_lane(&hits, j);
            leaf_closest(s, slot, count, &r, -1, &hit);
            set_hit_lane(&hits, j, &hit);
        }
        *h = packet_hit(&hits);
        return;
    }
    REAL tmax = max_lanes(lanes ? tie_reach_lanes(h->t) : (REALP)(0));
#if TRIANGLE_LANES
    for (int end = slot + tri_packets * PACKET_WIDTH; slot < end; slot += PACKET_WIDTH) {
        const __global TrianglePacket* pk = s->triangle_packets + slot / PACKET_WIDTH;
        int maybe = triangles_interval(pk, b, tmax);
        if (!maybe) continue;
        PickedCorners picked;
        if (p->uniform) picked = pick_corners(pk, p);
        for (; maybe; maybe &= maybe - 1) {
            int k = lowest_bit(maybe);
            int ref = s->prim_refs[slot + k];
            if (ref < 0) break;  // padding: the packet's last lanes
            REALP t, b1, b2;
            MASKP crossed = lanes & triangle_lanes(pk, &picked, k, p, &t, &b1, &b2);
            if (lane_mask(crossed)) consider_lanes(h, crossed, t, ref, slot + k, b1, b2);
        }
    }
#endif
#if SPHERE_LANES
    for (int end = slot + sphere_packets * PACKET_WIDTH; slot < end; slot += PACKET_WIDTH) {
        const __global SpherePacket* pk = s->sphere_packets + slot / PACKET_WIDTH;
        for (int maybe = spheres_interval(pk, b, tmax); maybe; maybe &= maybe - 1) {
            int k = lowest_bit(maybe);
            int ref = s->prim_refs[slot + k];
            if (ref < 0) break;
            REALP t0, t1;
            MASKP crossed = sphere_lanes(pk, k, p, lanes, &t0, &t1);
            if (!lane_mask(crossed)) continue;
            // consider_hit's choice: the first crossing ahead of the origin.
            REALP t = t0 > (REAL)0 ? t0 : t1;
            consider_lanes(h, crossed, t, ref, 0, (REALP)(0), (REALP)(0));
        }
    }
#endif
}

// The crossed children of a node for the lanes `bits`, nearest (by the packet's nearest entry)
// in child[0]: their entries, lanes and entry t's. Returns how many. The interval test first
// leaves out the children that no lane crosses, so the lane-wise box test (a vector of lanes
// for one box) runs only for the others: on a pixel's samples about 1.2 boxes a node instead of
// the node's 8.
HOT int node_children_lanes(const __global BvhNode* node, const RayPacket* p,
                            const PacketBounds* b, REALP tmax, int bits, int* child, int* count,
                            int* lanes, REAL* tnear) {
    MASKP active = lanes_of(bits);
    int maybe = node_children_interval(node, b, max_lanes(active ? tmax : (REALP)(0)));
    int n = 0;
    for (; maybe; maybe &= maybe - 1) {
        int c = lowest_bit(maybe);
        MASKP crossed;
        REALP t0 = box_lanes(node, c, p, tmax, &crossed);
        crossed &= active;
        int lane_bits_c = lane_mask(crossed);
        if (!lane_bits_c) continue;
        REAL t = min_lanes(crossed ? t0 : (REALP)(REAL_INF));
        // Insertion by entry t, nearest first.
        int at = n++;
        while (at > 0 && tnear[at - 1] > t) {
            child[at] = child[at - 1];
            count[at] = count[at - 1];
            lanes[at] = lanes[at - 1];
            tnear[at] = tnear[at - 1];
            at--;
        }
        child[at] = node->child[c];
        count[at] = node->count[c];
        lanes[at] = lane_bits_c;
        tnear[at] = t;
    }
    return n;
}

// Lanes that a subtree entered at `t` (the nearest lane's entry) can still give a hit: those
// whose hit is not nearer than t (beyond the tie reach, as closest_hit skips a pop).
HOT int reaching_lanes(const PacketHit* h, REAL t, int bits) {
    return bits & lane_mask(tie_reach_lanes(h->t) >= (REALP)(t));
}

// The BVH part of closest_hit for the lanes `bits`, from the hits in *h.
HOT void packet_walk_closest(const SceneRefs* s, const RayLanes* rays, const RayPacket* p,
                             const PacketBounds* b, int bits, PacketHit* h) {
    int stack_child[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE], stack_lanes[BVH_STACK_SIZE];
    REAL stack_t[BVH_STACK_SIZE];
    int sp = 0;
    int child = 0, count = 0;
    for (;;) {
        if (count > 0) {
            COUNT(s, closest_prims, leaf_prims(s, child, count));
            leaf_closest_lanes(s, child, count, rays, p, b, bits, h);
        } else if (popcount(bits) <= PACKET_MIN_LANES) {
            // Too few lanes to pay for the packet: the single-ray walk, lane by lane.
            HitLanes hits;
            store_hits(h, &hits);
            for (int rest = bits; rest; rest &= rest - 1) {
                int j = lowest_bit(rest);
                Ray r = ray_from_lanes(rays, j);
                Hit hit = hit_of_lane(&hits, j);
                walk_closest(s, &r, child, count, &hit);
                set_hit_lane(&hits, j, &hit);
            }
            *h = packet_hit(&hits);
        } else {
            const __global BvhNode* node = s->nodes + child;
            COUNT(s, closest_boxes, used_children(node));
            int c_child[BVH_WIDTH], c_count[BVH_WIDTH], c_lanes[BVH_WIDTH];
            REAL c_t[BVH_WIDTH];
            int n = node_children_lanes(node, p, b, tie_reach_lanes(h->t), bits, c_child, c_count,
                                        c_lanes, c_t);
            if (n > 0) {
                // Go on with the nearest; push the others farthest first, so nearer ones pop
                // first.
                for (int k = n - 1; k > 0; --k) {
                    stack_child[sp] = c_child[k];
                    stack_count[sp] = c_count[k];
                    stack_lanes[sp] = c_lanes[k];
                    stack_t[sp++] = c_t[k];
                }
                child = c_child[0];
                count = c_count[0];
                bits = c_lanes[0];
                continue;
            }
        }
        bits = 0;
        while (sp > 0 && !bits) {
            --sp;
            bits = reaching_lanes(h, stack_t[sp], stack_lanes[sp]);
        }
        if (!bits) break;
        child = stack_child[sp];
        count = stack_count[sp];
    }
}

#endif

// closest_hit for each lane of `bits` of the packet p (hits of the others: no hit); `rays`: the
// same rays lane by lane, for the lanes that go on alone. `lanes`, where not 0, gets the hits
// as lanes too (not with instances, and only where the scene has a BVH: SURFACE_LANES).
// Out of line (OUT_OF_LINE; issue 42, cold build): called once per packet, so the call costs
// nothing measurable beside the walk, and the sample-packet kernel's largest function (PoCL
// compiles it whole) shrinks: cornell_box's cold build 6.4 -> 3.9 CPU-s with the others below
// (benchmarks/cold_build.py, docs/acceleration.md).
OUT_OF_LINE void packet_closest(const SceneRefs* s, const RayPacket* p, const RayLanes* rays, int bits,
                          HitLanes* hits, PacketHit* lanes) {
#if HAS_INSTANCES || !HAS_BVH
    // Instances are walked ray by ray.
    Hit none = no_hit();
    for (int j = 0; j < PACKET_LANES; ++j) set_hit_lane(hits, j, &none);
    for (int rest = bits; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        Ray r = ray_from_lanes(rays, j);
        Hit hit = closest_hit(s, &r);
        set_hit_lane(hits, j, &hit);
    }
#else
    PacketHit h = no_hit_lanes();
#if HAS_PLANES
    consider_planes_lanes(s, p, lanes_of(bits), &h);
#endif
    if (s->n_nodes > 0) {
        PacketBounds b = packet_bounds(p, bits);
        packet_walk_closest(s, rays, p, &b, bits, &h);
    }
    store_hits(&h, hits);
    if (lanes) *lanes = h;
#endif
}

#if !HAS_TRANSMISSION && !HAS_INSTANCES && HAS_BVH
// Lanes of `bits` that a leaf blocks within (0, tmax): packet_blocks lane-wise, for the shapes
// that shapes_interval leaves in (b: the packet's intervals).
HOT int leaf_blocks_lanes(const SceneRefs* s, int slot, int count, const RayPacket* p,
                          const PacketBounds* b, REALP tmax, const REAL* tmax_lanes, int bits) {
    MASKP lanes = lanes_of(bits);
    int tri_packets = section_packets(count, PRIM_TRIANGLE);
    int sphere_packets = section_packets(count, PRIM_SPHERE);
    int blocked = 0;
    if (leaf_ray_by_ray(count) || popcount(bits) <= PACKET_MIN_LANES) {
        for (int rest = bits; rest; rest &= rest - 1) {
            int j = lowest_bit(rest);
            REAL3 filter = (REAL3)(1, 1, 1);
            Ray r = lane_ray(p, j);
            if (!leaf_transmission(s, slot, count, &r, -1, tmax_lanes[j], &filter)) {
                blocked |= 1 << j;
            }
        }
        return blocked;
    }
    REAL tmax_packet = max_lanes(lanes ? tmax : (REALP)(0));
#if TRIANGLE_LANES
    for (int end = slot + tri_packets * PACKET_WIDTH; slot < end; slot += PACKET_WIDTH) {
        const __global TrianglePacket* pk = s->triangle_packets + slot / PACKET_WIDTH;
        int maybe = triangles_interval(pk, b, tmax_packet);
        if (!maybe) continue;
        PickedCorners picked;
        if (p->uniform) picked = pick_corners(pk, p);
        for (; maybe; maybe &= maybe - 1) {
            int k = lowest_bit(maybe);
            if (s->prim_refs[slot + k] < 0) break;
            REALP t, b1, b2;
            MASKP crossed = lanes & triangle_lanes(pk, &picked, k, p, &t, &b1, &b2);
            blocked |= lane_mask(crossed & (t > (REAL)0) & (t < tmax));
        }
        if (blocked == bits) return blocked;
    }
#endif
#if SPHERE_LANES
    for (int end = slot + sphere_packets * PACKET_WIDTH; slot < end; slot += PACKET_WIDTH) {
        const __global SpherePacket* pk = s->sphere_packets + slot / PACKET_WIDTH;
        for (int maybe = spheres_interval(pk, b, tmax_packet); maybe; maybe &= maybe - 1) {
            int k = lowest_bit(maybe);
            if (s->prim_refs[slot + k] < 0) break;
            REALP t0, t1;
            MASKP crossed = sphere_lanes(pk, k, p, lanes, &t0, &t1);
            MASKP inside = ((t0 > (REAL)0) & (t0 < tmax)) | ((t1 > (REAL)0) & (t1 < tmax));
            blocked |= lane_mask(crossed & inside);
        }
        if (blocked == bits) return blocked;
    }
#endif
    return blocked;
}

#if HAS_PLANES
// The lanes of `bits` that a plane blocks within (0, tmax): planes_transmission in an opaque
// scene, lane-wise.
HOT int planes_blocked_lanes(const SceneRefs* s, const RayPacket* p, REALP tmax, int bits) {
    MASKP blocked = (MASKP)(0);
    for (int i = 0; i < s->n_planes; ++i) {
        REALP t;
        blocked |= plane_lanes(s->planes + i, p, &t) & (t > (REAL)0) & (t < tmax);
    }
    return bits & lane_mask(blocked);
}
#endif

// The lanes of `bits` whose shadow segment (0, tmax) some shape blocks, in an opaque scene:
// every crossed child is walked (any order) until every lane is blocked.
// Out of line: once per light per packet, and called from two places (point_light_direct,
// packet_transmission), so its walk is compiled once (issue 42, cold build).
OUT_OF_LINE int packet_blocked(const SceneRefs* s, const RayPacket* p, const REAL* tmax_lanes, int bits) {
    REALP tmax = VLOADP(0, tmax_lanes);
    int blocked = 0;
#if HAS_PLANES
    blocked = planes_blocked_lanes(s, p, tmax, bits);
#endif
    if (s->n_nodes == 0 || blocked == bits) return blocked;
    PacketBounds b = packet_bounds(p, bits & ~blocked);
    int stack_child[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE], stack_lanes[BVH_STACK_SIZE];
    int sp = 0;
    stack_child[sp] = 0;
    stack_count[sp] = 0;
    stack_lanes[sp++] = bits & ~blocked;
    while (sp > 0) {
        --sp;
        int child = stack_child[sp], count = stack_count[sp];
        int lanes = stack_lanes[sp] & ~blocked;
        if (!lanes) continue;
        if (count > 0) {
            COUNT(s, shadow_prims, leaf_prims(s, child, count));
            blocked |= leaf_blocks_lanes(s, child, count, p, &b, tmax, tmax_lanes, lanes);
            if (blocked == bits) return blocked;
            continue;
        }
        if (popcount(lanes) <= PACKET_MIN_LANES) {
            // Too few lanes to pay for the packet: the single-ray walk, lane by lane.
            for (int rest = lanes; rest; rest &= rest - 1) {
                int j = lowest_bit(rest);
                Ray r = lane_ray(p, j);
                REAL3 filter =
                    walk_transmission(s, &r, child, count, tmax_lanes[j], (REAL3)(1, 1, 1));
                if (max_comp3(filter) <= (REAL)0) blocked |= 1 << j;
            }
            if (blocked == bits) return blocked;
            continue;
        }
        const __global BvhNode* node = s->nodes + child;
        COUNT(s, shadow_boxes, used_children(node));
        MASKP active = lanes_of(lanes);
        int maybe = node_children_interval(node, &b, max_lanes(active ? tmax : (REALP)(0)));
        for (; maybe; maybe &= maybe - 1) {
            int c = lowest_bit(maybe);
            MASKP crossed;
            box_lanes(node, c, p, tmax, &crossed);
            int crossing = lane_mask(crossed & active);
            if (!crossing) continue;
            stack_child[sp] = node->child[c];
            stack_count[sp] = node->count[c];
            stack_lanes[sp++] = crossing;
        }
    }
    return blocked;
}
#endif

// transmission() for each lane of `bits`, into filter[lane].
// Out of line: once per light per packet (issue 42, cold build; see packet_closest).
OUT_OF_LINE void packet_transmission(const SceneRefs* s, const Ray* rays, const REAL* tmax, int bits,
                               REAL3* filter) {
#if !HAS_TRANSMISSION && !HAS_INSTANCES && HAS_BVH
    RayPacket p = ray_packet(rays);
    int blocked = packet_blocked(s, &p, tmax, bits);
    for (int j = 0; j < PACKET_LANES; ++j) {
        filter[j] = (blocked >> j) & 1 ? (REAL3)(0, 0, 0) : (REAL3)(1, 1, 1);
    }
#else
    // Coloured shadows multiply filters crossing by crossing: ray by ray.
    for (int rest = bits; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        filter[j] = transmission(s, rays + j, tmax[j]);
    }
#endif
}
#endif

#endif
