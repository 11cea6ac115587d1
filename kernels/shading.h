// Shading points: the hit's surface, the side the ray meets, the normal facing it and the colour
// there (shade_point); for sample packets the same lane-wise (shade_point_lanes), from each
// lane's shape and material records.
#ifndef CLRAY_SHADING_H
#define CLRAY_SHADING_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "lanes.h"
#include "shapes.h"
#include "surface.h"
#include "texture.h"
#include "lights.h"

STAGE ShadePoint shade_point(const SceneRefs* s, const __global Camera* camera, const Ray* ray,
                             const Hit* hit) {
    ShadePoint pt;
    pt.sf = surface_at(s, ray, hit,
                       material_needs_uv(s, crossing_material(s, hit->ref, hit->part,
                                                             hit->instance)));
    pt.entering = dot(ray->d, pt.sf.n_g) < (REAL)0;
    REAL3 n_f = pt.entering ? pt.sf.n_g : -pt.sf.n_g;
    pt.n = dot(pt.sf.n_s, ray->d) < (REAL)0 ? pt.sf.n_s : -pt.sf.n_s;
    pt.c = surface_color(s, s->materials + pt.sf.material, pt.sf.p + TO_REAL3(camera->world),
                         n_f, pt.sf.uv, v_ends_apart(hit->ref, hit->part));
#if HAS_VERTEX_COLORS
    pt.c *= pt.sf.tint;
#endif
    return pt;
}

#if SAMPLE_PACKETS
// Each lane's material and its colour at the shading point (texture looked up), as rows: what
// light_term reads of a ShadePoint besides its surface and normal.
typedef struct {
    REAL c[3][PACKET_LANES];
    int material[PACKET_LANES];
} MaterialRows;

// Lane j of *mr from its ShadePoint.
HOT void set_material_row(MaterialRows* mr, int j, const ShadePoint* pt) {
    mr->c[0][j] = pt->c.x;
    mr->c[1][j] = pt->c.y;
    mr->c[2][j] = pt->c.z;
    mr->material[j] = pt->sf.material;
}

// Lane j's colour in *mr.
HOT REAL3 color_of_lane(const MaterialRows* mr, int j) {
    return (REAL3)(mr->c[0][j], mr->c[1][j], mr->c[2][j]);
}

// As surface_lanes, for light_term (mr: the lanes' materials and colours).
HOT TermLanes term_lanes(const SceneRefs* s, const MaterialRows* mr, const RayLanes* seen,
                         int bits) {
    REAL f[14][PACKET_LANES];
    int spare = lowest_bit(bits);
    for (int j = 0; j < PACKET_LANES; ++j) {
        int k = ((bits >> j) & 1) ? j : spare;
        const __global Material* m = s->materials + mr->material[k];
        REAL3 v = -direction_of_lane(seen, k);
        f[0][j] = v.x;
        f[1][j] = v.y;
        f[2][j] = v.z;
        f[3][j] = mr->c[0][k];
        f[4][j] = mr->c[1][k];
        f[5][j] = mr->c[2][k];
        f[6][j] = TO_REAL(m->diffuse);
        f[7][j] = TO_REAL(m->specular);
        f[8][j] = TO_REAL(m->shininess);
        REAL3 e = TO_REAL3(m->emission);
        f[9][j] = TO_REAL(m->ambient);
        f[10][j] = e.x;
        f[11][j] = e.y;
        f[12][j] = e.z;
        f[13][j] = TO_REAL(m->reflect);
    }
    TermLanes t;
    t.vx = VLOADP(0, f[0]);
    t.vy = VLOADP(0, f[1]);
    t.vz = VLOADP(0, f[2]);
    t.cx = VLOADP(0, f[3]);
    t.cy = VLOADP(0, f[4]);
    t.cz = VLOADP(0, f[5]);
    t.diffuse = VLOADP(0, f[6]);
    t.specular = VLOADP(0, f[7]);
    t.shininess = VLOADP(0, f[8]);
    t.ambient = VLOADP(0, f[9]);
    t.ex = VLOADP(0, f[10]);
    t.ey = VLOADP(0, f[11]);
    t.ez = VLOADP(0, f[12]);
    t.reflect = VLOADP(0, f[13]);
    return t;
}
#endif

