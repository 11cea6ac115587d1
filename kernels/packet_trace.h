// Sample packets' drivers (TRAVERSAL_SAMPLE_PACKET): a pixel's samples traced PACKET_LANES at a
// time, their primary rays drawn, walked, shaded and lit as packets; without refraction each
// sample's chain of reflections goes on as packets too, level by level (PACKET_CHAINS).
#ifndef CLRAY_PACKET_TRACE_H
#define CLRAY_PACKET_TRACE_H

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
#include "direct.h"
#include "camera.h"
#include "background.h"
#include "ray_tree.h"

#if SAMPLE_PACKETS
// Without refraction a sample's ray tree is a chain of reflections, so a packet's samples go
// down their chains together, level by level, the reflected rays as packets too. With it a
// tree can branch, and only the primary rays go as packets.
#define PACKET_CHAINS (!HAS_REFRACTION)

// A packet of a pixel's samples. With chains: each lane's sample radiance, the light its
// chain's levels add, level by level as the ray tree adds it. Without: each lane's primary
// ray, hit, shading point and direct light (shade_direct's, its shadow rays traced as
// packets), from which the ray tree goes on ray by ray.
typedef struct {
    RayLanes ray;  // lane j's ray: ray_from_lanes(&ray, j)
    HitLanes hit;  // lane j's closest hit: hit_of_lane(&hit, j)
    ShadePoint pt[PACKET_LANES];
    REAL direct[3][PACKET_LANES];  // rows x, y, z
#if PACKET_CHAINS
    REAL radiance[3][PACKET_LANES];  // rows x, y, z
#endif
} SamplePacket;

// The closest hits of the lanes `bits` of the packet `rays` (pk->ray: the same rays lane by
// lane) into pk->hit, their shading points (as lanes in *q; without chains in pk->pt too,
// which the ray tree reads on), their materials' factors (*terms) and direct light
// (pk->direct): returns the lanes that hit something.
HOT int shade_packet(const SceneRefs* s, const __global Camera* camera,
                     const __global Params* params, SampleKey key, int bits, SamplePacket* pk,
                     const RayPacket* rays, SurfaceLanes* q, TermLanes* terms, int* shadow_rays) {
    int lit = 0;
    MaterialRows mr;
#if SURFACE_LANES
    PacketHit h;
    packet_closest(s, rays, &pk->ray, bits, &pk->hit, &h);
    lit = bits & lane_mask(h.t < REAL_INF);
    int left = lit;
    // Without chains the ray tree reads the primary rays' whole ShadePoints.
    if (lit) {
        left = shade_point_lanes(s, camera, rays, &h, &pk->hit, lit, !PACKET_CHAINS, pk->pt, q,
                                 terms, &mr);
    }
#else
    packet_closest(s, rays, &pk->ray, bits, &pk->hit, 0);
    for (int rest = bits; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        if (pk->hit.t[j] < REAL_INF) lit |= 1 << j;
    }
    int left = lit;
#endif
    for (int rest = left; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        Ray ray = ray_from_lanes(&pk->ray, j);
        Hit hit = hit_of_lane(&pk->hit, j);
        pk->pt[j] = shade_point(s, camera, &ray, &hit);
        set_material_row(&mr, j, pk->pt + j);
    }
    if (left == lit && lit) {
        *q = surface_lanes(pk->pt, lit);
    } else if (left) {
        merge_surface_lanes(surface_lanes(pk->pt, left), lanes_of(left), q);
    }
    // The lanes that shade_point shaded have no TermLanes: all are gathered then.
    if (left) *terms = term_lanes(s, &mr, &pk->ray, lit);
    packet_direct(s, &mr, &pk->ray, q, terms, TO_REAL3(params->ambient), key, lit,
                  pk->direct, shadow_rays);
    return lit;
}

#if PACKET_CHAINS
// Lane j's sample radiance.
static inline REAL3 sample_radiance(const SamplePacket* pk, int j) {
    return (REAL3)(pk->radiance[0][j], pk->radiance[1][j], pk->radiance[2][j]);
}

