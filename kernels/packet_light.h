// A sample packet's direct light (TRAVERSAL_SAMPLE_PACKET): shade_direct for every lane, its
// shadow rays one packet per light. Towards a point light in an opaque scene the shadow rays
// are set up lane-wise, light_ray's arithmetic for all lanes at once, straight into the
// packet's lanes (docs/acceleration.md, Sample packets); other lights, and lanes whose
// distances leave length_lanes's range, go through light_ray lane by lane. The shading
// points as lanes (surface_lanes, offset_origin_lanes) serve the chains' reflected rays too.
#ifndef CLRAY_PACKET_LIGHT_H
#define CLRAY_PACKET_LIGHT_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "intersect.h"
#include "lights.h"
#include "shading.h"
#include "packet.h"

#define POINT_LIGHT_LANES (!HAS_TRANSMISSION && !HAS_INSTANCES && HAS_BVH)

// The lanes' shading points, coordinate by coordinate: what light_ray and a reflected ray's
// set-up read of a ShadePoint.
typedef struct {
    REALP px, py, pz, err, gx, gy, gz, nx, ny, nz;
} SurfaceLanes;

// Each lane's material and its colour at the shading point (texture looked up), as rows: what
// light_term reads of a ShadePoint besides its surface and normal.
typedef struct {
    REAL c[3][PACKET_LANES];
    int material[PACKET_LANES];
} MaterialRows;

// Lane j of *mr from its ShadePoint.
HOT void set_material_row(MaterialRows* mr, int j, const ShadePoint* pt) {
    mr->c[0][j] = pt->c.x;
    mr->c[1][j] = pt->c.y;
    mr->c[2][j] = pt->c.z;
    mr->material[j] = pt->sf.material;
}

// Lane j's colour in *mr.
HOT REAL3 color_of_lane(const MaterialRows* mr, int j) {
    return (REAL3)(mr->c[0][j], mr->c[1][j], mr->c[2][j]);
}

// pt[j] for each lane of `bits`; the other lanes hold a copy of one of those.
HOT SurfaceLanes surface_lanes(const ShadePoint* pt, int bits) {
    REAL f[10][PACKET_LANES];
    int spare = lowest_bit(bits);
    for (int j = 0; j < PACKET_LANES; ++j) {
        const ShadePoint* q = pt + (((bits >> j) & 1) ? j : spare);
        f[0][j] = q->sf.p.x;
        f[1][j] = q->sf.p.y;
        f[2][j] = q->sf.p.z;
        f[3][j] = q->sf.err;
        f[4][j] = q->sf.n_g.x;
        f[5][j] = q->sf.n_g.y;
        f[6][j] = q->sf.n_g.z;
        f[7][j] = q->n.x;
        f[8][j] = q->n.y;
        f[9][j] = q->n.z;
    }
    SurfaceLanes q;
    q.px = VLOADP(0, f[0]);
    q.py = VLOADP(0, f[1]);
    q.pz = VLOADP(0, f[2]);
    q.err = VLOADP(0, f[3]);
    q.gx = VLOADP(0, f[4]);
    q.gy = VLOADP(0, f[5]);
    q.gz = VLOADP(0, f[6]);
    q.nx = VLOADP(0, f[7]);
    q.ny = VLOADP(0, f[8]);
    q.nz = VLOADP(0, f[9]);
    return q;
}

// Where `mine`, *q takes v's lanes.
HOT void merge_surface_lanes(SurfaceLanes v, MASKP mine, SurfaceLanes* q) {
    q->px = mine ? v.px : q->px;
    q->py = mine ? v.py : q->py;
    q->pz = mine ? v.pz : q->pz;
    q->err = mine ? v.err : q->err;
    q->gx = mine ? v.gx : q->gx;
    q->gy = mine ? v.gy : q->gy;
    q->gz = mine ? v.gz : q->gz;
    q->nx = mine ? v.nx : q->nx;
    q->ny = mine ? v.ny : q->ny;
    q->nz = mine ? v.nz : q->nz;
}

