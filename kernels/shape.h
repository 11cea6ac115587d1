// What the shapes share (each shape's header: plane.h, sphere.h, box.h, cylinder.h, cone.h,
// triangle.h; shapes.h dispatches over them). A test reports up to two crossings of the ray with
// the shape's surface (entry and exit for the solids), sorted, REAL_INF where there is none:
// closest-hit takes the first with t > 0, shadow rays count every crossing in range. A surface
// (hit.h) re-projects the hit onto the shape, with a bound on its rounding (ERR_ROUNDINGS).
// Formulas and their sources: docs/rendering.md and docs/acceleration.md; the study
// (docs/study/report.md) measures the textbook alternatives against them. For sample packets:
// the lanes' shape records (ShapeLanes) and surfaces (SurfaceOfLanes).
#ifndef CLRAY_SHAPE_H
#define CLRAY_SHAPE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"

typedef struct {
    REAL t[2];
    int part[2];  // which face: box axis*2 + (0 lo, 1 hi); cylinder/cone 0 side, 1/2 caps
    REAL b1, b2;  // triangle barycentrics of the (single) crossing
} Crossings;

static inline Crossings no_crossings(void) {
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
static inline void add_candidate(Crossings* c, int* n, REAL t, int part) {
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
static inline bool quadratic_roots(REAL a, REAL b, REAL c, REAL disc, REAL* t0, REAL* t1) {
    if (!(disc >= (REAL)0) || a == (REAL)0) return false;
    REAL q = -(b + copysign(sqrt(disc), b));
    if (q == (REAL)0) return false;  // tangent at the origin itself: no crossing ahead
    REAL r0 = c / q, r1 = q / a;
    *t0 = fmin(r0, r1);
    *t1 = fmax(r0, r1);
    return true;
}

// Slab test against [lo, hi] within (tmin, tmax). Compare-select keeps a NaN from 0 * inf (a
// zero direction component with the origin on a slab plane) out of the interval, and the far
// bound is widened by 1 + 2 gamma(3) so no ray slips past an edge (Ize 2013, pbrt). Which plane
// is near goes by the reciprocal's sign (Williams et al. 2005), not by comparing the two t: a
// NaN compares false, so with the origin on lo and d = -0 (inv = -inf) that comparison kept
// tf = (hi - o) * -inf = -inf as the far bound and the ray missed a box it runs along.
static inline bool slab_interval(REAL3 lo, REAL3 hi, const Ray* r, REAL* tmin, REAL* tmax,
                                 int* part0, int* part1) {
    REAL t0 = *tmin, t1 = *tmax;
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    for (int k = 0; k < 3; ++k) {
        REAL inv = comp3(r->inv_d, k), o = comp3(r->o, k);
        REAL tn = (comp3(lo, k) - o) * inv;
        REAL tf = (comp3(hi, k) - o) * inv;
        int pn = 2 * k, pf = 2 * k + 1;
        if (inv < (REAL)0) {
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

#if HAS_CYLINDERS || HAS_CONES
// Keep the side-surface roots whose axial coordinate fa + t da lies in [0, height], widened by a
// rounding bound so a ray at a rim is not lost between the side and the cap.
static inline void add_side_roots(Crossings* c, int* n, const REAL* ts, int count, REAL fa, REAL da,
                                  REAL height) {
    for (int i = 0; i < count; ++i) {
        REAL s = fa + ts[i] * da;
        REAL tol = gamma_n(8) * (fabs(fa) + fabs(ts[i] * da) + height);
        if (s >= -tol && s <= height + tol) add_candidate(c, n, ts[i], 0);
    }
}
#endif

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
#endif

// Error bounds are pbrt-style: gamma(n) times the magnitudes the point was computed from. Sixteen
// roundings is generous for every formula here and still a tiny fraction of the scene's scale.
#define ERR_ROUNDINGS 16

static inline REAL3 set_comp3(REAL3 v, int k, REAL value) {
    if (k == 0) v.x = value;
    else if (k == 1) v.y = value;
    else v.z = value;
    return v;
}

static inline REAL angle_u(REAL y, REAL x) { return REAL_C(0.5) + atan2(y, x) / ((REAL)2 * PI_R); }

// A cap disc's (u, v): its frame coordinates mapped from [-radius, radius] to [0, 1].
static inline REAL2 disc_uv(REAL3 q, REAL3 e1, REAL3 e2, REAL radius) {
    return (REAL2)(REAL_C(0.5) + REAL_C(0.5) * dot(q, e1) / radius,
                   REAL_C(0.5) + REAL_C(0.5) * dot(q, e2) / radius);
}

// (u, v) of a cylinder or cone: around the axis and along it on the side (part 0), the cap
// disc of radius cap_radius otherwise. q is the hit point relative to the base or apex.
static inline REAL2 axial_uv(REAL3 q, REAL3 axis, REAL along, int part, REAL cap_radius) {
    REAL3 e1, e2;
    frame(axis, &e1, &e2);
    if (part == 0) return (REAL2)(angle_u(dot(q, e2), dot(q, e1)), along);
    return disc_uv(q, e1, e2, cap_radius);
}

// Instances map their surfaces through matrices, and a double sphere build re-projects in
// double: those stay with shade_point.
#define SURFACE_LANES (SAMPLE_PACKETS && !HAS_INSTANCES && HAS_BVH && !SPHERE_FP64)

#if SURFACE_LANES
// The per-lane records that a lane's shape and material give its surface: for a triangle its
// corners (a, b, c) and vertex normals (na, nb, nc), for a sphere its centre (a) and radius
// (b.x), for a plane its normal (a) and point (b); the material's colour, diffuse, specular,
// shininess, ambient, emission and reflectance and, for a checker texture, its cell size,
// second colour and blend.
typedef struct {
    REALP red, green, blue, diffuse, specular, shininess, ambient, ex, ey, ez, reflect, ax, ay, az,
        bx, by, bz;
#if HAS_TRIANGLES
    REALP cx, cy, cz;
#if HAS_VERTEX_NORMALS
    REALP nax, nay, naz, nbx, nby, nbz, ncx, ncy, ncz;
    MASKP smooth;
#endif
#endif
#if HAS_TEXTURES
    REALP size, blend, red2, green2, blue2;
    MASKP checker;
#endif
    MASKP kind;
    int material[PACKET_LANES];
} ShapeLanes;

// The rows of shape_lanes' table: only those of the shapes and textures a build has.
enum {
    ROW_COLOR = 0,
    ROW_TERM = 3,
    ROW_GLOW = 6,
    ROW_REFLECT = 10,
    ROW_A = 11,
    ROW_B = 14,
    ROW_C = 17,
#if HAS_TRIANGLES
    ROW_NORMALS = 20,
#else
    ROW_NORMALS = 17,
#endif
#if HAS_TRIANGLES && HAS_VERTEX_NORMALS
    ROW_CHECKER = ROW_NORMALS + 9,
#else
    ROW_CHECKER = ROW_NORMALS,
#endif
#if HAS_TEXTURES
    SHAPE_FIELDS = ROW_CHECKER + 5
#else
    SHAPE_FIELDS = ROW_CHECKER
#endif
};

// shape_surface's point, error bound and normals, lane-wise.
typedef struct {
    REALP px, py, pz, err, gx, gy, gz, sx, sy, sz;
} SurfaceOfLanes;

// Where `mine`, *sf takes v.
HOT void take_surface(MASKP mine, const SurfaceOfLanes* v, SurfaceOfLanes* sf) {
    sf->px = mine ? v->px : sf->px;
    sf->py = mine ? v->py : sf->py;
    sf->pz = mine ? v->pz : sf->pz;
    sf->err = mine ? v->err : sf->err;
    sf->gx = mine ? v->gx : sf->gx;
    sf->gy = mine ? v->gy : sf->gy;
    sf->gz = mine ? v->gz : sf->gz;
    sf->sx = mine ? v->sx : sf->sx;
    sf->sy = mine ? v->sy : sf->sy;
    sf->sz = mine ? v->sz : sf->sz;
}
#endif

#endif
