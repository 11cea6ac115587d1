// Which traversal scheme the build has (TRAVERSAL, from KernelConfig.traversal), and for sample
// packets (TRAVERSAL_SAMPLE_PACKET) the lanes' types: PACKET_LANES rays of one pixel's samples,
// one a vector lane (docs/acceleration.md, Sample packets). Here are the lane-wise forms of
// ray.h's Ray (RayPacket, and RayLanes lane by lane), of hit.h's Hit (PacketHit, HitLanes) and
// of real.h's helpers; each shape's header has its lane-wise test and surface beside its
// single-ray ones. Everything lane-wise is in the build only with TRAVERSAL_SAMPLE_PACKET.
#ifndef CLRAY_LANES_H
#define CLRAY_LANES_H

#include "real.h"
#include "clray_types.h"
#include "hit.h"
#include "ray.h"

#define TRAVERSAL_SINGLE 0
#define TRAVERSAL_SAMPLE_PACKET 1
#define TRAVERSAL_GROUP_PACKET 2
#ifndef TRAVERSAL
#define TRAVERSAL TRAVERSAL_SINGLE
#endif
#define SAMPLE_PACKETS (TRAVERSAL == TRAVERSAL_SAMPLE_PACKET)
#define GROUP_PACKETS (TRAVERSAL == TRAVERSAL_GROUP_PACKET)

// The single-ray render's row segments (render_segment, below): where work-items run serially.
#define RENDER_SEGMENTS (SERIAL_WORK_ITEMS && !SAMPLE_PACKETS && !GROUP_PACKETS)

#if SAMPLE_PACKETS
#ifndef PACKET_LANES
#define PACKET_LANES 8
#endif
#ifndef PACKET_MIN_LANES
#define PACKET_MIN_LANES 2
#endif

// REALP: one REAL per lane; MASKP: what comparing two REALP gives (int lanes for float, long
// for double), also the type of per-lane integers that selects mix with REALP.
// UINTP: one uint per lane (the samplers' hashes); TO_REALP converts it to REALP, TO_MASKP a
// REALP to whole numbers (towards zero, as a cast does).
#define PACKET_PASTE_(a, b) a##b
#define PACKET_PASTE(a, b) PACKET_PASTE_(a, b)
#ifdef USE_DOUBLE
#define PACKET_TYPES(n) \
    typedef double##n REALP; \
    typedef long##n MASKP; \
    typedef uint##n UINTP;
#define TO_REALP PACKET_PASTE(convert_double, PACKET_LANES)
#define TO_MASKP PACKET_PASTE(convert_long, PACKET_LANES)
#define SIGNS_P PACKET_PASTE(as_long, PACKET_LANES)
#else
#define PACKET_TYPES(n) \
    typedef float##n REALP; \
    typedef int##n MASKP; \
    typedef uint##n UINTP;
#define TO_REALP PACKET_PASTE(convert_float, PACKET_LANES)
#define TO_MASKP PACKET_PASTE(convert_int, PACKET_LANES)
#define SIGNS_P PACKET_PASTE(as_int, PACKET_LANES)
#endif

#if PACKET_LANES == 16
PACKET_TYPES(16)
#define VLOADP vload16
#define VSTOREP vstore16
#define LANE_BITS \
    ((MASKP)(1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768))
#elif PACKET_LANES == 8
PACKET_TYPES(8)
#define VLOADP vload8
#define VSTOREP vstore8
#define LANE_BITS ((MASKP)(1, 2, 4, 8, 16, 32, 64, 128))
#elif PACKET_LANES == 4
PACKET_TYPES(4)
#define VLOADP vload4
#define VSTOREP vstore4
#define LANE_BITS ((MASKP)(1, 2, 4, 8))
#else
#error "PACKET_LANES must be 4, 8 or 16"
#endif

#ifdef USE_DOUBLE
typedef long LANE_INT;
#else
typedef int LANE_INT;
#endif

