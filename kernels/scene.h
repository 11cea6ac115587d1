// The scene as the kernels see it: its buffers in one order, and SceneRefs, the view of those
// a build reads that every query and shading function takes.
//
// SCENE_BUFFERS is that order, X(element type, name) per buffer. The kernels' parameter lists
// (SCENE_BUFFER_PARAMS) and the calls that pass them on (SCENE_BUFFER_ARGS) expand it, and
// the host sets arguments from clray/device/layout.py's SCENE_BUFFERS, which
// tests/test_layout.py checks against this list on the device: name, type and position. A new
// buffer is one line here and one there (and its struct in clray_types.h), and one in
// SCENE_BUFFERS_READ below, under the switch of the code that reads it.
#ifndef CLRAY_SCENE_H
#define CLRAY_SCENE_H

#include "clray_types.h"

#define SCENE_BUFFERS(X, SEP)               \
    X(Camera, camera) SEP                   \
    X(Params, params) SEP                   \
    X(Plane, planes) SEP                    \
    X(Sphere, spheres) SEP                  \
    X(Box, boxes) SEP                       \
    X(Cylinder, cylinders) SEP              \
    X(Cone, cones) SEP                      \
    X(Torus, tori) SEP                      \
    X(Triangle, triangles) SEP              \
    X(int, triangle_materials) SEP          \
    X(TrianglePacket, triangle_packets) SEP \
    X(SpherePacket, sphere_packets) SEP     \
    X(float4, normals) SEP                  \
    X(float2, uvs) SEP                      \
    X(float4, colors) SEP                   \
    X(BvhNode, nodes) SEP                   \
    X(int, prim_refs) SEP                   \
    X(Material, materials) SEP              \
    X(Texture, textures) SEP                \
    X(float4, texels) SEP                   \
    X(Light, lights) SEP                    \
    X(Instance, instances)

// A separator for SCENE_BUFFERS: a comma cannot be a macro argument itself.
#define SCENE_COMMA ,
#define SCENE_BUFFER_PARAM(type, name) __global const type* name
#define SCENE_BUFFER_ARG(type, name) name
#define SCENE_REFS_FIELD(type, name) __global const type* name;
#define SCENE_BUFFER_PARAMS SCENE_BUFFERS(SCENE_BUFFER_PARAM, SCENE_COMMA)
#define SCENE_BUFFER_ARGS SCENE_BUFFERS(SCENE_BUFFER_ARG, SCENE_COMMA)

// Whether the build has a BVH to walk: the planes, unbounded, are tested one by one.
#define HAS_BVH \
    (HAS_SPHERES || HAS_BOXES || HAS_CYLINDERS || HAS_CONES || HAS_TORI || HAS_TRIANGLES)

// Whether some triangle has vertex normals, uvs or colours. Then each triangle slot has a
// Triangle record in `triangles` (vertex indices and material word); else it has only its
// material word in `triangle_materials`, 4 bytes a slot instead of 16, as nothing else of the
// record would be read (clray/device/pack.py: _in_slot_order packs the one these switches read).
#define HAS_VERTEX_ATTRIBUTES (HAS_VERTEX_NORMALS || HAS_VERTEX_UVS || HAS_VERTEX_COLORS)

// COUNT_TESTS (the instrumented build of benchmarks/bench.py): box and primitive tests per
// work-item, for closest-hit and shadow queries apart.
typedef struct {
    int closest_boxes, closest_prims, shadow_boxes, shadow_prims;
} TestCounts;

#if COUNT_TESTS
#define COUNT(s, field, n) ((s)->counts->field += (n))
#else
#define COUNT(s, field, n)
#endif

