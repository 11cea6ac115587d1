// The scene as the kernels see it: its buffers in one order, and SceneRefs, the view of them
// that every query and shading function takes.
//
// SCENE_BUFFERS is that order, X(element type, name) per buffer. The kernels' parameter lists
// (SCENE_BUFFER_PARAMS), the calls that pass them on (SCENE_BUFFER_ARGS) and SceneRefs' fields
// all expand it, and the host sets arguments from clray/device/layout.py's SCENE_BUFFERS, which
// tests/test_layout.py checks against this list on the device: name, type and position. A new
// buffer is one line here and one there (and its struct in clray_types.h).
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
#define SCENE_REFS_SET(type, name) s.name = name;
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

typedef struct {
    SCENE_BUFFERS(SCENE_REFS_FIELD, )
    int n_planes, n_nodes, n_lights;  // from params, read once
#if COUNT_TESTS
    TestCounts* counts;  // the caller's, set after scene_refs
#endif
} SceneRefs;

static inline SceneRefs scene_refs(SCENE_BUFFER_PARAMS) {
    SceneRefs s;
    SCENE_BUFFERS(SCENE_REFS_SET, )
    s.n_planes = params->n_planes;
    s.n_nodes = params->n_nodes;
    s.n_lights = params->n_lights;
    return s;
}

#endif
