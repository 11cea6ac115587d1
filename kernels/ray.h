// A ray as the scene's queries take it: origin and direction, with the set-up every test of it
// shares (the reciprocal direction for the slab tests; the axis permutation and shear of the
// watertight triangle test).
#ifndef CLRAY_RAY_H
#define CLRAY_RAY_H

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
    // dz != 0: it is the largest component of a non-zero direction. One vector division, not
    // three: each lane is the same correctly rounded quotient, and a ray's set-up had waited
    // on three divisions in turn (docs/acceleration.md).
    REAL3 shear = (REAL3)(-comp3(d, r.kx), -comp3(d, r.ky), (REAL)1) / dz;
    r.sx = shear.x;
    r.sy = shear.y;
    r.sz = shear.z;
#endif
    return r;
}

#endif
