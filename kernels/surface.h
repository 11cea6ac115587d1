// The hit's surface in the scene's frame (surface_at: the shape's surface, mapped out of its
// instance), where a ray spawned from it starts (offset_origin), and the shading point built
// on it (ShadePoint; shading.h); for sample packets the lanes' shading points (SurfaceLanes).
#ifndef CLRAY_SURFACE_H
#define CLRAY_SURFACE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shapes.h"
#include "bvh.h"

#if HAS_INSTANCES
// n_g and n_s go to the scene's frame by the transpose of to_object's linear part M (the
// inverse transpose of to_world's), which keeps them normal to the surface and on its outward
// side. Not normalised: its length says how M stretches distances along the normal.
static inline REAL3 instance_normal(const __global Instance* in, REAL3 n) {
    return n.x * TO_REAL3(in->to_object[0]) + n.y * TO_REAL3(in->to_object[1]) +
           n.z * TO_REAL3(in->to_object[2]);
}

static inline REAL abs_sum3(REAL3 v) { return fabs(v.x) + fabs(v.y) + fabs(v.z); }

// A row of M scaled by a power of two (exact) so that its largest entry lies in [0.5, 1); *down
// is the factor. The exponent and the factor are read from and written into REAL's bits
// (exponent_of, power_of_two: real.h), not taken from frexp, whose pointer argument Oclgrind's
// check of uninitialised memory rejects, nor from ilogb and ldexp, library calls in PoCL. The
// row is multiplied by the factor, not put through ldexp (Oclgrind 21.10's ldexp of a vector by
// one int returned wrong numbers). A row's largest entry is at least M's smallest stretch, so
// positive and normal for a transform the loader took (within [1e-30, 1e30]); a zero row (or a
// NaN) keeps the factor 1.
static inline REAL3 unit_row(REAL3 row, REAL* down) {
    REAL big = max_abs3(row);
    *down = power_of_two(big > (REAL)0 ? -(exponent_of(big) + 1) : 0);
    return row * *down;
}

// to_world's rows [A | a], the inverse of to_object's [M | m] (the record keeps M alone, 48 B an
// instance less): A = adj(M) / det(M) from the cross products of M's rows, a = -A m, in REAL.
// Each row of M is scaled by its own power of two first (exact; M = D R, so A = R^-1 D^-1 scales
// column j of R's inverse by row j's factor): a transform that stretches one axis 1e19 and keeps
// the others would make one scale's cofactors underflow float32. det is not 0 for a matrix the
// host inverted unless R is too near singular for REAL's cofactors: then A is zero, and the
// error bound's residual term below pushes the point off by its whole miss.
HOT void instance_to_world(const __global Instance* in, REAL4* a0, REAL4* a1, REAL4* a2) {
    REAL4 m0 = TO_REAL4(in->to_object[0]), m1 = TO_REAL4(in->to_object[1]),
          m2 = TO_REAL4(in->to_object[2]);
    REAL d0, d1, d2;
    REAL3 r0 = unit_row(m0.xyz, &d0), r1 = unit_row(m1.xyz, &d1), r2 = unit_row(m2.xyz, &d2);
    REAL3 c0 = cross(r1, r2), c1 = cross(r2, r0), c2 = cross(r0, r1);
    REAL det = dot(r0, c0);
    REAL inv_det = det != (REAL)0 ? (REAL)1 / det : (REAL)0;
    REAL3 column = (REAL3)(d0, d1, d2) * inv_det;
    REAL3 m = (REAL3)(m0.w, m1.w, m2.w);
    REAL3 l0 = (REAL3)(c0.x, c1.x, c2.x) * column, l1 = (REAL3)(c0.y, c1.y, c2.y) * column,
          l2 = (REAL3)(c0.z, c1.z, c2.z) * column;
    *a0 = (REAL4)(l0, -dot(l0, m));
    *a1 = (REAL4)(l1, -dot(l1, m));
    *a2 = (REAL4)(l2, -dot(l2, m));
}

