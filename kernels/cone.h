// Cones (HAS_CONES), capped or open: the side as a quadratic in t, the base cap as a disc, and
// the surface on the side or cap crossed.
#ifndef CLRAY_CONE_H
#define CLRAY_CONE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "shape.h"

#if HAS_CONES
static OUT_OF_LINE Crossings intersect_cone(const __global Cone* co, const Ray* r) {
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
        // The discriminant b^2 - a cc is the same from any origin on the line, so it is taken
        // from g, the line's point nearest the apex, as the sphere's Hearn-Baker form takes it
        // from the point nearest the centre: from a far origin b^2 and a cc are both of the
        // order |f|^2 |d|^2 and their roundings swamp the difference (from 1,000 heights
        // away, 213 of 2,000 rays aimed through the axis missed), while g is within the
        // cone's own size of the apex wherever the line meets the cone. The roots keep the
        // origin's b and cc (Press pair): the one near the origin needs its small cc. A
        // direction whose square underflows (dd = 0) makes g NaN or infinite, and with it the
        // discriminant; a NaN one quadratic_roots refuses, and an infinite one needs an a of
        // the same order as dd, which is then 0 itself outside the most extreme cones.
        REAL dd = dot(r->d, r->d);
        REAL3 g = f - (dot(f, r->d) / dd) * r->d;
        REAL ga = dot(g, axis);
        REAL3 gp = g - ga * axis;
        REAL gb = dot(gp, dp) - k2 * ga * da;
        REAL gc = dot(gp, gp) - k2 * ga * ga;
        if (quadratic_roots(a, b, cc, difference_of_products(gb, gb, a, gc), &ts[0], &ts[1])) {
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

// shape_surface's part for a cone: *p, the ray's point on entry, put on its side (hit->part 0)
// or base cap (1); its outward normal, error bound (gamma: the bound's factor), material and,
// where want_uv, its (u, v) into *sf.
HOT void cone_surface(const __global Cone* co, const Ray* r, const Hit* hit, bool want_uv,
                      REAL gamma, REAL3* p, Surface* sf) {
    REAL3 apex = TO_REAL3(co->apex_tan), axis = TO_REAL3(co->axis_height);
    REAL tan_a = TO_REAL(co->apex_tan.w), height = TO_REAL(co->axis_height.w);
    REAL3 q = *p - apex;
    REAL h = dot(q, axis);
    if (hit->part == 0) {
        REAL3 radial = q - h * axis;
        REAL rl = length(radial);
        if (rl > (REAL)0) {
            radial /= rl;
            *p = apex + h * axis + (h * tan_a) * radial;
            // Outward normal of |perp| = tan * s is radial - tan * axis, normalised.
            sf->n_g = (radial - tan_a * axis) / sqrt((REAL)1 + tan_a * tan_a);
        } else {
            sf->n_g = -axis;  // the apex: any choice is a limit; point back out
        }
    } else {
        *p += (height - h) * axis;
        sf->n_g = axis;
    }
    if (want_uv) sf->uv = axial_uv(q, axis, h / height, hit->part, height * tan_a);
    sf->err = gamma * (max_abs3(*p) + max_abs3(apex) + height * ((REAL)1 + tan_a));
    sf->material = co->material;
}
#endif

#endif
