// A sample's ray tree (docs/rendering.md): the primary ray's task, and at each shaded hit the
// reflected and refracted rays pushed on an explicit stack (OpenCL C has no recursion), with
// the media stack that refraction walks through nested glass; the tree's light (tree_radiance),
// and a pixel's, its samples' trees traced ray by ray (pixel_radiance, the single-ray scheme).
#ifndef CLRAY_RAY_TREE_H
#define CLRAY_RAY_TREE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "bvh.h"
#include "surface.h"
#include "shading.h"
#include "direct.h"
#include "camera.h"
#include "fresnel.h"
#include "background.h"
#include "lanes.h"

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

// One node of the ray tree, waiting on the explicit stack (OpenCL C has no recursion).
typedef struct {
    REAL3 o, d, weight;
    int depth;
    int media_count;  // materials the ray is inside, innermost last
    int media[MEDIA_DEPTH];
} RayTask;

static inline REAL medium_ior(const SceneRefs* s, const RayTask* task) {
    return task->media_count > 0 ? TO_REAL(s->materials[task->media[task->media_count - 1]].ior)
                                 : (REAL)1;
}

// The mirror image of direction d in a surface of normal n (dn = d . n): for one ray (C: REAL3,
// its components at once; S: REAL) or one component of a packet's lanes (C and S: REALP),
// written once (real.h, Twins).
#define DEFINE_MIRROR(SPEC, C, S, NAME) \
    SPEC C NAME(C d, S dn, C n) { return d - (REAL)2 * dn * n; }
DEFINE_MIRROR(static inline, REAL3, REAL, mirror_of)

static inline REAL3 mirror(REAL3 d, REAL3 n) { return mirror_of(d, dot3(d, n), n); }

// A ray too faint to matter (weight below min_weight) is not traced: inside glass the tree
// doubles at every level, so deep trees need the cut.
static inline bool too_faint(REAL3 weight, float min_weight) {
    return fmax(fmax(weight.x, weight.y), weight.z) < (REAL)min_weight;
}

