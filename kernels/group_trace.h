// Group packets' drivers (TRAVERSAL_GROUP_PACKET): a pixel's samples and their ray trees traced
// with the work-group's, every query and shadow ray a walk of the whole group (group.h).
#ifndef CLRAY_GROUP_TRACE_H
#define CLRAY_GROUP_TRACE_H

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
#include "direct.h"
#include "camera.h"
#include "background.h"
#include "ray_tree.h"
#include "group.h"

#if GROUP_PACKETS
// shade_direct for the group: every work-item takes part in each light's shadow walk, with a
// shadow ray where `shaded` and the light reaches the point.
static inline REAL3 group_direct(const SceneRefs* s, Group* g, const ShadePoint* pt, REAL3 v,
                                 REAL3 ambient_light, SampleKey key, bool shaded,
                                 int* shadow_rays) {
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
        // As shade_direct's test (direct.h), so a NaN filter goes the same way in both.
        if (lit && !(max_comp3(filter) <= (REAL)0)) {
            result += light_term(s, i, pt->n, v, pt->c, m, l, atten, ndl, filter);
        }
    }
    return result;
}

// A pixel's radiance summed over its samples, its rays walking with the group's: every
// work-item of the group runs it, those outside the image (`live` false) without rays. Each
// pass of the loop takes one ray of the tree from every work-item that has one left.
static inline REAL3 group_pixel(const SceneRefs* s, Group* g, const __global Camera* camera,
                                const __global Params* params, const __global float4* texels, int x,
                                int y, uint pixel, bool live, int* secondary_rays,
                                int* shadow_rays) {
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

#endif
