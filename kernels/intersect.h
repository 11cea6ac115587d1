// Ray-primitive intersection. Each primitive reports up to two crossings of the ray with its
// surface (entry and exit for the solids), sorted, REAL_INF where there is none: closest-hit
// takes the first with t > 0, shadow rays count every crossing in range.
// Formulas and their sources: docs/rendering.md and docs/acceleration.md; the study
// (docs/study/report.md) measures the textbook alternatives against them.
#ifndef CLRAY_INTERSECT_H
#define CLRAY_INTERSECT_H

#include "real.h"
#include "clray_types.h"

typedef struct {
    REAL3 o, d;
    REAL3 inv_d;     // 1/d, +-inf for zero components (the slab test relies on it)
    int kx, ky, kz;  // Woop-Benthin-Wald axis permutation: kz is d's largest component
    REAL sx, sy, sz; // ... and the shear that maps d to +z (set only where triangles exist)
} Ray;

STAGE Ray make_ray(REAL3 o, REAL3 d) {
    Ray r;
    r.o = o;
    r.d = d;
    r.inv_d = (REAL)1 / d;
#if HAS_TRIANGLES
    REAL3 ad = fabs(d);
    r.kz = ad.x > ad.y ? (ad.x > ad.z ? 0 : 2) : (ad.y > ad.z ? 1 : 2);
    r.kx = r.kz == 2 ? 0 : r.kz + 1;
    r.ky = r.kx == 2 ? 0 : r.kx + 1;
    REAL dz = comp3(d, r.kz);
    if (dz < (REAL)0) {
        int swap = r.kx;
        r.kx = r.ky;
        r.ky = swap;
    }
    // dz != 0: it is the largest component of a non-zero direction.
    r.sx = -comp3(d, r.kx) / dz;
    r.sy = -comp3(d, r.ky) / dz;
    r.sz = (REAL)1 / dz;
#endif
    return r;
}

typedef struct {
    REAL t[2];
    int part[2];  // which face: box axis*2 + (0 lo, 1 hi); cylinder/cone 0 side, 1/2 caps
    REAL b1, b2;  // triangle barycentrics of the (single) crossing
} Crossings;

inline Crossings no_crossings(void) {
    Crossings c;
    c.t[0] = REAL_INF;
    c.t[1] = REAL_INF;
    c.part[0] = 0;
    c.part[1] = 0;
    c.b1 = 0;
    c.b2 = 0;
    return c;
}

// Keep the smallest and largest of the valid candidates: a convex solid is crossed at most
// twice, and near rims several surfaces may claim the same crossing.
inline void add_candidate(Crossings* c, int* n, REAL t, int part) {
    if (*n == 0) {
        c->t[0] = t;
        c->part[0] = part;
    } else if (*n == 1) {
        if (t < c->t[0]) {
            c->t[1] = c->t[0];
            c->part[1] = c->part[0];
            c->t[0] = t;
            c->part[0] = part;
        } else {
            c->t[1] = t;
            c->part[1] = part;
        }
    } else if (t < c->t[0]) {
        c->t[0] = t;
        c->part[0] = part;
    } else if (t > c->t[1]) {
        c->t[1] = t;
        c->part[1] = part;
    }
    (*n)++;
}

// Roots of a t^2 + 2 b t + c = 0 from the Press pair: no subtractive cancellation in either.
// disc is b^2 - a c, computed by the caller in whichever stable form fits the shape.
inline bool quadratic_roots(REAL a, REAL b, REAL c, REAL disc, REAL* t0, REAL* t1) {
    if (!(disc >= (REAL)0) || a == (REAL)0) return false;
    REAL q = -(b + copysign(sqrt(disc), b));
    if (q == (REAL)0) return false;  // tangent at the origin itself: no crossing ahead
    REAL r0 = c / q, r1 = q / a;
    *t0 = fmin(r0, r1);
    *t1 = fmax(r0, r1);
    return true;
}

#if HAS_SPHERES
// FP64_SPHERES (set by the packer only when clray.scene.scale flags a sphere that float32
// cannot intersect, e.g. a radius-1e5 ground): spheres are intersected and re-projected in
// double inside the float build. Only where the device has fp64; otherwise the float path
// runs and the loader's warning stands.
#if FP64_SPHERES && !defined(USE_DOUBLE) && defined(cl_khr_fp64)
#define SPHERE_FP64 1
#else
#define SPHERE_FP64 0
#endif

