// Passes (AOVs; docs/passes.md): what a pixel's primary rays meet, before any light. The same
// camera rays (sample_ray), closest hits (closest_hit) and shading points (shade_point) as the
// render, sample by sample: the mean depth, position and shading normal of the samples that hit,
// the mean albedo of all samples (a miss adds none), and the primitive, instance and material of
// the sample nearest the pixel centre. Built only into a passes build (PASSES, render.cl's
// render_passes), so a render without passes compiles none of it.
#ifndef CLRAY_PASSES_H
#define CLRAY_PASSES_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "bvh.h"
#include "surface.h"
#include "shading.h"
#include "camera.h"
#include "sampling.h"

// A pixel's passes: sums over its samples (depth, position and normal over those that hit) and
// the indices of its sample nearest the centre (-1 where that sample missed).
typedef struct {
    REAL3 normal, position, albedo;
    REAL depth;
    int hits;
    int ref, instance, material;
} PixelPasses;

// Pixel (x, y)'s passes over its spp samples.
HOT PixelPasses pixel_passes(const SceneRefs* s, const __global Camera* camera,
                             const __global Params* params, int x, int y, uint pixel) {
    PixelPasses out;
    out.normal = out.position = out.albedo = (REAL3)(0, 0, 0);
    out.depth = 0;
    out.hits = 0;
    out.ref = out.instance = out.material = -1;
    int spp = params->spp;
    REAL2 centre = (REAL2)((REAL)x + REAL_C(0.5), (REAL)y + REAL_C(0.5));
    REAL nearest = REAL_INF;
    for (int sample = 0; sample < spp; ++sample) {
        REAL3 o, d;
        sample_ray(camera, params, x, y, sample, pixel, &o, &d);
        Ray ray = make_walk_ray(o, d);
        Hit hit = closest_hit(s, &ray);
        bool found = hit.t < REAL_INF;
        int material = -1;
        if (found) {
            ShadePoint pt = shade_point(s, camera, &ray, &hit);
            out.depth += hit.t;
            out.position += pt.sf.p + TO_REAL3(camera->world);
            out.normal += pt.sf.n_s;
            out.albedo += pt.c;
            out.hits++;
            material = pt.sf.material;
        }
        // The first of equally near samples keeps the pixel's indices.
        REAL2 off = sample_position(x, y, sample, spp, params->seed, pixel) - centre;
        REAL away = dot(off, off);
        if (away < nearest) {
            nearest = away;
            out.ref = found ? hit.ref : -1;
            out.instance = found ? hit.instance : -1;
            out.material = material;
        }
    }
    return out;
}

#endif