// The surface of a hit inside an instance: found in the group's frame, then mapped to the
// scene's by to_world. A ray spawned here starts err |n_g|_1 along the normal (offset_origin) and
// must not be carried back through the surface, so the bound is what matters along the normal.
// A world distance d along the normal is d |M^T n| along the group frame's unit normal n
// (M A = I), so each group-frame term below is divided by |M^T n|: the group-frame bound
// (e per component is at most e |n|_1 along n), how far the point, mapped back into the group's
// frame by to_object's M (as a spawned ray is), misses the group-frame point (the residual: A
// is a computed inverse, exact only to the roundings of |M| |A| |p| and M's conditioning), and
// the rounding of that residual; the rounding of the map itself is a world bound as it is.
// Scaling by A's largest stretch instead put a ground made of a sphere stretched 1e4 along x and
// z a stretch's worth of roundings above itself, inside what stood on it. M is float32 in every
// build, so the rounding terms count float32 roundings even in the double build.
HOT Surface instance_surface(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
    const __global Instance* in = s->instances + hit->instance;
    Ray group_ray = instance_ray(in, r);
    Surface sf = shape_surface(s, &group_ray, hit, want_uv);
    REAL4 p = (REAL4)(sf.p, (REAL)1);
    REAL4 a0, a1, a2;
    instance_to_world(in, &a0, &a1, &a2);
    REAL4 m0 = TO_REAL4(in->to_object[0]), m1 = TO_REAL4(in->to_object[1]),
          m2 = TO_REAL4(in->to_object[2]);
    REAL3 world = (REAL3)(dot(a0, p), dot(a1, p), dot(a2, p));
    REAL4 ap = fabs(p);
    REAL3 mapped = (REAL3)(dot(fabs(a0), ap), dot(fabs(a1), ap), dot(fabs(a2), ap));
    REAL4 aw = (REAL4)(fabs(world) + mapped, (REAL)1);
    REAL back = fmax(dot(fabs(m0), aw), fmax(dot(fabs(m1), aw), dot(fabs(m2), aw)));
    REAL4 w = (REAL4)(world, (REAL)1);
    REAL miss = length((REAL3)(dot(m0, w), dot(m1, w), dot(m2, w)) - sf.p);
    REAL3 n_g = instance_normal(in, sf.n_g);
    REAL along = length(n_g);
    REAL gamma = fmax(gamma_n(ERR_ROUNDINGS), (REAL)(ERR_ROUNDINGS * FLT_EPSILON));
    REAL group_err = sf.err * abs_sum3(sf.n_g) + gamma * back + miss;
    sf.err = gamma * (max_abs3(world) + max_comp3(mapped)) +
             (along > (REAL)0 ? group_err / along : (REAL)0);
    sf.p = world;
    sf.n_g = safe_normalize(n_g);
    sf.n_s = safe_normalize(instance_normal(in, sf.n_s));
    if (in->material >= 0) sf.material = in->material;
    return sf;
}
#endif

// The hit's surface in the scene's frame.
HOT Surface surface_at(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
#if HAS_INSTANCES
    if (hit->instance >= 0) return instance_surface(s, r, hit, want_uv);
#ifdef USE_DOUBLE
    // Instances' surfaces lie where their float32 matrices put them, in every build: a scene
    // surface that meets one (a glass base standing on the floor) needs offsets of float32
    // size too, or a ray spawned from it can start on the wrong side of the instance's.
    Surface sf = shape_surface(s, r, hit, want_uv);
    sf.err = fmax(sf.err, (REAL)(ERR_ROUNDINGS * FLT_EPSILON) * max_abs3(sf.p));
    return sf;
#endif
#endif
    return shape_surface(s, r, hit, want_uv);
}

// How far offset_origin moves a point along n_g = (gx, gy, gz): the error bound err along the
// normal (or the study's fixed 1e-4); lane by lane for vectors (real.h, Twins).
#if OFFSET_FIXED_EPS
#define DEFINE_OFFSET_DISTANCE(T, NAME) \
    HOT T NAME(T err, T gx, T gy, T gz) { return (T)REAL_C(1e-4); }
#else
#define DEFINE_OFFSET_DISTANCE(T, NAME) \
    HOT T NAME(T err, T gx, T gy, T gz) { return err * (fabs(gx) + fabs(gy) + fabs(gz)); }
#endif
DEFINE_OFFSET_DISTANCE(REAL, offset_distance)

// Move p off the surface to the side of n_g that w leaves on, by the error bound along the
// normal: the spawned ray then starts beyond any rounding of p and needs no t epsilon.
static inline REAL3 offset_origin(const Surface* sf, REAL3 w) {
    REAL d = offset_distance(sf->err, sf->n_g.x, sf->n_g.y, sf->n_g.z);
    return dot3(w, sf->n_g) > (REAL)0 ? sf->p + d * sf->n_g : sf->p - d * sf->n_g;
}

// What shading a hit needs: its surface, its side, the normal facing the ray and its colour.
typedef struct {
    Surface sf;
    REAL3 n, c;
    bool entering;
} ShadePoint;

// A closest hit as intersect_rays reports it: the outward geometric normal and t (inf on a
// miss), and the primitive reference (-1).
static inline void report_hit(const SceneRefs* s, const Ray* ray, const Hit* hit,
                              __global float4* out, __global int* ref) {
    if (hit->t < REAL_INF) {
        Surface sf = surface_at(s, ray, hit, false);
        *out = (float4)((float)sf.n_g.x, (float)sf.n_g.y, (float)sf.n_g.z, (float)hit->t);
        *ref = hit->ref;
    } else {
        *out = (float4)(0.0f, 0.0f, 0.0f, INFINITY);
        *ref = -1;
    }
}

