// Scene queries: closest hit and shadow transmission over the planes (a short list: they are
// unbounded) and the wide BVH of every bounded primitive (clray_types.h: BvhNode).
// closest_hit and transmission walk it ray by ray; the sample packets' walk (packet.h) and the
// group's (group.h) run these walks for lanes and work-items that go on alone.
#ifndef CLRAY_BVH_H
#define CLRAY_BVH_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "shapes.h"

// BVH_STACK_SIZE: set by the host from the tree (clray/accel/wide.py: stack_size), so no walk
// can overflow it.

#if BVH_WIDTH == 8
typedef int8 INTW;
#define VLOADW vload8
#define VSTOREW vstore8
#ifdef USE_DOUBLE
typedef double8 REALW;
#define TO_REALW(v) convert_double8(v)
#define MASK_TO_INTW(m) convert_int8(m)
#define SIGNS_W as_long8
#else
typedef float8 REALW;
#define TO_REALW(v) (v)
#define MASK_TO_INTW(m) (m)
#define SIGNS_W as_int8
#endif
HOT int lane_bits(INTW m) { return lane_bits8(m); }
#elif BVH_WIDTH == 4
typedef int4 INTW;
#define VLOADW vload4
#define VSTOREW vstore4
#ifdef USE_DOUBLE
typedef double4 REALW;
#define TO_REALW(v) convert_double4(v)
#define MASK_TO_INTW(m) convert_int4(m)
#define SIGNS_W as_long4
#else
typedef float4 REALW;
#define TO_REALW(v) (v)
#define MASK_TO_INTW(m) (m)
#define SIGNS_W as_int4
#endif
HOT int lane_bits(INTW m) { return lane_bits4(m); }
#else
#error "BVH_WIDTH must be 4 or 8"
#endif

// Of two crossings that tie in t, whether (instance, ref) goes before the hit: the scene's own
// primitives first, by reference, which orders by type and then by scene order
// (docs/rendering.md); then instances in scene order, within one by reference.
static inline bool tie_before(const Hit* hit, int ref, int instance) {
#if HAS_INSTANCES
    if (instance != hit->instance) return instance < hit->instance;
#endif
    return ref < hit->ref;
}

// The first crossing ahead of the origin, ties going by tie_before. Crossings within
// TIE_ROUNDINGS roundings of each other tie: different shapes reach one point through
// different formulas, and an exact comparison would pick between coplanar primitives at random.
#define TIE_ROUNDINGS 64

// The relative width of a tie. An instance's crossings come through its float32 matrices in
// every build, so where instances exist ties count float32 roundings in the double build too:
// a box standing on a plane in an instance must tie with the plane there as it does in float.
static inline REAL tie_gamma(void) {
#if HAS_INSTANCES
    return fmax(gamma_n(TIE_ROUNDINGS), (REAL)(TIE_ROUNDINGS * FLT_EPSILON / 2));
#else
    return gamma_n(TIE_ROUNDINGS);
#endif
}

static inline void consider_hit(Hit* hit, const Crossings* c, int ref, int instance) {
    int k = c->t[0] > (REAL)0 ? 0 : 1;
    REAL t = c->t[k];
    if (!(t > (REAL)0) || !(t < REAL_INF)) return;
    REAL tol = hit->ref < 0 ? (REAL)0 : tie_gamma() * fmax(t, hit->t);
    if (hit->ref < 0 || t < hit->t - tol ||
        (t <= hit->t + tol && tie_before(hit, ref, instance))) {
        hit->t = t;
        hit->ref = ref;
        hit->instance = instance;
        hit->part = c->part[k];
        hit->b1 = c->b1;
        hit->b2 = c->b2;
    }
}

// How far past the closest hit (at t) a crossing can still tie with it, lane by lane for
// vectors (real.h, Twins).
#define DEFINE_TIE_REACH(SPEC, T, NAME) \
    SPEC T NAME(T t) { return t + (REAL)2 * tie_gamma() * t; }
DEFINE_TIE_REACH(static inline, REAL, tie_reach)

