// What a ray that hits nothing sees (docs/rendering.md, Background): the background colour, a
// vertical gradient, or an equirectangular environment image, by the build.
// sky: that light, weighted, where a ray of the tree leaves the scene.
#ifndef CLRAY_BACKGROUND_H
#define CLRAY_BACKGROUND_H

#include "real.h"
#include "clray_types.h"

#if HAS_BACKGROUND_IMAGE
static inline REAL3 environment_texel(__global const float4* texels, __global const Params* params,
                                      int x, int y) {
    return TO_REAL3(texels[params->background_texels + y * params->background_width + x]);
}

// Bilinear lookup of the panorama at (eu, ev): wrapping across u, rows clamped at the poles
// (row 0 at ev = 1).
static inline REAL3 environment_bilinear(__global const float4* texels,
                                         __global const Params* params, REAL eu, REAL ev) {
    int w = params->background_width, h = params->background_height;
    REAL sx = (eu - floor(eu)) * (REAL)w - REAL_C(0.5);
    REAL sy = clamp(((REAL)1 - ev) * (REAL)h - REAL_C(0.5), (REAL)0, (REAL)(h - 1));
    REAL fx0 = floor(sx), fy0 = floor(sy);
    REAL fx = sx - fx0, fy = sy - fy0;
    // Wrapping across u (x0 may be -1 or w - 1), clamped at the poles.
    int x0 = ((int)fx0 % w + w) % w, y0 = (int)fy0;
    int x1 = (x0 + 1) % w, y1 = min(y0 + 1, h - 1);
    REAL3 top = mix(environment_texel(texels, params, x0, y0),
                    environment_texel(texels, params, x1, y0), fx);
    REAL3 bottom = mix(environment_texel(texels, params, x0, y1),
                       environment_texel(texels, params, x1, y1), fx);
    return mix(top, bottom, fy);
}
#endif

static inline REAL3 background_radiance(__global const Params* params,
                                        __global const float4* texels, REAL3 d) {
#if HAS_BACKGROUND_GRADIENT || HAS_BACKGROUND_IMAGE
    // Reflected directions are unit only to rounding; the mapping wants them exactly unit.
    REAL3 u = safe_normalize(d);
#endif
#if HAS_BACKGROUND_GRADIENT
    REAL t = clamp(REAL_C(0.5) * (u.y + (REAL)1), (REAL)0, (REAL)1);
    return mix(TO_REAL3(params->background), TO_REAL3(params->background_top), t);
#elif HAS_BACKGROUND_IMAGE
    // u = 0.5 looks along -z and grows towards +x; v = 1 is straight up (image row 0).
    REAL eu = REAL_C(0.5) + atan2(u.x, -u.z) / ((REAL)2 * PI_R);
    REAL ev = REAL_C(0.5) + asin(clamp(u.y, (REAL)-1, (REAL)1)) / PI_R;
    return environment_bilinear(texels, params, eu, ev);
#else
    return TO_REAL3(params->background);
#endif
}

// Light from the sky where a ray of weight `weight` leaves the scene in direction d.
static inline REAL3 sky(const __global Params* params, const __global float4* texels, REAL3 d,
                        REAL3 weight) {
#if HAS_BACKGROUND_GRADIENT || HAS_BACKGROUND_IMAGE
    return weight * background_radiance(params, texels, d);
#else
    return weight * TO_REAL3(params->background);
#endif
}

#endif