#if SPHERE_FP64
inline Crossings intersect_sphere(const __global Sphere* s, const Ray* r) {
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
inline Crossings intersect_sphere(const __global Sphere* s, const Ray* r) {
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
#endif

#if HAS_PLANES
// Where r crosses the plane: its t, or infinity where it never does (parallel, or so nearly
// that t overflows).
inline REAL plane_t(const __global Plane* pl, const Ray* r) {
    REAL3 n = TO_REAL3(pl->normal);
    REAL dn = dot(r->d, n);
    if (dn == (REAL)0) return REAL_INF;  // parallel: never crossed
    REAL t = dot(TO_REAL3(pl->point) - r->o, n) / dn;
    return isfinite(t) ? t : REAL_INF;
}

inline Crossings intersect_plane(const __global Plane* pl, const Ray* r) {
    Crossings c = no_crossings();
    c.t[0] = plane_t(pl, r);
    return c;
}
#endif

// Slab test against [lo, hi] within (tmin, tmax). Compare-select keeps a NaN from 0 * inf (a
// zero direction component with the origin on a slab plane) out of the interval, and the far
// bound is widened by 1 + 2 gamma(3) so no ray slips past an edge (Ize 2013, pbrt).
inline bool slab_interval(REAL3 lo, REAL3 hi, const Ray* r, REAL* tmin, REAL* tmax, int* part0,
                          int* part1) {
    REAL t0 = *tmin, t1 = *tmax;
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    for (int k = 0; k < 3; ++k) {
        REAL inv = comp3(r->inv_d, k), o = comp3(r->o, k);
        REAL tn = (comp3(lo, k) - o) * inv;
        REAL tf = (comp3(hi, k) - o) * inv;
        int pn = 2 * k, pf = 2 * k + 1;
        if (tn > tf) {
            REAL swap = tn;
            tn = tf;
            tf = swap;
            pn = 2 * k + 1;
            pf = 2 * k;
        }
        tf *= widen;
        if (tn > t0) {
            t0 = tn;
            *part0 = pn;
        }
        if (tf < t1) {
            t1 = tf;
            *part1 = pf;
        }
        if (t0 > t1) return false;
    }
    *tmin = t0;
    *tmax = t1;
    return true;
}

#if HAS_BOXES
inline Crossings intersect_box(const __global Box* b, const Ray* r) {
    Crossings c = no_crossings();
    REAL t0 = -REAL_INF, t1 = REAL_INF;
    int p0 = 0, p1 = 0;
    if (!slab_interval(TO_REAL3(b->lo), TO_REAL3(b->hi), r, &t0, &t1, &p0, &p1)) return c;
    if (!isfinite(t0) || !isfinite(t1)) return c;
    c.t[0] = t0;
    c.t[1] = t1;
    c.part[0] = p0;
    c.part[1] = p1;
    return c;
}
#endif

#if HAS_CYLINDERS || HAS_CONES
// Keep the side-surface roots whose axial coordinate fa + t da lies in [0, height], widened by a
// rounding bound so a ray at a rim is not lost between the side and the cap.
inline void add_side_roots(Crossings* c, int* n, const REAL* ts, int count, REAL fa, REAL da,
                           REAL height) {
    for (int i = 0; i < count; ++i) {
        REAL s = fa + ts[i] * da;
        REAL tol = gamma_n(8) * (fabs(fa) + fabs(ts[i] * da) + height);
        if (s >= -tol && s <= height + tol) add_candidate(c, n, ts[i], 0);
    }
}
#endif

#if HAS_CYLINDERS
inline Crossings intersect_cylinder(const __global Cylinder* cy, const Ray* r) {
    Crossings c = no_crossings();
    int n = 0;
    REAL3 axis = TO_REAL3(cy->axis_height);
    REAL radius = TO_REAL(cy->base_radius.w), height = TO_REAL(cy->axis_height.w);
    REAL3 f = r->o - TO_REAL3(cy->base_radius);
    REAL fa = dot(f, axis), da = dot(r->d, axis);
    // The side is a 2D sphere problem in the plane across the axis.
    REAL3 fp = f - fa * axis, dp = r->d - da * axis;
    REAL a = dot(dp, dp), b = dot(fp, dp);
    REAL ts[2];
    if (a > (REAL)0) {
        REAL3 l = fp - (b / a) * dp;
        REAL ll = length(l), fl = length(fp);
        REAL disc = a * (radius - ll) * (radius + ll);
        if (quadratic_roots(a, b, (fl - radius) * (fl + radius), disc, &ts[0], &ts[1])) {
            add_side_roots(&c, &n, ts, 2, fa, da, height);
        }
    }
    if (cy->capped && da != (REAL)0) {
        REAL rr = radius * radius * ((REAL)1 + gamma_n(8));
        for (int cap = 0; cap < 2; ++cap) {
            REAL tc = ((cap ? height : (REAL)0) - fa) / da;
            REAL3 q = fp + tc * dp;
            if (dot(q, q) <= rr) add_candidate(&c, &n, tc, 1 + cap);
        }
    }
    if (n == 1) c.t[1] = REAL_INF;
    return c;
}
#endif

#if HAS_CONES
inline Crossings intersect_cone(const __global Cone* co, const Ray* r) {
    Crossings c = no_crossings();
    int n = 0;
    REAL3 axis = TO_REAL3(co->axis_height);
    REAL tan_a = TO_REAL(co->apex_tan.w), height = TO_REAL(co->axis_height.w);
    REAL3 f = r->o - TO_REAL3(co->apex_tan);
    REAL fa = dot(f, axis), da = dot(r->d, axis);
    REAL3 fp = f - fa * axis, dp = r->d - da * axis;
    // |perp|^2 = tan^2 s^2 with s the distance along the axis: a quadratic in t.
    REAL k2 = tan_a * tan_a;
    REAL a = dot(dp, dp) - k2 * da * da;
    REAL b = dot(fp, dp) - k2 * fa * da;
    REAL cc = dot(fp, fp) - k2 * fa * fa;
    REAL ts[2];
    int roots = 0;
    if (a != (REAL)0) {
        if (quadratic_roots(a, b, cc, difference_of_products(b, b, a, cc), &ts[0], &ts[1])) {
            roots = 2;
        }
    } else if (b != (REAL)0) {
        // A ray parallel to a generator line crosses the double cone once.
        ts[0] = -cc / ((REAL)2 * b);
        roots = 1;
    }
    add_side_roots(&c, &n, ts, roots, fa, da, height);
    if (co->capped && da != (REAL)0) {
        REAL tc = (height - fa) / da;
        REAL3 q = fp + tc * dp;
        REAL rb = height * tan_a;
        if (dot(q, q) <= rb * rb * ((REAL)1 + gamma_n(8))) add_candidate(&c, &n, tc, 1);
    }
    if (n == 1) c.t[1] = REAL_INF;
    return c;
}
#endif

#if HAS_TRIANGLES && TRIANGLE_MOLLER_TRUMBORE
// Study variant: the textbook Moller-Trumbore test. Not watertight: rays aimed at an edge
// shared by two triangles can miss both.
inline Crossings intersect_triangle(REAL3 p0, REAL3 p1, REAL3 p2, const Ray* r) {
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

#if HAS_TRIANGLES
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
HOT REAL4 pick4(REAL4 x, REAL4 y, REAL4 z, int k) { return k == 0 ? x : (k == 1 ? y : z); }

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
    REAL4 sx = (REAL4)(r->sx), sy = (REAL4)(r->sy);
    p0x += sx * p0z;
    p0y += sy * p0z;
    p1x += sx * p1z;
    p1y += sy * p1z;
    p2x += sx * p2z;
    p2y += sy * p2z;
    REAL4 e0 = difference_of_products4(p1x, p2y, p1y, p2x);
    REAL4 e1 = difference_of_products4(p2x, p0y, p2y, p0x);
    REAL4 e2 = difference_of_products4(p0x, p1y, p0y, p1x);
#if !defined(USE_DOUBLE) && defined(cl_khr_fp64) && !TRIANGLE_NO_FP64_FALLBACK
    int zero = lane_bits4((e0 == 0.0f) | (e1 == 0.0f) | (e2 == 0.0f));
    if (zero) {
        float q[6][4], e[3][4];
        vstore4(p0x, 0, q[0]);
        vstore4(p0y, 0, q[1]);
        vstore4(p1x, 0, q[2]);
        vstore4(p1y, 0, q[3]);
        vstore4(p2x, 0, q[4]);
        vstore4(p2y, 0, q[5]);
        vstore4(e0, 0, e[0]);
        vstore4(e1, 0, e[1]);
        vstore4(e2, 0, e[2]);
        for (int k = 0; k < PACKET_WIDTH; ++k) {
            if (!(zero & (1 << k))) continue;
            e[0][k] = (float)((double)q[2][k] * (double)q[5][k] - (double)q[3][k] * q[4][k]);
            e[1][k] = (float)((double)q[4][k] * (double)q[1][k] - (double)q[5][k] * q[0][k]);
            e[2][k] = (float)((double)q[0][k] * (double)q[3][k] - (double)q[1][k] * q[2][k]);
        }
        e0 = vload4(0, e[0]);
        e1 = vload4(0, e[1]);
        e2 = vload4(0, e[2]);
    }
#endif
    MASK4 mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0));
    REAL4 det = e0 + e1 + e2;
    REAL4 sz = (REAL4)(r->sz);
    p0z *= sz;
    p1z *= sz;
    p2z *= sz;
    REAL4 t_scaled = e0 * p0z + e1 * p1z + e2 * p2z;
    // A zero or NaN det fails both sign tests.
    MASK4 ahead = ((det < 0) & (t_scaled < 0)) | ((det > 0) & (t_scaled > 0));
    int bits = lane_bits4(convert_int4(ahead & ~mixed));
    if (bits) {
        REAL4 inv_det = (REAL)1 / det;
        vstore4(t_scaled * inv_det, 0, t);
        vstore4(e1 * inv_det, 0, b1);
        vstore4(e2 * inv_det, 0, b2);
    }
    return bits;
}
#endif
#endif