// One axis of the vector slab test, with the scalar slab_interval's rules: compare-select so a
// NaN from 0 * inf never narrows the interval, the near plane picked by the reciprocal's sign
// (so a -0 direction component with the origin on a plane leaves the NaN on the plane's side,
// where it is ignored), and the far bound widened by `widen`. For a
// wide node's boxes against one ray (REALW) and for one box against a sample packet's lanes
// (REALP, packet.h), lane by lane the same (real.h, Twins). SIGNS: T's bits as integers, for
// select, which picks by each lane's top bit, the reciprocal's sign (1/d is never -0 or NaN for
// a finite d): one blend a bound, as the min and max that compared the two t were. Written
// `inv < 0 ? tf : tn` it also compared inv with 0 at every node: the mesh's primary rays in
// intersect_rays took 440 instructions a ray, against 434 with select or with min and max.
#define DEFINE_SLAB_AXIS(T, SIGNS, NAME)                                   \
    HOT void NAME(T lo, T hi, T o, T inv, REAL widen, T* t0, T* t1) {      \
        T tn = (lo - o) * inv;                                             \
        T tf = (hi - o) * inv;                                             \
        T near = select(tn, tf, SIGNS(inv));                               \
        T far = select(tf, tn, SIGNS(inv)) * widen;                        \
        *t0 = near > *t0 ? near : *t0;                                     \
        *t1 = far < *t1 ? far : *t1;                                       \
    }
DEFINE_SLAB_AXIS(REALW, SIGNS_W, slab_axis)

// The children of a node whose boxes the ray crosses within [0, tmax], as bits, and where it
// enters each (tnear, meaningful for the crossed ones): one vector slab test for all children.
HOT int node_children(const __global BvhNode* node, const Ray* r, REAL tmax, REAL* tnear) {
    const REAL widen = (REAL)1 + (REAL)2 * gamma_n(3);
    REALW t0 = (REALW)(0), t1 = (REALW)(tmax);
    slab_axis(TO_REALW(VLOADW(0, node->lo_x)), TO_REALW(VLOADW(0, node->hi_x)), (REALW)(r->o.x),
              (REALW)(r->inv_d.x), widen, &t0, &t1);
    slab_axis(TO_REALW(VLOADW(0, node->lo_y)), TO_REALW(VLOADW(0, node->hi_y)), (REALW)(r->o.y),
              (REALW)(r->inv_d.y), widen, &t0, &t1);
    slab_axis(TO_REALW(VLOADW(0, node->lo_z)), TO_REALW(VLOADW(0, node->hi_z)), (REALW)(r->o.z),
              (REALW)(r->inv_d.z), widen, &t0, &t1);
    VSTOREW(t0, 0, tnear);
    INTW used = VLOADW(0, node->child) >= 0;
    return lane_bits(MASK_TO_INTW(t0 <= t1) & used);
}

#if COUNT_TESTS
static inline int used_children(const __global BvhNode* node) {
    return popcount(lane_bits(VLOADW(0, node->child) >= 0));
}

// Primitives a leaf tests: its packets' real shapes and its others.
static inline int leaf_prims(const SceneRefs* s, int slot, int count) {
    int packets =
        (count >> LEAF_TRIANGLE_SHIFT) + ((count >> LEAF_SPHERE_SHIFT) & LEAF_FIELD_MASK);
    int n = count & LEAF_FIELD_MASK;
    for (int k = 0; k < packets * PACKET_WIDTH; ++k) n += s->prim_refs[slot + k] >= 0;
    return n;
}
#endif

// Packets in a leaf's triangle or sphere section.
HOT int section_packets(int count, int kind) {
    return kind == PRIM_TRIANGLE ? count >> LEAF_TRIANGLE_SHIFT
                                 : (count >> LEAF_SPHERE_SHIFT) & LEAF_FIELD_MASK;
}

// Inline in every build. Out of line where leaves hold one-by-one shapes, as leaf_transmission
// is, it cut primitives' cold build 1.51 -> 1.38 CPU-s, but Intel's CPU runtime 2026.2 then
// found a box where a triangle was nearer (tests/test_intersect.py; docs/acceleration.md, The
// leaves' tests out of line).
HOT void leaf_closest(const SceneRefs* s, int slot, int count, const Ray* r, int instance,
                      Hit* hit) {
    Crossings c[PACKET_WIDTH];
    for (int section = 0; section < 2; ++section) {
        int kind = section == 0 ? PRIM_TRIANGLE : PRIM_SPHERE;
        for (int p = section_packets(count, kind); p > 0; --p, slot += PACKET_WIDTH) {
            for (int bits = packet_crossings(s, kind, slot, r, c); bits; bits &= bits - 1) {
                int k = lowest_bit(bits);
                consider_hit(hit, &c[k], s->prim_refs[slot + k], instance);
            }
        }
    }
#if HAS_ONE_BY_ONE_SHAPES
    for (int k = 0; k < (count & LEAF_FIELD_MASK); ++k) {
        int ref = s->prim_refs[slot + k];
        Crossings other = intersect_prim(s, ref, r);
        consider_hit(hit, &other, ref, instance);
    }
#endif
}

