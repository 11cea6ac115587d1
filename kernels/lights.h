// Lights (docs/rendering.md, Lights): a light's shadow ray from a surface and what it brings
// there (light_ray: point, directional and spot lights, and one sample point per area light per
// pixel sample), and its Phong term (light_term); for sample packets a point light's lane-wise.
#ifndef CLRAY_LIGHTS_H
#define CLRAY_LIGHTS_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shape.h"
#include "surface.h"
#include "sampling.h"

#if HAS_SPOT_LIGHTS
// 1 inside the inner cone, 0 outside the outer one, smoothstep between; vers_i == vers_o is a
// hard edge, and never reaches the division. The cone is measured in versines (vers = 1 - cos),
// not cosines: the cos of a cone under about 0.02 degrees rounds to 1 in float32, its versine
// (clray/lights/spot.py packs 2 sin^2(angle / 2)) does not. The ray's, vers_t, is
// |l + axis|^2 / 2 for unit l and axis (l = -axis on the axis): l + axis is near exact there,
// where 1 + dot(l, axis) would cancel, and the lengths' roundings enter only squared.
static inline REAL spot_factor(const __global Light* light, REAL3 l) {
    REAL3 s = l + TO_REAL3(light->axis_u);
    REAL vers_t = dot3(s, s) / (REAL)2;
    REAL vers_o = TO_REAL(light->axis_u.w), vers_i = TO_REAL(light->axis_v.w);
    if (!(vers_t < vers_o)) return 0;
    if (vers_t <= vers_i) return 1;
    REAL t = (vers_o - vers_t) / (vers_o - vers_i);
    return t * t * ((REAL)3 - (REAL)2 * t);
}
#endif

#if HAS_AREA_LIGHTS
// A sample's weight above this is clamped: light colours (<= 1e6) times material weights
// (<= 1e6) times it stay far inside float range. Irradiance from a light of radiance L is at
// most pi L, so only a sample within about 1e-10 light sizes of the shaded point reaches it.
#define AREA_WEIGHT_MAX (REAL_C(1e20))

// The lights sampled over their area. Kinds are labels (clray_types.h): named, never ordered.
static inline bool is_area_light(int kind) {
    return kind == LIGHT_RECT || kind == LIGHT_DISC || kind == LIGHT_SPHERE ||
           kind == LIGHT_TRIANGLE || kind == LIGHT_MESH;
}

#if HAS_MESH_LIGHTS
// The face of a mesh light (clray/lights/mesh.py) that `pick` takes: the first whose threshold
// is above it (the thresholds are the faces' cumulative share of the area in units of 2^-32,
// the last's 2^32 stored as 0, never compared), found by bisection; *weight is one over its
// probability, 2^32 over its width in picks, in 64-bit integers: the last face's width is
// 2^32 less the one below, all 2^32 where the faces before it share no picks.
static inline const __global Light* mesh_face(const __global Light* lights,
                                              const __global Light* mesh, uint pick,
                                              REAL* weight) {
    const __global Light* faces = lights + mesh->pad0;
    int lo = 0, hi = mesh->pad1 - 1;  // the face is in [lo, hi]
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (pick < (uint)faces[mid].pad0) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    ulong below = lo > 0 ? (ulong)(uint)faces[lo - 1].pad0 : 0ul;
    ulong above = lo < mesh->pad1 - 1 ? (ulong)(uint)faces[lo].pad0 : 0x100000000ul;
    // A face of no width is never picked, so the width here is at least 1.
    *weight = REAL_C(4294967296.0) / (REAL)(above - below);
    return faces + lo;
}
#endif