#define ALL_LANES ((1 << PACKET_LANES) - 1)

// The OR over the lanes. Clang's reduction compiles to a few instructions; a tree of halves
// (what PoCL's any() and all() amount to) costs shuffles at every level.
// PORTABLE_REDUCTIONS keeps to the loops: an interpreter built on an older LLVM (Oclgrind 21.10)
// cannot run the llvm.vector.reduce intrinsic that the builtin becomes.
#if defined(__clang__) && defined(__has_builtin) && !defined(PORTABLE_REDUCTIONS)
#if __has_builtin(__builtin_reduce_or)
#define REDUCE_OR(v) __builtin_reduce_or(v)
#endif
#endif
#ifndef REDUCE_OR
HOT LANE_INT reduce_or_lanes(MASKP v) {
    LANE_INT buf[PACKET_LANES];
    VSTOREP(v, 0, buf);
    LANE_INT m = buf[0];
    for (int k = 1; k < PACKET_LANES; ++k) m |= buf[k];
    return m;
}
#define REDUCE_OR(v) reduce_or_lanes(v)
#endif

// Bit k set where lane k of a comparison is true: movmsk on x86 (real.h, X86_LANE_BITS).
#if X86_LANE_BITS && !defined(USE_DOUBLE) && PACKET_LANES == 16
HOT int lane_mask(MASKP m) { return lane_bits8(m.lo) | (lane_bits8(m.hi) << 8); }
#elif X86_LANE_BITS && !defined(USE_DOUBLE) && PACKET_LANES == 8
HOT int lane_mask(MASKP m) { return lane_bits8(m); }
#else
HOT int lane_mask(MASKP m) { return (int)REDUCE_OR(m & LANE_BITS); }
#endif

// The lanes of `bits` as a comparison result.
HOT MASKP lanes_of(int bits) { return ((MASKP)(bits) & LANE_BITS) != (MASKP)(0); }

// The smallest and the largest lane, by halves with compare-selects, each level one vector
// minimum or maximum. Clang's __builtin_reduce_min and _max keep fmin's NaN rules, which x86
// has no instruction for: they cost several times more (packet_bounds's twelve reductions took
// 461 instructions a packet). A NaN lane may or may not win: the callers pass none in that
// matters (packet_bounds checks for them apart).
#define MIN_OF_HALVES(v) ((v).lo < (v).hi ? (v).lo : (v).hi)
#define MAX_OF_HALVES(v) ((v).lo > (v).hi ? (v).lo : (v).hi)
#if PACKET_LANES == 16
#define REDUCE_HALVES(v, HALF) HALF(HALF(HALF(HALF(v))))
#elif PACKET_LANES == 8
#define REDUCE_HALVES(v, HALF) HALF(HALF(HALF(v)))
#else
#define REDUCE_HALVES(v, HALF) HALF(HALF(v))
#endif

HOT REAL min_lanes(REALP v) { return REDUCE_HALVES(v, MIN_OF_HALVES); }

HOT REAL max_lanes(REALP v) { return REDUCE_HALVES(v, MAX_OF_HALVES); }

// The packet's rays, coordinate by coordinate, with each lane's set-up from make_ray.
typedef struct {
    REALP ox, oy, oz, dx, dy, dz, ix, iy, iz;
    REALP dd;  // d . d, as intersect_sphere_packet has it
#if HAS_TRIANGLES
    MASKP kx, ky, kz;
    REALP sx, sy, sz;
    // Whether every lane has lane 0's axis permutation (akx, aky, akz), as a pixel's samples
    // mostly do; then okx, oky, okz are the origins' coordinates along those axes.
    bool uniform;
    int akx, aky, akz;
    REALP okx, oky, okz;
#endif
} RayPacket;