#if SURFACE_LANES
// Material `material`'s record into f (row r at f[r * stride]), and whether its texture is a
// checker.
// False where shade_point must shade its lanes: an image texture.
HOT bool material_record(const SceneRefs* s, int material, REAL* f, int stride,
                         LANE_INT* checker) {
    const __global Material* m = s->materials + material;
    REAL3 color = TO_REAL3(m->color);
    f[ROW_COLOR * stride] = color.x;
    f[(ROW_COLOR + 1) * stride] = color.y;
    f[(ROW_COLOR + 2) * stride] = color.z;
    f[ROW_TERM * stride] = TO_REAL(m->diffuse);
    f[(ROW_TERM + 1) * stride] = TO_REAL(m->specular);
    f[(ROW_TERM + 2) * stride] = TO_REAL(m->shininess);
    REAL3 emission = TO_REAL3(m->emission);
    f[ROW_GLOW * stride] = TO_REAL(m->ambient);
    f[(ROW_GLOW + 1) * stride] = emission.x;
    f[(ROW_GLOW + 2) * stride] = emission.y;
    f[(ROW_GLOW + 3) * stride] = emission.z;
    f[ROW_REFLECT * stride] = TO_REAL(m->reflect);
    *checker = 0;
#if HAS_TEXTURES
    if (m->texture >= 0) {
        const __global Texture* tx = s->textures + m->texture;
        if (tx->kind != TEXTURE_CHECKER) return false;
        *checker = -1;
        REAL3 color2 = TO_REAL3(tx->color2);
        f[ROW_CHECKER * stride] = TO_REAL(tx->size);
        f[(ROW_CHECKER + 1) * stride] = TO_REAL(tx->blend);
        f[(ROW_CHECKER + 2) * stride] = color2.x;
        f[(ROW_CHECKER + 3) * stride] = color2.y;
        f[(ROW_CHECKER + 4) * stride] = color2.z;
    }
#endif
    return true;
}

// Rows [first, end) of f: column 0 in every column.
HOT void copy_column(REAL f[SHAPE_FIELDS][PACKET_LANES], int first, int end) {
    for (int row = first; row < end; ++row) VSTOREP((REALP)(f[row][0]), 0, f[row]);
}

// Row r of a record table as lanes: f[r * PACKET_LANES ...] lane by lane, or where `one` the
// single record f[r] in every lane.
#define RECORD_ROW(f, r, one) ((one) ? (REALP)((f)[r]) : VLOADP(0, (f) + (r) * PACKET_LANES))

