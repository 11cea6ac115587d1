// Triangles (HAS_TRIANGLES), in leaf packets of four (clray_types.h: TrianglePacket): the
// watertight test of Woop, Benthin and Wald on a packet's four triangles (or the study's
// Moller-Trumbore), the same lane-wise on a sample packet's rays, one triangle at a time, and
// the surface from the barycentrics, with vertex normals and texture coordinates.
#ifndef CLRAY_TRIANGLE_H
#define CLRAY_TRIANGLE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shape.h"

#if HAS_TRIANGLES
#if TRIANGLE_MOLLER_TRUMBORE
// Study variant: the textbook Moller-Trumbore test. Not watertight: rays aimed at an edge
// shared by two triangles can miss both.
static inline Crossings intersect_triangle(REAL3 p0, REAL3 p1, REAL3 p2, const Ray* r) {
    Crossings c = no_crossings();
    REAL3 e1 = p1 - p0, e2 = p2 - p0;
    REAL3 pv = cross(r->d, e2);
    REAL det = dot(e1, pv);
    if (det == (REAL)0) return c;
    REAL inv_det = (REAL)1 / det;
    REAL3 tv = r->o - p0;
    REAL u = dot(tv, pv) * inv_det;
    if (u < (REAL)0 || u > (REAL)1) return c;
    REAL3 qv = cross(tv, e1);
    REAL v = dot(r->d, qv) * inv_det;
    if (v < (REAL)0 || u + v > (REAL)1) return c;
    REAL t = dot(e2, qv) * inv_det;
    if (!(t > (REAL)0) || !isfinite(t)) return c;
    c.t[0] = t;
    c.b1 = u;
    c.b2 = v;
    return c;
}
#endif

// Hits of a ray with the triangles of a packet: bit k set where lane k is crossed, with its t
// and barycentrics in t[k], b1[k], b2[k]. Padding lanes hold NaN corners and are never crossed.
#if TRIANGLE_MOLLER_TRUMBORE
// The study variant tests lane by lane with the scalar formula.
HOT int intersect_triangle_packet(const __global TrianglePacket* pk, const Ray* r, REAL* t,
                                  REAL* b1, REAL* b2) {
    int bits = 0;
    for (int k = 0; k < PACKET_WIDTH; ++k) {
        Crossings c = intersect_triangle((REAL3)(pk->x0[k], pk->y0[k], pk->z0[k]),
                                         (REAL3)(pk->x1[k], pk->y1[k], pk->z1[k]),
                                         (REAL3)(pk->x2[k], pk->y2[k], pk->z2[k]), r);
        // Every lane's t, a miss's infinite: packet_blocks compares all four lanes.
        t[k] = c.t[0];
        if (c.t[0] < REAL_INF) {
            bits |= 1 << k;
            b1[k] = c.b1;
            b2[k] = c.b2;
        }
    }
    return bits;
}
#else
// The watertight test after the corners, written once (real.h, Twins) for a leaf packet's four
// triangles against one ray (REAL4) and for one triangle against a sample packet's rays (REALP):
// corners (p0x .. p2z) relative to the ray's origin, in its permuted axes; (sx, sy, sz) its
// shear. Gives the lanes crossed ahead of the origin, with the edge functions e1, e2, their sum
// det and t scaled by det, for the caller's division.
#if !defined(USE_DOUBLE) && defined(cl_khr_fp64) && !TRIANGLE_NO_FP64_FALLBACK
// An edge function that rounds to exactly zero is recomputed in double (N lanes; BITS: a
// comparison's lanes as bits; VSTORE, VLOAD: T's).
#define DEFINE_EXACT_ZERO_EDGES(T, N, BITS, VSTORE, VLOAD, NAME)                              \
    HOT void NAME(T p0x, T p0y, T p1x, T p1y, T p2x, T p2y, T* e0, T* e1, T* e2) {            \
        int zero = BITS((*e0 == 0.0f) | (*e1 == 0.0f) | (*e2 == 0.0f));                       \
        if (!zero) return;                                                                    \
        float q[6][N], e[3][N];                                                               \
        VSTORE(p0x, 0, q[0]);                                                                 \
        VSTORE(p0y, 0, q[1]);                                                                 \
        VSTORE(p1x, 0, q[2]);                                                                 \
        VSTORE(p1y, 0, q[3]);                                                                 \
        VSTORE(p2x, 0, q[4]);                                                                 \
        VSTORE(p2y, 0, q[5]);                                                                 \
        VSTORE(*e0, 0, e[0]);                                                                 \
        VSTORE(*e1, 0, e[1]);                                                                 \
        VSTORE(*e2, 0, e[2]);                                                                 \
        for (int k = 0; k < N; ++k) {                                                         \
            if (!(zero & (1 << k))) continue;                                                 \
            e[0][k] = (float)((double)q[2][k] * (double)q[5][k] - (double)q[3][k] * q[4][k]); \
            e[1][k] = (float)((double)q[4][k] * (double)q[1][k] - (double)q[5][k] * q[0][k]); \
            e[2][k] = (float)((double)q[0][k] * (double)q[3][k] - (double)q[1][k] * q[2][k]); \
        }                                                                                     \
        *e0 = VLOAD(0, e[0]);                                                                 \
        *e1 = VLOAD(0, e[1]);                                                                 \
        *e2 = VLOAD(0, e[2]);                                                                 \
    }