// offset_origin(sf, w) for every lane, into (ox, oy, oz): the same operations in the same
// order.
HOT void offset_origin_lanes(const SurfaceLanes* q, REALP wx, REALP wy, REALP wz, REALP* ox,
                             REALP* oy, REALP* oz) {
#if OFFSET_FIXED_EPS
    REALP d = (REALP)(1e-4);
#else
    REALP d = q->err * (fabs(q->gx) + fabs(q->gy) + fabs(q->gz));
#endif
    MASKP out = dot_lanes(wx, wy, wz, q->gx, q->gy, q->gz) > (REAL)0;
    *ox = out ? q->px + d * q->gx : q->px - d * q->gx;
    *oy = out ? q->py + d * q->gy : q->py - d * q->gy;
    *oz = out ? q->pz + d * q->gz : q->pz - d * q->gz;
}

// What light_term reads of each lane's shading point beyond SurfaceLanes: the direction to the
// eye, the surface colour and the material's diffuse, specular and shininess.
typedef struct {
    REALP vx, vy, vz, cx, cy, cz, diffuse, specular, shininess, ambient, ex, ey, ez, reflect;
} TermLanes;

// SurfaceLanes row by row, for the lanes that go on one at a time.
typedef struct {
    REAL f[10][PACKET_LANES];
} SurfaceRows;

HOT void store_surface_lanes(const SurfaceLanes* q, SurfaceRows* r) {
    VSTOREP(q->px, 0, r->f[0]);
    VSTOREP(q->py, 0, r->f[1]);
    VSTOREP(q->pz, 0, r->f[2]);
    VSTOREP(q->err, 0, r->f[3]);
    VSTOREP(q->gx, 0, r->f[4]);
    VSTOREP(q->gy, 0, r->f[5]);
    VSTOREP(q->gz, 0, r->f[6]);
    VSTOREP(q->nx, 0, r->f[7]);
    VSTOREP(q->ny, 0, r->f[8]);
    VSTOREP(q->nz, 0, r->f[9]);
}

// Lane j's surface as light_ray reads it (p, err, n_g; material: the caller's).
HOT Surface surface_of_lane(const SurfaceRows* r, int j) {
    Surface sf;
    sf.p = (REAL3)(r->f[0][j], r->f[1][j], r->f[2][j]);
    sf.err = r->f[3][j];
    sf.n_g = (REAL3)(r->f[4][j], r->f[5][j], r->f[6][j]);
    sf.n_s = sf.n_g;
    sf.uv = (REAL2)(0, 0);
    sf.material = 0;
    return sf;
}

// Lane j's shading normal n (ShadePoint.n).
HOT REAL3 normal_of_lane(const SurfaceRows* r, int j) {
    return (REAL3)(r->f[7][j], r->f[8][j], r->f[9][j]);
}

// Lane j of rows of light (x, y, z) plus v: the sums lane by lane of light that went lane by lane.
HOT void add_to_lane(REAL rows[3][PACKET_LANES], int j, REAL3 v) {
    rows[0][j] += v.x;
    rows[1][j] += v.y;
    rows[2][j] += v.z;
}

// length() lane-wise: sqrt of dot_lanes, which is what PoCL's length() computes wherever the
// squared length is within [2^-90, 2^90]; outside it, length() scales against underflow and
// overflow. False where a lane of `lanes` is outside that range (or NaN).
HOT bool length_lanes(REALP x, REALP y, REALP z, MASKP lanes, REALP* len) {
    REALP dd = dot_lanes(x, y, z, x, y, z);
    MASKP inside = (dd >= (REAL)0x1p-90) & (dd <= (REAL)0x1p90);
    *len = sqrt(GREATER(dd, (REALP)(0)));
    return !lane_mask(lanes & ~inside);
}

