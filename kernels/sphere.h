// Spheres (HAS_SPHERES): the crossings by the Hearn-Baker form of the quadratic (or in double
// where FP64_SPHERES asks, or the textbook form of the study), the same on a leaf's packet of
// four spheres and lane-wise on a sample packet's rays, and the surface re-projected onto the
// sphere.
#ifndef CLRAY_SPHERE_H
#define CLRAY_SPHERE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shape.h"

#if HAS_SPHERES
#if SPHERE_FP64
static inline Crossings intersect_sphere(const __global Sphere* s, const Ray* r) {
    Crossings c = no_crossings();
    double3 center = convert_double3(s->center_radius.xyz);
    double radius = (double)s->center_radius.w;
    double3 d = convert_double3(r->d);
    double3 f = convert_double3(r->o) - center;
    double a = dot(d, d), b = dot(f, d);
    double3 l = f - (b / a) * d;
    double ll = length(l), fl = length(f);
    double disc = a * (radius - ll) * (radius + ll);
    if (!(disc >= 0.0)) return c;
    double q = -(b + copysign(sqrt(disc), b));
    if (q == 0.0) return c;
    double r0 = ((fl - radius) * (fl + radius)) / q, r1 = q / a;
    c.t[0] = (float)fmin(r0, r1);
    c.t[1] = (float)fmax(r0, r1);
    return c;
}
#else
static inline Crossings intersect_sphere(const __global Sphere* s, const Ray* r) {
    Crossings c = no_crossings();
    REAL3 center = TO_REAL3(s->center_radius);
    REAL radius = TO_REAL(s->center_radius.w);
    REAL3 f = r->o - center;
    REAL a = dot(r->d, r->d);
    REAL b = dot(f, r->d);
#if SPHERE_TEXTBOOK
    REAL cc = dot(f, f) - radius * radius;
    REAL disc = b * b - a * cc;
    if (!(disc >= (REAL)0)) return c;
    REAL sq = sqrt(disc);
    c.t[0] = (-b - sq) / a;
    c.t[1] = (-b + sq) / a;
#else
    // Hearn-Baker: b^2 - a c = a (r - |l|)(r + |l|), l the centre's offset from the line.
    REAL3 l = f - (b / a) * r->d;
    REAL ll = length(l);
    REAL disc = a * (radius - ll) * (radius + ll);
    REAL fl = length(f);
    if (!quadratic_roots(a, b, (fl - radius) * (fl + radius), disc, &c.t[0], &c.t[1])) {
        return no_crossings();
    }
#endif
    return c;
}
#endif  // SPHERE_FP64

#if HAS_SPHERES && !SPHERE_FP64 && !SPHERE_TEXTBOOK
// intersect_sphere's Hearn-Baker formula, written once (real.h, Twins) for a leaf packet's four
// spheres against one ray (REAL4) and for one sphere against a sample packet's rays (REALP):
// b^2 - a c as a (r - |l|)(r + |l|), l the centre's offset from the line (f: the origin less
// the centre, d the direction, a = d . d, b = f . d).
#define DEFINE_SPHERE_DISC(T, NAME)                                                   \
    HOT T NAME(T a, T b, T fx, T fy, T fz, T dx, T dy, T dz, T radius) {              \
        T along = b / a;                                                              \
        T lx = fx - along * dx, ly = fy - along * dy, lz = fz - along * dz;           \
        T ll = sqrt(lx * lx + ly * ly + lz * lz);                                     \
        return a * (radius - ll) * (radius + ll);                                     \
    }
// quadratic_roots's Press pair lane by lane, into t0 <= t1 (c = f . f - r^2); gives q, which
// is zero where there is no root ahead. GREATER keeps sqrt's argument non-negative: lanes with
// disc < 0 (or NaN) are masked by the caller.
#define DEFINE_SPHERE_ROOTS(T, NAME)                                                  \
    HOT T NAME(T a, T b, T c, T disc, T* t0, T* t1) {                                 \
        T q = -(b + copysign(sqrt(GREATER(disc, (T)(0))), b));                        \
        T r0 = c / q, r1 = q / a;                                                     \
        *t0 = fmin(r0, r1);                                                           \
        *t1 = fmax(r0, r1);                                                           \
        return q;                                                                     \
    }