#else
#define DEFINE_EXACT_ZERO_EDGES(T, N, BITS, VSTORE, VLOAD, NAME) \
    HOT void NAME(T p0x, T p0y, T p1x, T p1y, T p2x, T p2y, T* e0, T* e1, T* e2) {}
#endif
// M: what comparing Ts gives; DOP: difference_of_products for T; EXACT: DEFINE_EXACT_ZERO_EDGES's.
#define DEFINE_WATERTIGHT(T, M, DOP, EXACT, NAME)                                            \
    HOT M NAME(T p0x, T p0y, T p0z, T p1x, T p1y, T p1z, T p2x, T p2y, T p2z, T sx, T sy,    \
               T sz, T* e1_out, T* e2_out, T* det_out, T* t_scaled_out) {                    \
        p0x += sx * p0z;                                                                     \
        p0y += sy * p0z;                                                                     \
        p1x += sx * p1z;                                                                     \
        p1y += sy * p1z;                                                                     \
        p2x += sx * p2z;                                                                     \
        p2y += sy * p2z;                                                                     \
        T e0 = DOP(p1x, p2y, p1y, p2x);                                                      \
        T e1 = DOP(p2x, p0y, p2y, p0x);                                                      \
        T e2 = DOP(p0x, p1y, p0y, p1x);                                                      \
        EXACT(p0x, p0y, p1x, p1y, p2x, p2y, &e0, &e1, &e2);                                  \
        M mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0));      \
        T det = e0 + e1 + e2;                                                                \
        p0z *= sz;                                                                           \
        p1z *= sz;                                                                           \
        p2z *= sz;                                                                           \
        T t_scaled = e0 * p0z + e1 * p1z + e2 * p2z;                                         \
        /* A zero or NaN det fails both sign tests. */                                       \
        M ahead = ((det < 0) & (t_scaled < 0)) | ((det > 0) & (t_scaled > 0));               \
        *e1_out = e1;                                                                        \
        *e2_out = e2;                                                                        \
        *det_out = det;                                                                      \
        *t_scaled_out = t_scaled;                                                            \
        return ahead & ~mixed;                                                               \
    }
DEFINE_EXACT_ZERO_EDGES(REAL4, PACKET_WIDTH, lane_bits4, vstore4, vload4, exact_zero_edges4)
DEFINE_WATERTIGHT(REAL4, MASK4, difference_of_products4, exact_zero_edges4, watertight4)

// Coordinate k (0, 1, 2: x, y, z) of a point, lane by lane where K is a vector (real.h, Twins).
#define DEFINE_PICK(T, K, NAME) \
    HOT T NAME(T x, T y, T z, K k) { return k == 0 ? x : (k == 1 ? y : z); }
DEFINE_PICK(REAL4, int, pick4)