// rays[k] for every lane (lanes without a ray of their own hold a copy of another's). The rays
// come from make_ray: the lanes' axes and shears are read here, which a make_walk_ray ray has
// not made yet.
HOT RayPacket ray_packet(const Ray* rays) {
    REAL f[10][PACKET_LANES];
    for (int k = 0; k < PACKET_LANES; ++k) {
        const Ray* r = rays + k;
        f[0][k] = r->o.x;
        f[1][k] = r->o.y;
        f[2][k] = r->o.z;
        f[3][k] = r->d.x;
        f[4][k] = r->d.y;
        f[5][k] = r->d.z;
        f[6][k] = r->inv_d.x;
        f[7][k] = r->inv_d.y;
        f[8][k] = r->inv_d.z;
        f[9][k] = dot3(r->d, r->d);
    }
    RayPacket p;
    p.ox = VLOADP(0, f[0]);
    p.oy = VLOADP(0, f[1]);
    p.oz = VLOADP(0, f[2]);
    p.dx = VLOADP(0, f[3]);
    p.dy = VLOADP(0, f[4]);
    p.dz = VLOADP(0, f[5]);
    p.ix = VLOADP(0, f[6]);
    p.iy = VLOADP(0, f[7]);
    p.iz = VLOADP(0, f[8]);
    p.dd = VLOADP(0, f[9]);
#if HAS_TRIANGLES
    LANE_INT axis[3][PACKET_LANES];
    for (int k = 0; k < PACKET_LANES; ++k) {
        axis[0][k] = rays[k].kx;
        axis[1][k] = rays[k].ky;
        axis[2][k] = rays[k].kz;
        f[0][k] = rays[k].sx;
        f[1][k] = rays[k].sy;
        f[2][k] = rays[k].sz;
    }
    p.kx = VLOADP(0, axis[0]);
    p.ky = VLOADP(0, axis[1]);
    p.kz = VLOADP(0, axis[2]);
    p.sx = VLOADP(0, f[0]);
    p.sy = VLOADP(0, f[1]);
    p.sz = VLOADP(0, f[2]);
    p.akx = rays[0].kx;
    p.aky = rays[0].ky;
    p.akz = rays[0].kz;
    p.uniform = true;
    for (int k = 1; k < PACKET_LANES; ++k) {
        p.uniform &= rays[k].kx == p.akx && rays[k].ky == p.aky && rays[k].kz == p.akz;
    }
    p.okx = p.akx == 0 ? p.ox : (p.akx == 1 ? p.oy : p.oz);
    p.oky = p.aky == 0 ? p.ox : (p.aky == 1 ? p.oy : p.oz);
    p.okz = p.akz == 0 ? p.ox : (p.akz == 1 ? p.oy : p.oz);
#endif
    return p;
}

// dot3 lane by lane (real.h: the rounded products added left to right, not fused).
DEFINE_DOT(HOT, REALP, dot_lanes)
// plain_squared_length lane by lane: the lanes that length_lanes and its kin can measure.
DEFINE_PLAIN_SQUARED_LENGTH(HOT, REALP, MASKP, plain_squared_length_lanes)

// A packet's rays lane by lane: the arrays that ray_from_lanes reads.
typedef struct {
    REAL f[12][PACKET_LANES];
    LANE_INT axis[3][PACKET_LANES];
} RayLanes;

HOT void store_ray_lanes(const RayPacket* p, RayLanes* r) {
    VSTOREP(p->ox, 0, r->f[0]);
    VSTOREP(p->oy, 0, r->f[1]);
    VSTOREP(p->oz, 0, r->f[2]);
    VSTOREP(p->dx, 0, r->f[3]);
    VSTOREP(p->dy, 0, r->f[4]);
    VSTOREP(p->dz, 0, r->f[5]);
    VSTOREP(p->ix, 0, r->f[6]);
    VSTOREP(p->iy, 0, r->f[7]);
    VSTOREP(p->iz, 0, r->f[8]);
#if HAS_TRIANGLES
    VSTOREP(p->sx, 0, r->f[9]);
    VSTOREP(p->sy, 0, r->f[10]);
    VSTOREP(p->sz, 0, r->f[11]);
    VSTOREP(p->kx, 0, r->axis[0]);
    VSTOREP(p->ky, 0, r->axis[1]);
    VSTOREP(p->kz, 0, r->axis[2]);
#endif
}

