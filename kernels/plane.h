// Planes (HAS_PLANES): unbounded, so the walks test them one by one before the BVH
// (bvh.h: consider_planes). The crossing, the surface, and for sample packets both lane-wise.
#ifndef CLRAY_PLANE_H
#define CLRAY_PLANE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shape.h"

#if HAS_PLANES
// Where r crosses the plane: its t, or infinity where it never does (parallel, or so nearly
// that t overflows).
static inline REAL plane_t(const __global Plane* pl, const Ray* r) {
    REAL3 n = TO_REAL3(pl->normal);
    REAL dn = dot3(r->d, n);
    if (dn == (REAL)0) return REAL_INF;  // parallel: never crossed
    REAL t = dot3(TO_REAL3(pl->point) - r->o, n) / dn;
    return isfinite(t) ? t : REAL_INF;
}

static inline Crossings intersect_plane(const __global Plane* pl, const Ray* r) {
    Crossings c = no_crossings();
    c.t[0] = plane_t(pl, r);
    return c;
}

// shape_surface's part for a plane: *p, the ray's point on entry, projected onto the plane;
// its normal, error bound (gamma: the bound's factor), material and, where want_uv, its (u, v)
// into *sf.
HOT void plane_surface(const __global Plane* pl, const Ray* r, const Hit* hit, bool want_uv,
                       REAL gamma, REAL3* p, Surface* sf) {
    REAL3 n = TO_REAL3(pl->normal), q = TO_REAL3(pl->point);
    *p -= dot3(*p - q, n) * n;
    sf->n_g = n;
    sf->err = gamma * (max_abs3(*p) + max_abs3(q));
    if (want_uv) {
        REAL3 e1, e2;
        frame(n, &e1, &e2);
        sf->uv = (REAL2)(dot(*p - q, e1) + TO_REAL(pl->point.w),
                         dot(*p - q, e2) + TO_REAL(pl->normal.w));
    }
    sf->material = pl->material;
}

#if SAMPLE_PACKETS
// intersect_plane lane-wise: the lanes that cross the plane, with their t.
HOT MASKP plane_lanes(const __global Plane* plane, const RayPacket* p, REALP* t) {
    REAL3 n = TO_REAL3(plane->normal), q = TO_REAL3(plane->point);
    REALP nx = (REALP)(n.x), ny = (REALP)(n.y), nz = (REALP)(n.z);
    REALP dn = dot_lanes(p->dx, p->dy, p->dz, nx, ny, nz);
    *t = dot_lanes((REALP)(q.x) - p->ox, (REALP)(q.y) - p->oy, (REALP)(q.z) - p->oz, nx, ny, nz) /
         dn;
    // isfinite as one comparison: PoCL's vector isfinite tests the bits in integer lanes.
    return (dn != (REAL)0) & (fabs(*t) < REAL_INF);
}

#if SURFACE_LANES
// plane_surface lane-wise: the point projected onto the plane.
HOT SurfaceOfLanes plane_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                       const PacketHit* h) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP px = r->ox + h->t * r->dx;
    REALP py = r->oy + h->t * r->dy;
    REALP pz = r->oz + h->t * r->dz;
    REALP e = dot_lanes(px - g->bx, py - g->by, pz - g->bz, g->ax, g->ay, g->az);
    v.px = px - e * g->ax;
    v.py = py - e * g->ay;
    v.pz = pz - e * g->az;
    v.gx = v.sx = g->ax;
    v.gy = v.sy = g->ay;
    v.gz = v.sz = g->az;
    v.err = gamma * (fmax(fabs(v.px), fmax(fabs(v.py), fabs(v.pz))) +
                     fmax(fabs(g->bx), fmax(fabs(g->by), fabs(g->bz))));
    return v;
}

// shape_record for a plane: its normal (a) and point (b).
HOT bool plane_record(const SceneRefs* s, int i, int part, REAL* f, int stride, int* material,
                      LANE_INT* smooth) {
    const __global Plane* pl = s->planes + i;
    REAL3 n = TO_REAL3(pl->normal), q = TO_REAL3(pl->point);
    f[ROW_A * stride] = n.x;
    f[(ROW_A + 1) * stride] = n.y;
    f[(ROW_A + 2) * stride] = n.z;
    f[ROW_B * stride] = q.x;
    f[(ROW_B + 1) * stride] = q.y;
    f[(ROW_B + 2) * stride] = q.z;
    *material = pl->material;
    return true;
}
#endif
#endif
#endif

#endif
