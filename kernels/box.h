// Axis-aligned boxes (HAS_BOXES): the slab test's interval (shape.h: slab_interval) and the
// surface on the face it enters or leaves by.
#ifndef CLRAY_BOX_H
#define CLRAY_BOX_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "shape.h"

#if HAS_BOXES
static inline Crossings intersect_box(const __global Box* b, const Ray* r) {
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

// shape_surface's part for a box: *p, the ray's point on entry, put on the face crossed
// (hit->part: axis * 2 + side); its normal, error bound (gamma: the bound's factor), material
// and (u, v) into *sf.
HOT void box_surface(const __global Box* b, const Ray* r, const Hit* hit, bool want_uv,
                     REAL gamma, REAL3* p, Surface* sf) {
    REAL3 lo = TO_REAL3(b->lo), hi = TO_REAL3(b->hi);
    int axis = hit->part / 2, side = hit->part % 2;
    *p = set_comp3(*p, axis, comp3(side ? hi : lo, axis));
    sf->n_g = set_comp3((REAL3)(0, 0, 0), axis, side ? (REAL)1 : (REAL)-1);
    // The box's own magnitude too: a hit at the packed origin still gets an offset.
    sf->err = gamma * (max_abs3(lo) + max_abs3(hi));
    int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
    REAL w1 = comp3(hi, a1) - comp3(lo, a1), w2 = comp3(hi, a2) - comp3(lo, a2);
    sf->uv = (REAL2)(w1 > (REAL)0 ? (comp3(*p, a1) - comp3(lo, a1)) / w1 : (REAL)0,
                     w2 > (REAL)0 ? (comp3(*p, a2) - comp3(lo, a2)) / w2 : (REAL)0);
    sf->material = b->material;
}
#endif

#endif