// The rows of a record table (f: a row of PACKET_LANES lanes each) or of one record (`one`, a
// constant at each call) into g's lanes.
HOT void shape_rows(const REAL* f, bool one, ShapeLanes* g) {
    g->red = RECORD_ROW(f, ROW_COLOR, one);
    g->green = RECORD_ROW(f, ROW_COLOR + 1, one);
    g->blue = RECORD_ROW(f, ROW_COLOR + 2, one);
    g->diffuse = RECORD_ROW(f, ROW_TERM, one);
    g->specular = RECORD_ROW(f, ROW_TERM + 1, one);
    g->shininess = RECORD_ROW(f, ROW_TERM + 2, one);
    g->ambient = RECORD_ROW(f, ROW_GLOW, one);
    g->ex = RECORD_ROW(f, ROW_GLOW + 1, one);
    g->ey = RECORD_ROW(f, ROW_GLOW + 2, one);
    g->ez = RECORD_ROW(f, ROW_GLOW + 3, one);
    g->reflect = RECORD_ROW(f, ROW_REFLECT, one);
    g->ax = RECORD_ROW(f, ROW_A, one);
    g->ay = RECORD_ROW(f, ROW_A + 1, one);
    g->az = RECORD_ROW(f, ROW_A + 2, one);
    g->bx = RECORD_ROW(f, ROW_B, one);
    g->by = RECORD_ROW(f, ROW_B + 1, one);
    g->bz = RECORD_ROW(f, ROW_B + 2, one);
#if HAS_TRIANGLES
    g->cx = RECORD_ROW(f, ROW_C, one);
    g->cy = RECORD_ROW(f, ROW_C + 1, one);
    g->cz = RECORD_ROW(f, ROW_C + 2, one);
#if HAS_VERTEX_NORMALS
    g->nax = RECORD_ROW(f, ROW_NORMALS, one);
    g->nay = RECORD_ROW(f, ROW_NORMALS + 1, one);
    g->naz = RECORD_ROW(f, ROW_NORMALS + 2, one);
    g->nbx = RECORD_ROW(f, ROW_NORMALS + 3, one);
    g->nby = RECORD_ROW(f, ROW_NORMALS + 4, one);
    g->nbz = RECORD_ROW(f, ROW_NORMALS + 5, one);
    g->ncx = RECORD_ROW(f, ROW_NORMALS + 6, one);
    g->ncy = RECORD_ROW(f, ROW_NORMALS + 7, one);
    g->ncz = RECORD_ROW(f, ROW_NORMALS + 8, one);
#endif
#endif
#if HAS_TEXTURES
    g->size = RECORD_ROW(f, ROW_CHECKER, one);
    g->blend = RECORD_ROW(f, ROW_CHECKER + 1, one);
    g->red2 = RECORD_ROW(f, ROW_CHECKER + 2, one);
    g->green2 = RECORD_ROW(f, ROW_CHECKER + 3, one);
    g->blue2 = RECORD_ROW(f, ROW_CHECKER + 4, one);
#endif
}

// shape_lanes where every lane of lit hit the shape of its lowest lane (as a pixel's samples
// mostly do): that shape's and its material's records read once, into every lane.
HOT ShapeLanes one_shape_lanes(const SceneRefs* s, const HitLanes* hits, int lit, int* left) {
    // Each kind fills its own rows: the others are zeros, so that every kind's arithmetic runs
    // on defined numbers in every lane.
    REAL f[SHAPE_FIELDS];
    for (int row = 0; row < SHAPE_FIELDS; ++row) f[row] = 0;
    ShapeLanes g;
    int first = lowest_bit(lit), material = 0;
    int ref = (int)hits->ref[first];
    LANE_INT smooth = 0, checker = 0;
    bool shaded = shape_record(s, ref, (int)hits->part[first], f, 1, &material, &smooth) &&
                  material_record(s, material, f, 1, &checker);
    *left = shaded ? 0 : lit;
    shape_rows(f, true, &g);
#if HAS_TRIANGLES && HAS_VERTEX_NORMALS
    g.smooth = (MASKP)(smooth);
#endif
#if HAS_TEXTURES
    g.checker = (MASKP)(checker);
#endif
    g.kind = (MASKP)(shaded ? ref >> PRIM_TYPE_SHIFT : -1);
    for (int j = 0; j < PACKET_LANES; ++j) g.material[j] = material;
    return g;
}

