// Cylinders (HAS_CYLINDERS), capped or open: the side as a quadratic across the axis, the caps
// as discs, and the surface on the side or cap crossed.
#ifndef CLRAY_CYLINDER_H
#define CLRAY_CYLINDER_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "shape.h"

#if HAS_CYLINDERS
static OUT_OF_LINE Crossings intersect_cylinder(const __global Cylinder* cy, const Ray* r) {
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

// shape_surface's part for a cylinder: *p, the ray's point on entry, put on its side
// (hit->part 0) or cap (1, 2); its outward normal, error bound (gamma: the bound's factor),
// material and, where want_uv, its (u, v) into *sf.
HOT void cylinder_surface(const __global Cylinder* cy, const Ray* r, const Hit* hit, bool want_uv,
                          REAL gamma, REAL3* p, Surface* sf) {
    REAL3 base = TO_REAL3(cy->base_radius), axis = TO_REAL3(cy->axis_height);
    REAL radius = TO_REAL(cy->base_radius.w), height = TO_REAL(cy->axis_height.w);
    REAL3 q = *p - base;
    REAL h = dot(q, axis);
    if (hit->part == 0) {
        REAL3 radial = safe_normalize(q - h * axis);
        *p = base + h * axis + radius * radial;
        sf->n_g = radial;
    } else {
        REAL cap = hit->part == 2 ? height : (REAL)0;
        *p += (cap - h) * axis;
        sf->n_g = hit->part == 2 ? axis : -axis;
    }
    if (want_uv) sf->uv = axial_uv(q, axis, h / height, hit->part, radius);
    sf->err = gamma * (max_abs3(*p) + max_abs3(base) + radius + height);
    sf->material = cy->material;
}
#endif

#endif
