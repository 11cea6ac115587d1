// Group packets (TRAVERSAL_GROUP_PACKET): a work-group's pixels (the host launches square
// tiles, clray.device.launch) walk the BVH together, one node at a time for the whole group.
// The node's index and boxes are the same for every work-item, so a driver that packs
// work-items into a vector's lanes (Intel's CPU runtime, GPUs) can load them once, not as a
// gather per lane, and test the boxes against a vector of rays. Each work-item keeps its own
// ray, hit and entry t's, and tests a leaf with the single-ray code (walk_closest,
// walk_transmission: instances too) where its own ray reaches it. On both CPU devices measured
// the walk is slower than the single-ray walk (docs/acceleration.md, Group packets).
//
// A step of the walk is one barrier: each work-item tests the group's node against its ray and
// posts which children it crosses (and where it enters them) in __local memory; after the
// barrier every work-item reads all the posts and takes the same next step, so the group's
// stack is the same in every work-item's private memory and no work-item waits for another to
// write it. The posts rotate through three parts of the __local arrays, step by step, so a
// work-item may post the next step while others still read this one. Every work-item of the
// group calls group_any, group_closest and group_transmission the same number of times (they
// hold the barriers); a work-item without a ray rides along inactive.
//
// Each work-item finds the hit the single-ray walk finds: it tests the crossings the
// single-ray walk tests, in another order, and the closest with its ties does not depend on
// the order, but for one case: three or more crossings within two tie widths of each other
// (bvh.h: TIE_ROUNDINGS), where a tie is not transitive and the order can decide. Shadow rays visit the leaves in the single-ray walk's order, so a filter's product
// is the same too.
#ifndef CLRAY_GROUP_H
#define CLRAY_GROUP_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "bvh.h"
#include "lanes.h"

#if GROUP_PACKETS

// The group's posts, three steps' worth: the OR of the children the work-items cross, the
// group's nearest entry into each, and the farthest its hits can still reach, gathered by
// atomics on non-negative floats' bits (which order as the floats do; a double is rounded
// outward to float first). A part is cleared by the first work-item in the step before it is
// posted to: every work-item has passed the barrier after which that part was last read.
#define GROUP_NONE (-1)
typedef struct {
    int bits[3];
    int near[3][BVH_WIDTH];
    int reach[3];
} GroupPosts;

typedef struct {
    __local GroupPosts* posts;
    int lid;    // the work-item's index in the group
    int step;   // the part of the posts the next step posts to (0 to 2): the same in every
                // work-item
} Group;

// A non-negative t as int bits that order as the floats do, for the posts' atomics; a double
// rounded to float downward (a lower bound) or upward.
static inline int order_bits(REAL t, bool up) {
#ifdef USE_DOUBLE
    return as_int(up ? convert_float_rtp(t) : convert_float_rtn(t));
#else
    return as_int(t);
#endif
}

// The part the next step posts to, cleared by the first work-item.
static inline void group_clear(Group* g) {
    __local GroupPosts* p = g->posts;
    int next = g->step == 2 ? 0 : g->step + 1;
    if (g->lid == 0) {
        p->bits[next] = 0;
        p->reach[next] = GROUP_NONE;
        for (int k = 0; k < BVH_WIDTH; ++k) p->near[next][k] = as_int(INFINITY);
    }
}

// The group's start, in every work-item before its first walk: the first part cleared.
static inline void group_init(Group* g, __local GroupPosts* posts, int lid) {
    g->posts = posts;
    g->lid = lid;
    g->step = 2;
    group_clear(g);
    g->step = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
}