#if HAS_INSTANCES
// The ray in an instance's group frame: o' = L o + t, d' = L d. d' is not normalised, so a
// crossing's t is the same number in both frames and hits compare across them.
HOT Ray instance_ray(const __global Instance* in, const Ray* r) {
    REAL4 o = (REAL4)(r->o, (REAL)1), d = (REAL4)(r->d, (REAL)0);
    REAL4 m0 = TO_REAL4(in->to_object[0]), m1 = TO_REAL4(in->to_object[1]),
          m2 = TO_REAL4(in->to_object[2]);
    return make_ray((REAL3)(dot(m0, o), dot(m1, o), dot(m2, o)),
                    (REAL3)(dot(m0, d), dot(m1, d), dot(m2, d)));
}

// Push the instances among a scene leaf's other primitives as ENTER_INSTANCE entries, in
// reference order, with entry t 0 where the walk keeps entry t's (stack_t not 0). Only a leaf
// where instances sit beside other primitives holds them (an instance alone is its node's lane,
// its box tested there); their boxes are not kept: the group's root node, its children's boxes
// in the group's frame, culls the ray there as the box would. Returns the new stack size.
HOT int push_instances(const SceneRefs* s, int slot, int count, int* stack_child,
                       int* stack_count, REAL* stack_t, int sp) {
    slot += (section_packets(count, PRIM_TRIANGLE) + section_packets(count, PRIM_SPHERE)) *
            PACKET_WIDTH;
    for (int k = 0; k < (count & LEAF_FIELD_MASK); ++k) {
        int ref = s->prim_refs[slot + k];
        if ((ref >> PRIM_TYPE_SHIFT) != PRIM_INSTANCE) continue;
        if (stack_t) stack_t[sp] = 0;
        stack_child[sp] = ref & PRIM_INDEX_MASK;
        stack_count[sp++] = ENTER_INSTANCE;
    }
    return sp;
}
#endif

#if HAS_BVH
HOT void walk_closest(const SceneRefs* s, const Ray* world, int child, int count, Hit* found);
#endif

#if HAS_INSTANCES
// walk_closest's step into instance *child (an ENTER_INSTANCE entry): the scene's ray in its
// group's frame into *group_ray, a LEAVE_INSTANCE entry (t -inf: never skipped) pushed to bring
// the scene's ray back, and the group's root as the next entry (*child, *count). Returns the
// new stack size.
HOT int enter_instance(const SceneRefs* s, const Ray* world, Ray* group_ray, int* child,
                       int* count, int* stack_child, int* stack_count, REAL* stack_t, int sp) {
    const __global Instance* in = s->instances + *child;
    *group_ray = instance_ray(in, world);
    stack_child[sp] = 0;
    stack_count[sp] = LEAVE_INSTANCE;
    stack_t[sp++] = -REAL_INF;
    *child = in->root;  // the group's root node
    *count = 0;
    return sp;
}
#endif

// A query's start: no hit, t = inf (hit.h: DEFINE_NO_HIT).
DEFINE_NO_HIT(static inline, Hit, REAL, int, no_hit, h.instance = -1;)

#if HAS_PLANES
// The planes' crossings into *hit: a short list, tested before the BVH (they are unbounded).
HOT void consider_planes(const SceneRefs* s, const Ray* r, Hit* hit) {
    for (int i = 0; i < s->n_planes; ++i) {
        Crossings c = intersect_plane(s->planes + i, r);
        consider_hit(hit, &c, (PRIM_PLANE << PRIM_TYPE_SHIFT) | i, -1);
    }
}
#endif

STAGE Hit closest_hit(const SceneRefs* s, const Ray* world) {
    Hit hit = no_hit();
#if HAS_PLANES
    consider_planes(s, world, &hit);
#endif
#if HAS_BVH
    if (s->n_nodes > 0) walk_closest(s, world, 0, 0, &hit);
#endif
    return hit;
}