#if HAS_SPHERES && !SPHERE_FP64 && !SPHERE_TEXTBOOK
// intersect_sphere's Hearn-Baker formula on the four spheres of a packet: bit k set where lane
// k has roots t0[k] <= t1[k]. Padding lanes hold NaN and have none.
HOT int intersect_sphere_packet(const __global SpherePacket* pk, const Ray* r, REAL* t0,
                                REAL* t1) {
    REAL a = dot(r->d, r->d);
    if (a == (REAL)0) return 0;
    REAL4 fx = (REAL4)(r->o.x) - TO_REAL4(vload4(0, pk->x));
    REAL4 fy = (REAL4)(r->o.y) - TO_REAL4(vload4(0, pk->y));
    REAL4 fz = (REAL4)(r->o.z) - TO_REAL4(vload4(0, pk->z));
    REAL4 radius = TO_REAL4(vload4(0, pk->radius));
    REAL4 dx = (REAL4)(r->d.x), dy = (REAL4)(r->d.y), dz = (REAL4)(r->d.z);
    REAL4 b = fx * dx + fy * dy + fz * dz;
    REAL4 along = b / a;
    REAL4 lx = fx - along * dx, ly = fy - along * dy, lz = fz - along * dz;
    REAL4 ll = sqrt(lx * lx + ly * ly + lz * lz);
    REAL4 disc = (REAL4)(a) * (radius - ll) * (radius + ll);
    // Most packets a ray reaches miss in every lane: stop before the other square roots and
    // divisions, on the same disc the roots below are masked by.
    MASK4 crossed = disc >= (REAL)0;
    if (!lane_bits4(convert_int4(crossed))) return 0;
    REAL4 fl = sqrt(fx * fx + fy * fy + fz * fz);
    // fmax keeps sqrt's argument non-negative; lanes with disc < 0 (or NaN) are masked below.
    REAL4 q = -(b + copysign(sqrt(fmax(disc, (REAL4)(0))), b));
    MASK4 roots = crossed & (q != (REAL)0);
    REAL4 r0 = ((fl - radius) * (fl + radius)) / q, r1 = q / a;
    vstore4(fmin(r0, r1), 0, t0);
    vstore4(fmax(r0, r1), 0, t1);
    return lane_bits4(convert_int4(roots));
}
#endif

#endif
