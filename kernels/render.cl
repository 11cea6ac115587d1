// The kernels: render (one work-item per pixel; the host launches bands of rows),
// in an intersection build intersect_rays (closest hits of given rays, for tests and tools)
// and, in a passes build only,
// render_passes (a pixel's passes, passes.h). What they run is in the
// headers: a pixel's samples and their ray trees (ray_tree.h: pixel_radiance, on a CPU a row
// segment of them, render_segment) over the scene's
// queries (bvh.h) and shading (shading.h, direct.h), or the same by the sample-packet and
// group-packet schemes (packet_trace.h: packet_pixel_radiance, group_trace.h: group_pixel).
//
// Build switches (all from clray/device/program.py's KernelConfig): HAS_PLANES, HAS_SPHERES,
// HAS_BOXES, HAS_CYLINDERS, HAS_CONES, HAS_TORI, HAS_TRIANGLES, HAS_VERTEX_NORMALS, HAS_VERTEX_UVS,
// HAS_TEXTURES, HAS_TRANSMISSION, HAS_REFRACTION, HAS_FRESNEL, HAS_THIN_LENS, HAS_ORTHOGRAPHIC,
// HAS_BACKGROUND_GRADIENT, HAS_BACKGROUND_IMAGE (0 or 1), MAX_DEPTH, BVH_WIDTH, BVH_STACK_SIZE,
// USE_DOUBLE, the study variants SPHERE_TEXTBOOK, OFFSET_FIXED_EPS, TRIANGLE_NO_FP64_FALLBACK,
// TRIANGLE_MOLLER_TRUMBORE, FRESNEL_SCHLICK; FP64_SPHERES (the packer's per-scene fp64 path
// for spheres float32 cannot intersect); COUNT_TESTS (the instrumented build: box and
// primitive tests per pixel).
// HAS_SPOT_LIGHTS, HAS_AREA_LIGHTS, HAS_MESH_LIGHTS (0 or 1): the scene has spot lights, area
// lights, mesh lights (many emissive faces as one light).
// HAS_INSTANCES (0 or 1): the scene places groups by transforms (kernels/bvh.h walks into them).
// PASSES (0 or 1): the build has render_passes, for a render that asks for passes; without it
// the program is the same text as before passes existed. INTERSECT_RAYS (0 or 1): the build has
// intersect_rays (clray.device.launch.intersect_rays).
// TRAVERSAL: TRAVERSAL_SINGLE (every ray walks the BVH alone), TRAVERSAL_SAMPLE_PACKET (a
// pixel's samples' primary and shadow rays walk it in packets of PACKET_LANES, kernels/packet.h;
// PACKET_MIN_LANES: below it, lanes go on ray by ray) or TRAVERSAL_GROUP_PACKET (a work-group's
// pixels walk it together, kernels/group.h).
#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "bvh.h"
#include "surface.h"
#include "shading.h"
#include "direct.h"
#include "camera.h"
#include "background.h"
#include "ray_tree.h"
#include "packet.h"
#include "packet_trace.h"
#include "group.h"
#include "group_trace.h"
#if PASSES
#include "passes.h"
#endif

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

__kernel WORK_ITEM_LANES void render(SCENE_BUFFER_PARAMS, __global float* image,
                                     __global int2* ray_counts, __global int4* test_counts,
                                     int row_offset) {
    int x = get_global_id(0), y = get_global_id(1) + row_offset;
    int width = params->width, height = params->height;
#if RENDER_SEGMENTS
    // The group's first work-item renders its row segment (ray_tree.h: render_segment).
    if (get_local_id(0) == 0 && x < width && y < height) {
        SceneRefs s = scene_refs(SCENE_BUFFER_ARGS);
        render_segment(&s, camera, params, image, ray_counts, test_counts, x, y,
                       min((int)get_local_size(0), width - x), (int)get_global_id(1) * width + x);
    }
#else
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
    int secondary_rays = 0, shadow_rays = 0;
#if GROUP_PACKETS
    REAL3 sum = group_pixel(&s, &g, camera, params, texels, x, y, pixel, live, &secondary_rays,
                            &shadow_rays);
    if (!live) return;
#elif SAMPLE_PACKETS
    REAL3 sum = packet_pixel_radiance(&s, camera, params, x, y, pixel, &secondary_rays,
                                      &shadow_rays);
#else
    // A GPU's work-items, side by side: a pixel each.
    REAL3 sum = pixel_radiance(&s, camera, params, x, y, pixel, 0, &secondary_rays,
                               &shadow_rays);
#endif
    int slot = get_global_id(1) * width + x;
    store_pixel(&s, image, ray_counts, test_counts, slot, sum, params->spp, secondary_rays,
                shadow_rays);
#endif
}