#if HAS_BVH
// The closest hit below the tree entry (child, count) (as in BvhNode; (0, 0) is the root) that
// goes before *found: closest_hit's walk, which the packet walk also runs for single lanes
// (kernels/packet.h). The node's insertion stays inline: as a function of its own it ran the
// spheres' single-ray kernel 0.4 % more instructions (docs/acceleration.md).
HOT void walk_closest(const SceneRefs* s, const Ray* world, int child, int count, Hit* found) {
    Hit hit = *found;
    // Entries are (child, count) pairs as in BvhNode, with the t where the ray enters them:
    // a pop is skipped without another slab test once a nearer hit is known.
    int stack_child[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE];
    REAL stack_t[BVH_STACK_SIZE];
    int sp = 0;
    // The walk's copy of world, whose triangle set-up it makes at the first leaf where world
    // has none (ray.h, LAZY_SHEAR).
    Ray own = *world;
    Ray* r = &own;
#if HAS_INSTANCES
    // Inside an instance the walk goes on in its group's BVH with the ray in the group's frame
    // (enter_instance).
    Ray group_ray;
    int instance = -1;
#else
    const int instance = -1;
#endif
    for (;;) {
        if (count > 0) {
            COUNT(s, closest_prims, leaf_prims(s, child, count));
#if LAZY_SHEAR
            if (r->kz < 0) shear_walk_ray(r);
#endif
            leaf_closest(s, child, count, r, instance, &hit);
#if HAS_INSTANCES
            if (instance < 0) {
                sp = push_instances(s, child, count, stack_child, stack_count, stack_t, sp);
            }
        } else if (count == ENTER_INSTANCE) {
            instance = child;
            sp = enter_instance(s, world, &group_ray, &child, &count, stack_child, stack_count,
                                stack_t, sp);
            r = &group_ray;
            continue;
        } else if (count == LEAVE_INSTANCE) {
            instance = -1;
            r = &own;
#endif
        } else {
            const __global BvhNode* node = s->nodes + child;
            COUNT(s, closest_boxes, used_children(node));
            REAL tnear[BVH_WIDTH];
            int bits = node_children(node, r, tie_reach(hit.t), tnear);
            if (bits) {
                // Go on with the nearest crossed child; push the others so that nearer ones
                // pop first (an insertion into this node's part of the stack, which holds at
                // most BVH_WIDTH - 1 entries).
                int near = lowest_bit(bits);
                bits &= bits - 1;
                int base = sp;
                while (bits) {
                    int far = lowest_bit(bits);
                    bits &= bits - 1;
                    if (tnear[far] < tnear[near]) {
                        int swap = far;
                        far = near;
                        near = swap;
                    }
                    int at = sp++;
                    while (at > base && stack_t[at - 1] < tnear[far]) {
                        stack_child[at] = stack_child[at - 1];
                        stack_count[at] = stack_count[at - 1];
                        stack_t[at] = stack_t[at - 1];
                        at--;
                    }
                    stack_child[at] = node->child[far];
                    stack_count[at] = node->count[far];
                    stack_t[at] = tnear[far];
                }
                child = node->child[near];
                count = node->count[near];
                continue;
            }
        }
        while (sp > 0 && stack_t[sp - 1] > tie_reach(hit.t)) sp--;
        if (sp == 0) break;
        --sp;
        child = stack_child[sp];
        count = stack_count[sp];
    }
    *found = hit;
}
#endif

// The material a crossing shades or filters with: the instance's, where it replaces its
// group's.
static inline int crossing_material(const SceneRefs* s, int ref, int part, int instance) {
#if HAS_INSTANCES
    if (instance >= 0 && s->instances[instance].material >= 0) {
        return s->instances[instance].material;
    }
#endif
    return prim_material(s, ref, part);
}

// Multiply in transmit * colour for each crossing of a primitive within (0, tmax); false once
// no light is left.
static inline bool filter_crossings(const SceneRefs* s, const Crossings* c, int ref, int instance,
                                    REAL tmax, REAL3* filter) {
    for (int k = 0; k < 2; ++k) {
        if (c->t[k] > (REAL)0 && c->t[k] < tmax) {
#if HAS_TRANSMISSION
            const __global Material* m =
                s->materials + crossing_material(s, ref, c->part[k], instance);
            *filter *= TO_REAL(m->transmit) * TO_REAL3(m->color);
            if (max_comp3(*filter) <= (REAL)0) return false;
#else
            // Every material is opaque: no need to load the primitive's record (a cache miss
            // on every shadowed hit of a large mesh) to learn that.
            return false;
#endif
        }
    }
    return true;
}

