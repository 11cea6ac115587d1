// Counter-based random numbers: a pure function of (seed, pixel, sample, dimension), so an image
// does not depend on launch order, tiling or device.
#ifndef CLRAY_RNG_H
#define CLRAY_RNG_H

#include "real.h"

inline uint pcg_hash(uint x) {
    uint state = x * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform in [0, 1) with 24 bits, exact in float and double.
inline REAL rng_uniform(uint seed, uint pixel, uint sample, uint dim) {
    uint key = pcg_hash(pcg_hash(pcg_hash(seed) ^ pixel) ^ (4u * sample + dim));
    return (REAL)(key >> 8) * (REAL)(1.0 / 16777216.0);
}

#endif
