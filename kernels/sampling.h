// Where a pixel sample's random numbers (rng.h) go: its point in the pixel (a jittered grid),
// on the lens (permuted angular strata) and on each area light (stratified over the pixel's
// samples, on a square or mapped to a disc).
#ifndef CLRAY_SAMPLING_H
#define CLRAY_SAMPLING_H

#include "real.h"
#include "clray_types.h"
#include "rng.h"

// The columns of a pixel's grid of spp samples (and of an area light's strata): the integer
// ceil(sqrt(spp)), as a float sqrt may be 3 ulp off and round a square up. Its rows:
// (spp + nx - 1) / nx.
static inline int grid_columns(int spp) {
    int nx = 1;
    while (nx * nx < spp) nx++;
    return nx;
}

// The strata of a pixel's spp samples (its position in the pixel, and each area light's point):
// rows of nx = grid_columns(spp) cells, nx / spp high, and a last row of the cells that remain,
// as much wider and lower, so that every stratum has area 1 / spp and together they tile the
// unit square. Stratum k is in row k / nx, column k % nx, of a row of `cells` cells; a point of
// it is (jitter(col, r0, 1, cells), jitter(row nx, r1, cells, spp)) for r0, r1 in [0, 1), one
// formula for both axes: (start + r width) / n; lane by lane for vectors (real.h, Twins).
#define DEFINE_JITTER(T, NAME) \
    HOT T NAME(T start, T r, T width, T n) { return (start + r * width) / n; }
DEFINE_JITTER(REAL, jitter)

// The cells of stratum row `row`: nx, or what the last row holds.
static inline int row_cells(int row, int nx, int spp) { return min(nx, spp - row * nx); }

// Sample s of spp (spp > 1) inside pixel (x, y), in pixel units: a jittered point of stratum s.
static OUT_OF_LINE REAL2 jittered_position(int x, int y, int s, int spp, uint seed, uint pixel) {
    int nx = grid_columns(spp);
    int row = s / nx, cells = row_cells(row, nx, spp);
    REAL r0 = rng_uniform(seed, pixel, (uint)s, 0u);
    REAL r1 = rng_uniform(seed, pixel, (uint)s, 1u);
    return (REAL2)((REAL)x + jitter((REAL)(s % nx), r0, (REAL)1, (REAL)cells),
                   (REAL)y + jitter((REAL)(row * nx), r1, (REAL)cells, (REAL)spp));
}

// Sample s of spp inside pixel (x, y), in pixel units: the centre for one sample, else
// jittered_position. The centre is taken inline: through the call, the single-ray render of
// one sample a pixel ran 2.9 % more instructions on the mesh's primary rays and 1.2 % more on
// spheres' (docs/acceleration.md, The render against Embree, a core each).
HOT REAL2 sample_position(int x, int y, int s, int spp, uint seed, uint pixel) {
    if (spp == 1) return (REAL2)((REAL)x + REAL_C(0.5), (REAL)y + REAL_C(0.5));
    return jittered_position(x, y, s, spp, seed, pixel);
}

#if HAS_THIN_LENS
// Sample s's point on the lens disc, in (right, up) coordinates times the lens radius: spp
// angular strata, taken in an order permuted per pixel (keyed by the bits of r_2 of the sample
// index spp, which no sample uses) so that a sample's stratum is independent of its cell in the
// pixel and of its light points, with the angle jittered in the stratum by r_2 and the radius
// sqrt(r_3) (uniform over the disc).
static OUT_OF_LINE REAL2 lens_sample(int s, int spp, uint seed, uint pixel) {
    int stratum = (int)permute_stratum((uint)s, (uint)spp, rng_bits(seed, pixel, (uint)spp, 2u));
    REAL angle = (REAL)2 * PI_R * ((REAL)stratum + rng_uniform(seed, pixel, (uint)s, 2u)) /
                 (REAL)spp;
    REAL rho = sqrt(rng_uniform(seed, pixel, (uint)s, 3u));
    return (REAL2)(rho * cos(angle), rho * sin(angle));
}
#endif

// Which pixel sample is being shaded: area lights draw their sample point from it.
typedef struct {
    uint seed, pixel;
    int sample, spp;
    int nx;  // columns of the light's strata: ceil(sqrt(spp)), as the pixel's grid
} SampleKey;

// A pixel's key, its sample still to be set.
static inline SampleKey sample_key(uint seed, uint pixel, int spp) {
    SampleKey k;
    k.seed = seed;
    k.pixel = pixel;
    k.sample = 0;
    k.spp = spp;
    // Integer ceil(sqrt(spp)), as sample_position has it.
    k.nx = grid_columns(spp);
    return k;
}

#if HAS_AREA_LIGHTS
// A light's random stream has its own key: the counter 2^31 | light is above every
// 4 sample + dim the pixel's jitter uses (spp <= 4096), so the two never share a hash input.
static inline uint light_key(SampleKey k, int light) {
    return pcg_hash(pcg_hash(pcg_hash(k.seed) ^ k.pixel) ^ (0x80000000u | (uint)light));
}

static inline REAL light_uniform(uint key, int sample, uint dim) {
    return (REAL)(pcg_hash(key ^ (2u * (uint)sample + dim)) >> 8) * REAL_C(0x1p-24);
}

#if HAS_MESH_LIGHTS
// Which face of mesh light `light` a pixel sample's shadow ray aims at (lights.h, mesh_face): a
// uint32 pick. The spp samples take the spp strata of the picks, each once, as the light's
// square has them (light_square), by a permutation of their own: the faces, in the mesh's
// order, are shared out among the samples by area. Their key is the light's own stream hashed
// with bit 30, apart from the square's counters (2 sample + dim, below 2^13); within its
// stratum the pick is uniform: (stratum 2^32 + r) / spp in 64-bit integers, exact.
static inline uint light_pick(SampleKey k, int light) {
    uint pick_key = pcg_hash(light_key(k, light) ^ 0x40000000u);
    uint stratum = permute_stratum((uint)k.sample, (uint)k.spp, pick_key);
    uint r = pcg_hash(pick_key ^ (uint)k.sample);
    return (uint)((((ulong)stratum << 32) | (ulong)r) / (ulong)k.spp);
}
#endif

// A point of the unit square for this light at this pixel sample. The spp samples take the
// spp strata (DEFINE_JITTER), each once: sample s takes stratum permute_stratum(s), a
// permutation drawn per pixel and light, so that a light's strata are independent of the
// pixel's jitter cells and of every other light's strata.
static OUT_OF_LINE REAL2 light_square(SampleKey k, int light) {
    uint key = light_key(k, light);
    int stratum = (int)permute_stratum((uint)k.sample, (uint)k.spp, key);
    int row = stratum / k.nx, cells = row_cells(row, k.nx, k.spp);
    REAL r0 = light_uniform(key, k.sample, 0u), r1 = light_uniform(key, k.sample, 1u);
    return (REAL2)(jitter((REAL)(stratum % k.nx), r0, (REAL)1, (REAL)cells),
                   jitter((REAL)(row * k.nx), r1, (REAL)cells, (REAL)k.spp));
}

// Shirley and Chiu's concentric map of the unit square onto the unit disc: area-preserving, so
// the strata stay strata.
static inline REAL2 concentric_disc(REAL2 u) {
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
#endif

#endif