#if SAMPLE_PACKETS
// The lanes' shading points, coordinate by coordinate: what light_ray and a reflected ray's
// set-up read of a ShadePoint.
typedef struct {
    REALP px, py, pz, err, gx, gy, gz, nx, ny, nz;
} SurfaceLanes;

// pt[j] for each lane of `bits`; the other lanes hold a copy of one of those.
HOT SurfaceLanes surface_lanes(const ShadePoint* pt, int bits) {
    REAL f[10][PACKET_LANES];
    int spare = lowest_bit(bits);
    for (int j = 0; j < PACKET_LANES; ++j) {
        const ShadePoint* q = pt + (((bits >> j) & 1) ? j : spare);
        f[0][j] = q->sf.p.x;
        f[1][j] = q->sf.p.y;
        f[2][j] = q->sf.p.z;
        f[3][j] = q->sf.err;
        f[4][j] = q->sf.n_g.x;
        f[5][j] = q->sf.n_g.y;
        f[6][j] = q->sf.n_g.z;
        f[7][j] = q->n.x;
        f[8][j] = q->n.y;
        f[9][j] = q->n.z;
    }
    SurfaceLanes q;
    q.px = VLOADP(0, f[0]);
    q.py = VLOADP(0, f[1]);
    q.pz = VLOADP(0, f[2]);
    q.err = VLOADP(0, f[3]);
    q.gx = VLOADP(0, f[4]);
    q.gy = VLOADP(0, f[5]);
    q.gz = VLOADP(0, f[6]);
    q.nx = VLOADP(0, f[7]);
    q.ny = VLOADP(0, f[8]);
    q.nz = VLOADP(0, f[9]);
    return q;
}

// Where `mine`, *q takes v's lanes.
HOT void merge_surface_lanes(SurfaceLanes v, MASKP mine, SurfaceLanes* q) {
    q->px = mine ? v.px : q->px;
    q->py = mine ? v.py : q->py;
    q->pz = mine ? v.pz : q->pz;
    q->err = mine ? v.err : q->err;
    q->gx = mine ? v.gx : q->gx;
    q->gy = mine ? v.gy : q->gy;
    q->gz = mine ? v.gz : q->gz;
    q->nx = mine ? v.nx : q->nx;
    q->ny = mine ? v.ny : q->ny;
    q->nz = mine ? v.nz : q->nz;
}

DEFINE_OFFSET_DISTANCE(REALP, offset_distance_lanes)

// offset_origin(sf, w) for every lane, into (ox, oy, oz): the same operations in the same
// order.
HOT void offset_origin_lanes(const SurfaceLanes* q, REALP wx, REALP wy, REALP wz, REALP* ox,
                             REALP* oy, REALP* oz) {
    REALP d = offset_distance_lanes(q->err, q->gx, q->gy, q->gz);
    MASKP out = dot_lanes(wx, wy, wz, q->gx, q->gy, q->gz) > (REAL)0;
    *ox = out ? q->px + d * q->gx : q->px - d * q->gx;
    *oy = out ? q->py + d * q->gy : q->py - d * q->gy;
    *oz = out ? q->pz + d * q->gz : q->pz - d * q->gz;
}

// SurfaceLanes row by row, for the lanes that go on one at a time.
typedef struct {
    REAL f[10][PACKET_LANES];
} SurfaceRows;

HOT void store_surface_lanes(const SurfaceLanes* q, SurfaceRows* r) {
    VSTOREP(q->px, 0, r->f[0]);
    VSTOREP(q->py, 0, r->f[1]);
    VSTOREP(q->pz, 0, r->f[2]);
    VSTOREP(q->err, 0, r->f[3]);
    VSTOREP(q->gx, 0, r->f[4]);
    VSTOREP(q->gy, 0, r->f[5]);
    VSTOREP(q->gz, 0, r->f[6]);
    VSTOREP(q->nx, 0, r->f[7]);
    VSTOREP(q->ny, 0, r->f[8]);
    VSTOREP(q->nz, 0, r->f[9]);
}

// Lane j's surface as light_ray reads it (p, err, n_g; material: the caller's).
HOT Surface surface_of_lane(const SurfaceRows* r, int j) {
    Surface sf;
    sf.p = (REAL3)(r->f[0][j], r->f[1][j], r->f[2][j]);
    sf.err = r->f[3][j];
    sf.n_g = (REAL3)(r->f[4][j], r->f[5][j], r->f[6][j]);
    sf.n_s = sf.n_g;
    sf.uv = (REAL2)(0, 0);
    sf.material = 0;
#if HAS_VERTEX_COLORS
    sf.tint = (REAL3)(1, 1, 1);
#endif
    return sf;
}

// Lane j's shading normal n (ShadePoint.n).
HOT REAL3 normal_of_lane(const SurfaceRows* r, int j) {
    return (REAL3)(r->f[7][j], r->f[8][j], r->f[9][j]);
}
#endif

#endif