// Push a secondary ray whose direction (and media) are set: it starts off the surface on the
// side it leaves to, one level deeper in the ray tree, unless it is too faint. Returns the rays
// pushed (0 or 1).
static inline int spawn(RayTask* stack, int* sp, RayTask* next, const Surface* sf, REAL3 weight,
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
static inline REAL refract_media(const SceneRefs* s, const RayTask* in, RayTask* out, int m,
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

#if MAX_DEPTH > 0
// Push the reflected and refracted rays of a shaded hit (ray, pt) of `task`: returns the rays
// pushed.
static inline int spawn_secondary(const SceneRefs* s, const __global Params* params, RayTask* stack,
                                  int* sp, const RayTask* task, const Ray* ray,
                                  const ShadePoint* pt) {
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
        REAL cos_i = -dot3(ray->d, n);
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
            next.d = normalize3(eta * ray->d + (eta * cos_i - sqrt(k)) * n);
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

// The ray tree's root task: a primary ray (o, d), in no medium, of full weight.
static inline RayTask root_task(REAL3 o, REAL3 d) {
    RayTask task;
    task.o = o;
    task.d = d;
    task.weight = (REAL3)(1, 1, 1);
    task.depth = 0;
    task.media_count = 0;
    return task;
}

// The sample's primary ray as the ray tree's root task.
static inline RayTask primary_task(const __global Camera* camera, const __global Params* params,
                                   int x, int y, int sample, uint pixel) {
    REAL3 o, d;
    sample_ray(camera, params, x, y, sample, pixel, &o, &d);
    return root_task(o, d);
}

// The light of a sample's ray tree from the sp tasks on the stack, added to `radiance` task by
// task: where a task's ray leaves the scene the sky's, else the direct light at its hit
// (ambient: the scene's ambient light), weighted, with its reflected and refracted rays
// pushed.
HOT REAL3 tree_radiance(const SceneRefs* s, const __global Camera* camera,
                        const __global Params* params, SampleKey key, REAL3 ambient,
                        RayTask* stack, int sp, REAL3 radiance, int* secondary_rays,
                        int* shadow_rays) {
    while (sp > 0) {
        RayTask task = stack[--sp];
        Ray ray = make_walk_ray(task.o, task.d);
        Hit hit = closest_hit(s, &ray);
        if (!(hit.t < REAL_INF)) {
            radiance += sky(params, s->texels, task.d, task.weight);
            continue;
        }
        ShadePoint pt = shade_point(s, camera, &ray, &hit);
        const __global Material* m = s->materials + pt.sf.material;
        radiance += task.weight * shade_direct(s, &pt.sf, pt.n, -ray.d, pt.c, m, ambient, key,
                                               shadow_rays);
#if MAX_DEPTH > 0
        *secondary_rays += spawn_secondary(s, params, stack, &sp, &task, &ray, &pt);
#endif
    }
    return radiance;
}

// Pixel (x, y)'s radiance summed over its samples, each sample's ray tree traced ray by ray:
// the sample's own radiance first, then the pixel's sum (a sample packet sums its lanes'
// samples so, each lane's levels in the same order). With `first`, sample 0's primary ray is
// that task, made ahead (render_segment); without (0), made here as the others.
// Inlined into render_segment's loop, where a call a pixel cost 3 to 4 % of the mesh's 1-spp
// render's CPU time, except where LARGE_LEAF_TESTS (bvh.h): there it stays a function of its
// own, for a clBuildProgram not 0.04 to 0.06 CPU-s longer (docs/acceleration.md, The
// single-ray render's row segments). A GPU build inlines it into the render kernel.
#if RENDER_SEGMENTS && LARGE_LEAF_TESTS
#define PIXEL_RADIANCE OUT_OF_LINE
#else
#define PIXEL_RADIANCE HOT
#endif
PIXEL_RADIANCE REAL3 pixel_radiance(const SceneRefs* s, const __global Camera* camera,
                         const __global Params* params, int x, int y, uint pixel,
                         const RayTask* first, int* secondary_rays, int* shadow_rays) {
    REAL3 sum = (REAL3)(0, 0, 0), ambient = TO_REAL3(params->ambient);
    int spp = params->spp;
    SampleKey key = sample_key(params->seed, pixel, spp);
    for (int sample = 0; sample < spp; ++sample) {
        key.sample = sample;
        RayTask stack[RAY_STACK_SIZE];
        stack[0] = first && sample == 0 ? *first
                                        : primary_task(camera, params, x, y, sample, pixel);
        sum += tree_radiance(s, camera, params, key, ambient, stack, 1, (REAL3)(0, 0, 0),
                             secondary_rays, shadow_rays);
    }
    return sum;
}

// A pixel's output in the launch's band (slot: its place there; the buffers hold the band's
// rows only, so that an image of any size renders within the device's largest allocation):
// the mean radiance as three packed floats, which the host copies straight into its image's
// rows, and the secondary and shadow rays (the host counts the spp primary rays): 20 bytes a
// pixel, not two float4s' 32. In the instrumented build, also the pixel's tests (s->counts).
HOT void store_pixel(const SceneRefs* s, __global float* image, __global int2* ray_counts,
                     __global int4* test_counts, int slot, REAL3 sum, int spp,
                     int secondary_rays, int shadow_rays) {
    REAL3 mean = sum / (REAL)spp;
    vstore3((float3)((float)mean.x, (float)mean.y, (float)mean.z), slot, image);
    ray_counts[slot] = (int2)(secondary_rays, shadow_rays);
#if COUNT_TESTS
    test_counts[slot] = (int4)(s->counts->closest_boxes, s->counts->closest_prims,
                               s->counts->shadow_boxes, s->counts->shadow_prims);
#endif
}

#if RENDER_SEGMENTS
// Where work-items run one after another (SERIAL_WORK_ITEMS) the single-ray render kernel's
// first work-item of a group renders the group's row segment: `count` pixels of row y from
// x = first on, written from band slot `slot` on; the group's other work-items do nothing.
// A CPU driver runs a group's work-items in a loop on one thread anyway; written here, the
// loop is the renderer's own:
// - PoCL's work-item loop had cost more than the pixels' work where rays are cheap: a pass a
//   pixel, SceneRefs' 22 pointers copied for the call, the call's prologue. A group's pixels in
//   this loop ran the mesh's primary rays (1 spp, 13 % hit) in 0.032 s, not 0.050, and 620
//   instructions a ray, not 677; whole scenes at 1 spp 5 to 11 % faster;
// - out of line, the renderer is compiled once. PoCL inlines a kernel's body into its
//   work-item loop and that loop into the two work-group functions it makes
//   (_pocl_kernel_render, _workgroup and _workgroup_fast): a renderer inlined into the kernel
//   was optimised and compiled to machine code three times at the first launch (issue 42);
// - the camera rays of CAMERA_AHEAD pixels are made before their walks: each is a chain of
//   dependent divisions and a square root, which overlap from pixel to pixel in a loop of
//   their own, where ahead of each walk the walk waited on its ray (one ahead, not 16: the
//   kernel 8 % slower); a pinhole's at one sample a pixel in a vector's lanes
//   (camera.h, row_directions)
// (docs/acceleration.md, The single-ray render's row segments, 2026-12-05, and The render's
// camera rays in lanes, 2026-12-07).
// restrict: the image and counts it writes are other buffers than the camera and params it
// reads, so the compiler keeps their fields in registers from pixel to pixel rather than load
// them again after every store: 514 -> 510 instructions a ray on the mesh at 1 spp, 0.6 %
// fewer on spheres.
OUT_OF_LINE void render_segment(SceneRefs* s, const __global Camera* restrict camera,
                                const __global Params* restrict params,
                                __global float* restrict image,
                                __global int2* restrict ray_counts,
                                __global int4* restrict test_counts,
                                int first, int y, int count, int slot) {
    int width = params->width, spp = params->spp;
    for (int start = 0; start < count; start += CAMERA_AHEAD) {
        int n = min(CAMERA_AHEAD, count - start);
        RayTask rays[CAMERA_AHEAD];
#if CAMERA_ROW_LANES
        REAL dx[CAMERA_AHEAD], dy[CAMERA_AHEAD], dz[CAMERA_AHEAD];
        if (spp == 1 && row_directions(camera, first + start, y, n, width, params->height,
                                       dx, dy, dz)) {
            REAL3 o = TO_REAL3(camera->position);
            for (int i = 0; i < n; ++i) rays[i] = root_task(o, (REAL3)(dx[i], dy[i], dz[i]));
        } else
#endif
        for (int i = 0; i < n; ++i) {
            int x = first + start + i;
            REAL3 o, d;
            sample_ray(camera, params, x, y, 0, (uint)(y * width + x), &o, &d);
            rays[i] = root_task(o, d);
        }
        for (int i = 0; i < n; ++i) {
            int x = first + start + i, secondary_rays = 0, shadow_rays = 0;
#if COUNT_TESTS
            TestCounts counts = {0, 0, 0, 0};
            s->counts = &counts;
#endif
            REAL3 sum = pixel_radiance(s, camera, params, x, y, (uint)(y * width + x),
                                       rays + i, &secondary_rays, &shadow_rays);
            store_pixel(s, image, ray_counts, test_counts, slot + start + i, sum, spp,
                        secondary_rays, shadow_rays);
        }
    }
}
#endif

#endif
