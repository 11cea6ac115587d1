// Scene queries: closest hit and shadow transmission over the planes (a short list: they are
// unbounded) and the BVH of every bounded primitive.
#ifndef CLRAY_BVH_H
#define CLRAY_BVH_H

#define BVH_STACK_SIZE 64

typedef struct {
    __global const Plane* planes;
    __global const Sphere* spheres;
    __global const Box* boxes;
    __global const Cylinder* cylinders;
    __global const Cone* cones;
    __global const Triangle* triangles;
    __global const float4* vertices;
    __global const float4* normals;
    __global const float2* uvs;
    __global const BvhNode* nodes;
    __global const int* prim_refs;
    __global const Material* materials;
    __global const Texture* textures;
    __global const float4* texels;
    __global const Light* lights;
    int n_planes, n_nodes, n_lights;
} SceneRefs;

typedef struct {
    REAL t;
    int ref;  // PRIM_* << PRIM_TYPE_SHIFT | index; meaningful when t < REAL_INF
    int part;
    REAL b1, b2;
} Hit;

inline Crossings intersect_prim(const SceneRefs* s, int ref, const Ray* r) {
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
#if HAS_TRIANGLES
        case PRIM_TRIANGLE: {
            Triangle tri = s->triangles[i];
            return intersect_triangle(TO_REAL3(s->vertices[tri.v0]),
                                      TO_REAL3(s->vertices[tri.v1]),
                                      TO_REAL3(s->vertices[tri.v2]), r);
        }
#endif
        default:
            return no_crossings();
    }
}

inline int prim_material(const SceneRefs* s, int ref) {
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
#if HAS_TRIANGLES
        case PRIM_TRIANGLE:
            return s->triangles[i].material & TRIANGLE_MATERIAL_MASK;
#endif
        default:
            return 0;
    }
}

// The first crossing ahead of the origin; ties in t go to the smaller reference, which orders
// by type and then by scene order (docs/rendering.md).
inline void consider_hit(Hit* hit, const Crossings* c, int ref) {
    int k = c->t[0] > (REAL)0 ? 0 : 1;
    REAL t = c->t[k];
    if (!(t > (REAL)0) || !(t < REAL_INF)) return;
    if (t < hit->t || (t == hit->t && ref < hit->ref)) {
        hit->t = t;
        hit->ref = ref;
        hit->part = c->part[k];
        hit->b1 = c->b1;
        hit->b2 = c->b2;
    }
}

inline bool node_entry(const __global BvhNode* node, const Ray* r, REAL tmax, REAL* tnear) {
    REAL3 lo = (REAL3)(node->lo[0], node->lo[1], node->lo[2]);
    REAL3 hi = (REAL3)(node->hi[0], node->hi[1], node->hi[2]);
    REAL t0 = 0, t1 = tmax;
    int p0, p1;
    if (!slab_interval(lo, hi, r, &t0, &t1, &p0, &p1)) return false;
    *tnear = t0;
    return true;
}

inline Hit closest_hit(const SceneRefs* s, const Ray* r) {
    Hit hit;
    hit.t = REAL_INF;
    hit.ref = -1;
    hit.part = 0;
    hit.b1 = 0;
    hit.b2 = 0;
#if HAS_PLANES
    for (int i = 0; i < s->n_planes; ++i) {
        Crossings c = intersect_plane(s->planes + i, r);
        consider_hit(&hit, &c, (PRIM_PLANE << PRIM_TYPE_SHIFT) | i);
    }
#endif
#if HAS_BVH
    REAL tnear;
    if (s->n_nodes == 0 || !node_entry(s->nodes, r, hit.t, &tnear)) return hit;
    // Pushed nodes keep their entry t, so a pop is rejected without a second slab test once a
    // nearer hit is known.
    int stack[BVH_STACK_SIZE];
    REAL stack_t[BVH_STACK_SIZE];
    int sp = 0;
    int index = 0;
    for (;;) {
        const __global BvhNode* node = s->nodes + index;
        if (node->count > 0) {
            for (int k = 0; k < node->count; ++k) {
                int ref = s->prim_refs[node->first + k];
                Crossings c = intersect_prim(s, ref, r);
                consider_hit(&hit, &c, ref);
            }
        } else {
            // Visit the nearer child first; <= keeps equal-t candidates for the tie rule.
            int left = index + 1, right = node->first;
            REAL tl, tr;
            bool hl = node_entry(s->nodes + left, r, hit.t, &tl);
            bool hr = node_entry(s->nodes + right, r, hit.t, &tr);
            if (hl && hr) {
                bool left_first = tl <= tr;
                if (sp < BVH_STACK_SIZE) {
                    stack[sp] = left_first ? right : left;
                    stack_t[sp++] = left_first ? tr : tl;
                }
                index = left_first ? left : right;
                continue;
            }
            if (hl || hr) {
                index = hl ? left : right;
                continue;
            }
        }
        while (sp > 0 && stack_t[sp - 1] > hit.t) sp--;
        if (sp == 0) break;
        index = stack[--sp];
    }
#endif
    return hit;
}

// Multiply in transmit * colour for each crossing of a primitive within (0, tmax).
inline bool filter_crossings(const SceneRefs* s, const Crossings* c, int ref, REAL tmax,
                             REAL3* filter) {
    for (int k = 0; k < 2; ++k) {
        if (c->t[k] > (REAL)0 && c->t[k] < tmax) {
            const __global Material* m = s->materials + prim_material(s, ref);
            *filter *= TO_REAL(m->transmit) * TO_REAL3(m->color);
            if (max_comp3(*filter) <= (REAL)0) return false;
        }
    }
    return true;
}

// Light reaching the end of a shadow segment: 0 at the first opaque crossing.
inline REAL3 transmission(const SceneRefs* s, const Ray* r, REAL tmax) {
    REAL3 filter = (REAL3)(1, 1, 1);
#if HAS_PLANES
    for (int i = 0; i < s->n_planes; ++i) {
        Crossings c = intersect_plane(s->planes + i, r);
        if (!filter_crossings(s, &c, (PRIM_PLANE << PRIM_TYPE_SHIFT) | i, tmax, &filter)) {
            return (REAL3)(0, 0, 0);
        }
    }
#endif
#if HAS_BVH
    REAL tnear;
    if (s->n_nodes == 0 || !node_entry(s->nodes, r, tmax, &tnear)) return filter;
    int stack[BVH_STACK_SIZE];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int index = stack[--sp];
        const __global BvhNode* node = s->nodes + index;
        if (node->count > 0) {
            for (int k = 0; k < node->count; ++k) {
                int ref = s->prim_refs[node->first + k];
                Crossings c = intersect_prim(s, ref, r);
                if (!filter_crossings(s, &c, ref, tmax, &filter)) return (REAL3)(0, 0, 0);
            }
        } else {
            int left = index + 1, right = node->first;
            if (sp + 2 <= BVH_STACK_SIZE) {
                if (node_entry(s->nodes + right, r, tmax, &tnear)) stack[sp++] = right;
                if (node_entry(s->nodes + left, r, tmax, &tnear)) stack[sp++] = left;
            }
        }
    }
#endif
    return filter;
}

#endif
