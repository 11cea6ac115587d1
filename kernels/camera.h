#ifndef CLRAY_CAMERA_H
#define CLRAY_CAMERA_H

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

inline REAL3 camera_direction(const __global Camera* camera, REAL2 sample, int width,
                              int height) {
    REAL px = (REAL)2 * sample.x / (REAL)width - (REAL)1;
    REAL py = (REAL)1 - (REAL)2 * sample.y / (REAL)height;
    REAL3 d = TO_REAL3(camera->forward) + px * TO_REAL3(camera->right) +
              py * TO_REAL3(camera->up);
    return normalize(d);
}

#endif