// Post the work-item's crossed children (bits), where it enters them and its reach (< 0:
// none), and wait for the group's. Returns the group's bits; *reach its farthest reach
// (-inf: none), near[k] its nearest entry into child k.
static inline int group_post(Group* g, int bits, const REAL* tnear, REAL reach, REAL* group_reach,
                             REAL* near) {
    __local GroupPosts* p = g->posts;
    int q = g->step;
    group_clear(g);
    if (bits) atomic_or(&p->bits[q], bits);
    for (int k = 0; k < BVH_WIDTH; ++k) {
        if ((bits >> k) & 1) atomic_min(&p->near[q][k], order_bits(tnear[k], false));
    }
    if (reach >= (REAL)0) atomic_max(&p->reach[q], order_bits(reach, true));
    barrier(CLK_LOCAL_MEM_FENCE);
    int r = p->reach[q];
    *group_reach = r == GROUP_NONE ? -REAL_INF : (REAL)as_float(r);
    for (int k = 0; k < BVH_WIDTH; ++k) near[k] = (REAL)as_float(p->near[q][k]);
    g->step = q == 2 ? 0 : q + 1;
    return p->bits[q];
}

// Whether any work-item of the group has `v`: the same answer in every work-item.
static inline bool group_any(Group* g, bool v) {
    REAL tnear[BVH_WIDTH], near[BVH_WIDTH], reach;
    for (int k = 0; k < BVH_WIDTH; ++k) tnear[k] = 0;
    return group_post(g, v ? 1 : 0, tnear, -1, &reach, near) != 0;
}

#if HAS_BVH
// The group's stack, the same in every work-item: (child, count) entries as in BvhNode with
// the group's nearest entry t, and the work-item's own entry t (-1: its ray does not enter).
typedef struct {
    int child[BVH_STACK_SIZE], count[BVH_STACK_SIZE];
    REAL t[BVH_STACK_SIZE], own_t[BVH_STACK_SIZE];
    int sp;
} GroupStack;

// Where the group's walk is: a tree entry and the work-item's own entry t into it.
typedef struct {
    int child, count;
    REAL t;
} GroupEntry;

// The work-item's part of a step at `at`: a leaf or an instance (count ENTER_INSTANCE) walked
// with the single-ray walk where its ray reaches it, or a node's children it crosses (bits;
// where it enters them in tnear).
static inline int group_visit(const SceneRefs* s, const Ray* r, GroupEntry at, bool live,
                              bool closest, REAL tmax, Hit* hit, REAL3* filter, REAL* tnear) {
    REAL reach = closest ? tie_reach(hit->t) : tmax;
    for (int k = 0; k < BVH_WIDTH; ++k) tnear[k] = 0;
    if (!(live && at.t >= (REAL)0 && at.t <= reach)) return 0;
    if (at.count != 0) {
        if (closest) {
            walk_closest(s, r, at.child, at.count, hit);
        } else {
            *filter = walk_transmission(s, r, at.child, at.count, tmax, *filter);
        }
        return 0;
    }
    const __global BvhNode* node = s->nodes + at.child;
#if COUNT_TESTS
    if (closest) {
        COUNT(s, closest_boxes, used_children(node));
    } else {
        COUNT(s, shadow_boxes, used_children(node));
    }
#endif
    return node_children(node, r, reach, tnear);
}

// A closest-hit step's children (any: crossed by some work-item): the nearest for the group
// is visited next, the others pushed so that nearer ones pop first (an insertion into this
// node's part of the stack).
static inline GroupEntry group_push_closest(GroupStack* st, const __global BvhNode* node, int any,
                                            int bits, const REAL* tnear, const REAL* near_t) {
    int near = lowest_bit(any);
    int rest = any & (any - 1);
    int base = st->sp;
    while (rest) {
        int far = lowest_bit(rest);
        rest &= rest - 1;
        if (near_t[far] < near_t[near]) {
            int swap = far;
            far = near;
            near = swap;
        }
        int at = st->sp++;
        while (at > base && st->t[at - 1] < near_t[far]) {
            st->child[at] = st->child[at - 1];
            st->count[at] = st->count[at - 1];
            st->t[at] = st->t[at - 1];
            st->own_t[at] = st->own_t[at - 1];
            at--;
        }
        st->child[at] = node->child[far];
        st->count[at] = node->count[far];
        st->t[at] = near_t[far];
        st->own_t[at] = (bits >> far) & 1 ? tnear[far] : (REAL)-1;
    }
    GroupEntry next;
    next.child = node->child[near];
    next.count = node->count[near];
    next.t = (bits >> near) & 1 ? tnear[near] : (REAL)-1;
    return next;
}