DEFINE_SPHERE_DISC(REAL4, sphere_disc4)
DEFINE_SPHERE_ROOTS(REAL4, sphere_roots4)

// intersect_sphere's Hearn-Baker formula on the four spheres of a packet: bit k set where lane
// k has roots t0[k] <= t1[k]. Padding lanes hold NaN and have none.
HOT int intersect_sphere_packet(const __global SpherePacket* pk, const Ray* r, REAL* t0,
                                REAL* t1) {
    REAL a = dot3(r->d, r->d);
    if (a == (REAL)0) return 0;
    REAL4 fx = (REAL4)(r->o.x) - TO_REAL4(vload4(0, pk->x));
    REAL4 fy = (REAL4)(r->o.y) - TO_REAL4(vload4(0, pk->y));
    REAL4 fz = (REAL4)(r->o.z) - TO_REAL4(vload4(0, pk->z));
    REAL4 radius = TO_REAL4(vload4(0, pk->radius));
    REAL4 dx = (REAL4)(r->d.x), dy = (REAL4)(r->d.y), dz = (REAL4)(r->d.z);
    REAL4 b = fx * dx + fy * dy + fz * dz;
    REAL4 disc = sphere_disc4((REAL4)(a), b, fx, fy, fz, dx, dy, dz, radius);
    // Most packets a ray reaches miss in every lane: stop before the other square roots and
    // divisions, on the same disc the roots below are masked by.
    MASK4 crossed = disc >= (REAL)0;
    if (!lane_bits4(convert_int4(crossed))) return 0;
    REAL4 fl = sqrt(fx * fx + fy * fy + fz * fz);
    REAL4 lo, hi;
    REAL4 q = sphere_roots4((REAL4)(a), b, (fl - radius) * (fl + radius), disc, &lo, &hi);
    vstore4(lo, 0, t0);
    vstore4(hi, 0, t1);
    return lane_bits4(convert_int4(crossed & (q != (REAL)0)));
}
#endif

#if SAMPLE_PACKETS && !SPHERE_FP64 && !SPHERE_TEXTBOOK
DEFINE_SPHERE_DISC(REALP, sphere_disc_lanes)
DEFINE_SPHERE_ROOTS(REALP, sphere_roots_lanes)

// Sphere k of a packet against every lane: intersect_sphere_packet's Hearn-Baker formula with
// the roles swapped (sphere_disc_lanes, sphere_roots_lanes). Lanes with roots t0 <= t1 come
// back set.
HOT MASKP sphere_lanes(const __global SpherePacket* pk, int k, const RayPacket* r, MASKP lanes,
                       REALP* t0, REALP* t1) {
    REALP a = r->dd;
    REALP fx = r->ox - (REALP)(TO_REAL(pk->x[k]));
    REALP fy = r->oy - (REALP)(TO_REAL(pk->y[k]));
    REALP fz = r->oz - (REALP)(TO_REAL(pk->z[k]));
    REALP radius = (REALP)(TO_REAL(pk->radius[k]));
    REALP b = fx * r->dx + fy * r->dy + fz * r->dz;
    REALP fl = sqrt(fx * fx + fy * fy + fz * fz);
    REALP c = (fl - radius) * (fl + radius);
    // A lane starting outside the sphere (c >= 0) and heading away from its centre (b > 0), as
    // shadow and reflected rays leave a sphere, has no root ahead: q < 0 below, so both roots
    // are <= 0, which the callers decline. Where every lane is so, nothing more to compute.
    if (!lane_mask(lanes & ~((b > (REAL)0) & (c >= (REAL)0)))) {
        *t0 = *t1 = (REALP)(REAL_INF);
        return (MASKP)(0);
    }
    REALP disc = sphere_disc_lanes(a, b, fx, fy, fz, r->dx, r->dy, r->dz, radius);
    MASKP crossed = lanes & (disc >= (REAL)0) & (a != (REAL)0);
    if (!lane_mask(crossed)) {
        // The callers mask t0 and t1 with the crossed lanes: they must still hold values.
        *t0 = *t1 = (REALP)(REAL_INF);
        return crossed;
    }
    REALP q = sphere_roots_lanes(a, b, c, disc, t0, t1);
    return crossed & (q != (REAL)0);
}
#define SPHERE_LANES 1
#else
#define SPHERE_LANES 0
#endif

