// The ray tree and the render kernels. One work-item per pixel; the host launches bands of rows.
// This file holds the ray tree (the media stack, reflected and refracted rays, the sky; walked
// with an explicit stack), the drivers of each traversal scheme (sample packets: shade_packet,
// trace_chains, reflect_lanes, trace_sample_packet; group packets: group_direct, group_pixel)
// and the two kernels, render and intersect_rays (closest hits of given rays, for tests). The
// queries, shading and packets' lane-wise arithmetic are in the headers it includes.
//
// Build switches (all from clray/device/program.py's KernelConfig): HAS_PLANES, HAS_SPHERES,
// HAS_BOXES, HAS_CYLINDERS, HAS_CONES, HAS_TRIANGLES, HAS_VERTEX_NORMALS, HAS_VERTEX_UVS,
// HAS_TEXTURES, HAS_TRANSMISSION, HAS_REFRACTION, HAS_FRESNEL, HAS_THIN_LENS, HAS_ORTHOGRAPHIC,
// HAS_BACKGROUND_GRADIENT, HAS_BACKGROUND_IMAGE (0 or 1), MAX_DEPTH, BVH_WIDTH, BVH_STACK_SIZE,
// USE_DOUBLE, the study variants SPHERE_TEXTBOOK, OFFSET_FIXED_EPS, TRIANGLE_NO_FP64_FALLBACK,
// TRIANGLE_MOLLER_TRUMBORE, FRESNEL_SCHLICK; FP64_SPHERES (the packer's per-scene fp64 path
// for spheres float32 cannot intersect); COUNT_TESTS (the instrumented build: box and
// primitive tests per pixel).
// HAS_SPOT_LIGHTS, HAS_AREA_LIGHTS (0 or 1): the scene has spot lights, area lights.
// HAS_INSTANCES (0 or 1): the scene places groups by transforms (kernels/bvh.h walks into them).
// TRAVERSAL: TRAVERSAL_SINGLE (every ray walks the BVH alone), TRAVERSAL_SAMPLE_PACKET (a
// pixel's samples' primary and shadow rays walk it in packets of PACKET_LANES, kernels/packet.h;
// PACKET_MIN_LANES: below it, lanes go on ray by ray) or TRAVERSAL_GROUP_PACKET (a work-group's
// pixels walk it together, kernels/group.h).
#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "rng.h"
#include "camera.h"
#include "intersect.h"
#include "bvh.h"
#include "texture.h"
#include "shading.h"
#include "fresnel.h"
#include "background.h"

// The media a ray can be inside at once (nested glass); a deeper one is not recorded.
#define MEDIA_DEPTH 4
// Depth first, a task pushes at most two children (refraction and reflection), so the stack
// holds at most one waiting task per level: MAX_DEPTH + 1 entries. Without refraction a task
// pushes at most one, and one entry is enough whatever the depth.
#if HAS_REFRACTION
#define RAY_STACK_SIZE (MAX_DEPTH + 1)
#else
#define RAY_STACK_SIZE 1
#endif

#define TRAVERSAL_SINGLE 0
#define TRAVERSAL_SAMPLE_PACKET 1
#define TRAVERSAL_GROUP_PACKET 2
#ifndef TRAVERSAL
#define TRAVERSAL TRAVERSAL_SINGLE
#endif
#define SAMPLE_PACKETS (TRAVERSAL == TRAVERSAL_SAMPLE_PACKET)
#define GROUP_PACKETS (TRAVERSAL == TRAVERSAL_GROUP_PACKET)

// IMPLICIT_VECTORIZATION 0 (the default) asks a driver that packs work-items into a vector's
// lanes (Intel's CPU runtime, 8 or 16 a thread) to run one work-item a thread instead: the
// pixels' walks diverge and every node or primitive load becomes a gather, so the packed
// kernel ran 2.1x (spheres) to 3.5x (mesh) slower there (docs/acceleration.md). The hint is
// that compiler's own attribute; a compiler without it (PoCL, GPUs) builds the kernel as it is.
#ifndef IMPLICIT_VECTORIZATION
#define IMPLICIT_VECTORIZATION 0
#endif
// Group packets are written for that packing: their work-items share each node.
#if !IMPLICIT_VECTORIZATION && !GROUP_PACKETS && defined(__has_attribute)
#if __has_attribute(intel_vec_len_hint)
#define WORK_ITEM_LANES __attribute__((intel_vec_len_hint(1)))
#endif
#endif
#ifndef WORK_ITEM_LANES
#define WORK_ITEM_LANES
#endif
#if SAMPLE_PACKETS
#include "packet.h"
#include "packet_camera.h"
#include "packet_light.h"
#include "packet_surface.h"
#endif
#if GROUP_PACKETS
#include "group.h"
#endif