// Closest hit for given rays, for tests and tools: t (inf on a miss), the primitive reference
// and the surface's outward geometric normal. In the intersection build only (INTERSECT_RAYS):
// in every render's program, clang optimised it at clBuildProgram for nothing (issue 42, the
// cold build). Uses the same scene buffers as render. With
// sample packets a work-item takes PACKET_LANES rays as one packet, with group packets a
// work-group's rays walk together (the host pads the last group).
#if INTERSECT_RAYS
#if !SAMPLE_PACKETS && !GROUP_PACKETS
// Ray i's closest hit, reported: a work-item's whole work, or one step of its group's loop.
HOT void intersect_one(const SceneRefs* s, __global const float4* origins,
                       __global const float4* directions, __global float4* hits,
                       __global int* refs, int i) {
    Ray ray = make_walk_ray(TO_REAL3(origins[i]), TO_REAL3(directions[i]));
    Hit hit = closest_hit(s, &ray);
    report_hit(s, &ray, &hit, hits + i, refs + i);
}
#endif

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
#elif RENDER_SEGMENTS
    // The group's first work-item walks the group's rays in a loop of its own, as the render's
    // row segments do (ray_tree.h, render_segment): PoCL's loop over work-items copied
    // SceneRefs' pointers and ran a call's prologue for every ray.
    // The group's rays end within the launch: the program is OpenCL C 1.2 (no -cl-std), whose
    // work-groups are uniform (the global size a multiple of the local size, whether the host
    // or the driver picks it), a non-uniform group's get_local_size is its own, and no launch
    // (clray.device.launch.intersect_rays, benchmarks/embree.py) gives a global offset.
    if (get_local_id(0) != 0) return;
    int end = i + (int)get_local_size(0);
    for (; i < end; ++i) intersect_one(&s, origins, directions, hits, refs, i);
#else
    intersect_one(&s, origins, directions, hits, refs, i);
#endif
}
#endif

#if PASSES
// A pixel's passes (passes.h), one work-item per pixel over a band of rows as render's: normal
// and depth, position, albedo, and the nearest sample's primitive reference, instance and
// material. Depth, position and normal are the means over the samples that hit (the normal
// renormalised; depth inf, position and normal 0 where none hit), albedo the mean over all.
__kernel WORK_ITEM_LANES void render_passes(SCENE_BUFFER_PARAMS, __global float4* geometry,
                                            __global float4* position, __global float4* albedo,
                                            __global int4* indices, int row_offset) {
    int x = get_global_id(0), y = get_global_id(1) + row_offset;
    int width = params->width;
    if (x >= width || y >= params->height) return;
    SceneRefs s = scene_refs(SCENE_BUFFER_ARGS);
#if COUNT_TESTS
    TestCounts counts = {0, 0, 0, 0};
    s.counts = &counts;
#endif
    PixelPasses p = pixel_passes(&s, camera, params, x, y, (uint)(y * width + x));
    REAL hits = (REAL)p.hits;
    REAL3 normal = p.hits > 0 ? safe_normalize(p.normal) : (REAL3)(0, 0, 0);
    REAL3 where = p.hits > 0 ? p.position / hits : (REAL3)(0, 0, 0);
    REAL3 colour = p.albedo / (REAL)params->spp;
    int slot = get_global_id(1) * width + x;
    geometry[slot] = (float4)((float)normal.x, (float)normal.y, (float)normal.z,
                              p.hits > 0 ? (float)(p.depth / hits) : INFINITY);
    position[slot] = (float4)((float)where.x, (float)where.y, (float)where.z, 0.0f);
    albedo[slot] = (float4)((float)colour.x, (float)colour.y, (float)colour.z, 0.0f);
    indices[slot] = (int4)(p.ref, p.instance, p.material, 0);
}
#endif