// shape_surface's part for a sphere: *p, the ray's point on entry, re-projected onto the
// sphere along its normal; the normal, error bound (gamma: the bound's factor), material and,
// where want_uv, its (u, v) into *sf.
HOT void sphere_surface(const __global Sphere* sp, const Ray* r, const Hit* hit, bool want_uv,
                        REAL gamma, REAL3* p, Surface* sf) {
#if SPHERE_FP64
    // Re-projecting in float would round p at the scale of the centre (ulp(1e5) is
    // 0.008): do it in double, so the bound is the float rounding of p alone.
    double3 cd = convert_double3(sp->center_radius.xyz);
    double3 pd = convert_double3(r->o) + (double)hit->t * convert_double3(r->d);
    double3 nd = pd - cd;
    double nl = length(nd);
    nd = nl > 0.0 ? nd / nl : nd;
    pd = cd + (double)sp->center_radius.w * nd;
    REAL3 n = convert_float3(nd);
    *p = convert_float3(pd);
    sf->n_g = n;
    sf->err = gamma * max_abs3(*p);
#else
    REAL3 c = TO_REAL3(sp->center_radius);
    REAL radius = TO_REAL(sp->center_radius.w);
    REAL3 n = safe_normalize(*p - c);
    *p = c + radius * n;
    sf->n_g = n;
    sf->err = gamma * (max_abs3(c) + radius);
#endif
    if (want_uv) {
        sf->uv = (REAL2)(angle_u(n.x, n.z),
                         REAL_C(0.5) + asin(clamp(n.y, (REAL)-1, (REAL)1)) / PI_R);
    }
    sf->material = sp->material;
}

#if SURFACE_LANES
// sphere_surface lane-wise: the point re-projected onto the sphere along its normal.
HOT SurfaceOfLanes sphere_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                        const PacketHit* h, MASKP* outside) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP px = r->ox + h->t * r->dx;
    REALP py = r->oy + h->t * r->dy;
    REALP pz = r->oz + h->t * r->dz;
    REALP nx = px - g->ax, ny = py - g->ay, nz = pz - g->az;
    safe_normalize_lanes(&nx, &ny, &nz, outside);
    v.px = g->ax + g->bx * nx;
    v.py = g->ay + g->bx * ny;
    v.pz = g->az + g->bx * nz;
    v.gx = v.sx = nx;
    v.gy = v.sy = ny;
    v.gz = v.sz = nz;
    v.err = gamma * (fmax(fabs(g->ax), fmax(fabs(g->ay), fabs(g->az))) + g->bx);
    return v;
}

// shape_record for a sphere: its centre (a) and radius (b.x).
HOT bool sphere_record(const SceneRefs* s, int i, int part, REAL* f, int stride, int* material,
                       LANE_INT* smooth) {
    const __global Sphere* sp = s->spheres + i;
    REAL4 c = TO_REAL4(sp->center_radius);
    f[ROW_A * stride] = c.x;
    f[(ROW_A + 1) * stride] = c.y;
    f[(ROW_A + 2) * stride] = c.z;
    f[ROW_B * stride] = c.w;
    *material = sp->material;
    return true;
}
#endif
#endif

#endif