// SCENE_BUFFERS_READ: the buffers that the build's kernels read, each under the switch of the
// code that reads it; SceneRefs has fields for these only, so a read outside its switch does
// not compile. Why not all 22: the single-ray render kernel makes a SceneRefs for each
// work-item (PoCL gives each its own copy of a variable whose address a call takes) and passes
// it to pixel_radiance, out of line (ray_tree.h), which the compiler cannot see read only some
// fields: each field was a store a pixel. The 327,680-triangle mesh at depth 0 went from 682
// to 658 instructions a ray (docs/acceleration.md, The render kernel's SceneRefs, 2026-12-05).
// texels is in every build (the sky's calls pass it whether or not a background image reads
// it), and nodes and prim_refs (bvh.h's leaf helpers are built whether or not HAS_BVH).
#if HAS_PLANES
#define SCENE_READS_PLANES(X) X(Plane, planes)
#else
#define SCENE_READS_PLANES(X)
#endif
#if HAS_SPHERES
#define SCENE_READS_SPHERES(X) X(Sphere, spheres) X(SpherePacket, sphere_packets)
#else
#define SCENE_READS_SPHERES(X)
#endif
#if HAS_BOXES
#define SCENE_READS_BOXES(X) X(Box, boxes)
#else
#define SCENE_READS_BOXES(X)
#endif
#if HAS_CYLINDERS
#define SCENE_READS_CYLINDERS(X) X(Cylinder, cylinders)
#else
#define SCENE_READS_CYLINDERS(X)
#endif
#if HAS_CONES
#define SCENE_READS_CONES(X) X(Cone, cones)
#else
#define SCENE_READS_CONES(X)
#endif
#if HAS_TORI
#define SCENE_READS_TORI(X) X(Torus, tori)
#else
#define SCENE_READS_TORI(X)
#endif
#if HAS_TRIANGLES
#define SCENE_READS_TRIANGLES(X) \
    X(Triangle, triangles) X(int, triangle_materials) X(TrianglePacket, triangle_packets)
#else
#define SCENE_READS_TRIANGLES(X)
#endif
#if HAS_VERTEX_NORMALS
#define SCENE_READS_NORMALS(X) X(float4, normals)
#else
#define SCENE_READS_NORMALS(X)
#endif
#if HAS_VERTEX_UVS
#define SCENE_READS_UVS(X) X(float2, uvs)
#else
#define SCENE_READS_UVS(X)
#endif
#if HAS_VERTEX_COLORS
#define SCENE_READS_COLORS(X) X(float4, colors)
#else
#define SCENE_READS_COLORS(X)
#endif
#if HAS_TEXTURES
#define SCENE_READS_TEXTURES(X) X(Texture, textures)
#else
#define SCENE_READS_TEXTURES(X)
#endif
#if HAS_INSTANCES
#define SCENE_READS_INSTANCES(X) X(Instance, instances)
#else
#define SCENE_READS_INSTANCES(X)
#endif
#define SCENE_BUFFERS_READ(X)                                                               \
    X(Camera, camera) X(Params, params) X(Material, materials) X(float4, texels)          \
    X(Light, lights) X(BvhNode, nodes) X(int, prim_refs) SCENE_READS_PLANES(X)           \
    SCENE_READS_SPHERES(X) SCENE_READS_BOXES(X) SCENE_READS_CYLINDERS(X)                  \
    SCENE_READS_CONES(X) SCENE_READS_TORI(X) SCENE_READS_TRIANGLES(X)                     \
    SCENE_READS_NORMALS(X) SCENE_READS_UVS(X) SCENE_READS_COLORS(X) SCENE_READS_TEXTURES(X) \
    SCENE_READS_INSTANCES(X)
#define SCENE_REFS_SET(type, name) s.name = name;

typedef struct {
    SCENE_BUFFERS_READ(SCENE_REFS_FIELD)
    int n_planes, n_nodes, n_lights;  // from params, read once
#if COUNT_TESTS
    TestCounts* counts;  // the caller's, set after scene_refs
#endif
} SceneRefs;

static inline SceneRefs scene_refs(SCENE_BUFFER_PARAMS) {
    SceneRefs s;
    SCENE_BUFFERS_READ(SCENE_REFS_SET)
    s.n_planes = params->n_planes;
    s.n_nodes = params->n_nodes;
    s.n_lights = params->n_lights;
    return s;
}

#endif