#if HAS_TORI && HAS_TRANSMISSION
// filter_crossings for a torus, which a line can cross four times: every crossing in (0, tmax).
static inline bool filter_torus_crossings(const SceneRefs* s, int ref, const Ray* r, int instance,
                                          REAL tmax, REAL3* filter) {
    REAL t[TORUS_ROOTS];
    int n = torus_crossings(s->tori + (ref & PRIM_INDEX_MASK), r, t);
    const __global Material* m = s->materials + crossing_material(s, ref, 0, instance);
    for (int k = 0; k < n && t[k] < tmax; ++k) {
        *filter *= TO_REAL(m->transmit) * TO_REAL3(m->color);
        if (max_comp3(*filter) <= (REAL)0) return false;
    }
    return true;
}
#endif

#if !HAS_TRANSMISSION
// Whether any shape of a packet crosses the segment (0, tmax): in an opaque scene that is all a
// shadow ray needs, decided on the lanes' t without building their Crossings.
HOT bool packet_blocks(const SceneRefs* s, int kind, int slot, const Ray* r, REAL tmax) {
    REAL t0[PACKET_WIDTH], t1[PACKET_WIDTH], b1[PACKET_WIDTH], b2[PACKET_WIDTH];
    REAL4 lo = (REAL4)(0), hi = (REAL4)(tmax);
#if HAS_TRIANGLES
    if (kind == PRIM_TRIANGLE) {
        int bits = intersect_triangle_packet(s->triangle_packets + slot / PACKET_WIDTH, r, t0,
                                             b1, b2);
        if (!bits) return false;
        REAL4 t = vload4(0, t0);
        return (bits & lane_bits4(convert_int4((t > lo) & (t < hi)))) != 0;
    }
#endif
#if HAS_SPHERES && !SPHERE_FP64 && !SPHERE_TEXTBOOK
    if (kind == PRIM_SPHERE) {
        int bits = intersect_sphere_packet(s->sphere_packets + slot / PACKET_WIDTH, r, t0, t1);
        if (!bits) return false;
        REAL4 near = vload4(0, t0), far = vload4(0, t1);
        MASK4 inside = ((near > lo) & (near < hi)) | ((far > lo) & (far < hi));
        return (bits & lane_bits4(convert_int4(inside))) != 0;
    }
#endif
    // The study variants' scalar spheres.
    Crossings c[PACKET_WIDTH];
    REAL3 filter = (REAL3)(1, 1, 1);
    for (int bits = packet_crossings(s, kind, slot, r, c); bits; bits &= bits - 1) {
        int k = lowest_bit(bits);
        if (!filter_crossings(s, &c[k], s->prim_refs[slot + k], -1, tmax, &filter)) return true;
    }
    return false;
}
#endif

// LARGE_LEAF_TESTS: the build's leaves can hold one-by-one shapes or instances, whose tests
// are large. There the renderer is compiled as more functions than one (this one and
// ray_tree.h's pixel_radiance), since the optimisers' passes grow faster than linearly in a
// function's size; where leaves hold only triangles and spheres, the build is small enough to
// inline them (issue 42, the cold build).
#define LARGE_LEAF_TESTS (HAS_ONE_BY_ONE_SHAPES || HAS_INSTANCES)

// Out of line where LARGE_LEAF_TESTS. The code is the same size either way (primitives'
// render.so 39,269 -> 38,941 bytes), yet the renderer in two functions compiled faster than in
// one: cold builds 3 to 8 % shorter, renders' instructions -2.2 to +0.4 % (glass -2.2 %,
// primitives -1.7 %, instances -0.04 %, tori +0.4 %) (docs/acceleration.md, The leaves' tests
// out of line).
#if LARGE_LEAF_TESTS
#define LEAF_TRANSMISSION OUT_OF_LINE
#else
#define LEAF_TRANSMISSION HOT
#endif

// false once the leaf stops the light entirely.
LEAF_TRANSMISSION bool leaf_transmission(const SceneRefs* s, int slot, int count, const Ray* r,
                                         int instance, REAL tmax, REAL3* filter) {
    for (int section = 0; section < 2; ++section) {
        int kind = section == 0 ? PRIM_TRIANGLE : PRIM_SPHERE;
        for (int p = section_packets(count, kind); p > 0; --p, slot += PACKET_WIDTH) {
#if HAS_TRANSMISSION
            Crossings c[PACKET_WIDTH];
            for (int bits = packet_crossings(s, kind, slot, r, c); bits; bits &= bits - 1) {
                int k = lowest_bit(bits);
                if (!filter_crossings(s, &c[k], s->prim_refs[slot + k], instance, tmax,
                                      filter)) {
                    return false;
                }
            }
#else
            if (packet_blocks(s, kind, slot, r, tmax)) return false;
#endif
        }
    }
#if HAS_ONE_BY_ONE_SHAPES
    for (int k = 0; k < (count & LEAF_FIELD_MASK); ++k) {
        int ref = s->prim_refs[slot + k];
#if HAS_TORI && HAS_TRANSMISSION
        if ((ref >> PRIM_TYPE_SHIFT) == PRIM_TORUS) {
            if (!filter_torus_crossings(s, ref, r, instance, tmax, filter)) return false;
            continue;
        }
#endif
        Crossings other = intersect_prim(s, ref, r);
        if (!filter_crossings(s, &other, ref, instance, tmax, filter)) return false;
    }
#endif
    return true;
}