// The records of the lanes of `lit` (their hits in rows): each lane's shape and its
// material's; the other lanes hold a copy of one of those. Where the shapes differ and their
// materials do not (a mesh), the material's record is read once. *left: the lanes whose
// records shape_record or material_record declines.
HOT ShapeLanes shape_lanes(const SceneRefs* s, const HitLanes* hits, int lit, int* left) {
    REAL f[SHAPE_FIELDS][PACKET_LANES];
    LANE_INT kind[PACKET_LANES], smooth[PACKET_LANES], checker[PACKET_LANES];
    ShapeLanes g;
    int spare = lowest_bit(lit);
    for (int row = 0; row < SHAPE_FIELDS; ++row) VSTOREP((REALP)(0), 0, f[row]);
    int shaped = 0;  // lanes j whose shape_record was read
    for (int j = 0; j < PACKET_LANES; ++j) {
        int k = ((lit >> j) & 1) ? j : spare;
        int ref = (int)hits->ref[k];
        kind[j] = ref >> PRIM_TYPE_SHIFT;
        g.material[j] = 0;
        if (shape_record(s, ref, (int)hits->part[k], &f[0][j], PACKET_LANES, g.material + j,
                         smooth + j)) {
            shaped |= 1 << j;
        }
    }
    int material = shaped ? g.material[lowest_bit(shaped)] : 0;
    bool one_material = shaped != 0;
    for (int rest = shaped; rest; rest &= rest - 1) {
        one_material &= g.material[lowest_bit(rest)] == material;
    }
    int textured = 0;  // lanes j whose material_record declines
    if (one_material) {
        if (!material_record(s, material, &f[0][0], PACKET_LANES, checker)) textured = ALL_LANES;
        copy_column(f, 0, ROW_A);
#if HAS_TEXTURES
        copy_column(f, ROW_CHECKER, SHAPE_FIELDS);
#endif
        for (int j = 1; j < PACKET_LANES; ++j) checker[j] = checker[0];
    } else {
        for (int j = 0; j < PACKET_LANES; ++j) {
            checker[j] = 0;
            if (((shaped >> j) & 1) &&
                !material_record(s, g.material[j], &f[0][j], PACKET_LANES, checker + j)) {
                textured |= 1 << j;
            }
        }
    }
    // Lane j declined: its sample's lane (j, or for a lane outside lit the spare it copies)
    // goes to shade_point.
    int declined = ~shaped | textured;
    *left = 0;
    for (int j = 0; j < PACKET_LANES; ++j) {
        if ((declined >> j) & 1) {
            kind[j] = -1;
            *left |= 1 << (((lit >> j) & 1) ? j : spare);
        }
    }
    *left &= lit;
    shape_rows(&f[0][0], false, &g);
#if HAS_TRIANGLES && HAS_VERTEX_NORMALS
    g.smooth = VLOADP(0, smooth);
#endif
#if HAS_TEXTURES
    g.checker = VLOADP(0, checker);
#endif
    g.kind = VLOADP(0, kind);
    return g;
}

// The rest of each ShadePoint of the lanes of `done`, beside their colours and materials.
HOT void store_shade_points(const SurfaceOfLanes* sf, const SurfaceLanes* q, MASKP entering,
                            const HitLanes* hits, int done, ShadePoint* pt) {
    REAL f[13][PACKET_LANES];
    LANE_INT in[PACKET_LANES];
    VSTOREP(sf->px, 0, f[0]);
    VSTOREP(sf->py, 0, f[1]);
    VSTOREP(sf->pz, 0, f[2]);
    VSTOREP(sf->err, 0, f[3]);
    VSTOREP(sf->gx, 0, f[4]);
    VSTOREP(sf->gy, 0, f[5]);
    VSTOREP(sf->gz, 0, f[6]);
    VSTOREP(sf->sx, 0, f[7]);
    VSTOREP(sf->sy, 0, f[8]);
    VSTOREP(sf->sz, 0, f[9]);
    VSTOREP(q->nx, 0, f[10]);
    VSTOREP(q->ny, 0, f[11]);
    VSTOREP(q->nz, 0, f[12]);
    VSTOREP(entering, 0, in);
    for (int rest = done; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        ShadePoint* p = pt + j;
        p->sf.p = (REAL3)(f[0][j], f[1][j], f[2][j]);
        p->sf.err = f[3][j];
        p->sf.n_g = (REAL3)(f[4][j], f[5][j], f[6][j]);
        p->sf.n_s = (REAL3)(f[7][j], f[8][j], f[9][j]);
        p->n = (REAL3)(f[10][j], f[11][j], f[12][j]);
        p->entering = in[j] != 0;
        // shape_surface's (u, v): a triangle's barycentrics, (0, 0) for the others (no
        // texture reads them here).
        p->sf.uv = (REAL2)(0, 0);
#if HAS_VERTEX_COLORS
        p->sf.tint = (REAL3)(1, 1, 1);  // vertex-coloured triangles are shade_point's
#endif
#if HAS_TRIANGLES
        if (hits->ref[j] >> PRIM_TYPE_SHIFT == PRIM_TRIANGLE) {
            p->sf.uv = (REAL2)(hits->b1[j], hits->b2[j]);
        }
#endif
    }
}

