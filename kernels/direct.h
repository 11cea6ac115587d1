// Direct light at a shading point: its glow (ambient and emission) plus each light's term times
// the light its shadow ray lets through (shade_direct); for sample packets the same for every
// lane, one shadow-ray packet per light (packet_direct), a point light's rays set up lane-wise
// in an opaque scene (docs/acceleration.md, Sample packets).
#ifndef CLRAY_DIRECT_H
#define CLRAY_DIRECT_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "bvh.h"
#include "surface.h"
#include "lights.h"
#include "shading.h"
#include "packet.h"

// What a surface of colour c gives whatever the lights: its ambient term and its emission.
static inline REAL3 surface_glow(const __global Material* m, REAL3 c, REAL3 ambient_light) {
    return TO_REAL(m->ambient) * c * ambient_light + TO_REAL3(m->emission);
}

// Ambient plus, for each light on the lit side, diffuse and specular times the light that
// reaches p through the shadow ray. key: the pixel sample, which picks area lights' samples.
HOT REAL3 shade_direct(const SceneRefs* s, const Surface* sf, REAL3 n, REAL3 v, REAL3 c,
                          const __global Material* m, REAL3 ambient_light, SampleKey key,
                          int* shadow_rays) {
    REAL3 result = surface_glow(m, c, ambient_light);
    for (int i = 0; i < s->n_lights; ++i) {
        REAL3 l;
        REAL atten, ndl, tmax;
        Ray shadow;
        if (!light_ray(s, sf, n, i, key, &l, &atten, &ndl, &shadow, &tmax)) continue;
        (*shadow_rays)++;
        REAL3 filter = transmission(s, &shadow, tmax);
        if (max_comp3(filter) <= (REAL)0) continue;
        result += light_term(s, i, n, v, c, m, l, atten, ndl, filter);
    }
    return result;
}

#if SAMPLE_PACKETS
// Lane j of rows of light (x, y, z) plus v: the sums lane by lane of light that went lane by lane.
HOT void add_to_lane(REAL (*rows)[PACKET_LANES], int j, REAL3 v) {
    rows[0][j] += v.x;
    rows[1][j] += v.y;
    rows[2][j] += v.z;
}

#if POINT_LIGHT_LANES
// Light i's terms on the lanes of `bits`, a point light's shadow rays set up lane-wise: adds
// to direct[j]. False (nothing added) where point_light_lanes declines.
HOT bool point_light_direct(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                            int i, const SurfaceLanes* q, const TermLanes* m, int bits,
                            REAL (*direct)[PACKET_LANES], int* shadow_rays) {
    const __global Light* light = s->lights + i;
    RayPacket rays;
    REALP tmax, lx, ly, lz, atten, ndl;
    int shot;
    if (!point_light_lanes(light, q, bits, &rays, &tmax, &lx, &ly, &lz, &atten, &ndl, &shot)) {
        return false;
    }
    if (!shot) return true;
    *shadow_rays += popcount(shot);
    REAL f[6][PACKET_LANES];
    VSTOREP(tmax, 0, f[0]);
    int lit = shot & ~packet_blocked(s, &rays, f[0], shot);
    if (!lit) return true;
    REALP tx, ty, tz;
    if (light_term_lanes(light, q, m, lanes_of(lit), lx, ly, lz, atten, ndl, &tx, &ty, &tz)) {
        MASKP mine = lanes_of(lit);
        REALP dx = VLOADP(0, direct[0]), dy = VLOADP(0, direct[1]), dz = VLOADP(0, direct[2]);
        VSTOREP(mine ? dx + tx : dx, 0, direct[0]);
        VSTOREP(mine ? dy + ty : dy, 0, direct[1]);
        VSTOREP(mine ? dz + tz : dz, 0, direct[2]);
        return true;
    }
    VSTOREP(lx, 0, f[0]);
    VSTOREP(ly, 0, f[1]);
    VSTOREP(lz, 0, f[2]);
    VSTOREP(atten, 0, f[3]);
    VSTOREP(ndl, 0, f[4]);
    SurfaceRows rows;
    store_surface_lanes(q, &rows);
    for (int rest = lit; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        REAL3 l = (REAL3)(f[0][j], f[1][j], f[2][j]);
        add_to_lane(direct, j,
                    light_term(s, i, normal_of_lane(&rows, j), -direction_of_lane(seen, j),
                               color_of_lane(mr, j), s->materials + mr->material[j], l,
                               f[3][j], f[4][j], (REAL3)(1, 1, 1)));
    }
    return true;
}
#endif

// shade_direct for the lanes of `bits`, each at its own shading point seen along its ray in
// `seen` (its surface and normal in q, its colour and material in mr; m: their TermLanes),
// into the rows of `direct`, with one shadow-ray packet per light. key.sample: lane 0's
// sample. The per-lane arithmetic is shade_direct's, in its order: the glow first, then each
// light's term added.
// Out of line: once per packet and level (issue 42, cold build; see packet_closest).
OUT_OF_LINE void packet_direct(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                       const SurfaceLanes* q, const TermLanes* m, REAL3 ambient_light,
                       SampleKey key, int bits, REAL (*direct)[PACKET_LANES], int* shadow_rays) {
    int first = key.sample;
    if (!bits) return;
    // surface_glow's arithmetic on every lane.
    VSTOREP(m->ambient * m->cx * ambient_light.x + m->ex, 0, direct[0]);
    VSTOREP(m->ambient * m->cy * ambient_light.y + m->ey, 0, direct[1]);
    VSTOREP(m->ambient * m->cz * ambient_light.z + m->ez, 0, direct[2]);
    // The other lights' rays are set up lane by lane.
    SurfaceRows points;
    bool stored = false;
    for (int i = 0; i < s->n_lights; ++i) {
#if POINT_LIGHT_LANES
        if (s->lights[i].kind == LIGHT_POINT &&
            point_light_direct(s, mr, seen, i, q, m, bits, direct, shadow_rays)) {
            continue;
        }
#endif
        if (!stored) {
            store_surface_lanes(q, &points);
            stored = true;
        }
        Ray rays[PACKET_LANES];
        REAL3 l[PACKET_LANES], filter[PACKET_LANES];
        REAL atten[PACKET_LANES], ndl[PACKET_LANES], tmax[PACKET_LANES];
        int shot = 0;
        for (int rest = bits; rest; rest &= rest - 1) {
            int j = lowest_bit(rest);
            key.sample = first + j;
            Surface sf = surface_of_lane(&points, j);
            if (light_ray(s, &sf, normal_of_lane(&points, j), i, key, l + j, atten + j, ndl + j,
                          rays + j, tmax + j)) {
                shot |= 1 << j;
            }
        }
        if (!shot) continue;
        *shadow_rays += popcount(shot);
        // Lanes without a shadow ray ride along as copies of one that has.
        int spare = lowest_bit(shot);
        for (int j = 0; j < PACKET_LANES; ++j) {
            if (!((shot >> j) & 1)) {
                rays[j] = rays[spare];
                tmax[j] = tmax[spare];
            }
        }
        packet_transmission(s, rays, tmax, shot, filter);
        for (int rest = shot; rest; rest &= rest - 1) {
            int j = lowest_bit(rest);
            if (max_comp3(filter[j]) <= (REAL)0) continue;
            add_to_lane(direct, j,
                        light_term(s, i, normal_of_lane(&points, j),
                                   -direction_of_lane(seen, j), color_of_lane(mr, j),
                                   s->materials + mr->material[j], l[j], atten[j], ndl[j],
                                   filter[j]));
        }
    }
}
#endif

#endif
