// A ray as the scene's queries take it: origin and direction, with the set-up every test of it
// shares (the reciprocal direction for the slab tests; the axis permutation and shear of the
// watertight triangle test, which a single-ray closest-hit walk may make only when it reaches a
// leaf: make_walk_ray).
#ifndef CLRAY_RAY_H
#define CLRAY_RAY_H

#include "real.h"
#include "clray_types.h"

typedef struct {
    REAL3 o, d;
    REAL3 inv_d;     // 1/d, +-inf for zero components (the slab test relies on it)
    int kx, ky, kz;  // Woop-Benthin-Wald axis permutation: kz is d's largest component
    REAL sx, sy, sz; // ... and the shear that maps d to +z (set only where triangles exist;
                     // kz < 0 where not made yet: make_walk_ray)
} Ray;

// LAZY_SHEAR: the single-ray closest-hit walks make the triangle set-up at the first leaf a ray
// reaches (bvh.h, walk_closest), where work-items run one after another (CPU drivers). Not in
// a GPU build: there the walk's copy of the ray, whose address the out-of-line set-up takes,
// would live in private memory a GPU keeps off its registers (not measured on a GPU).
#define LAZY_SHEAR (HAS_TRIANGLES && SERIAL_WORK_ITEMS)

// The origin, the direction and the reciprocal, without the triangle set-up (kz < 0).
HOT Ray unsheared_ray(REAL3 o, REAL3 d) {
    Ray r;
    r.o = o;
    r.d = d;
    r.inv_d = (REAL)1 / d;
    r.kz = -1;
    return r;
}

#if HAS_TRIANGLES
// The watertight triangle test's set-up: the axis permutation and the shear.
HOT void shear_ray(Ray* r) {
    REAL3 d = r->d;
    REAL3 ad = fabs(d);
    r->kz = ad.x > ad.y ? (ad.x > ad.z ? 0 : 2) : (ad.y > ad.z ? 1 : 2);
    r->kx = r->kz == 2 ? 0 : r->kz + 1;
    r->ky = r->kx == 2 ? 0 : r->kx + 1;
    REAL dz = comp3(d, r->kz);
    if (dz < (REAL)0) {
        int swap = r->kx;
        r->kx = r->ky;
        r->ky = swap;
    }
    // dz != 0: it is the largest component of a non-zero direction. One vector division, not
    // three: each lane is the same correctly rounded quotient, and a ray's set-up had waited
    // on three divisions in turn (docs/acceleration.md).
    REAL3 shear = (REAL3)(-comp3(d, r->kx), -comp3(d, r->ky), (REAL)1) / dz;
    r->sx = shear.x;
    r->sy = shear.y;
    r->sz = shear.z;
}
#endif

STAGE Ray make_ray(REAL3 o, REAL3 d) {
    Ray r = unsheared_ray(o, d);
#if HAS_TRIANGLES
    shear_ray(&r);
#endif
    return r;
}

#if LAZY_SHEAR
// A ray for a single-ray closest-hit walk, which makes its triangle set-up at the first leaf:
// most rays of a scene that fills little of the frame reach none. The mesh's primary rays
// (13 % hit, 13.5 % reach a leaf): 557 -> 514 instructions a ray in the render, 434 -> 394 in
// intersect_rays (docs/acceleration.md).
STAGE Ray make_walk_ray(REAL3 o, REAL3 d) { return unsheared_ray(o, d); }

// shear_ray for a walk's first leaf. Out of line: inline, the compiler hoisted the set-up out
// of the walk's loop to every ray's start, where it ran whether or not the ray reached a leaf.
OUT_OF_LINE void shear_walk_ray(Ray* r) { shear_ray(r); }
#else
#define make_walk_ray make_ray
#endif

#endif