// Lane j's ray, as make_ray made it.
HOT Ray ray_from_lanes(const RayLanes* l, int j) {
    Ray r;
    r.o = (REAL3)(l->f[0][j], l->f[1][j], l->f[2][j]);
    r.d = (REAL3)(l->f[3][j], l->f[4][j], l->f[5][j]);
    r.inv_d = (REAL3)(l->f[6][j], l->f[7][j], l->f[8][j]);
#if HAS_TRIANGLES
    r.sx = l->f[9][j];
    r.sy = l->f[10][j];
    r.sz = l->f[11][j];
    r.kx = (int)l->axis[0][j];
    r.ky = (int)l->axis[1][j];
    r.kz = (int)l->axis[2][j];
#endif
    return r;
}

// Lane j's ray, for the single-ray code's fallbacks.
HOT Ray lane_ray(const RayPacket* p, int j) {
    RayLanes l;
    store_ray_lanes(p, &l);
    return ray_from_lanes(&l, j);
}

// make_ray(o, d) for every lane, into a packet; `lanes`: those whose permutation counts for
// RayPacket.uniform (the others ride along).
HOT RayPacket make_ray_packet(REALP ox, REALP oy, REALP oz, REALP dx, REALP dy, REALP dz,
                              int lanes) {
    RayPacket p;
    p.ox = ox;
    p.oy = oy;
    p.oz = oz;
    p.dx = dx;
    p.dy = dy;
    p.dz = dz;
    p.ix = (REAL)1 / dx;
    p.iy = (REAL)1 / dy;
    p.iz = (REAL)1 / dz;
    p.dd = dot_lanes(dx, dy, dz, dx, dy, dz);
#if HAS_TRIANGLES
    REALP ax = fabs(dx), ay = fabs(dy), az = fabs(dz);
    const MASKP zero = (MASKP)(0), one = (MASKP)(1), two = (MASKP)(2);
    p.kz = ax > ay ? (ax > az ? zero : two) : (ay > az ? one : two);
    p.kx = p.kz == two ? zero : p.kz + one;
    p.ky = p.kx == two ? zero : p.kx + one;
    REALP along = p.kz == zero ? dx : (p.kz == one ? dy : dz);
    MASKP swap = along < (REAL)0;
    MASKP kx = swap ? p.ky : p.kx;
    p.ky = swap ? p.kx : p.ky;
    p.kx = kx;
    REALP across_x = p.kx == zero ? dx : (p.kx == one ? dy : dz);
    REALP across_y = p.ky == zero ? dx : (p.ky == one ? dy : dz);
    p.sx = -across_x / along;
    p.sy = -across_y / along;
    p.sz = (REAL)1 / along;
    LANE_INT axis[3][PACKET_LANES];
    VSTOREP(p.kx, 0, axis[0]);
    VSTOREP(p.ky, 0, axis[1]);
    VSTOREP(p.kz, 0, axis[2]);
    int first = lowest_bit(lanes);
    p.akx = (int)axis[0][first];
    p.aky = (int)axis[1][first];
    p.akz = (int)axis[2][first];
    MASKP same = (p.kx == (MASKP)(p.akx)) & (p.ky == (MASKP)(p.aky)) & (p.kz == (MASKP)(p.akz));
    p.uniform = (lane_mask(same) & lanes) == lanes;
    p.okx = p.akx == 0 ? p.ox : (p.akx == 1 ? p.oy : p.oz);
    p.oky = p.aky == 0 ? p.ox : (p.aky == 1 ? p.oy : p.oz);
    p.okz = p.akz == 0 ? p.ox : (p.akz == 1 ? p.oy : p.oz);
#endif
    return p;
}

