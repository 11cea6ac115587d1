// The hit's surface (point, normals, error bound, texture coordinates) and its Phong shading.
#ifndef CLRAY_SHADING_H
#define CLRAY_SHADING_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "intersect.h"
#include "bvh.h"
#include "lights.h"
#include "texture.h"

// Error bounds are pbrt-style: gamma(n) times the magnitudes the point was computed from. Sixteen
// roundings is generous for every formula here and still a tiny fraction of the scene's scale.
#define ERR_ROUNDINGS 16

inline REAL3 set_comp3(REAL3 v, int k, REAL value) {
    if (k == 0) v.x = value;
    else if (k == 1) v.y = value;
    else v.z = value;
    return v;
}

inline REAL angle_u(REAL y, REAL x) { return (REAL)0.5 + atan2(y, x) / ((REAL)2 * PI_R); }

// A cap disc's (u, v): its frame coordinates mapped from [-radius, radius] to [0, 1].
inline REAL2 disc_uv(REAL3 q, REAL3 e1, REAL3 e2, REAL radius) {
    return (REAL2)((REAL)0.5 + (REAL)0.5 * dot(q, e1) / radius,
                   (REAL)0.5 + (REAL)0.5 * dot(q, e2) / radius);
}

// (u, v) of a cylinder or cone: around the axis and along it on the side (part 0), the cap
// disc of radius cap_radius otherwise. q is the hit point relative to the base or apex.
inline REAL2 axial_uv(REAL3 q, REAL3 axis, REAL along, int part, REAL cap_radius) {
    REAL3 e1, e2;
    frame(axis, &e1, &e2);
    if (part == 0) return (REAL2)(angle_u(dot(q, e2), dot(q, e1)), along);
    return disc_uv(q, e1, e2, cap_radius);
}