// As surface_lanes, for light_term (mr: the lanes' materials and colours).
HOT TermLanes term_lanes(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                         int bits) {
    REAL f[14][PACKET_LANES];
    int spare = lowest_bit(bits);
    for (int j = 0; j < PACKET_LANES; ++j) {
        int k = ((bits >> j) & 1) ? j : spare;
        const __global Material* m = s->materials + mr->material[k];
        REAL3 v = -direction_of_lane(seen, k);
        f[0][j] = v.x;
        f[1][j] = v.y;
        f[2][j] = v.z;
        f[3][j] = mr->c[0][k];
        f[4][j] = mr->c[1][k];
        f[5][j] = mr->c[2][k];
        f[6][j] = TO_REAL(m->diffuse);
        f[7][j] = TO_REAL(m->specular);
        f[8][j] = TO_REAL(m->shininess);
        REAL3 e = TO_REAL3(m->emission);
        f[9][j] = TO_REAL(m->ambient);
        f[10][j] = e.x;
        f[11][j] = e.y;
        f[12][j] = e.z;
        f[13][j] = TO_REAL(m->reflect);
    }
    TermLanes t;
    t.vx = VLOADP(0, f[0]);
    t.vy = VLOADP(0, f[1]);
    t.vz = VLOADP(0, f[2]);
    t.cx = VLOADP(0, f[3]);
    t.cy = VLOADP(0, f[4]);
    t.cz = VLOADP(0, f[5]);
    t.diffuse = VLOADP(0, f[6]);
    t.specular = VLOADP(0, f[7]);
    t.shininess = VLOADP(0, f[8]);
    t.ambient = VLOADP(0, f[9]);
    t.ex = VLOADP(0, f[10]);
    t.ey = VLOADP(0, f[11]);
    t.ez = VLOADP(0, f[12]);
    t.reflect = VLOADP(0, f[13]);
    return t;
}

#if POINT_LIGHT_LANES
// phong_power lane-wise where every lane's exponent is a whole number within [0, 4096] (the
// caller checks): each lane's multiplications are phong_power's, in the same order.
HOT REALP phong_power_lanes(REALP x, REALP s) {
    MASKP n = TO_MASKP(s);
    REALP r = (REALP)(1);
    while (lane_mask(n != (MASKP)(0))) {
        r = (n & (MASKP)(1)) != (MASKP)(0) ? r * x : r;
        x *= x;
        n >>= (MASKP)(1);
    }
    return r;
}

// light_term of a point light on every lane, with nothing filtered (an unblocked lane of an
// opaque scene): the same arithmetic in the same order (the filter's factor 1 is exact), into
// (tx, ty, tz). False where a lane of `lanes` has an exponent phong_power_lanes cannot take.
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
    REALP spec = rv > (REAL)0 ? phong_power_lanes(rv, whole ? m->shininess : (REALP)(0))
                              : (REALP)(0);
    REAL3 color = TO_REAL3(light->color);
    *tx = atten * color.x * (m->diffuse * ndl * m->cx + m->specular * spec);
    *ty = atten * color.y * (m->diffuse * ndl * m->cy + m->specular * spec);
    *tz = atten * color.z * (m->diffuse * ndl * m->cz + m->specular * spec);
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
    REAL3 k = TO_REAL3(light->attenuation);
    REALP denom = (REALP)(k.x) + k.y * dist + k.z * dist * dist;
    *atten = denom > (REAL)0 ? LESSER((REALP)(1), (REAL)1 / denom) : (REALP)(1);
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
    *tmax = span * ((REAL)1 - gamma_n(ERR_ROUNDINGS));
    *shot = lane_mask(lit);
    if (*shot) *rays = make_ray_packet(ox, oy, oz, dx, dy, dz, *shot);
    return true;
}

// Light i's terms on the lanes of `bits`, a point light's shadow rays set up lane-wise: adds
// to direct[j]. False (nothing added) where point_light_lanes declines.
HOT bool point_light_direct(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                            int i, const SurfaceLanes* q, const TermLanes* m, int bits,
                            REAL direct[3][PACKET_LANES], int* shadow_rays) {
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
HOT void packet_direct(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                       const SurfaceLanes* q, const TermLanes* m, REAL3 ambient_light,
                       SampleKey key, int bits, REAL direct[3][PACKET_LANES], int* shadow_rays) {
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