// One sample point `target` of an area light seen from p, and its weight: the factor that
// multiplies the light's colour (its radiance) in place of a point light's attenuation, so
// that weight * colour is the sample's estimate of the irradiance on a surface facing it.
// False when the sample gives nothing: behind a one-sided light, p inside a sphere light, a
// sample point within p's error bound.
static OUT_OF_LINE bool sample_area_light(const __global Light* light, REAL3 p, REAL err, REAL2 u,
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
        // w_c is computed, so at |w_c.x| near 0.9 the builds and the reference may rotate the
        // samples differently: the same distribution, another pattern of noise.
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
    if (light->kind == LIGHT_RECT || light->kind == LIGHT_TRIANGLE) {
        REAL3 eu = TO_REAL3(light->axis_u), ev = TO_REAL3(light->axis_v);
        // A triangle folds the square's far half onto its near one: uniform by area still.
        if (light->kind == LIGHT_TRIANGLE && u.x + u.y > (REAL)1) {
            u = (REAL2)((REAL)1 - u.x, (REAL)1 - u.y);
        }
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

// A light's falloff at distance dist: 1 / (k.x + k.y dist + k.z dist^2) (k: its attenuation),
// at most 1, and 1 where the denominator is not positive; lane by lane for vectors (real.h,
// Twins). LESSER, not fmin: a positive denominator's reciprocal is never NaN.
#define DEFINE_FALLOFF(T, NAME)                                                  \
    HOT T NAME(const __global Light* light, T dist) {                            \
        REAL3 k = TO_REAL3(light->attenuation);                                  \
        T denom = (T)(k.x) + k.y * dist + k.z * dist * dist;                     \
        return denom > (REAL)0 ? LESSER((T)(1), (REAL)1 / denom) : (T)(1);       \
    }
DEFINE_FALLOFF(REAL, falloff)

// x^s for the specular term: by repeated squaring where s is a whole number up to 4096 (at most
// 2 log2(s) multiplications: x in [0.5, 1] within 0.8 s ulp of x^s, 100 ulp for s = 128, far
// below a 16-bit code), else as exp2(s log2 x) (about 0.35 s ulp). Squaring took the spheres
// scene's kernel 9 to 14 % faster than exp2 and log2; PoCL's full-precision pow costs several
// times more than either.
// The squaring: x^n for whole n >= 0, lane by lane for vectors (real.h, Twins; N: T's integers,
// ANY: whether a comparison of Ns holds in any lane).
#define DEFINE_POWER_BY_SQUARING(T, N, ANY, NAME)        \
    HOT T NAME(T x, N n) {                               \
        T r = (T)(1);                                    \
        while (ANY(n != 0)) {                            \
            r = (n & 1) != 0 ? r * x : r;                \
            x *= x;                                      \
            n >>= 1;                                     \
        }                                                \
        return r;                                        \
    }
#define ANY_SCALAR(m) (m)
DEFINE_POWER_BY_SQUARING(REAL, int, ANY_SCALAR, power_by_squaring)

HOT REAL phong_power(REAL x, REAL s) {
    if (!(s >= (REAL)0 && s <= (REAL)4096 && s == floor(s))) return exp2(s * log2(x));
    return power_by_squaring(x, (int)s);
}

// Light i's shadow ray from the surface (origin off it, towards the light or its sample, up to
// tmax) and what the light brings if nothing blocks it: direction l, attenuation and n.l. False
// when the light gives nothing there, and no shadow ray is traced. key: the pixel sample, which
// picks area lights' samples.
STAGE bool light_ray(const SceneRefs* s, const Surface* sf, REAL3 n, int i, SampleKey key,
                     REAL3* l_out, REAL* atten_out, REAL* ndl_out, Ray* shadow, REAL* tmax_out) {
    const __global Light* light = s->lights + i;
    REAL3 l;
    REAL atten = 1;
    // Where a shadow ray towards a light at a finite place aims: the light, or its sample.
    REAL3 target = TO_REAL3(light->position);
#if HAS_AREA_LIGHTS
    if (is_area_light(light->kind)) {
        const __global Light* area = light;
#if HAS_MESH_LIGHTS
        REAL pick_weight = 1;
        if (light->kind == LIGHT_MESH) area = mesh_face(s->lights, light, light_pick(key, i),
                                                        &pick_weight);
#endif
        if (!sample_area_light(area, sf->p, sf->err, light_square(key, i), &target, &atten)) {
            return false;
        }
#if HAS_MESH_LIGHTS
        atten = fmin(atten * pick_weight, AREA_WEIGHT_MAX);  // the face's over its probability
#endif
        l = safe_normalize(target - sf->p);
    } else
#endif
    if (light->kind != LIGHT_DIRECTIONAL) {
        REAL3 to_light = target - sf->p;
        REAL dist = length3(to_light);
        if (!(dist > sf->err)) return false;  // a light at the hit point lights nothing
        l = to_light / dist;
        atten = falloff(light, dist);
#if HAS_SPOT_LIGHTS
        if (light->kind == LIGHT_SPOT) {
            atten *= spot_factor(light, l);
            if (!(atten > (REAL)0)) return false;  // outside the cone: no shadow ray
        }
#endif
    } else {
        l = -safe_normalize(TO_REAL3(light->position));
    }
    REAL ndl = dot3(n, l);
    if (!(ndl > (REAL)0)) return false;
    REAL3 origin = offset_origin(sf, l);
    // Aimed from the offset origin itself: a ray parallel to l from there passes beside a
    // point light, and crosses a surface that holds the light before reaching it. It stops
    // just short of the light so such a surface does not shadow it.
    REAL3 shadow_dir = l;
    REAL tmax = REAL_INF;
    if (light->kind != LIGHT_DIRECTIONAL) {
        REAL3 to_light = target - origin;
        REAL span = length3(to_light);
        shadow_dir = span > (REAL)0 ? to_light / span : l;
        // Short by float32 roundings in the double build too: the light and a surface holding
        // it (a tilted plane) are where their float32 records put them, a float32 rounding
        // to either side of each other.
        tmax = span * ((REAL)1 - gamma_f32(ERR_ROUNDINGS));
    }
    *shadow = make_ray(origin, shadow_dir);
    *l_out = l;
    *atten_out = atten;
    *ndl_out = ndl;
    *tmax_out = tmax;
    return true;
}

// A light's diffuse and specular term, written once (real.h, Twins): for one ray (C: REAL3, its
// channels at once; S: REAL) or one channel of a packet's lanes (C and S: REALP).
#define DEFINE_PHONG_TERM(SPEC, C, S, NAME)                                                \
    SPEC C NAME(S atten, C color, C filter, S diffuse, S ndl, C c, S specular, S spec) {  \
        return atten * color * filter * (diffuse * ndl * c + specular * spec);           \
    }
DEFINE_PHONG_TERM(HOT, REAL3, REAL, phong_term)

// Light i's diffuse and specular term, `filter` being the light its shadow ray let through.
STAGE REAL3 light_term(const SceneRefs* s, int i, REAL3 n, REAL3 v, REAL3 c,
                       const __global Material* m, REAL3 l, REAL atten, REAL ndl, REAL3 filter) {
    REAL3 refl = (REAL)2 * ndl * n - l;
    REAL rv = dot3(refl, v);
    REAL spec = rv > (REAL)0 ? phong_power(rv, TO_REAL(m->shininess)) : (REAL)0;
    REAL diffuse = TO_REAL(m->diffuse), specular = TO_REAL(m->specular);
    const __global Light* light = s->lights + i;
    return phong_term(atten, TO_REAL3(light->color), filter, diffuse, ndl, c, specular, spec);
}

#if SAMPLE_PACKETS
#define POINT_LIGHT_LANES (!HAS_TRANSMISSION && !HAS_INSTANCES && HAS_BVH)

// What light_term reads of each lane's shading point beyond SurfaceLanes: the direction to the
// eye, the surface colour and the material's diffuse, specular and shininess.
typedef struct {
    REALP vx, vy, vz, cx, cy, cz, diffuse, specular, shininess, ambient, ex, ey, ez, reflect;
} TermLanes;

#if POINT_LIGHT_LANES
DEFINE_FALLOFF(REALP, falloff_lanes)

// phong_power lane-wise where every lane's exponent is a whole number within [0, 4096] (the
// caller checks): each lane's multiplications are phong_power's, in the same order.
DEFINE_POWER_BY_SQUARING(REALP, MASKP, lane_mask, power_by_squaring_lanes)
DEFINE_PHONG_TERM(HOT, REALP, REALP, phong_term_lanes)

// light_term of a point light on every lane, with nothing filtered (an unblocked lane of an
// opaque scene): the same arithmetic in the same order (phong_term's; the filter's factor 1 is
// exact, and the compiler drops it), into (tx, ty, tz). False where a lane of `lanes` has an
// exponent power_by_squaring_lanes cannot take.
HOT bool light_term_lanes(const __global Light* light, const SurfaceLanes* q, const TermLanes* m,
                          MASKP lanes, REALP lx, REALP ly, REALP lz, REALP atten, REALP ndl,
                          REALP* tx, REALP* ty, REALP* tz) {
    MASKP whole = (m->shininess >= (REAL)0) & (m->shininess <= (REAL)4096) &
                  (m->shininess == floor(m->shininess));
    if (lane_mask(lanes & ~whole)) return false;
    REALP rx = (REAL)2 * ndl * q->nx - lx;
    REALP ry = (REAL)2 * ndl * q->ny - ly;
    REALP rz = (REAL)2 * ndl * q->nz - lz;
    REALP rv = dot_lanes(rx, ry, rz, m->vx, m->vy, m->vz);
    REALP spec = rv > (REAL)0
                     ? power_by_squaring_lanes(rv, TO_MASKP(whole ? m->shininess : (REALP)(0)))
                     : (REALP)(0);
    REAL3 color = TO_REAL3(light->color);
    const REALP one = (REALP)(1);
    *tx = phong_term_lanes(atten, (REALP)(color.x), one, m->diffuse, ndl, m->cx, m->specular, spec);
    *ty = phong_term_lanes(atten, (REALP)(color.y), one, m->diffuse, ndl, m->cy, m->specular, spec);
    *tz = phong_term_lanes(atten, (REALP)(color.z), one, m->diffuse, ndl, m->cz, m->specular, spec);
    return true;
}

// What light_ray gives for a point light on every lane of `bits`, lane-wise: the lanes it
// reaches (*shot), their shadow rays (*rays, up to tmax), l, attenuation and n . l. False
// where a lane's distance is outside length_lanes's range: the caller then goes lane by lane.
HOT bool point_light_lanes(const __global Light* light, const SurfaceLanes* q, int bits,
                           RayPacket* rays, REALP* tmax, REALP* lx, REALP* ly, REALP* lz,
                           REALP* atten, REALP* ndl, int* shot) {
    MASKP lanes = lanes_of(bits);
    REAL3 target = TO_REAL3(light->position);
    REALP tx = (REALP)(target.x), ty = (REALP)(target.y), tz = (REALP)(target.z);
    REALP dist;
    if (!length_lanes(tx - q->px, ty - q->py, tz - q->pz, lanes, &dist)) return false;
    // A light at the hit point lights nothing.
    MASKP lit = lanes & (dist > q->err);
    *lx = (tx - q->px) / dist;
    *ly = (ty - q->py) / dist;
    *lz = (tz - q->pz) / dist;
    *atten = falloff_lanes(light, dist);
    *ndl = dot_lanes(q->nx, q->ny, q->nz, *lx, *ly, *lz);
    lit &= *ndl > (REAL)0;
    REALP ox, oy, oz;
    offset_origin_lanes(q, *lx, *ly, *lz, &ox, &oy, &oz);
    REALP span;
    if (!length_lanes(tx - ox, ty - oy, tz - oz, lit, &span)) return false;
    MASKP away = span > (REAL)0;
    REALP dx = away ? (tx - ox) / span : *lx;
    REALP dy = away ? (ty - oy) / span : *ly;
    REALP dz = away ? (tz - oz) / span : *lz;
    *tmax = span * ((REAL)1 - gamma_f32(ERR_ROUNDINGS));  // as light_ray's
    *shot = lane_mask(lit);
    if (*shot) *rays = make_ray_packet(ox, oy, oz, dx, dy, dz, *shot);
    return true;
}
#endif
#endif

#endif