// A shadow step's children, as walk_transmission pushes them: every crossed child, the last
// popped first. Their group t is 0: a shadow ray's reach is its whole segment.
static inline void group_push_shadow(GroupStack* st, const __global BvhNode* node, int any,
                                     int bits) {
    for (int rest = any; rest; rest &= rest - 1) {
        int k = lowest_bit(rest);
        st->child[st->sp] = node->child[k];
        st->count[st->sp] = node->count[k];
        st->t[st->sp] = 0;
        st->own_t[st->sp++] = (bits >> k) & 1 ? (REAL)0 : (REAL)-1;
    }
}

// The stack's top that some work-item's hits can still reach (the group's farthest reach),
// into *at; false when none is left.
static inline bool group_pop(GroupStack* st, REAL reach, GroupEntry* at) {
    while (st->sp > 0 && st->t[st->sp - 1] > reach) st->sp--;
    if (st->sp == 0) return false;
    --st->sp;
    at->child = st->child[st->sp];
    at->count = st->count[st->sp];
    at->t = st->own_t[st->sp];
    return true;
}

// The group's walk below the root: the closest hit of the work-item's ray where `active`
// (closest: into *hit, which holds the planes' closest or t = inf), or the light its shadow
// segment (0, tmax) lets through (into *filter).
static inline void group_walk(const SceneRefs* s, Group* g, const Ray* r, bool active, bool closest,
                              REAL tmax, Hit* hit, REAL3* filter) {
    GroupStack st;
    st.sp = 0;
    GroupEntry at;
    at.child = 0;
    at.count = 0;
    at.t = active ? (REAL)0 : (REAL)-1;
    for (;;) {
        bool live = active && (closest || max_comp3(*filter) > (REAL)0);
        REAL tnear[BVH_WIDTH];
        int bits = group_visit(s, r, at, live, closest, tmax, hit, filter, tnear);
        live = active && (closest || max_comp3(*filter) > (REAL)0);
        REAL group_reach, near_t[BVH_WIDTH];
        int any = group_post(g, bits, tnear, live ? (closest ? tie_reach(hit->t) : tmax) : -1,
                             &group_reach, near_t);
        if (at.count == 0 && any) {
            const __global BvhNode* node = s->nodes + at.child;
            if (closest) {
                at = group_push_closest(&st, node, any, bits, tnear, near_t);
                continue;
            }
            group_push_shadow(&st, node, any, bits);
        }
        if (!group_pop(&st, group_reach, &at)) break;
    }
}
#endif

// closest_hit for the group: every work-item calls it; the hit of the work-item's ray where
// `active` (t = inf otherwise).
static inline Hit group_closest(const SceneRefs* s, Group* g, const Ray* r, bool active) {
    Hit hit = no_hit();
#if HAS_PLANES
    if (active) consider_planes(s, r, &hit);
#endif
#if HAS_BVH
    REAL3 unused = (REAL3)(0, 0, 0);
    if (s->n_nodes > 0) group_walk(s, g, r, active, true, 0, &hit, &unused);
#endif
    return hit;
}

// transmission for the group: every work-item calls it; the light reaching the end of the
// work-item's shadow segment where `active`.
static inline REAL3 group_transmission(const SceneRefs* s, Group* g, const Ray* r, REAL tmax,
                                       bool active) {
    REAL3 filter = (REAL3)(1, 1, 1);
#if HAS_PLANES
    if (active && !planes_transmission(s, r, tmax, &filter)) filter = (REAL3)(0, 0, 0);
#endif
#if HAS_BVH
    Hit unused = no_hit();
    if (s->n_nodes > 0) group_walk(s, g, r, active, false, tmax, &unused, &filter);
#endif
    return active ? filter : (REAL3)(0, 0, 0);
}
#endif

#endif
