// What a closest-hit query finds (Hit) and the surface there that shading reads (Surface).
#ifndef CLRAY_HIT_H
#define CLRAY_HIT_H

#include "real.h"
#include "clray_types.h"

typedef struct {
    REAL t;
    int ref;  // PRIM_* << PRIM_TYPE_SHIFT | index; meaningful when t < REAL_INF
    int part;
    REAL b1, b2;
    int instance;  // the instance `ref` was crossed in (ref is then in its group), or -1
} Hit;

typedef struct {
    REAL3 p;    // on the surface (re-projected where the shape allows)
    REAL3 n_g;  // geometric normal, outward (planes: as given; triangles: by winding)
    REAL3 n_s;  // shading normal on the same side as n_g
    REAL err;   // bound on the rounding error of p, per component
    REAL2 uv;
    int material;
#if HAS_VERTEX_COLORS
    REAL3 tint;  // the vertex colours blended (white off vertex-coloured triangles)
#endif
} Surface;

// A query's start: no hit, t = inf; for one ray (H: Hit) or every lane (PacketHit, T and M
// its REALP and MASKP), written once (real.h, Twins). REST: what the one form has beyond the
// other (a single ray's instance).
#define DEFINE_NO_HIT(SPEC, H, T, M, NAME, REST) \
    SPEC H NAME(void) {                          \
        H h;                                     \
        h.t = (T)(REAL_INF);                     \
        h.ref = (M)(-1);                         \
        h.part = (M)(0);                         \
        h.b1 = (T)(0);                           \
        h.b2 = (T)(0);                           \
        REST                                     \
        return h;                                \
    }

#endif