// One node of the ray tree, waiting on the explicit stack (OpenCL C has no recursion).
typedef struct {
    REAL3 o, d, weight;
    int depth;
    int media_count;  // materials the ray is inside, innermost last
    int media[MEDIA_DEPTH];
} RayTask;

inline REAL medium_ior(const SceneRefs* s, const RayTask* task) {
    return task->media_count > 0 ? TO_REAL(s->materials[task->media[task->media_count - 1]].ior)
                                 : (REAL)1;
}

// The mirror image of direction d in a surface of normal n.
inline REAL3 mirror(REAL3 d, REAL3 n) { return d - (REAL)2 * dot(d, n) * n; }

// A ray too faint to matter (weight below min_weight) is not traced: inside glass the tree
// doubles at every level, so deep trees need the cut.
inline bool too_faint(REAL3 weight, float min_weight) {
    return fmax(fmax(weight.x, weight.y), weight.z) < (REAL)min_weight;
}

// Push a secondary ray whose direction (and media) are set: it starts off the surface on the
// side it leaves to, one level deeper in the ray tree, unless it is too faint. Returns the rays
// pushed (0 or 1).
inline int spawn(RayTask* stack, int* sp, RayTask* next, const Surface* sf, REAL3 weight,
                 int depth, float min_weight) {
    if (too_faint(weight, min_weight)) return 0;
    next->o = offset_origin(sf, next->d);
    next->weight = weight;
    next->depth = depth + 1;
    stack[(*sp)++] = *next;
    return 1;
}

#if HAS_REFRACTION
// The refracted ray's media and eta = n1 / n2 at a surface of material m.
inline REAL refract_media(const SceneRefs* s, const RayTask* in, RayTask* out, int m,
                          bool entering) {
    out->media_count = in->media_count;
    for (int k = 0; k < MEDIA_DEPTH; ++k) out->media[k] = in->media[k];
    REAL ior_m = TO_REAL(s->materials[m].ior);
    if (entering) {
        REAL n1 = medium_ior(s, in);
        if (out->media_count < MEDIA_DEPTH) out->media[out->media_count++] = m;
        return n1 / ior_m;
    }
    for (int k = out->media_count - 1; k >= 0; --k) {
        if (out->media[k] == m) {
            for (int j = k; j < out->media_count - 1; ++j) out->media[j] = out->media[j + 1];
            out->media_count--;
            break;
        }
    }
    return ior_m / medium_ior(s, out);
}
#endif

// The primary ray of pixel sample `sample`.
STAGE void sample_ray(const __global Camera* camera, const __global Params* params, int x,
                      int y, int sample, uint pixel, REAL3* o, REAL3* d) {
    int spp = params->spp;
    REAL2 pos = sample_position(x, y, sample, spp, params->seed, pixel);
#if HAS_THIN_LENS || HAS_ORTHOGRAPHIC
    camera_ray(camera, pos, params->width, params->height, sample, spp, params->seed, pixel, o,
               d);
#else
    *o = TO_REAL3(camera->position);
    *d = camera_direction(camera, pos, params->width, params->height);
#endif
}

#if MAX_DEPTH > 0
// Push the reflected and refracted rays of a shaded hit (ray, pt) of `task`: returns the rays
// pushed.
inline int spawn_secondary(const SceneRefs* s, const __global Params* params, RayTask* stack,
                           int* sp, const RayTask* task, const Ray* ray, const ShadePoint* pt) {
    if (task->depth >= MAX_DEPTH) return 0;
    const __global Material* m = s->materials + pt->sf.material;
    REAL3 n = pt->n;
    int pushed = 0;
    REAL kr = TO_REAL(m->reflect);
#if HAS_REFRACTION
    REAL kt = TO_REAL(m->transmit);
    if (kt > (REAL)0) {
        RayTask next;
        REAL eta = refract_media(s, task, &next, pt->sf.material, pt->entering);
        REAL cos_i = -dot(ray->d, n);
        REAL k = (REAL)1 - eta * eta * ((REAL)1 - cos_i * cos_i);
        if (k < (REAL)0) {
            kr += kt;  // total internal reflection
        } else {
#if HAS_FRESNEL
            if (m->fresnel) {
                REAL f = fresnel_reflectance(eta, cos_i, sqrt(k));
                kr += f * kt;
                kt *= (REAL)1 - f;
            }
#endif
            next.d = normalize(eta * ray->d + (eta * cos_i - sqrt(k)) * n);
            pushed += spawn(stack, sp, &next, &pt->sf, task->weight * kt, task->depth,
                            params->min_weight);
        }
    }
#endif
    if (kr > (REAL)0) {
        RayTask next = *task;  // a reflection stays in the same media
        next.d = mirror(ray->d, n);
        pushed += spawn(stack, sp, &next, &pt->sf, task->weight * kr, task->depth,
                        params->min_weight);
    }
    return pushed;
}
#endif

