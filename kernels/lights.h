// Spot and area lights (docs/rendering.md, Lights): a spot light's cone, and one sample point
// per area light per pixel sample, stratified over the pixel's samples.
#ifndef CLRAY_LIGHTS_H
#define CLRAY_LIGHTS_H

#include "real.h"
#include "clray_types.h"
#include "rng.h"

// Which pixel sample is being shaded: area lights draw their sample point from it.
typedef struct {
    uint seed, pixel;
    int sample, spp;
    int nx;  // columns of the light's strata: ceil(sqrt(spp)), as the pixel's grid
} SampleKey;

// A pixel's key, its sample still to be set.
inline SampleKey sample_key(uint seed, uint pixel, int spp) {
    SampleKey k;
    k.seed = seed;
    k.pixel = pixel;
    k.sample = 0;
    k.spp = spp;
    // Integer ceil(sqrt(spp)), as sample_position has it.
    k.nx = 1;
    while (k.nx * k.nx < spp) k.nx++;
    return k;
}

#if HAS_SPOT_LIGHTS
// 1 inside the inner cone, 0 outside the outer one, smoothstep in cos between; cos_i == cos_o
// is a hard edge, and never reaches the division.
inline REAL spot_factor(const __global Light* light, REAL3 l) {
    REAL cos_t = -dot(l, TO_REAL3(light->axis_u));
    REAL cos_o = TO_REAL(light->axis_u.w), cos_i = TO_REAL(light->axis_v.w);
    if (!(cos_t > cos_o)) return 0;
    if (cos_t >= cos_i) return 1;
    REAL t = (cos_t - cos_o) / (cos_i - cos_o);
    return t * t * ((REAL)3 - (REAL)2 * t);
}
#endif

#if HAS_AREA_LIGHTS
// A light's random stream has its own key: the counter 2^31 | light is above every
// 4 sample + dim the pixel's jitter uses (spp <= 4096), so the two never share a hash input.
inline uint light_key(SampleKey k, int light) {
    return pcg_hash(pcg_hash(pcg_hash(k.seed) ^ k.pixel) ^ (0x80000000u | (uint)light));
}

inline REAL light_uniform(uint key, int sample, uint dim) {
    return (REAL)(pcg_hash(key ^ (2u * (uint)sample + dim)) >> 8) * (REAL)(1.0 / 16777216.0);
}

// A point of the unit square for this light at this pixel sample. The spp samples take the
// spp strata of a grid of rows of nx cells (the last row may hold fewer, its cells as much
// wider as the row is shorter, so every stratum has area 1/spp), each stratum once: sample s
// takes stratum (s + rotation) mod spp, the rotation drawn per pixel and light so that a
// light's strata are not tied to the pixel's jitter cells.
inline REAL2 light_square(SampleKey k, int light) {
    uint key = light_key(k, light);
    int stratum = (int)(((uint)k.sample + key % (uint)k.spp) % (uint)k.spp);
    int row = stratum / k.nx, col = stratum % k.nx;
    int cells = min(k.nx, k.spp - row * k.nx);
    REAL r0 = light_uniform(key, k.sample, 0u), r1 = light_uniform(key, k.sample, 1u);
    return (REAL2)(((REAL)col + r0) / (REAL)cells,
                   ((REAL)(row * k.nx) + r1 * (REAL)cells) / (REAL)k.spp);
}

// Shirley and Chiu's concentric map of the unit square onto the unit disc: area-preserving, so
// the strata stay strata.
inline REAL2 concentric_disc(REAL2 u) {
    REAL a = (REAL)2 * u.x - (REAL)1, b = (REAL)2 * u.y - (REAL)1;
    if (a == (REAL)0 && b == (REAL)0) return (REAL2)(0, 0);
    REAL r, phi;
    if (fabs(a) > fabs(b)) {
        r = a;
        phi = (PI_R / (REAL)4) * (b / a);
    } else {
        r = b;
        phi = PI_R / (REAL)2 - (PI_R / (REAL)4) * (a / b);
    }
    return (REAL2)(r * cos(phi), r * sin(phi));
}

// A sample's weight above this is clamped: light colours (<= 1e6) times material weights
// (<= 1e6) times it stay far inside float range. Irradiance from a light of radiance L is at
// most pi L, so only a sample within about 1e-10 light sizes of the shaded point reaches it.
#define AREA_WEIGHT_MAX ((REAL)1e20)

// One sample point `target` of an area light seen from p, and its weight: the factor that
// multiplies the light's colour (its radiance) in place of a point light's attenuation, so
// that weight * colour is the sample's estimate of the irradiance on a surface facing it.
// False when the sample gives nothing: behind a one-sided light, p inside a sphere light, a
// sample point within p's error bound.
inline bool sample_area_light(const __global Light* light, REAL3 p, REAL err, REAL2 u,
                              REAL3* target, REAL* weight) {
    REAL3 c = TO_REAL3(light->position);
    if (light->kind == LIGHT_SPHERE) {
        // Uniform over the cone of directions the sphere fills (pbrt's sphere sampling):
        // weight = solid angle = 2 pi (1 - cos_max).
        REAL radius = TO_REAL(light->position.w);
        REAL3 to_c = c - p;
        REAL dist = length(to_c);
        if (!(dist > radius)) return false;
        REAL s = radius / dist;
        // 1 - cos_max without cancellation for a small or distant sphere.
        REAL k = s * s / ((REAL)1 + sqrt(fmax((REAL)0, (REAL)1 - s * s)));
        REAL one_minus_cos = u.x * k;
        REAL cos_t = (REAL)1 - one_minus_cos;
        REAL sin_t = sqrt(fmax((REAL)0, one_minus_cos * ((REAL)2 - one_minus_cos)));
        REAL phi = (REAL)2 * PI_R * u.y;
        REAL3 w_c = to_c / dist, e1, e2;
        frame(w_c, &e1, &e2);
        REAL3 w = cos_t * w_c + sin_t * (cos(phi) * e1 + sin(phi) * e2);
        // The nearer crossing of the sphere along w: (d^2 - R^2) / (d cos + sqrt(R^2 - d^2
        // sin^2)), the product of the roots over the larger one, which does not cancel; in
        // units of d, so no square overflows.
        REAL root = sqrt(fmax((REAL)0, s * s - sin_t * sin_t));
        REAL t = dist * (((REAL)1 - s) * ((REAL)1 + s) / (cos_t + root));
        *target = p + t * w;
        *weight = (REAL)2 * PI_R * k;
        return true;
    }
    REAL3 y, n_l;
    if (light->kind == LIGHT_RECT) {
        REAL3 eu = TO_REAL3(light->axis_u), ev = TO_REAL3(light->axis_v);
        y = c + u.x * eu + u.y * ev;
        n_l = safe_normalize(cross(eu, ev));
    } else {
        n_l = TO_REAL3(light->axis_u);
        REAL3 e1, e2;
        frame(n_l, &e1, &e2);
        REAL2 q = TO_REAL(light->position.w) * concentric_disc(u);
        y = c + q.x * e1 + q.y * e2;
    }
    REAL3 to_y = y - p;
    REAL dist = length(to_y);
    if (!(dist > err)) return false;
    REAL cos_l = -dot(n_l, to_y / dist);
    if (!(cos_l > (REAL)0)) return false;  // one-sided: the back emits nothing
    // Area sampling: weight = area cos_l / dist^2, divided twice so dist^2 cannot underflow.
    *target = y;
    *weight = fmin(TO_REAL(light->color.w) * cos_l / dist / dist, AREA_WEIGHT_MAX);
    return true;
}
#endif

#endif