// What the lanes `leaving`, whose rays (pk->ray) of weight (wx, wy, wz) leave the scene, add
// to their radiance: sky's light, added as the ray tree adds it (the product rounded, then
// added).
HOT void add_sky_lanes(const __global Params* params, const __global float4* texels,
                       int leaving, SamplePacket* pk, REALP wx, REALP wy, REALP wz) {
    MASKP out = lanes_of(leaving);
#if HAS_BACKGROUND_GRADIENT || HAS_BACKGROUND_IMAGE
    // The background depends on the direction: sky's own arithmetic, lane by lane (the rows
    // cleared first: the other lanes are not added, but must hold values).
    REAL sky_rows[3][PACKET_LANES];
    for (int c = 0; c < 3; ++c) VSTOREP((REALP)(0), 0, sky_rows[c]);
    REAL wr[3][PACKET_LANES];
    VSTOREP(wx, 0, wr[0]);
    VSTOREP(wy, 0, wr[1]);
    VSTOREP(wz, 0, wr[2]);
    for (int rest = leaving; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        REAL3 light = sky(params, texels, direction_of_lane(&pk->ray, j),
                          (REAL3)(wr[0][j], wr[1][j], wr[2][j]));
        sky_rows[0][j] = light.x;
        sky_rows[1][j] = light.y;
        sky_rows[2][j] = light.z;
    }
    REALP lx = VLOADP(0, sky_rows[0]), ly = VLOADP(0, sky_rows[1]), lz = VLOADP(0, sky_rows[2]);
#else
    REAL3 background = TO_REAL3(params->background);
    REALP lx = wx * background.x;
    REALP ly = wy * background.y;
    REALP lz = wz * background.z;
#endif
    REALP rx = VLOADP(0, pk->radiance[0]), ry = VLOADP(0, pk->radiance[1]),
          rz = VLOADP(0, pk->radiance[2]);
    VSTOREP(out ? rx + lx : rx, 0, pk->radiance[0]);
    VSTOREP(out ? ry + ly : ry, 0, pk->radiance[1]);
    VSTOREP(out ? rz + lz : rz, 0, pk->radiance[2]);
}

// mirror lane by lane, one component at a time.
DEFINE_MIRROR(HOT, REALP, REALP, mirror_lanes)

// The reflected rays of the lanes `lit` (their shading points q, their materials'
// reflectances in m, their rays `rays`, of weight (wx, wy, wz)) where the material reflects
// and the ray is not too faint, as spawn_secondary makes them but lane-wise: mirror,
// offset_origin and make_ray's operations in the same order. Returns the lanes that go on,
// their rays in *rays and pk->ray, their weights in (wx, wy, wz). Out of line: inlined into
// trace_chains' loop, 16 lanes of doubles ran clang 15's AMDGPU register allocator out of
// registers.
OUT_OF_LINE int reflect_lanes(const __global Params* params, int lit, const SurfaceLanes* q,
                              const TermLanes* m, RayPacket* rays, SamplePacket* pk, REALP* wx,
                              REALP* wy, REALP* wz) {
    REALP kr = lanes_of(lit) ? m->reflect : (REALP)(0);
    REALP rx = *wx * kr, ry = *wy * kr, rz = *wz * kr;
    // too_faint's comparison negated, so that a NaN weight goes on as it does there.
    MASKP faint = fmax(fmax(rx, ry), rz) < (REAL)params->min_weight;
    int bits = lit & lane_mask((kr > (REAL)0) & ~faint);
    if (!bits) return 0;
    REALP dn = dot_lanes(rays->dx, rays->dy, rays->dz, q->nx, q->ny, q->nz);
    REALP dx = mirror_lanes(rays->dx, dn, q->nx);
    REALP dy = mirror_lanes(rays->dy, dn, q->ny);
    REALP dz = mirror_lanes(rays->dz, dn, q->nz);
    REALP ox, oy, oz;
    offset_origin_lanes(q, dx, dy, dz, &ox, &oy, &oz);
    *rays = make_ray_packet(ox, oy, oz, dx, dy, dz, bits);
    store_ray_lanes(rays, &pk->ray);
    *wx = rx;
    *wy = ry;
    *wz = rz;
    return bits;
}