#if HAS_BVH
HOT REAL3 walk_transmission(const SceneRefs* s, const Ray* world, int child, int count,
                            REAL tmax, REAL3 filter);
#endif

#if HAS_PLANES
// The light the planes let through a shadow segment (0, tmax), into *filter; false at the
// first opaque crossing.
HOT bool planes_transmission(const SceneRefs* s, const Ray* r, REAL tmax, REAL3* filter) {
    for (int i = 0; i < s->n_planes; ++i) {
#if HAS_TRANSMISSION
        Crossings c = intersect_plane(s->planes + i, r);
        if (!filter_crossings(s, &c, (PRIM_PLANE << PRIM_TYPE_SHIFT) | i, -1, tmax, filter)) {
            return false;
        }
#else
        // Every material is opaque: a crossing within the segment is all there is to know,
        // without building the plane's Crossings (a shadow ray took 21 instructions fewer).
        REAL t = plane_t(s->planes + i, r);
        if (t > (REAL)0 && t < tmax) return false;
#endif
    }
    return true;
}
#endif

// Light reaching the end of a shadow segment: 0 at the first opaque crossing.
STAGE REAL3 transmission(const SceneRefs* s, const Ray* world, REAL tmax) {
    REAL3 filter = (REAL3)(1, 1, 1);
#if HAS_PLANES
    if (!planes_transmission(s, world, tmax, &filter)) return (REAL3)(0, 0, 0);
#endif
#if HAS_BVH
    if (s->n_nodes > 0) filter = walk_transmission(s, world, 0, 0, tmax, filter);
#endif
    return filter;
}

#if HAS_BVH
// `filter` times the light let through below the tree entry (child, count) (as in BvhNode), 0
// at the first opaque crossing: transmission's walk, which the packet walk also runs for single
// lanes (kernels/packet.h).
HOT REAL3 walk_transmission(const SceneRefs* s, const Ray* world, int child, int count,
                            REAL tmax, REAL3 filter) {
    int stack_child[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE];
    int sp = 0;
    stack_child[sp] = child;
    stack_count[sp++] = count;
    const Ray* r = world;
#if HAS_INSTANCES
    Ray group_ray;  // as in closest_hit
    int instance = -1;
#else
    const int instance = -1;
#endif
    while (sp > 0) {
        --sp;
        int child = stack_child[sp], count = stack_count[sp];
        if (count > 0) {
            COUNT(s, shadow_prims, leaf_prims(s, child, count));
            if (!leaf_transmission(s, child, count, r, instance, tmax, &filter)) {
                return (REAL3)(0, 0, 0);
            }
#if HAS_INSTANCES
            if (instance < 0) {
                sp = push_instances(s, child, count, stack_child, stack_count, 0, sp);
            }
#endif
            continue;
        }
#if HAS_INSTANCES
        if (count == ENTER_INSTANCE) {
            const __global Instance* in = s->instances + child;
            instance = child;
            group_ray = instance_ray(in, world);
            r = &group_ray;
            stack_child[sp] = 0;
            stack_count[sp++] = LEAVE_INSTANCE;
            stack_child[sp] = in->root;
            stack_count[sp++] = 0;
            continue;
        }
        if (count == LEAVE_INSTANCE) {
            instance = -1;
            r = world;
            continue;
        }
#endif
        const __global BvhNode* node = s->nodes + child;
        COUNT(s, shadow_boxes, used_children(node));
        REAL tnear[BVH_WIDTH];
        int bits = node_children(node, r, tmax, tnear);
        while (bits) {
            int k = lowest_bit(bits);
            bits &= bits - 1;
            stack_child[sp] = node->child[k];
            stack_count[sp++] = node->count[k];
        }
    }
    return filter;
}
#endif

#endif
