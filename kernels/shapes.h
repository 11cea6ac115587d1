// Every shape, and the switches over them by a primitive reference's type (clray_types.h:
// PRIM_*): its crossings, its material and its surface; a leaf packet's crossings (triangles
// and spheres, four at a time); for sample packets its record and surface lane-wise.
#ifndef CLRAY_SHAPES_H
#define CLRAY_SHAPES_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shape.h"
#include "plane.h"
#include "sphere.h"
#include "box.h"
#include "cylinder.h"
#include "cone.h"
#include "torus.h"
#include "triangle.h"

// Triangles and spheres are tested in packets (leaf_closest, leaf_transmission), the other
// primitives one by one. No leaf reaches the sphere and plane cases (spheres go in packets,
// planes are not in the BVH: clray/accel/wide.py), but left out they ran primitives' 1-spp
// render 0.18 % more instructions (clang laid the walks out anew), so they stay.
// HAS_ONE_BY_ONE_SHAPES: whether a leaf can hold a box, cylinder, cone or torus; without, the
// walks compile no loop over a leaf's one-by-one section, which then holds instances only
// (entered by push_instances): spheres' 1-spp render ran 1.2 % fewer instructions and its code
// shrank 12 % (issue 42, the cold build: docs/acceleration.md, The one-by-one shapes' loop
// compiled only where they exist, 2026-12-05).
#define HAS_ONE_BY_ONE_SHAPES (HAS_BOXES || HAS_CYLINDERS || HAS_CONES || HAS_TORI)
#if HAS_ONE_BY_ONE_SHAPES
HOT Crossings intersect_prim(const SceneRefs* s, int ref, const Ray* r) {
    int i = ref & PRIM_INDEX_MASK;
    switch (ref >> PRIM_TYPE_SHIFT) {
#if HAS_PLANES
        case PRIM_PLANE:
            return intersect_plane(s->planes + i, r);
#endif
#if HAS_SPHERES
        case PRIM_SPHERE:
            return intersect_sphere(s->spheres + i, r);
#endif
#if HAS_BOXES
        case PRIM_BOX:
            return intersect_box(s->boxes + i, r);
#endif
#if HAS_CYLINDERS
        case PRIM_CYLINDER:
            return intersect_cylinder(s->cylinders + i, r);
#endif
#if HAS_CONES
        case PRIM_CONE:
            return intersect_cone(s->cones + i, r);
#endif
#if HAS_TORI
        case PRIM_TORUS:
            return intersect_torus(s->tori + i, r);
#endif
        default:
            return no_crossings();
    }
}
#endif

// part: the crossing's part, which for a triangle is its slot (the index of its Triangle record
// or material word: these are in prim_refs' order, so that the hits of neighbouring rays read
// neighbouring records).
static inline int prim_material(const SceneRefs* s, int ref, int part) {
    int i = ref & PRIM_INDEX_MASK;
    switch (ref >> PRIM_TYPE_SHIFT) {
#if HAS_PLANES
        case PRIM_PLANE:
            return s->planes[i].material;
#endif
#if HAS_SPHERES
        case PRIM_SPHERE:
            return s->spheres[i].material;
#endif
#if HAS_BOXES
        case PRIM_BOX:
            return s->boxes[i].material;
#endif
#if HAS_CYLINDERS
        case PRIM_CYLINDER:
            return s->cylinders[i].material;
#endif
#if HAS_CONES
        case PRIM_CONE:
            return s->cones[i].material;
#endif
#if HAS_TORI
        case PRIM_TORUS:
            return s->tori[i].material;
#endif
#if HAS_TRIANGLES
        case PRIM_TRIANGLE:
            return triangle_material(s, part) & TRIANGLE_MATERIAL_MASK;
#endif
        default:
            return 0;
    }
}

// The crossings of a packet's PACKET_WIDTH shapes: bit k set where lane k is crossed, its
// crossings in c[k]. kind: PRIM_TRIANGLE or PRIM_SPHERE. A triangle's part is its slot, where
// shading finds its corners (triangle.h: triangle_surface).
HOT int packet_crossings(const SceneRefs* s, int kind, int slot, const Ray* r, Crossings* c) {
    int bits = 0;
    REAL t0[PACKET_WIDTH], t1[PACKET_WIDTH], b1[PACKET_WIDTH], b2[PACKET_WIDTH];
#if HAS_TRIANGLES
    if (kind == PRIM_TRIANGLE) {
        bits = intersect_triangle_packet(s->triangle_packets + slot / PACKET_WIDTH, r, t0, b1,
                                         b2);
        for (int rest = bits; rest; rest &= rest - 1) {
            int k = lowest_bit(rest);
            c[k] = no_crossings();
            c[k].t[0] = t0[k];
            c[k].part[0] = slot + k;
            c[k].b1 = b1[k];
            c[k].b2 = b2[k];
        }
    }
#endif
#if HAS_SPHERES
    if (kind == PRIM_SPHERE) {
#if SPHERE_FP64 || SPHERE_TEXTBOOK
        // These variants keep their scalar formula, lane by lane.
        for (int k = 0; k < PACKET_WIDTH; ++k) {
            int ref = s->prim_refs[slot + k];
            if (ref < 0) continue;
            c[k] = intersect_sphere(s->spheres + (ref & PRIM_INDEX_MASK), r);
            if (c[k].t[0] < REAL_INF || c[k].t[1] < REAL_INF) bits |= 1 << k;
        }
#else
        bits = intersect_sphere_packet(s->sphere_packets + slot / PACKET_WIDTH, r, t0, t1);
        for (int rest = bits; rest; rest &= rest - 1) {
            int k = lowest_bit(rest);
            c[k] = no_crossings();
            c[k].t[0] = t0[k];
            c[k].t[1] = t1[k];
        }
#endif
    }
#endif
    return bits;
}