// The lanes of `bits` from their primary rays (pk->ray, as the packet *rays) to the ends of
// their chains: each level's light (the sky, weighted, where a ray leaves; else the direct
// light, with the ray's weight beside it), and the reflected rays (reflect_lanes).
HOT void trace_chains(const SceneRefs* s, const __global Camera* camera,
                      const __global Params* params, SampleKey key, int bits, SamplePacket* pk,
                      RayPacket* rays, int* secondary_rays, int* shadow_rays) {
    REALP wx = (REALP)(1), wy = (REALP)(1), wz = (REALP)(1);
    // The radiance stays in memory across a level: in registers, 16 lanes of doubles ran clang
    // 15's AMDGPU register allocator out of registers.
    for (int c = 0; c < 3; ++c) VSTOREP((REALP)(0), 0, pk->radiance[c]);
    for (int depth = 0; bits; ++depth) {
        SurfaceLanes q;
        TermLanes m;
        int lit = shade_packet(s, camera, params, key, bits, pk, rays, &q, &m, shadow_rays);
        if (lit) {
            // The ray tree's radiance += weight * direct: one expression, so that the
            // multiply-add contracts as it does there.
            MASKP on = lanes_of(lit);
            REALP rx = VLOADP(0, pk->radiance[0]), ry = VLOADP(0, pk->radiance[1]),
                  rz = VLOADP(0, pk->radiance[2]);
            REALP ax = rx + wx * VLOADP(0, pk->direct[0]);
            REALP ay = ry + wy * VLOADP(0, pk->direct[1]);
            REALP az = rz + wz * VLOADP(0, pk->direct[2]);
            VSTOREP(on ? ax : rx, 0, pk->radiance[0]);
            VSTOREP(on ? ay : ry, 0, pk->radiance[1]);
            VSTOREP(on ? az : rz, 0, pk->radiance[2]);
        }
        if (bits & ~lit) add_sky_lanes(params, s->texels, bits & ~lit, pk, wx, wy, wz);
        if (depth >= MAX_DEPTH || !lit) break;
        bits = reflect_lanes(params, lit, &q, &m, rays, pk, &wx, &wy, &wz);
        *secondary_rays += popcount(bits);
    }
}
#endif

// Samples first .. first + lanes - 1 of the pixel: with chains to their ends, without to the
// end of their primary rays' direct light.
OUT_OF_LINE void trace_sample_packet(const SceneRefs* s, const __global Camera* camera,
                                     const __global Params* params, int x, int y, uint pixel,
                                     SampleKey key, int lanes, SamplePacket* pk,
                                     int* secondary_rays, int* shadow_rays) {
    int first = key.sample;
    RayPacket primary;
    bool drawn = false;
#if CAMERA_LANES
    drawn = camera_ray_lanes(camera, params, x, y, first, lanes, pixel, &primary);
#endif
    if (!drawn) {
        Ray rays[PACKET_LANES];
        for (int j = 0; j < PACKET_LANES; ++j) {
            REAL3 o, d;
            // Lanes past the pixel's last sample ride along as copies of its first.
            sample_ray(camera, params, x, y, first + (j < lanes ? j : 0), pixel, &o, &d);
            rays[j] = make_ray(o, d);
        }
        primary = ray_packet(rays);
    }
    store_ray_lanes(&primary, &pk->ray);
    int bits = (1 << lanes) - 1;
#if PACKET_CHAINS
    trace_chains(s, camera, params, key, bits, pk, &primary, secondary_rays, shadow_rays);
#else
    SurfaceLanes q;
    TermLanes m;
    shade_packet(s, camera, params, key, bits, pk, &primary, &q, &m, shadow_rays);
#endif
}