// Woop, Benthin, Wald, "Watertight Ray/Triangle Intersection", JCGT 2013, as in pbrt-v4, on four
// triangles at once: edge functions in a ray-aligned sheared frame, so rays at shared edges hit
// one side or both. An edge function that rounds to exactly zero is recomputed in double.
HOT int intersect_triangle_packet(const __global TrianglePacket* pk, const Ray* r, REAL* t,
                                  REAL* b1, REAL* b2) {
    REAL4 ox = (REAL4)(r->o.x), oy = (REAL4)(r->o.y), oz = (REAL4)(r->o.z);
    REAL4 ax = TO_REAL4(vload4(0, pk->x0)) - ox, ay = TO_REAL4(vload4(0, pk->y0)) - oy,
          az = TO_REAL4(vload4(0, pk->z0)) - oz;
    REAL4 bx = TO_REAL4(vload4(0, pk->x1)) - ox, by = TO_REAL4(vload4(0, pk->y1)) - oy,
          bz = TO_REAL4(vload4(0, pk->z1)) - oz;
    REAL4 cx = TO_REAL4(vload4(0, pk->x2)) - ox, cy = TO_REAL4(vload4(0, pk->y2)) - oy,
          cz = TO_REAL4(vload4(0, pk->z2)) - oz;
    REAL4 p0x = pick4(ax, ay, az, r->kx), p0y = pick4(ax, ay, az, r->ky),
          p0z = pick4(ax, ay, az, r->kz);
    REAL4 p1x = pick4(bx, by, bz, r->kx), p1y = pick4(bx, by, bz, r->ky),
          p1z = pick4(bx, by, bz, r->kz);
    REAL4 p2x = pick4(cx, cy, cz, r->kx), p2y = pick4(cx, cy, cz, r->ky),
          p2z = pick4(cx, cy, cz, r->kz);
    REAL4 e1, e2, det, t_scaled;
    MASK4 crossed = watertight4(p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z, (REAL4)(r->sx),
                                (REAL4)(r->sy), (REAL4)(r->sz), &e1, &e2, &det, &t_scaled);
    int bits = lane_bits4(convert_int4(crossed));
    if (bits) {
        REAL4 inv_det = (REAL)1 / det;
        vstore4(t_scaled * inv_det, 0, t);
        vstore4(e1 * inv_det, 0, b1);
        vstore4(e2 * inv_det, 0, b2);
    }
    return bits;
}
#endif

#if SAMPLE_PACKETS && !TRIANGLE_MOLLER_TRUMBORE
DEFINE_PICK(REALP, MASKP, pick_lanes)

// Triangle k's corners relative to each lane's origin, in each lane's permuted axes.
typedef struct {
    REALP p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z;
} CornerLanes;

// A leaf packet's corners along the packet's permuted axes (RayPacket akx, aky, akz): corner
// j's coordinates of its PACKET_WIDTH triangles, picked with one vector select each for all
// of them, where every lane shares the permutation.
typedef struct {
    float x[3][PACKET_WIDTH], y[3][PACKET_WIDTH], z[3][PACKET_WIDTH];
} PickedCorners;

DEFINE_PICK(float4, int, pick_axis4)

HOT void pick_corner(const __global float* x, const __global float* y, const __global float* z,
                     const RayPacket* r, int j, PickedCorners* q) {
    float4 vx = vload4(0, x), vy = vload4(0, y), vz = vload4(0, z);
    vstore4(pick_axis4(vx, vy, vz, r->akx), 0, q->x[j]);
    vstore4(pick_axis4(vx, vy, vz, r->aky), 0, q->y[j]);
    vstore4(pick_axis4(vx, vy, vz, r->akz), 0, q->z[j]);
}

HOT PickedCorners pick_corners(const __global TrianglePacket* pk, const RayPacket* r) {
    PickedCorners q;
    pick_corner(pk->x0, pk->y0, pk->z0, r, 0, &q);
    pick_corner(pk->x1, pk->y1, pk->z1, r, 1, &q);
    pick_corner(pk->x2, pk->y2, pk->z2, r, 2, &q);
    return q;
}