// want_uv: the material samples an image texture. Only then are (u, v) computed: a sphere's
// atan2 and asin cost as much as the rest of its shading. r and the primitive in one frame.
HOT Surface shape_surface(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
    Surface sf;
    int i = hit->ref & PRIM_INDEX_MASK;
    REAL3 p = r->o + hit->t * r->d;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    sf.uv = (REAL2)(0, 0);
#if HAS_VERTEX_COLORS
    sf.tint = (REAL3)(1, 1, 1);
#endif
    switch (hit->ref >> PRIM_TYPE_SHIFT) {
#if HAS_PLANES
        case PRIM_PLANE:
            plane_surface(s->planes + i, r, hit, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_SPHERES
        case PRIM_SPHERE:
            sphere_surface(s->spheres + i, r, hit, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_BOXES
        case PRIM_BOX:
            box_surface(s->boxes + i, r, hit, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_CYLINDERS
        case PRIM_CYLINDER:
            cylinder_surface(s->cylinders + i, r, hit, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_CONES
        case PRIM_CONE:
            cone_surface(s->cones + i, r, hit, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_TORI
        case PRIM_TORUS:
            torus_surface(s->tori + i, want_uv, gamma, &p, &sf);
            break;
#endif
#if HAS_TRIANGLES
        case PRIM_TRIANGLE:
            return triangle_surface(s, r, hit, want_uv);
#endif
        default:
            sf.n_g = -r->d;
            sf.err = 0;
            sf.material = 0;
            break;
    }
    sf.p = p;
    sf.n_s = sf.n_g;
    return sf;
}

#if SURFACE_LANES
// The record of the shape hit as (ref, part) into f (row r at f[r * stride]: its corners,
// centre or plane), its material and smoothness. False where shade_point must shade the lane:
// another shape or vertex texture coordinates.
HOT bool shape_record(const SceneRefs* s, int ref, int part, REAL* f, int stride, int* material,
                      LANE_INT* smooth) {
    int i = ref & PRIM_INDEX_MASK;
    *smooth = 0;
    switch (ref >> PRIM_TYPE_SHIFT) {
#if HAS_TRIANGLES
        case PRIM_TRIANGLE:
            return triangle_record(s, part, f, stride, material, smooth);
#endif
#if HAS_SPHERES
        case PRIM_SPHERE:
            return sphere_record(s, i, part, f, stride, material, smooth);
#endif
#if HAS_PLANES
        case PRIM_PLANE:
            return plane_record(s, i, part, f, stride, material, smooth);
#endif
        default:
            return false;
    }
}

// shape_surface lane-wise, for the lanes of each kind of shape (g->kind): lanes whose lengths
// leave plain_length_lanes's range are added to *outside.
HOT SurfaceOfLanes shape_surface_lanes(const ShapeLanes* g, const RayPacket* r, const PacketHit* h,
                                       MASKP* outside) {
    SurfaceOfLanes sf = {0};
#if HAS_TRIANGLES
    MASKP triangles = g->kind == (MASKP)(PRIM_TRIANGLE);
    if (lane_mask(triangles)) {
        MASKP wide = (MASKP)(0);
        SurfaceOfLanes v = triangle_surface_lanes(g, r, h, &wide);
        *outside |= triangles & wide;
        take_surface(triangles, &v, &sf);
    }
#endif
#if HAS_SPHERES
    MASKP spheres = g->kind == (MASKP)(PRIM_SPHERE);
    if (lane_mask(spheres)) {
        MASKP wide = (MASKP)(0);
        SurfaceOfLanes v = sphere_surface_lanes(g, r, h, &wide);
        *outside |= spheres & wide;
        take_surface(spheres, &v, &sf);
    }
#endif
#if HAS_PLANES
    MASKP planes = g->kind == (MASKP)(PRIM_PLANE);
    if (lane_mask(planes)) {
        SurfaceOfLanes v = plane_surface_lanes(g, r, h);
        take_surface(planes, &v, &sf);
    }
#endif
    return sf;
}
#endif

#endif
