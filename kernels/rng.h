// Counter-based random numbers: a pure function of (seed, pixel, sample, dimension), so an image
// does not depend on launch order, tiling or device.
// For sample packets rng_uniform lane-wise.
#ifndef CLRAY_RNG_H
#define CLRAY_RNG_H

#include "real.h"
#include "lanes.h"

// PCG's output hash of x, lane by lane for vectors of uints (real.h, Twins).
#define DEFINE_PCG_HASH(SPEC, T, NAME)                                  \
    SPEC T NAME(T x) {                                                  \
        T state = x * 747796405u + 2891336453u;                         \
        T word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u; \
        return (word >> 22u) ^ word;                                    \
    }
DEFINE_PCG_HASH(static inline, uint, pcg_hash)

// The 32 hashed bits behind r_dim of (seed, pixel, sample).
static inline uint rng_bits(uint seed, uint pixel, uint sample, uint dim) {
    return pcg_hash(pcg_hash(pcg_hash(seed) ^ pixel) ^ (4u * sample + dim));
}

// Uniform in [0, 1) with 24 bits, exact in float and double.
static inline REAL rng_uniform(uint seed, uint pixel, uint sample, uint dim) {
    return (REAL)(rng_bits(seed, pixel, sample, dim) >> 8) * REAL_C(0x1p-24);
}

// Which of n strata sample i takes: a permutation of 0..n-1 chosen by `key` (Kensler's hashed
// permutation, "Correlated Multi-Jittered Sampling", 2013). Each dimension draws its own key per
// pixel, so the strata one dimension gives a sample are independent of those another gives it
// (a fixed pairing would tie, say, the light point to the position in the pixel, and leave each
// pixel a bias no spp removes). The rounds are a bijection on [0, w], w + 1 the power of two at
// or above n; walking it from i < n ends at a value below n (i's own cycle holds one).
static inline uint permute_stratum(uint i, uint n, uint key) {
    uint w = n - 1u;
    w |= w >> 1;
    w |= w >> 2;
    w |= w >> 4;
    w |= w >> 8;
    w |= w >> 16;
    do {
        i ^= key;
        i *= 0xe170893du;
        i ^= key >> 16;
        i ^= (i & w) >> 4;
        i ^= key >> 8;
        i *= 0x0929eb3fu;
        i ^= key >> 23;
        i ^= (i & w) >> 1;
        i *= 1u | key >> 27;
        i *= 0x6935fa69u;
        i ^= (i & w) >> 11;
        i *= 0x74dcb303u;
        i ^= (i & w) >> 2;
        i *= 0x9e501cc3u;
        i ^= (i & w) >> 2;
        i *= 0xc860a3dfu;
        i &= w;
        i ^= i >> 5;
    } while (i >= n);
    // key % n first: i + key could wrap past 2^32, which is no multiple of n.
    return (i + key % n) % n;
}

#if SAMPLE_PACKETS
DEFINE_PCG_HASH(HOT, UINTP, pcg_hash_lanes)

// rng_uniform(seed, pixel, sample[j], dim) in lane j; pixel_key: the pixel's first two hashes,
// pcg_hash(pcg_hash(seed) ^ pixel).
HOT REALP rng_uniform_lanes(uint pixel_key, UINTP sample, uint dim) {
    UINTP bits = pcg_hash_lanes((UINTP)(pixel_key) ^ ((UINTP)(4u) * sample + (UINTP)(dim)));
    return TO_REALP(bits >> (UINTP)(8u)) * REAL_C(0x1p-24);
}
#endif

#endif