// Triangle k's corners relative to each lane's origin, in each lane's permuted axes; `picked`:
// the packet's pick_corners where the lanes share the permutation.
HOT CornerLanes triangle_corners_lanes(const __global TrianglePacket* pk,
                                       const PickedCorners* picked, int k, const RayPacket* r) {
    CornerLanes q;
    if (r->uniform) {
        q.p0x = (REALP)(TO_REAL(picked->x[0][k])) - r->okx;
        q.p0y = (REALP)(TO_REAL(picked->y[0][k])) - r->oky;
        q.p0z = (REALP)(TO_REAL(picked->z[0][k])) - r->okz;
        q.p1x = (REALP)(TO_REAL(picked->x[1][k])) - r->okx;
        q.p1y = (REALP)(TO_REAL(picked->y[1][k])) - r->oky;
        q.p1z = (REALP)(TO_REAL(picked->z[1][k])) - r->okz;
        q.p2x = (REALP)(TO_REAL(picked->x[2][k])) - r->okx;
        q.p2y = (REALP)(TO_REAL(picked->y[2][k])) - r->oky;
        q.p2z = (REALP)(TO_REAL(picked->z[2][k])) - r->okz;
        return q;
    }
    REALP ax = (REALP)(TO_REAL(pk->x0[k])) - r->ox, ay = (REALP)(TO_REAL(pk->y0[k])) - r->oy,
          az = (REALP)(TO_REAL(pk->z0[k])) - r->oz;
    REALP bx = (REALP)(TO_REAL(pk->x1[k])) - r->ox, by = (REALP)(TO_REAL(pk->y1[k])) - r->oy,
          bz = (REALP)(TO_REAL(pk->z1[k])) - r->oz;
    REALP cx = (REALP)(TO_REAL(pk->x2[k])) - r->ox, cy = (REALP)(TO_REAL(pk->y2[k])) - r->oy,
          cz = (REALP)(TO_REAL(pk->z2[k])) - r->oz;
    q.p0x = pick_lanes(ax, ay, az, r->kx);
    q.p0y = pick_lanes(ax, ay, az, r->ky);
    q.p0z = pick_lanes(ax, ay, az, r->kz);
    q.p1x = pick_lanes(bx, by, bz, r->kx);
    q.p1y = pick_lanes(bx, by, bz, r->ky);
    q.p1z = pick_lanes(bx, by, bz, r->kz);
    q.p2x = pick_lanes(cx, cy, cz, r->kx);
    q.p2y = pick_lanes(cx, cy, cz, r->ky);
    q.p2z = pick_lanes(cx, cy, cz, r->kz);
    return q;
}

DEFINE_EXACT_ZERO_EDGES(REALP, PACKET_LANES, lane_mask, VSTOREP, VLOADP, exact_zero_edges_lanes)
DEFINE_WATERTIGHT(REALP, MASKP, difference_of_products_lanes, exact_zero_edges_lanes,
                  watertight_lanes)

// Triangle k of a packet against every lane: intersect_triangle_packet's watertight test with
// the triangle and the ray's roles swapped (one triangle, PACKET_LANES rays), written once
// (watertight_lanes). Crossed lanes come back with t and barycentrics.
HOT MASKP triangle_lanes(const __global TrianglePacket* pk, const PickedCorners* picked, int k,
                         const RayPacket* r, REALP* t, REALP* b1, REALP* b2) {
    CornerLanes q = triangle_corners_lanes(pk, picked, k, r);
    REALP e1, e2, det, t_scaled;
    MASKP crossed = watertight_lanes(q.p0x, q.p0y, q.p0z, q.p1x, q.p1y, q.p1z, q.p2x, q.p2y, q.p2z,
                                     r->sx, r->sy, r->sz, &e1, &e2, &det, &t_scaled);
    REALP inv_det = (REAL)1 / det;
    *t = t_scaled * inv_det;
    *b1 = e1 * inv_det;
    *b2 = e2 * inv_det;
    return crossed;
}
#define TRIANGLE_LANES 1
#else
#define TRIANGLE_LANES 0
#endif

// A triangle slot's material word (the index and the TRIANGLE_* flags): its Triangle record's
// where the scene has vertex attributes, else the slot's entry of triangle_materials, which
// holds the word alone (scene.h: HAS_VERTEX_ATTRIBUTES), or its one entry where every
// triangle has the same word (HAS_ONE_TRIANGLE_MATERIAL: a model of one material).
HOT int triangle_material(const SceneRefs* s, int slot) {
#if HAS_VERTEX_ATTRIBUTES
    return s->triangles[slot].material;
#elif HAS_ONE_TRIANGLE_MATERIAL
    return s->triangle_materials[0];
#else
    return s->triangle_materials[slot];
#endif
}