// shade_point for the lanes of `lit` that this can shade: their coordinates into *q, what
// light_term reads into *terms, their colours and materials into *mr, and where `whole` into
// pt[j] too, with the rest of the ShadePoint (the chains read none of it). Returns the lanes
// left to shade_point (their lanes of q, terms, mr and pt[j] are not written).
HOT int shade_point_lanes(const SceneRefs* s, const __global Camera* camera, const RayPacket* r,
                          const PacketHit* h, const HitLanes* hits, int lit, bool whole,
                          ShadePoint* pt, SurfaceLanes* q, TermLanes* terms, MaterialRows* mr) {
    int left;
    int first = lowest_bit(lit);
    MASKP other = (h->ref != (MASKP)(hits->ref[first])) |
                  (h->part != (MASKP)(hits->part[first]));
    bool same = !lane_mask(lanes_of(lit) & other);
    ShapeLanes g =
        same ? one_shape_lanes(s, hits, lit, &left) : shape_lanes(s, hits, lit, &left);
    if (left == lit) return left;
    MASKP outside = (MASKP)(0);
    SurfaceOfLanes sf = shape_surface_lanes(&g, r, h, &outside);
    left |= lane_mask(outside);
    left &= lit;
    MASKP entering = dot_lanes(r->dx, r->dy, r->dz, sf.gx, sf.gy, sf.gz) < (REAL)0;
    MASKP toward = dot_lanes(sf.sx, sf.sy, sf.sz, r->dx, r->dy, r->dz) < (REAL)0;
#if HAS_TEXTURES
    if (lane_mask(g.checker)) checker_lanes(&g, camera, &sf, entering);
#endif
    q->px = sf.px;
    q->py = sf.py;
    q->pz = sf.pz;
    q->err = sf.err;
    q->gx = sf.gx;
    q->gy = sf.gy;
    q->gz = sf.gz;
    q->nx = toward ? sf.sx : -sf.sx;
    q->ny = toward ? sf.sy : -sf.sy;
    q->nz = toward ? sf.sz : -sf.sz;
    terms->vx = -r->dx;
    terms->vy = -r->dy;
    terms->vz = -r->dz;
    terms->cx = g.red;
    terms->cy = g.green;
    terms->cz = g.blue;
    terms->diffuse = g.diffuse;
    terms->specular = g.specular;
    terms->shininess = g.shininess;
    terms->ambient = g.ambient;
    terms->ex = g.ex;
    terms->ey = g.ey;
    terms->ez = g.ez;
    terms->reflect = g.reflect;
    // Every lane's row: shade_packet then writes the lanes left to shade_point.
    VSTOREP(g.red, 0, mr->c[0]);
    VSTOREP(g.green, 0, mr->c[1]);
    VSTOREP(g.blue, 0, mr->c[2]);
    for (int j = 0; j < PACKET_LANES; ++j) mr->material[j] = g.material[j];
    int done = lit & ~left;
    if (!whole || !done) return left;
    for (int rest = done; rest; rest &= rest - 1) {
        int j = lowest_bit(rest);
        pt[j].c = color_of_lane(mr, j);
        pt[j].sf.material = mr->material[j];
    }
    store_shade_points(&sf, q, entering, hits, done, pt);
    return left;
}
#endif

#endif
