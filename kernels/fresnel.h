// The share of a transmissive material's weight that a surface reflects (docs/rendering.md,
// Fresnel): exact for an unpolarised dielectric, or Schlick's approximation (study variant).
#ifndef CLRAY_FRESNEL_H
#define CLRAY_FRESNEL_H

#include "real.h"

#if HAS_FRESNEL
// eta = n1 / n2; cos_i, cos_t >= 0 the cosines of the incident and refracted rays.
static inline REAL fresnel_reflectance(REAL eta, REAL cos_i, REAL cos_t) {
#if FRESNEL_SCHLICK
    REAL r0 = ((REAL)1 - eta) / ((REAL)1 + eta);  // eta > 0: IORs are positive
    r0 *= r0;
    // The cosine on the less dense side: past the critical angle Schlick would not reach 1.
    REAL c = (REAL)1 - (eta > (REAL)1 ? cos_t : cos_i);
    REAL c2 = c * c;
    return r0 + ((REAL)1 - r0) * c2 * c2 * c;
#else
    REAL ds = eta * cos_i + cos_t, dp = cos_i + eta * cos_t;
    // Both vanish only at grazing incidence between equal media: the limit there is 1.
    if (!(ds > (REAL)0) || !(dp > (REAL)0)) return (REAL)1;
    REAL rs = (eta * cos_i - cos_t) / ds, rp = (cos_i - eta * cos_t) / dp;
    return REAL_C(0.5) * (rs * rs + rp * rp);
#endif
}
#endif

#endif
