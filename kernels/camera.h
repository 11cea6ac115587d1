#ifndef CLRAY_CAMERA_H
#define CLRAY_CAMERA_H

#include "real.h"
#include "clray_types.h"
#include "rng.h"

// Sample s of spp inside pixel (x, y), in pixel units: the centre for one sample, else a jittered
// point in cell (s mod nx, s div nx) of an nx x ny grid.
inline REAL2 sample_position(int x, int y, int s, int spp, uint seed, uint pixel) {
    if (spp == 1) return (REAL2)((REAL)x + (REAL)0.5, (REAL)y + (REAL)0.5);
    // Integer ceil(sqrt(spp)): a float sqrt may be 3 ulp off and round a square up.
    int nx = 1;
    while (nx * nx < spp) nx++;
    int ny = (spp + nx - 1) / nx;
    REAL r0 = rng_uniform(seed, pixel, (uint)s, 0u);
    REAL r1 = rng_uniform(seed, pixel, (uint)s, 1u);
    return (REAL2)((REAL)x + ((REAL)(s % nx) + r0) / (REAL)nx,
                   (REAL)y + ((REAL)(s / nx) + r1) / (REAL)ny);
}

// Image point `sample` (pixel units) as (x, y) in [-1, 1] on the image plane, y up.
inline REAL2 image_plane_point(REAL2 sample, int width, int height) {
    return (REAL2)((REAL)2 * sample.x / (REAL)width - (REAL)1,
                   (REAL)1 - (REAL)2 * sample.y / (REAL)height);
}

inline REAL3 camera_direction(const __global Camera* camera, REAL2 sample, int width,
                              int height) {
    REAL2 p = image_plane_point(sample, width, height);
    REAL3 d = TO_REAL3(camera->forward) + p.x * TO_REAL3(camera->right) +
              p.y * TO_REAL3(camera->up);
    return normalize(d);
}

#if HAS_THIN_LENS || HAS_ORTHOGRAPHIC
#if HAS_THIN_LENS
// Sample s's point on the lens disc, in (right, up) coordinates times the lens radius: spp
// angular strata, taken in an order shifted per pixel (by r_2 of the sample index spp, which no
// sample uses) so that a sample's stratum does not follow its cell in the pixel, with the
// angle jittered in the stratum by r_2 and the radius sqrt(r_3) (uniform over the disc).
inline REAL2 lens_sample(int s, int spp, uint seed, uint pixel) {
    // Integer arithmetic on the 24 bits of r_2, so the shift is the reference's exactly.
    uint bits = (uint)(rng_uniform(seed, pixel, (uint)spp, 2u) * (REAL)16777216);
    int shift = (int)(((ulong)bits * (ulong)spp) >> 24);
    int stratum = (s + shift) % spp;
    REAL angle = (REAL)2 * PI_R * ((REAL)stratum + rng_uniform(seed, pixel, (uint)s, 2u)) /
                 (REAL)spp;
    REAL rho = sqrt(rng_uniform(seed, pixel, (uint)s, 3u));
    return (REAL2)(rho * cos(angle), rho * sin(angle));
}
#endif

// The camera ray of sample s at image point `sample` (pixel units): from the eye (a
// perspective camera) or from the image point on the view plane (orthographic), then, with a
// lens, from a point of the lens towards the same point of the focus plane.
inline void camera_ray(const __global Camera* camera, REAL2 sample, int width, int height,
                       int s, int spp, uint seed, uint pixel, REAL3* o, REAL3* d) {
    REAL2 p = image_plane_point(sample, width, height);
    REAL3 across = p.x * TO_REAL3(camera->right) + p.y * TO_REAL3(camera->up);
    // aim: from the origin to the ray's point on the focus plane, per unit of focus distance
    // (its component along forward is 1).
#if HAS_ORTHOGRAPHIC
    *o = TO_REAL3(camera->position) + across;
    REAL3 aim = TO_REAL3(camera->forward);
#else
    *o = TO_REAL3(camera->position);
    REAL3 aim = TO_REAL3(camera->forward) + across;
#endif
#if HAS_THIN_LENS
    REAL2 l = lens_sample(s, spp, seed, pixel);
    REAL3 lens = l.x * TO_REAL3(camera->lens_u) + l.y * TO_REAL3(camera->lens_v);
    // aim's component along forward is 1 and the lens lies across forward, so this is at
    // least 1 long; the loader keeps lens / focus distance below 1e6, well inside float32.
    *d = normalize(aim - TO_REAL(camera->lens_u.w) * lens);
    *o += lens;
#else
    *d = normalize(aim);
#endif
}
#endif

#endif