// shape_surface for a triangle: the point from the barycentrics, pulled towards the
// centroid, the winding's normal and the blended vertex normal.
HOT Surface triangle_surface(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
    Surface sf;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    int word = triangle_material(s, hit->part);
#if HAS_VERTEX_ATTRIBUTES
    Triangle tri = s->triangles[hit->part];  // its vertex indices, beside the word
#endif
    // The corners from the hit's packet lane (its part is its slot, shapes.h:
    // packet_crossings): the mesh's float32 vertices, which the device does not keep.
    const __global TrianglePacket* pk = s->triangle_packets + hit->part / PACKET_WIDTH;
    int lane = hit->part % PACKET_WIDTH;
    REAL3 p0 = (REAL3)((REAL)pk->x0[lane], (REAL)pk->y0[lane], (REAL)pk->z0[lane]);
    REAL3 p1 = (REAL3)((REAL)pk->x1[lane], (REAL)pk->y1[lane], (REAL)pk->z1[lane]);
    REAL3 p2 = (REAL3)((REAL)pk->x2[lane], (REAL)pk->y2[lane], (REAL)pk->z2[lane]);
    REAL b1 = hit->b1, b2 = hit->b2, b0 = (REAL)1 - b1 - b2;
    REAL3 p = b0 * p0 + b1 * p1 + b2 * p2;
    sf.err = gamma * max_comp3(fabs(b0 * p0) + fabs(b1 * p1) + fabs(b2 * p2));
    // A hit on an edge also lies on the neighbouring triangle's plane, so a ray spawned
    // from it (offset along this normal only) could start on that plane and leave
    // through a concave edge at t = 0. Pulling the point a few error bounds towards
    // this triangle's centroid, within the triangle, takes it off that plane.
    REAL3 to_centroid = (p0 + p1 + p2) / (REAL)3 - p;
    REAL reach = length3(to_centroid);
    if (reach > (REAL)0) {
        p += fmin((REAL)4 * sf.err, REAL_C(0.5) * reach) / reach * to_centroid;
    }
    REAL3 n = safe_normalize(cross3(p1 - p0, p2 - p0));
    // A degenerate triangle has no normal: let it face the ray.
    sf.n_g = dot3(n, n) > (REAL)0 ? n : -r->d;
    sf.uv = (REAL2)(b1, b2);
#if HAS_VERTEX_NORMALS
    if (word & TRIANGLE_SMOOTH) {
        REAL3 ns = b0 * TO_REAL3(s->normals[tri.v0]) +
                   b1 * TO_REAL3(s->normals[tri.v1]) +
                   b2 * TO_REAL3(s->normals[tri.v2]);
        sf.n_s = safe_normalize(ns);
    }
#endif
#if HAS_VERTEX_UVS
    if (word & TRIANGLE_UV) {
        sf.uv = b0 * TO_REAL2(s->uvs[tri.v0]) + b1 * TO_REAL2(s->uvs[tri.v1]) +
                b2 * TO_REAL2(s->uvs[tri.v2]);
    }
#endif
#if HAS_VERTEX_COLORS
    sf.tint = (REAL3)(1, 1, 1);
    if (word & TRIANGLE_COLOR) {
        sf.tint = b0 * TO_REAL3(s->colors[tri.v0]) + b1 * TO_REAL3(s->colors[tri.v1]) +
                  b2 * TO_REAL3(s->colors[tri.v2]);
    }
#endif
    sf.material = word & TRIANGLE_MATERIAL_MASK;
    sf.p = p;
#if HAS_VERTEX_NORMALS
    if ((word & TRIANGLE_SMOOTH) && dot3(sf.n_s, sf.n_s) > (REAL)0) return sf;
#endif
    sf.n_s = sf.n_g;
    return sf;
}