// want_uv: the material samples an image texture. Only then are (u, v) computed: a sphere's
// atan2 and asin cost as much as the rest of its shading. r and the primitive in one frame.
HOT Surface shape_surface(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
    Surface sf;
    int i = hit->ref & PRIM_INDEX_MASK;
    REAL3 p = r->o + hit->t * r->d;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    sf.uv = (REAL2)(0, 0);
    switch (hit->ref >> PRIM_TYPE_SHIFT) {
#if HAS_PLANES
        case PRIM_PLANE: {
            const __global Plane* pl = s->planes + i;
            REAL3 n = TO_REAL3(pl->normal), q = TO_REAL3(pl->point);
            p -= dot(p - q, n) * n;
            sf.n_g = n;
            sf.err = gamma * (max_abs3(p) + max_abs3(q));
            if (want_uv) {
                REAL3 e1, e2;
                frame(n, &e1, &e2);
                sf.uv = (REAL2)(dot(p - q, e1) + TO_REAL(pl->point.w),
                                dot(p - q, e2) + TO_REAL(pl->normal.w));
            }
            sf.material = pl->material;
            break;
        }
#endif
#if HAS_SPHERES
        case PRIM_SPHERE: {
            const __global Sphere* sp = s->spheres + i;
#if SPHERE_FP64
            // Re-projecting in float would round p at the scale of the centre (ulp(1e5) is
            // 0.008): do it in double, so the bound is the float rounding of p alone.
            double3 cd = convert_double3(sp->center_radius.xyz);
            double3 pd = convert_double3(r->o) + (double)hit->t * convert_double3(r->d);
            double3 nd = pd - cd;
            double nl = length(nd);
            nd = nl > 0.0 ? nd / nl : nd;
            pd = cd + (double)sp->center_radius.w * nd;
            REAL3 n = convert_float3(nd);
            p = convert_float3(pd);
            sf.n_g = n;
            sf.err = gamma * max_abs3(p);
#else
            REAL3 c = TO_REAL3(sp->center_radius);
            REAL radius = TO_REAL(sp->center_radius.w);
            REAL3 n = safe_normalize(p - c);
            p = c + radius * n;
            sf.n_g = n;
            sf.err = gamma * (max_abs3(c) + radius);
#endif
            if (want_uv) {
                sf.uv = (REAL2)(angle_u(n.x, n.z),
                                (REAL)0.5 + asin(clamp(n.y, (REAL)-1, (REAL)1)) / PI_R);
            }
            sf.material = sp->material;
            break;
        }
#endif
#if HAS_BOXES
        case PRIM_BOX: {
            const __global Box* b = s->boxes + i;
            REAL3 lo = TO_REAL3(b->lo), hi = TO_REAL3(b->hi);
            int axis = hit->part / 2, side = hit->part % 2;
            p = set_comp3(p, axis, comp3(side ? hi : lo, axis));
            sf.n_g = set_comp3((REAL3)(0, 0, 0), axis, side ? (REAL)1 : (REAL)-1);
            // The box's own magnitude too: a hit at the packed origin still gets an offset.
            sf.err = gamma * (max_abs3(lo) + max_abs3(hi));
            int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
            REAL w1 = comp3(hi, a1) - comp3(lo, a1), w2 = comp3(hi, a2) - comp3(lo, a2);
            sf.uv = (REAL2)(w1 > (REAL)0 ? (comp3(p, a1) - comp3(lo, a1)) / w1 : (REAL)0,
                            w2 > (REAL)0 ? (comp3(p, a2) - comp3(lo, a2)) / w2 : (REAL)0);
            sf.material = b->material;
            break;
        }
#endif
#if HAS_CYLINDERS
        case PRIM_CYLINDER: {
            const __global Cylinder* cy = s->cylinders + i;
            REAL3 base = TO_REAL3(cy->base_radius), axis = TO_REAL3(cy->axis_height);
            REAL radius = TO_REAL(cy->base_radius.w), height = TO_REAL(cy->axis_height.w);
            REAL3 q = p - base;
            REAL h = dot(q, axis);
            if (hit->part == 0) {
                REAL3 radial = safe_normalize(q - h * axis);
                p = base + h * axis + radius * radial;
                sf.n_g = radial;
            } else {
                REAL cap = hit->part == 2 ? height : (REAL)0;
                p += (cap - h) * axis;
                sf.n_g = hit->part == 2 ? axis : -axis;
            }
            if (want_uv) sf.uv = axial_uv(q, axis, h / height, hit->part, radius);
            sf.err = gamma * (max_abs3(p) + max_abs3(base) + radius + height);
            sf.material = cy->material;
            break;
        }
#endif
#if HAS_CONES
        case PRIM_CONE: {
            const __global Cone* co = s->cones + i;
            REAL3 apex = TO_REAL3(co->apex_tan), axis = TO_REAL3(co->axis_height);
            REAL tan_a = TO_REAL(co->apex_tan.w), height = TO_REAL(co->axis_height.w);
            REAL3 q = p - apex;
            REAL h = dot(q, axis);
            if (hit->part == 0) {
                REAL3 radial = q - h * axis;
                REAL rl = length(radial);
                if (rl > (REAL)0) {
                    radial /= rl;
                    p = apex + h * axis + (h * tan_a) * radial;
                    // Outward normal of |perp| = tan * s is radial - tan * axis, normalised.
                    sf.n_g = (radial - tan_a * axis) / sqrt((REAL)1 + tan_a * tan_a);
                } else {
                    sf.n_g = -axis;  // the apex: any choice is a limit; point back out
                }
            } else {
                p += (height - h) * axis;
                sf.n_g = axis;
            }
            if (want_uv) sf.uv = axial_uv(q, axis, h / height, hit->part, height * tan_a);
            sf.err = gamma * (max_abs3(p) + max_abs3(apex) + height * ((REAL)1 + tan_a));
            sf.material = co->material;
            break;
        }
#endif
#if HAS_TRIANGLES
        case PRIM_TRIANGLE: {
            Triangle tri = s->triangles[i];
            // The corners from the hit's packet lane (its part is its slot, bvh.h:
            // packet_crossings): the mesh's float32 vertices, which the device does not keep.
            const __global TrianglePacket* pk = s->triangle_packets + hit->part / PACKET_WIDTH;
            int lane = hit->part % PACKET_WIDTH;
            REAL3 p0 = (REAL3)((REAL)pk->x0[lane], (REAL)pk->y0[lane], (REAL)pk->z0[lane]);
            REAL3 p1 = (REAL3)((REAL)pk->x1[lane], (REAL)pk->y1[lane], (REAL)pk->z1[lane]);
            REAL3 p2 = (REAL3)((REAL)pk->x2[lane], (REAL)pk->y2[lane], (REAL)pk->z2[lane]);
            REAL b1 = hit->b1, b2 = hit->b2, b0 = (REAL)1 - b1 - b2;
            p = b0 * p0 + b1 * p1 + b2 * p2;
            sf.err = gamma * max_comp3(fabs(b0 * p0) + fabs(b1 * p1) + fabs(b2 * p2));
            // A hit on an edge also lies on the neighbouring triangle's plane, so a ray spawned
            // from it (offset along this normal only) could start on that plane and leave
            // through a concave edge at t = 0. Pulling the point a few error bounds towards
            // this triangle's centroid, within the triangle, takes it off that plane.
            REAL3 to_centroid = (p0 + p1 + p2) / (REAL)3 - p;
            REAL reach = length(to_centroid);
            if (reach > (REAL)0) {
                p += fmin((REAL)4 * sf.err, (REAL)0.5 * reach) / reach * to_centroid;
            }
            REAL3 n = safe_normalize(cross(p1 - p0, p2 - p0));
            // A degenerate triangle has no normal: let it face the ray.
            sf.n_g = dot(n, n) > (REAL)0 ? n : -r->d;
            sf.uv = (REAL2)(b1, b2);
#if HAS_VERTEX_NORMALS
            if (tri.material & TRIANGLE_SMOOTH) {
                REAL3 ns = b0 * TO_REAL3(s->normals[tri.v0]) +
                           b1 * TO_REAL3(s->normals[tri.v1]) +
                           b2 * TO_REAL3(s->normals[tri.v2]);
                sf.n_s = safe_normalize(ns);
            }
#endif
#if HAS_VERTEX_UVS
            if (tri.material & TRIANGLE_UV) {
                sf.uv = b0 * TO_REAL2(s->uvs[tri.v0]) + b1 * TO_REAL2(s->uvs[tri.v1]) +
                        b2 * TO_REAL2(s->uvs[tri.v2]);
            }
#endif
            sf.material = tri.material & TRIANGLE_MATERIAL_MASK;
            sf.p = p;
#if HAS_VERTEX_NORMALS
            if ((tri.material & TRIANGLE_SMOOTH) && dot(sf.n_s, sf.n_s) > (REAL)0) return sf;
#endif
            sf.n_s = sf.n_g;
            return sf;
        }
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

#if HAS_INSTANCES
// n_g and n_s go to the scene's frame by the transpose of to_object's linear part M (the
// inverse transpose of to_world's), which keeps them normal to the surface and on its outward
// side. Not normalised: its length says how M stretches distances along the normal.
inline REAL3 instance_normal(const __global Instance* in, REAL3 n) {
    return n.x * TO_REAL3(in->to_object[0]) + n.y * TO_REAL3(in->to_object[1]) +
           n.z * TO_REAL3(in->to_object[2]);
}

inline REAL abs_sum3(REAL3 v) { return fabs(v.x) + fabs(v.y) + fabs(v.z); }

// The surface of a hit inside an instance: found in the group's frame, then mapped to the
// scene's. Its error bound covers three things: the group-frame bound mapped through the
// linear part A of to_world (the sum of |A| bounds its largest stretch); the rounding of that
// map; and how far a ray spawned here moves when mapped back into the group's frame by
// to_object M, which must not carry its origin back through the surface: a distance e there
// is at most e / |M^T n| along the normal here. The matrices are float32 in every build and M
// is only the rounded inverse of A, so out and back moves a point by float32 roundings of
// |M| |A| |p| even in the double build: those terms count float32 roundings.
HOT Surface instance_surface(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
    const __global Instance* in = s->instances + hit->instance;
    Ray group_ray = instance_ray(in, r);
    Surface sf = shape_surface(s, &group_ray, hit, want_uv);
    REAL4 p = (REAL4)(sf.p, (REAL)1);
    REAL4 a0 = TO_REAL4(in->to_world[0]), a1 = TO_REAL4(in->to_world[1]),
          a2 = TO_REAL4(in->to_world[2]);
    REAL4 m0 = TO_REAL4(in->to_object[0]), m1 = TO_REAL4(in->to_object[1]),
          m2 = TO_REAL4(in->to_object[2]);
    REAL3 world = (REAL3)(dot(a0, p), dot(a1, p), dot(a2, p));
    REAL4 ap = fabs(p);
    REAL3 mapped = (REAL3)(dot(fabs(a0), ap), dot(fabs(a1), ap), dot(fabs(a2), ap));
    REAL stretch = abs_sum3(a0.xyz) + abs_sum3(a1.xyz) + abs_sum3(a2.xyz);
    REAL4 aw = (REAL4)(fabs(world) + mapped, (REAL)1);
    REAL back = fmax(dot(fabs(m0), aw), fmax(dot(fabs(m1), aw), dot(fabs(m2), aw)));
    REAL3 n_g = instance_normal(in, sf.n_g);
    REAL along = length(n_g);
    REAL gamma = fmax(gamma_n(ERR_ROUNDINGS), (REAL)(ERR_ROUNDINGS * FLT_EPSILON));
    sf.err = sf.err * stretch + gamma * (max_abs3(world) + max_comp3(mapped)) +
             (along > (REAL)0 ? gamma * back / along : (REAL)0);
    sf.p = world;
    sf.n_g = safe_normalize(n_g);
    sf.n_s = safe_normalize(instance_normal(in, sf.n_s));
    if (in->material >= 0) sf.material = in->material;
    return sf;
}
#endif

// The hit's surface in the scene's frame.
HOT Surface surface_at(const SceneRefs* s, const Ray* r, const Hit* hit, bool want_uv) {
#if HAS_INSTANCES
    if (hit->instance >= 0) return instance_surface(s, r, hit, want_uv);
#ifdef USE_DOUBLE
    // Instances' surfaces lie where their float32 matrices put them, in every build: a scene
    // surface that meets one (a glass base standing on the floor) needs offsets of float32
    // size too, or a ray spawned from it can start on the wrong side of the instance's.
    Surface sf = shape_surface(s, r, hit, want_uv);
    sf.err = fmax(sf.err, (REAL)(ERR_ROUNDINGS * FLT_EPSILON) * max_abs3(sf.p));
    return sf;
#endif
#endif
    return shape_surface(s, r, hit, want_uv);
}

// Move p off the surface to the side of n_g that w leaves on, by the error bound along the
// normal: the spawned ray then starts beyond any rounding of p and needs no t epsilon.
inline REAL3 offset_origin(const Surface* sf, REAL3 w) {
#if OFFSET_FIXED_EPS
    REAL d = (REAL)1e-4;
#else
    REAL d = sf->err * (fabs(sf->n_g.x) + fabs(sf->n_g.y) + fabs(sf->n_g.z));
#endif
    return dot(w, sf->n_g) > (REAL)0 ? sf->p + d * sf->n_g : sf->p - d * sf->n_g;
}

// x^s for the specular term: by repeated squaring where s is a whole number up to 4096 (at most
// 2 log2(s) multiplications: x in [0.5, 1] within 0.8 s ulp of x^s, 100 ulp for s = 128, far
// below a 16-bit code), else as exp2(s log2 x) (about 0.35 s ulp). Squaring took the spheres
// scene's kernel 9 to 14 % faster than exp2 and log2; PoCL's full-precision pow costs several
// times more than either.
HOT REAL phong_power(REAL x, REAL s) {
    if (!(s >= (REAL)0 && s <= (REAL)4096 && s == floor(s))) return exp2(s * log2(x));
    REAL r = 1;
    for (int n = (int)s; n; n >>= 1) {
        if (n & 1) r *= x;
        x *= x;
    }
    return r;
}

// Light i's shadow ray from the surface (origin off it, towards the light or its sample, up to
// tmax) and what the light brings if nothing blocks it: direction l, attenuation and n.l. False
// when the light gives nothing there, and no shadow ray is traced. key: the pixel sample, which
// picks area lights' samples.
STAGE bool light_ray(const SceneRefs* s, const Surface* sf, REAL3 n, int i, SampleKey key,
                     REAL3* l_out, REAL* atten_out, REAL* ndl_out, Ray* shadow, REAL* tmax_out) {
    const __global Light* light = s->lights + i;
    REAL3 l;
    REAL atten = 1;
    // Where a shadow ray towards a light at a finite place aims: the light, or its sample.
    REAL3 target = TO_REAL3(light->position);
#if HAS_AREA_LIGHTS
    if (light->kind >= LIGHT_RECT) {
        if (!sample_area_light(light, sf->p, sf->err, light_square(key, i), &target, &atten)) {
            return false;
        }
        l = safe_normalize(target - sf->p);
    } else
#endif
    if (light->kind != LIGHT_DIRECTIONAL) {
        REAL3 to_light = target - sf->p;
        REAL dist = length(to_light);
        if (!(dist > sf->err)) return false;  // a light at the hit point lights nothing
        l = to_light / dist;
        REAL3 k = TO_REAL3(light->attenuation);
        REAL denom = k.x + k.y * dist + k.z * dist * dist;
        atten = denom > (REAL)0 ? fmin((REAL)1, (REAL)1 / denom) : (REAL)1;
#if HAS_SPOT_LIGHTS
        if (light->kind == LIGHT_SPOT) {
            atten *= spot_factor(light, l);
            if (!(atten > (REAL)0)) return false;  // outside the cone: no shadow ray
        }
#endif
    } else {
        l = -safe_normalize(TO_REAL3(light->position));
    }
    REAL ndl = dot(n, l);
    if (!(ndl > (REAL)0)) return false;
    REAL3 origin = offset_origin(sf, l);
    // Aimed from the offset origin itself: a ray parallel to l from there passes beside a
    // point light, and crosses a surface that holds the light before reaching it. It stops
    // just short of the light so such a surface does not shadow it.
    REAL3 shadow_dir = l;
    REAL tmax = REAL_INF;
    if (light->kind != LIGHT_DIRECTIONAL) {
        REAL3 to_light = target - origin;
        REAL span = length(to_light);
        shadow_dir = span > (REAL)0 ? to_light / span : l;
        tmax = span * ((REAL)1 - gamma_n(ERR_ROUNDINGS));
    }
    *shadow = make_ray(origin, shadow_dir);
    *l_out = l;
    *atten_out = atten;
    *ndl_out = ndl;
    *tmax_out = tmax;
    return true;
}

// Light i's diffuse and specular term, `filter` being the light its shadow ray let through.
STAGE REAL3 light_term(const SceneRefs* s, int i, REAL3 n, REAL3 v, REAL3 c,
                       const __global Material* m, REAL3 l, REAL atten, REAL ndl, REAL3 filter) {
    REAL3 refl = (REAL)2 * ndl * n - l;
    REAL rv = dot(refl, v);
    REAL spec = rv > (REAL)0 ? phong_power(rv, TO_REAL(m->shininess)) : (REAL)0;
    REAL diffuse = TO_REAL(m->diffuse), specular = TO_REAL(m->specular);
    const __global Light* light = s->lights + i;
    return atten * TO_REAL3(light->color) * filter * (diffuse * ndl * c + specular * spec);
}

// What a surface of colour c gives whatever the lights: its ambient term and its emission.
inline REAL3 surface_glow(const __global Material* m, REAL3 c, REAL3 ambient_light) {
    return TO_REAL(m->ambient) * c * ambient_light + TO_REAL3(m->emission);
}

// Ambient plus, for each light on the lit side, diffuse and specular times the light that
// reaches p through the shadow ray. key: the pixel sample, which picks area lights' samples.
HOT REAL3 shade_direct(const SceneRefs* s, const Surface* sf, REAL3 n, REAL3 v, REAL3 c,
                          const __global Material* m, REAL3 ambient_light, SampleKey key,
                          int* shadow_rays) {
    REAL3 result = surface_glow(m, c, ambient_light);
    for (int i = 0; i < s->n_lights; ++i) {
        REAL3 l;
        REAL atten, ndl, tmax;
        Ray shadow;
        if (!light_ray(s, sf, n, i, key, &l, &atten, &ndl, &shadow, &tmax)) continue;
        (*shadow_rays)++;
        REAL3 filter = transmission(s, &shadow, tmax);
        if (max_comp3(filter) <= (REAL)0) continue;
        result += light_term(s, i, n, v, c, m, l, atten, ndl, filter);
    }
    return result;
}

// What shading a hit needs: its surface, its side, the normal facing the ray and its colour.
typedef struct {
    Surface sf;
    REAL3 n, c;
    bool entering;
} ShadePoint;

STAGE ShadePoint shade_point(const SceneRefs* s, const __global Camera* camera, const Ray* ray,
                             const Hit* hit) {
    ShadePoint pt;
    pt.sf = surface_at(s, ray, hit,
                       material_needs_uv(s, crossing_material(s, hit->ref, hit->instance)));
    pt.entering = dot(ray->d, pt.sf.n_g) < (REAL)0;
    REAL3 n_f = pt.entering ? pt.sf.n_g : -pt.sf.n_g;
    pt.n = dot(pt.sf.n_s, ray->d) < (REAL)0 ? pt.sf.n_s : -pt.sf.n_s;
    pt.c = surface_color(s, s->materials + pt.sf.material, pt.sf.p + TO_REAL3(camera->world),
                         n_f, pt.sf.uv);
    return pt;
}

#endif