// Light from the sky where a ray of weight `weight` leaves the scene in direction d.
inline REAL3 sky(const __global Params* params, const __global float4* texels, REAL3 d,
                 REAL3 weight) {
#if HAS_BACKGROUND_GRADIENT || HAS_BACKGROUND_IMAGE
    return weight * background_radiance(params, texels, d);
#else
    return weight * TO_REAL3(params->background);
#endif
}

// The ray tree's root task: a primary ray (o, d), in no medium, of full weight.
inline RayTask root_task(REAL3 o, REAL3 d) {
    RayTask task;
    task.o = o;
    task.d = d;
    task.weight = (REAL3)(1, 1, 1);
    task.depth = 0;
    task.media_count = 0;
    return task;
}

// The sample's primary ray as the ray tree's root task.
inline RayTask primary_task(const __global Camera* camera, const __global Params* params, int x,
                            int y, int sample, uint pixel) {
    REAL3 o, d;
    sample_ray(camera, params, x, y, sample, pixel, &o, &d);
    return root_task(o, d);
}

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
inline REAL3 sample_radiance(const SamplePacket* pk, int j) {
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
    REALP twice = (REAL)2 * dot_lanes(rays->dx, rays->dy, rays->dz, q->nx, q->ny, q->nz);
    REALP dx = rays->dx - twice * q->nx;
    REALP dy = rays->dy - twice * q->ny;
    REALP dz = rays->dz - twice * q->nz;
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
#endif

#if GROUP_PACKETS
// shade_direct for the group: every work-item takes part in each light's shadow walk, with a
// shadow ray where `shaded` and the light reaches the point.
inline REAL3 group_direct(const SceneRefs* s, Group* g, const ShadePoint* pt, REAL3 v,
                          REAL3 ambient_light, SampleKey key, bool shaded, int* shadow_rays) {
    const __global Material* m = s->materials + (shaded ? pt->sf.material : 0);
    REAL3 result = (REAL3)(0, 0, 0);
    if (shaded) result = surface_glow(m, pt->c, ambient_light);
    for (int i = 0; i < s->n_lights; ++i) {
        REAL3 l = (REAL3)(0, 0, 0);
        REAL atten = 0, ndl = 0, tmax = 0;
        Ray shadow = make_ray((REAL3)(0, 0, 0), (REAL3)(0, 0, 1));
        bool lit = shaded && light_ray(s, &pt->sf, pt->n, i, key, &l, &atten, &ndl, &shadow,
                                       &tmax);
        if (lit) (*shadow_rays)++;
        REAL3 filter = group_transmission(s, g, &shadow, tmax, lit);
        if (lit && max_comp3(filter) > (REAL)0) {
            result += light_term(s, i, pt->n, v, pt->c, m, l, atten, ndl, filter);
        }
    }
    return result;
}

// A pixel's radiance summed over its samples, its rays walking with the group's: every
// work-item of the group runs it, those outside the image (`live` false) without rays. Each
// pass of the loop takes one ray of the tree from every work-item that has one left.
inline REAL3 group_pixel(const SceneRefs* s, Group* g, const __global Camera* camera,
                         const __global Params* params, const __global float4* texels, int x,
                         int y, uint pixel, bool live, int* secondary_rays, int* shadow_rays) {
    REAL3 sum = (REAL3)(0, 0, 0), ambient = TO_REAL3(params->ambient);
    int spp = params->spp;
    SampleKey key = sample_key(params->seed, pixel, spp);
    for (int sample = 0; sample < spp; ++sample) {
        key.sample = sample;
        RayTask stack[RAY_STACK_SIZE];
        int sp = 0;
        if (live) stack[sp++] = primary_task(camera, params, x, y, sample, pixel);
        REAL3 radiance = (REAL3)(0, 0, 0);  // the sample's, then the pixel's sum, as render's
        for (;;) {
            bool has = sp > 0;
            if (!group_any(g, has)) break;
            // A work-item without a ray walks a stand-in, inactive.
            RayTask task = has ? stack[--sp] : root_task((REAL3)(0, 0, 0), (REAL3)(0, 0, 1));
            Ray ray = make_ray(task.o, task.d);
            Hit hit = group_closest(s, g, &ray, has);
            bool shaded = has && hit.t < REAL_INF;
            if (has && !shaded) radiance += sky(params, texels, task.d, task.weight);
            ShadePoint pt;
            if (shaded) pt = shade_point(s, camera, &ray, &hit);
            REAL3 direct = group_direct(s, g, &pt, -ray.d, ambient, key, shaded, shadow_rays);
            if (!shaded) continue;
            radiance += task.weight * direct;
#if MAX_DEPTH > 0
            *secondary_rays += spawn_secondary(s, params, stack, &sp, &task, &ray, &pt);
#endif
        }
        sum += radiance;
    }
    return sum;
}
#endif

__kernel WORK_ITEM_LANES void render(SCENE_BUFFER_PARAMS, __global float4* image,
                                     __global int4* ray_counts, __global int4* test_counts,
                                     int row_offset) {
    int x = get_global_id(0), y = get_global_id(1) + row_offset;
    int width = params->width, height = params->height;
#if GROUP_PACKETS
    // No early return: the work-items past the image's edge ride along in the group's walks.
    bool live = x < width && y < height;
    __local GroupPosts posts;
    Group g;
    group_init(&g, &posts, get_local_id(1) * get_local_size(0) + get_local_id(0));
#else
    if (x >= width || y >= height) return;
#endif

    SceneRefs s = scene_refs(SCENE_BUFFER_ARGS);
#if COUNT_TESTS
    TestCounts counts = {0, 0, 0, 0};
    s.counts = &counts;
#endif

    uint pixel = (uint)(y * width + x);
    int spp = params->spp;
    int secondary_rays = 0, shadow_rays = 0;
#if GROUP_PACKETS
    REAL3 sum = group_pixel(&s, &g, camera, params, texels, x, y, pixel, live, &secondary_rays,
                            &shadow_rays);
    if (!live) return;
#else
    REAL3 sum = (REAL3)(0, 0, 0), ambient = TO_REAL3(params->ambient);
    SampleKey key = sample_key(params->seed, pixel, spp);
#if SAMPLE_PACKETS
    // With one sample a pixel there is no packet: its rays go alone.
    SamplePacket packet;
    int lane = 0;
#endif
    for (int sample = 0; sample < spp; ++sample) {
        key.sample = sample;
        RayTask stack[RAY_STACK_SIZE];
        int sp = 0;
#if SAMPLE_PACKETS
        lane = sample % PACKET_LANES;
        if (spp > 1 && lane == 0) {
            trace_sample_packet(&s, camera, params, x, y, pixel, key,
                                min(PACKET_LANES, spp - sample), &packet, &secondary_rays,
                                &shadow_rays);
        }
#if PACKET_CHAINS
        if (spp > 1) {
            // The packet traced the sample's chain.
            sum += sample_radiance(&packet, lane);
            continue;
        }
#endif
        if (spp > 1) {
            // The packet drew the sample's ray already.
            Ray drawn = ray_from_lanes(&packet.ray, lane);
            stack[0] = root_task(drawn.o, drawn.d);
        } else
#endif
        stack[0] = primary_task(camera, params, x, y, sample, pixel);
        sp = 1;
        // The sample's own radiance first, then the pixel's sum: a sample packet sums its
        // lanes' samples so, each lane's levels in the same order.
        REAL3 radiance = (REAL3)(0, 0, 0);
        while (sp > 0) {
            RayTask task = stack[--sp];
#if SAMPLE_PACKETS
            // A primary ray of a packet: its hit and direct light are known.
            bool packed = !PACKET_CHAINS && spp > 1 && task.depth == 0;
            Ray ray = packed ? ray_from_lanes(&packet.ray, lane) : make_ray(task.o, task.d);
            Hit hit = packed ? hit_of_lane(&packet.hit, lane) : closest_hit(&s, &ray);
#else
            Ray ray = make_ray(task.o, task.d);
            Hit hit = closest_hit(&s, &ray);
#endif
            if (!(hit.t < REAL_INF)) {
                radiance += sky(params, texels, task.d, task.weight);
                continue;
            }
#if SAMPLE_PACKETS
            ShadePoint pt = packed ? packet.pt[lane] : shade_point(&s, camera, &ray, &hit);
#else
            ShadePoint pt = shade_point(&s, camera, &ray, &hit);
#endif
            const __global Material* m = materials + pt.sf.material;
#if SAMPLE_PACKETS
            REAL3 packed_direct = (REAL3)(packet.direct[0][lane], packet.direct[1][lane],
                                          packet.direct[2][lane]);
            radiance += task.weight * (packed ? packed_direct
                                              : shade_direct(&s, &pt.sf, pt.n, -ray.d, pt.c, m,
                                                             ambient, key, &shadow_rays));
#else
            radiance += task.weight * shade_direct(&s, &pt.sf, pt.n, -ray.d, pt.c, m, ambient,
                                                   key, &shadow_rays);
#endif
#if MAX_DEPTH > 0
            secondary_rays += spawn_secondary(&s, params, stack, &sp, &task, &ray, &pt);
#endif
        }
        sum += radiance;
    }
#endif
    REAL3 mean = sum / (REAL)spp;
    // The output buffers hold this launch's band of rows only, so that an image of any size
    // renders within the device's largest allocation.
    int slot = get_global_id(1) * width + x;
    image[slot] = (float4)((float)mean.x, (float)mean.y, (float)mean.z, 0.0f);
    ray_counts[slot] = (int4)(spp, secondary_rays, shadow_rays, 0);
#if COUNT_TESTS
    test_counts[slot] = (int4)(counts.closest_boxes, counts.closest_prims, counts.shadow_boxes,
                               counts.shadow_prims);
#endif
}

// A closest hit as intersect_rays reports it: the outward geometric normal and t (inf on a
// miss), and the primitive reference (-1).
inline void report_hit(const SceneRefs* s, const Ray* ray, const Hit* hit, __global float4* out,
                       __global int* ref) {
    if (hit->t < REAL_INF) {
        Surface sf = surface_at(s, ray, hit, false);
        *out = (float4)((float)sf.n_g.x, (float)sf.n_g.y, (float)sf.n_g.z, (float)hit->t);
        *ref = hit->ref;
    } else {
        *out = (float4)(0.0f, 0.0f, 0.0f, INFINITY);
        *ref = -1;
    }
}

// Closest hit for given rays, for tests and tools: t (inf on a miss), the primitive reference
// and the surface's outward geometric normal. Uses the same scene buffers as render. With
// sample packets a work-item takes PACKET_LANES rays as one packet, with group packets a
// work-group's rays walk together (the host pads the last group).
__kernel WORK_ITEM_LANES void intersect_rays(__global const float4* origins,
                                             __global const float4* directions,
                                             SCENE_BUFFER_PARAMS, __global float4* hits,
                                             __global int* refs) {
    int i = get_global_id(0);
    SceneRefs s = scene_refs(SCENE_BUFFER_ARGS);
#if COUNT_TESTS
    TestCounts counts = {0, 0, 0, 0};
    s.counts = &counts;
#endif
#if SAMPLE_PACKETS
    int first = i * PACKET_LANES;
    Ray rays[PACKET_LANES];
    HitLanes found;
    for (int j = 0; j < PACKET_LANES; ++j) {
        rays[j] = make_ray(TO_REAL3(origins[first + j]), TO_REAL3(directions[first + j]));
    }
    RayPacket p = ray_packet(rays);
    RayLanes lanes;
    store_ray_lanes(&p, &lanes);
    packet_closest(&s, &p, &lanes, ALL_LANES, &found, 0);
    for (int j = 0; j < PACKET_LANES; ++j) {
        Hit hit = hit_of_lane(&found, j);
        report_hit(&s, rays + j, &hit, hits + first + j, refs + first + j);
    }
#elif GROUP_PACKETS
    // A work-group's rays walk as one group packet (the host pads the last group).
    __local GroupPosts posts;
    Group g;
    group_init(&g, &posts, get_local_id(0));
    Ray ray = make_ray(TO_REAL3(origins[i]), TO_REAL3(directions[i]));
    Hit hit = group_closest(&s, &g, &ray, true);
    report_hit(&s, &ray, &hit, hits + i, refs + i);
#else
    Ray ray = make_ray(TO_REAL3(origins[i]), TO_REAL3(directions[i]));
    Hit hit = closest_hit(&s, &ray);
    report_hit(&s, &ray, &hit, hits + i, refs + i);
#endif
}