#if !PACKET_CHAINS
// The root of lane `lane`'s ray tree, whose primary ray the packet traced (its hit, shading
// point and direct light are known): its light added to *radiance (the sky's, or the direct
// light, weighted) and its reflected and refracted rays pushed. Returns the rays on the stack.
HOT int packed_root(const SceneRefs* s, const __global Params* params, const SamplePacket* pk,
                    int lane, RayTask* stack, REAL3* radiance, int* secondary_rays) {
    int sp = 0;
    Ray ray = ray_from_lanes(&pk->ray, lane);
    RayTask task = root_task(ray.o, ray.d);
    Hit hit = hit_of_lane(&pk->hit, lane);
    if (!(hit.t < REAL_INF)) {
        *radiance += sky(params, s->texels, task.d, task.weight);
        return sp;
    }
    REAL3 direct = (REAL3)(pk->direct[0][lane], pk->direct[1][lane], pk->direct[2][lane]);
    *radiance += task.weight * direct;
#if MAX_DEPTH > 0
    *secondary_rays += spawn_secondary(s, params, stack, &sp, &task, &ray, pk->pt + lane);
#endif
    return sp;
}

// tree_radiance out of line (issue 42, cold build): once a sample, after its packet, or alone
// at one sample a pixel (a ray tree's worth of work a call). Inlined, it put a second copy of
// the single-ray walks, shading and lights into the kernel's largest function beside the
// packets' own.
OUT_OF_LINE REAL3 sample_tree_radiance(const SceneRefs* s, const __global Camera* camera,
                                       const __global Params* params, SampleKey key,
                                       REAL3 ambient, RayTask* stack, int sp, REAL3 radiance,
                                       int* secondary_rays, int* shadow_rays) {
    return tree_radiance(s, camera, params, key, ambient, stack, sp, radiance, secondary_rays,
                         shadow_rays);
}
#endif

// pixel_radiance with sample packets: the pixel's samples PACKET_LANES at a time
// (trace_sample_packet). With chains the packets trace them to their ends, even one sample a
// pixel (a packet of one lane): the build then holds no ray-by-ray tree (issue 42: it was
// 8,858 of cornell_box's 72,874 bytes of code compiled at the first launch, and clray's
// renders build this kernel only above 1 spp, clray.device.policy.device_plan). Without
// chains a tree can branch: from the primary rays' hits on, ray by ray, and with one sample a
// pixel there is no packet, its rays go alone.
HOT REAL3 packet_pixel_radiance(const SceneRefs* s, const __global Camera* camera,
                                const __global Params* params, int x, int y, uint pixel,
                                int* secondary_rays, int* shadow_rays) {
    REAL3 sum = (REAL3)(0, 0, 0);
#if !PACKET_CHAINS
    REAL3 ambient = TO_REAL3(params->ambient);  // the ray-by-ray trees' (chains have their own)
#endif
    int spp = params->spp;
    SampleKey key = sample_key(params->seed, pixel, spp);
    SamplePacket packet;
    for (int sample = 0; sample < spp; ++sample) {
        key.sample = sample;
        int lane = sample % PACKET_LANES;
        if ((PACKET_CHAINS || spp > 1) && lane == 0) {
            trace_sample_packet(s, camera, params, x, y, pixel, key,
                                min(PACKET_LANES, spp - sample), &packet, secondary_rays,
                                shadow_rays);
        }
#if PACKET_CHAINS
        // The packet traced the sample's chain.
        sum += sample_radiance(&packet, lane);
#else
        RayTask stack[RAY_STACK_SIZE];
        REAL3 radiance = (REAL3)(0, 0, 0);
        int sp = 1;
        if (spp > 1) {
            sp = packed_root(s, params, &packet, lane, stack, &radiance, secondary_rays);
        } else {
            stack[0] = primary_task(camera, params, x, y, sample, pixel);
        }
        sum += sample_tree_radiance(s, camera, params, key, ambient, stack, sp, radiance,
                                    secondary_rays, shadow_rays);
#endif
    }
    return sum;
}
#endif

#endif