#if SURFACE_LANES
// triangle_surface lane-wise: the point from the barycentrics, pulled towards the centroid,
// the winding's normal and the blended vertex normal.
HOT SurfaceOfLanes triangle_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                          const PacketHit* h, MASKP* outside) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP b1 = h->b1, b2 = h->b2, b0 = (REAL)1 - b1 - b2;
    v.px = b0 * g->ax + b1 * g->bx + b2 * g->cx;
    v.py = b0 * g->ay + b1 * g->by + b2 * g->cy;
    v.pz = b0 * g->az + b1 * g->bz + b2 * g->cz;
    REALP ex = fabs(b0 * g->ax) + fabs(b1 * g->bx) + fabs(b2 * g->cx);
    REALP ey = fabs(b0 * g->ay) + fabs(b1 * g->by) + fabs(b2 * g->cy);
    REALP ez = fabs(b0 * g->az) + fabs(b1 * g->bz) + fabs(b2 * g->cz);
    v.err = gamma * fmax(ex, fmax(ey, ez));
    REALP tx = (g->ax + g->bx + g->cx) / (REAL)3 - v.px;
    REALP ty = (g->ay + g->by + g->cy) / (REAL)3 - v.py;
    REALP tz = (g->az + g->bz + g->cz) / (REAL)3 - v.pz;
    REALP reach = plain_length_lanes(tx, ty, tz, outside);
    MASKP move = reach > (REAL)0;
    // Divided by 1 in the lanes that stay (a degenerate triangle's, or no lane's hit), so that
    // no lane computes 0/0, even one whose result the select below discards.
    REALP k = fmin((REAL)4 * v.err, REAL_C(0.5) * reach) / (move ? reach : (REAL)1);
    v.px = move ? v.px + k * tx : v.px;
    v.py = move ? v.py + k * ty : v.py;
    v.pz = move ? v.pz + k * tz : v.pz;
    // cross3(p1 - p0, p2 - p0) (real.h): each product rounded, none fused.
    REALP e1x = g->bx - g->ax, e1y = g->by - g->ay, e1z = g->bz - g->az;
    REALP e2x = g->cx - g->ax, e2y = g->cy - g->ay, e2z = g->cz - g->az;
    REALP yz = e1y * e2z;
    REALP zy = e1z * e2y;
    REALP zx = e1z * e2x;
    REALP xz = e1x * e2z;
    REALP xy = e1x * e2y;
    REALP yx = e1y * e2x;
    REALP nx = yz - zy, ny = zx - xz, nz = xy - yx;
    safe_normalize_lanes(&nx, &ny, &nz, outside);
    // A degenerate triangle has no normal: it faces the ray.
    MASKP some = dot_lanes(nx, ny, nz, nx, ny, nz) > (REAL)0;
    v.gx = some ? nx : -r->dx;
    v.gy = some ? ny : -r->dy;
    v.gz = some ? nz : -r->dz;
    v.sx = v.gx;
    v.sy = v.gy;
    v.sz = v.gz;
#if HAS_VERTEX_NORMALS
    if (lane_mask(g->smooth)) {
        REALP sx = b0 * g->nax + b1 * g->nbx + b2 * g->ncx;
        REALP sy = b0 * g->nay + b1 * g->nby + b2 * g->ncy;
        REALP sz = b0 * g->naz + b1 * g->nbz + b2 * g->ncz;
        MASKP wide = (MASKP)(0);
        safe_normalize_lanes(&sx, &sy, &sz, &wide);
        *outside |= g->smooth & wide;
        MASKP blend = g->smooth & (dot_lanes(sx, sy, sz, sx, sy, sz) > (REAL)0);
        v.sx = blend ? sx : v.sx;
        v.sy = blend ? sy : v.sy;
        v.sz = blend ? sz : v.sz;
    }
#endif
    return v;
}

// shape_record for a triangle: its corners (a, b, c) and vertex normals (na, nb, nc). False
// with vertex texture coordinates or colours.
HOT bool triangle_record(const SceneRefs* s, int part, REAL* f, int stride, int* material,
                         LANE_INT* smooth) {
    int word = triangle_material(s, part);
    if (word & (TRIANGLE_UV | TRIANGLE_COLOR)) return false;
    const __global TrianglePacket* pk = s->triangle_packets + part / PACKET_WIDTH;
    int lane = part % PACKET_WIDTH;
    f[ROW_A * stride] = (REAL)pk->x0[lane];
    f[(ROW_A + 1) * stride] = (REAL)pk->y0[lane];
    f[(ROW_A + 2) * stride] = (REAL)pk->z0[lane];
    f[ROW_B * stride] = (REAL)pk->x1[lane];
    f[(ROW_B + 1) * stride] = (REAL)pk->y1[lane];
    f[(ROW_B + 2) * stride] = (REAL)pk->z1[lane];
    f[ROW_C * stride] = (REAL)pk->x2[lane];
    f[(ROW_C + 1) * stride] = (REAL)pk->y2[lane];
    f[(ROW_C + 2) * stride] = (REAL)pk->z2[lane];
#if HAS_VERTEX_NORMALS
    if (word & TRIANGLE_SMOOTH) {
        *smooth = -1;
        Triangle tri = s->triangles[part];
        int v[3] = {tri.v0, tri.v1, tri.v2};
        for (int c = 0; c < 3; ++c) {
            REAL3 n = TO_REAL3(s->normals[v[c]]);
            f[(ROW_NORMALS + 3 * c) * stride] = n.x;
            f[(ROW_NORMALS + 3 * c + 1) * stride] = n.y;
            f[(ROW_NORMALS + 3 * c + 2) * stride] = n.z;
        }
    }
#endif
    *material = word & TRIANGLE_MATERIAL_MASK;
    return true;
}
#endif
#endif

#endif