// Lane j's direction, as make_ray made it.
HOT REAL3 direction_of_lane(const RayLanes* l, int j) {
    return (REAL3)(l->f[3][j], l->f[4][j], l->f[5][j]);
}

// The lanes' hits (Hit, lane by lane; instances are not walked by packets).
typedef struct {
    REALP t, b1, b2;
    MASKP ref, part;
} PacketHit;

// The lanes' hits row by row, for the lanes that go on one at a time (hit_of_lane).
typedef struct {
    REAL t[PACKET_LANES], b1[PACKET_LANES], b2[PACKET_LANES];
    LANE_INT ref[PACKET_LANES], part[PACKET_LANES], instance[PACKET_LANES];
} HitLanes;

HOT Hit hit_of_lane(const HitLanes* r, int j) {
    Hit h;
    h.t = r->t[j];
    h.b1 = r->b1[j];
    h.b2 = r->b2[j];
    h.ref = (int)r->ref[j];
    h.part = (int)r->part[j];
    h.instance = (int)r->instance[j];
    return h;
}

HOT void set_hit_lane(HitLanes* r, int j, const Hit* h) {
    r->t[j] = h->t;
    r->b1[j] = h->b1;
    r->b2[j] = h->b2;
    r->ref[j] = h->ref;
    r->part[j] = h->part;
    r->instance[j] = h->instance;
}

HOT PacketHit packet_hit(const HitLanes* r) {
    PacketHit h;
    h.t = VLOADP(0, r->t);
    h.b1 = VLOADP(0, r->b1);
    h.b2 = VLOADP(0, r->b2);
    h.ref = VLOADP(0, r->ref);
    h.part = VLOADP(0, r->part);
    return h;
}

HOT void store_hits(const PacketHit* h, HitLanes* r) {
    VSTOREP(h->t, 0, r->t);
    VSTOREP(h->b1, 0, r->b1);
    VSTOREP(h->b2, 0, r->b2);
    VSTOREP(h->ref, 0, r->ref);
    VSTOREP(h->part, 0, r->part);
    VSTOREP((MASKP)(-1), 0, r->instance);
}

// no_hit() in every lane.
DEFINE_NO_HIT(HOT, PacketHit, REALP, MASKP, no_hit_lanes, )

DEFINE_DIFFERENCE_OF_PRODUCTS(HOT, REALP, difference_of_products_lanes)

// length3 lane-wise (real.h): the square root of dot_lanes where the squared length is within
// [2^-90, 2^90] or the vector is zero. Lanes where it is not (a squared length that underflows
// to zero among them: the builtin length() scales those) are added to *outside.
HOT REALP plain_length_lanes(REALP x, REALP y, REALP z, MASKP* outside) {
    REALP dd = dot_lanes(x, y, z, x, y, z);
    MASKP zero = (x == (REAL)0) & (y == (REAL)0) & (z == (REAL)0);
    *outside |= ~(zero | plain_squared_length_lanes(dd));
    return sqrt(GREATER(dd, (REALP)(0)));
}

// safe_normalize lane-wise, for the lanes that plain_length_lanes can measure.
HOT void safe_normalize_lanes(REALP* x, REALP* y, REALP* z, MASKP* outside) {
    REALP len = plain_length_lanes(*x, *y, *z, outside);
    MASKP some = len > (REAL)0;
    *x = some ? *x / len : *x;
    *y = some ? *y / len : *y;
    *z = some ? *z / len : *z;
}

// length3 lane-wise (real.h): sqrt of dot_lanes. False where a lane of `lanes` has a squared
// length outside [2^-90, 2^90] (or NaN), where length3 takes the builtin, which scales.
HOT bool length_lanes(REALP x, REALP y, REALP z, MASKP lanes, REALP* len) {
    REALP dd = dot_lanes(x, y, z, x, y, z);
    MASKP inside = plain_squared_length_lanes(dd);
    *len = sqrt(GREATER(dd, (REALP)(0)));
    return !lane_mask(lanes & ~inside);
}
#endif

#endif
