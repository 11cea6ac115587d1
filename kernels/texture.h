// Surface colour: the material colour, or a texel blended with it (docs/rendering.md); for
// sample packets the checker lane-wise.
#ifndef CLRAY_TEXTURE_H
#define CLRAY_TEXTURE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "lanes.h"
#include "shape.h"

// Whether a crossing's v runs from pole to pole or rim to rim (a sphere; a cylinder's or
// cone's side, part 0), so that its two ends are not neighbours on the surface.
static inline bool v_ends_apart(int ref, int part) {
    int kind = ref >> PRIM_TYPE_SHIFT;
    return kind == PRIM_SPHERE || ((kind == PRIM_CYLINDER || kind == PRIM_CONE) && part == 0);
}

#if HAS_TEXTURES
static inline REAL3 texel_at(const SceneRefs* s, const __global Texture* tx, int x, int y) {
    return TO_REAL3(s->texels[tx->texel_offset + y * tx->width + x]);
}

// Wrap a coordinate into [0, 1); a non-finite one (a degenerate uv) maps to 0.
static inline REAL wrap01(REAL x) {
    if (!isfinite(x)) return 0;
    REAL f = x - floor(x);
    return f < (REAL)1 ? f : 0;
}

// Bilinear at uv, wrapping between repeated tiles; where ends_apart, v is first held within
// half a texel row of its outermost ends (0 and repeat_v), so that a pole or rim does not
// blend the image's first row with its last as wrapping would. fmax and fmin, not clamp:
// with repeat_v * h < 1 the bounds cross, where clamp is undefined (and a NaN gets the low
// bound, as it would from a clamp).
static OUT_OF_LINE REAL3 image_texel(const SceneRefs* s, const __global Texture* tx, REAL2 uv,
                                     bool ends_apart) {
    int w = tx->width, h = tx->height;
    REAL sx = wrap01(uv.x * TO_REAL(tx->repeat_u)) * (REAL)w - REAL_C(0.5);
    REAL tv = uv.y * TO_REAL(tx->repeat_v);
    if (ends_apart) {
        REAL half_row = REAL_C(0.5) / (REAL)h;
        tv = fmin(fmax(tv, half_row), TO_REAL(tx->repeat_v) - half_row);
    }
    REAL sy = ((REAL)1 - wrap01(tv)) * (REAL)h - REAL_C(0.5);
    REAL fx0 = floor(sx), fy0 = floor(sy);
    REAL fx = sx - fx0, fy = sy - fy0;
    // Bilinear with wrap-around: x0 may be -1 or w - 1 here, y0 likewise.
    int x0 = ((int)fx0 % w + w) % w, y0 = ((int)fy0 % h + h) % h;
    int x1 = (x0 + 1) % w, y1 = (y0 + 1) % h;
    REAL3 top = mix(texel_at(s, tx, x0, y0), texel_at(s, tx, x1, y0), fx);
    REAL3 bottom = mix(texel_at(s, tx, x0, y1), texel_at(s, tx, x1, y1), fx);
    return mix(top, bottom, fy);
}

// Whether the checker's cell holding q (in cells) is an odd one, lane by lane for vectors
// (real.h, Twins; M: what comparing Ts gives). The parity of the integer-valued sum, exactly
// (fmod is a slow library call here); beyond 2^24 (2^53 in double) every sum is even, and a NaN
// or inf is neither.
#define DEFINE_CHECKER_ODD(T, M, NAME)                                  \
    HOT M NAME(T qx, T qy, T qz) {                                      \
        T cells = floor(qx) + floor(qy) + floor(qz);                    \
        return cells - (REAL)2 * floor(cells * REAL_C(0.5)) == (REAL)1;   \
    }
DEFINE_CHECKER_ODD(REAL, int, checker_odd)

// 3D checker at the hit point moved a quarter cell into the surface (n_f faces the viewer),
// so a surface lying on a cell boundary gets one stable colour.
static inline REAL3 checker_texel(const __global Texture* tx, REAL3 color, REAL3 p, REAL3 n_f) {
    REAL size = TO_REAL(tx->size);
    REAL3 q = (p - REAL_C(0.25) * size * n_f) / size;
    return checker_odd(q.x, q.y, q.z) ? TO_REAL3(tx->color2) : color;
}
#endif

// Only image textures read (u, v); the checker is a solid texture of the hit point.
static inline bool material_needs_uv(const SceneRefs* s, int material) {
#if HAS_TEXTURES
    int t = s->materials[material].texture;
    return t >= 0 && s->textures[t].kind == TEXTURE_IMAGE;
#else
    return false;
#endif
}

// p_world: the hit point in world space (the checker is a world-space solid texture).
// ends_apart: v_ends_apart of the crossing.
static inline REAL3 surface_color(const SceneRefs* s, const __global Material* m, REAL3 p_world,
                                  REAL3 n_f, REAL2 uv, bool ends_apart) {
    REAL3 color = TO_REAL3(m->color);
#if HAS_TEXTURES
    if (m->texture >= 0) {
        const __global Texture* tx = s->textures + m->texture;
        REAL3 texel = tx->kind == TEXTURE_CHECKER ? checker_texel(tx, color, p_world, n_f)
                                                  : image_texel(s, tx, uv, ends_apart);
        REAL blend = TO_REAL(tx->blend);
        return blend * texel + ((REAL)1 - blend) * color;
    }
#endif
    return color;
}

#if SURFACE_LANES && HAS_TEXTURES
DEFINE_CHECKER_ODD(REALP, MASKP, checker_odd_lanes)

// surface_color's checker, lane-wise: where g->checker, g's colour becomes the texture's.
HOT void checker_lanes(ShapeLanes* g, const __global Camera* camera, const SurfaceOfLanes* sf,
                       MASKP entering) {
    REAL3 world = TO_REAL3(camera->world);
    REALP nx = entering ? sf->gx : -sf->gx;
    REALP ny = entering ? sf->gy : -sf->gy;
    REALP nz = entering ? sf->gz : -sf->gz;
    REALP size = g->size;
    REALP qx = (sf->px + world.x - REAL_C(0.25) * size * nx) / size;
    REALP qy = (sf->py + world.y - REAL_C(0.25) * size * ny) / size;
    REALP qz = (sf->pz + world.z - REAL_C(0.25) * size * nz) / size;
    MASKP second = checker_odd_lanes(qx, qy, qz);
    REALP red = second ? g->red2 : g->red;
    REALP green = second ? g->green2 : g->green;
    REALP blue = second ? g->blue2 : g->blue;
    REALP blend = g->blend;
    g->red = g->checker ? blend * red + ((REAL)1 - blend) * g->red : g->red;
    g->green = g->checker ? blend * green + ((REAL)1 - blend) * g->green : g->green;
    g->blue = g->checker ? blend * blue + ((REAL)1 - blend) * g->blue : g->blue;
}
#endif

#endif
