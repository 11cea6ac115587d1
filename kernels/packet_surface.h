// A sample packet's shading points lane-wise (TRAVERSAL_SAMPLE_PACKET): shade_point's
// arithmetic for every lane at once, for the shapes whose surfaces are a few vector operations
// (triangles, spheres, planes) and materials without a texture or with a checker. The
// operations are shade_point's, in its order and with its contractions (one expression where
// it has one, a statement of its own where it has none), so each lane's ShadePoint is bit for
// bit the one shade_point gives (tests/test_packets.py compares the images of both schemes
// pixel for pixel). Lanes of other shapes, image textures, vertex texture coordinates and
// lengths outside length()'s plain range are left to shade_point.
#ifndef CLRAY_PACKET_SURFACE_H
#define CLRAY_PACKET_SURFACE_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "shading.h"
#include "packet.h"
#include "packet_light.h"

// Instances map their surfaces through matrices, and a double sphere build re-projects in
// double: those stay with shade_point.
#define SURFACE_LANES (!HAS_INSTANCES && HAS_BVH && !SPHERE_FP64)

#if SURFACE_LANES
// The per-lane records that a lane's shape and material give its surface: for a triangle its
// corners (a, b, c) and vertex normals (na, nb, nc), for a sphere its centre (a) and radius
// (b.x), for a plane its normal (a) and point (b); the material's colour, diffuse, specular,
// shininess, ambient, emission and reflectance and, for a checker texture, its cell size,
// second colour and blend.
typedef struct {
    REALP red, green, blue, diffuse, specular, shininess, ambient, ex, ey, ez, reflect, ax, ay, az,
        bx, by, bz;
#if HAS_TRIANGLES
    REALP cx, cy, cz;
#if HAS_VERTEX_NORMALS
    REALP nax, nay, naz, nbx, nby, nbz, ncx, ncy, ncz;
    MASKP smooth;
#endif
#endif
#if HAS_TEXTURES
    REALP size, blend, red2, green2, blue2;
    MASKP checker;
#endif
    MASKP kind;
    int material[PACKET_LANES];
} ShapeLanes;

// The rows of shape_lanes' table: only those of the shapes and textures a build has.
enum {
    ROW_COLOR = 0,
    ROW_TERM = 3,
    ROW_GLOW = 6,
    ROW_REFLECT = 10,
    ROW_A = 11,
    ROW_B = 14,
    ROW_C = 17,
#if HAS_TRIANGLES
    ROW_NORMALS = 20,
#else
    ROW_NORMALS = 17,
#endif
#if HAS_TRIANGLES && HAS_VERTEX_NORMALS
    ROW_CHECKER = ROW_NORMALS + 9,
#else
    ROW_CHECKER = ROW_NORMALS,
#endif
#if HAS_TEXTURES
    SHAPE_FIELDS = ROW_CHECKER + 5
#else
    SHAPE_FIELDS = ROW_CHECKER
#endif
};

// The record of the shape hit as (ref, part) into f (row r at f[r * stride]: its corners,
// centre or plane), its material and smoothness. False where shade_point must shade the lane:
// another shape or vertex texture coordinates.
HOT bool shape_record(const SceneRefs* s, int ref, int part, REAL* f, int stride, int* material,
                      LANE_INT* smooth) {
    int i = ref & PRIM_INDEX_MASK;
    *smooth = 0;
    switch (ref >> PRIM_TYPE_SHIFT) {
#if HAS_TRIANGLES
        case PRIM_TRIANGLE: {
            Triangle tri = s->triangles[i];
            if (tri.material & TRIANGLE_UV) return false;
            const __global TrianglePacket* pk = s->triangle_packets + part / PACKET_WIDTH;
            int lane = part % PACKET_WIDTH;
            f[ROW_A * stride] = (REAL)pk->x0[lane];
            f[(ROW_A + 1) * stride] = (REAL)pk->y0[lane];
            f[(ROW_A + 2) * stride] = (REAL)pk->z0[lane];
            f[ROW_B * stride] = (REAL)pk->x1[lane];
            f[(ROW_B + 1) * stride] = (REAL)pk->y1[lane];
            f[(ROW_B + 2) * stride] = (REAL)pk->z1[lane];
            f[ROW_C * stride] = (REAL)pk->x2[lane];
            f[(ROW_C + 1) * stride] = (REAL)pk->y2[lane];
            f[(ROW_C + 2) * stride] = (REAL)pk->z2[lane];
#if HAS_VERTEX_NORMALS
            if (tri.material & TRIANGLE_SMOOTH) {
                *smooth = -1;
                int v[3] = {tri.v0, tri.v1, tri.v2};
                for (int c = 0; c < 3; ++c) {
                    REAL3 n = TO_REAL3(s->normals[v[c]]);
                    f[(ROW_NORMALS + 3 * c) * stride] = n.x;
                    f[(ROW_NORMALS + 3 * c + 1) * stride] = n.y;
                    f[(ROW_NORMALS + 3 * c + 2) * stride] = n.z;
                }
            }
#endif
            *material = tri.material & TRIANGLE_MATERIAL_MASK;
            return true;
        }
#endif
#if HAS_SPHERES
        case PRIM_SPHERE: {
            const __global Sphere* sp = s->spheres + i;
            REAL4 c = TO_REAL4(sp->center_radius);
            f[ROW_A * stride] = c.x;
            f[(ROW_A + 1) * stride] = c.y;
            f[(ROW_A + 2) * stride] = c.z;
            f[ROW_B * stride] = c.w;
            *material = sp->material;
            return true;
        }
#endif
#if HAS_PLANES
        case PRIM_PLANE: {
            const __global Plane* pl = s->planes + i;
            REAL3 n = TO_REAL3(pl->normal), q = TO_REAL3(pl->point);
            f[ROW_A * stride] = n.x;
            f[(ROW_A + 1) * stride] = n.y;
            f[(ROW_A + 2) * stride] = n.z;
            f[ROW_B * stride] = q.x;
            f[(ROW_B + 1) * stride] = q.y;
            f[(ROW_B + 2) * stride] = q.z;
            *material = pl->material;
            return true;
        }
#endif
        default:
            return false;
    }
}

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

// length() lane-wise: the square root of dot_lanes where the squared length is within
// [2^-90, 2^90] (length_lanes) or the vector is zero. Lanes where it is not (a squared length
// that underflows to zero among them: length() scales those) are added to *outside.
HOT REALP plain_length_lanes(REALP x, REALP y, REALP z, MASKP* outside) {
    REALP dd = dot_lanes(x, y, z, x, y, z);
    MASKP zero = (x == (REAL)0) & (y == (REAL)0) & (z == (REAL)0);
    *outside |= ~(zero | ((dd >= (REAL)0x1p-90) & (dd <= (REAL)0x1p90)));
    return sqrt(GREATER(dd, (REALP)(0)));
}

// safe_normalize lane-wise, for the lanes that plain_length_lanes can measure.
HOT void safe_normalize_lanes(REALP* x, REALP* y, REALP* z, MASKP* outside) {
    REALP len = plain_length_lanes(*x, *y, *z, outside);
    MASKP some = len > (REAL)0;
    *x = some ? *x / len : *x;
    *y = some ? *y / len : *y;
    *z = some ? *z / len : *z;
}

// shape_surface's point, error bound and normals, lane-wise.
typedef struct {
    REALP px, py, pz, err, gx, gy, gz, sx, sy, sz;
} SurfaceOfLanes;

// Where `mine`, *sf takes v.
HOT void take_surface(MASKP mine, const SurfaceOfLanes* v, SurfaceOfLanes* sf) {
    sf->px = mine ? v->px : sf->px;
    sf->py = mine ? v->py : sf->py;
    sf->pz = mine ? v->pz : sf->pz;
    sf->err = mine ? v->err : sf->err;
    sf->gx = mine ? v->gx : sf->gx;
    sf->gy = mine ? v->gy : sf->gy;
    sf->gz = mine ? v->gz : sf->gz;
    sf->sx = mine ? v->sx : sf->sx;
    sf->sy = mine ? v->sy : sf->sy;
    sf->sz = mine ? v->sz : sf->sz;
}

#if HAS_TRIANGLES
// shape_surface's triangle case: the point from the barycentrics, pulled towards the centroid,
// the winding's normal and the blended vertex normal.
HOT SurfaceOfLanes triangle_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                          const PacketHit* h, MASKP* outside) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP b1 = h->b1, b2 = h->b2, b0 = (REAL)1 - b1 - b2;
    v.px = b0 * g->ax + b1 * g->bx + b2 * g->cx;
    v.py = b0 * g->ay + b1 * g->by + b2 * g->cy;
    v.pz = b0 * g->az + b1 * g->bz + b2 * g->cz;
    REALP ex = fabs(b0 * g->ax) + fabs(b1 * g->bx) + fabs(b2 * g->cx);
    REALP ey = fabs(b0 * g->ay) + fabs(b1 * g->by) + fabs(b2 * g->cy);
    REALP ez = fabs(b0 * g->az) + fabs(b1 * g->bz) + fabs(b2 * g->cz);
    v.err = gamma * fmax(ex, fmax(ey, ez));
    REALP tx = (g->ax + g->bx + g->cx) / (REAL)3 - v.px;
    REALP ty = (g->ay + g->by + g->cy) / (REAL)3 - v.py;
    REALP tz = (g->az + g->bz + g->cz) / (REAL)3 - v.pz;
    REALP reach = plain_length_lanes(tx, ty, tz, outside);
    REALP k = fmin((REAL)4 * v.err, (REAL)0.5 * reach) / reach;
    MASKP move = reach > (REAL)0;
    v.px = move ? v.px + k * tx : v.px;
    v.py = move ? v.py + k * ty : v.py;
    v.pz = move ? v.pz + k * tz : v.pz;
    // cross(p1 - p0, p2 - p0) as PoCL's cross() has it: each product rounded, none fused.
    REALP e1x = g->bx - g->ax, e1y = g->by - g->ay, e1z = g->bz - g->az;
    REALP e2x = g->cx - g->ax, e2y = g->cy - g->ay, e2z = g->cz - g->az;
    REALP yz = e1y * e2z;
    REALP zy = e1z * e2y;
    REALP zx = e1z * e2x;
    REALP xz = e1x * e2z;
    REALP xy = e1x * e2y;
    REALP yx = e1y * e2x;
    REALP nx = yz - zy, ny = zx - xz, nz = xy - yx;
    safe_normalize_lanes(&nx, &ny, &nz, outside);
    // A degenerate triangle has no normal: it faces the ray.
    MASKP some = dot_lanes(nx, ny, nz, nx, ny, nz) > (REAL)0;
    v.gx = some ? nx : -r->dx;
    v.gy = some ? ny : -r->dy;
    v.gz = some ? nz : -r->dz;
    v.sx = v.gx;
    v.sy = v.gy;
    v.sz = v.gz;
#if HAS_VERTEX_NORMALS
    if (lane_mask(g->smooth)) {
        REALP sx = b0 * g->nax + b1 * g->nbx + b2 * g->ncx;
        REALP sy = b0 * g->nay + b1 * g->nby + b2 * g->ncy;
        REALP sz = b0 * g->naz + b1 * g->nbz + b2 * g->ncz;
        MASKP wide = (MASKP)(0);
        safe_normalize_lanes(&sx, &sy, &sz, &wide);
        *outside |= g->smooth & wide;
        MASKP blend = g->smooth & (dot_lanes(sx, sy, sz, sx, sy, sz) > (REAL)0);
        v.sx = blend ? sx : v.sx;
        v.sy = blend ? sy : v.sy;
        v.sz = blend ? sz : v.sz;
    }
#endif
    return v;
}
#endif

#if HAS_SPHERES
// shape_surface's sphere case: the point re-projected onto the sphere along its normal.
HOT SurfaceOfLanes sphere_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                        const PacketHit* h, MASKP* outside) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP px = r->ox + h->t * r->dx;
    REALP py = r->oy + h->t * r->dy;
    REALP pz = r->oz + h->t * r->dz;
    REALP nx = px - g->ax, ny = py - g->ay, nz = pz - g->az;
    safe_normalize_lanes(&nx, &ny, &nz, outside);
    v.px = g->ax + g->bx * nx;
    v.py = g->ay + g->bx * ny;
    v.pz = g->az + g->bx * nz;
    v.gx = v.sx = nx;
    v.gy = v.sy = ny;
    v.gz = v.sz = nz;
    v.err = gamma * (fmax(fabs(g->ax), fmax(fabs(g->ay), fabs(g->az))) + g->bx);
    return v;
}
#endif

#if HAS_PLANES
// shape_surface's plane case: the point projected onto the plane.
HOT SurfaceOfLanes plane_surface_lanes(const ShapeLanes* g, const RayPacket* r,
                                       const PacketHit* h) {
    SurfaceOfLanes v;
    REAL gamma = gamma_n(ERR_ROUNDINGS);
    REALP px = r->ox + h->t * r->dx;
    REALP py = r->oy + h->t * r->dy;
    REALP pz = r->oz + h->t * r->dz;
    REALP e = dot_lanes(px - g->bx, py - g->by, pz - g->bz, g->ax, g->ay, g->az);
    v.px = px - e * g->ax;
    v.py = py - e * g->ay;
    v.pz = pz - e * g->az;
    v.gx = v.sx = g->ax;
    v.gy = v.sy = g->ay;
    v.gz = v.sz = g->az;
    v.err = gamma * (fmax(fabs(v.px), fmax(fabs(v.py), fabs(v.pz))) +
                     fmax(fabs(g->bx), fmax(fabs(g->by), fabs(g->bz))));
    return v;
}
#endif

#if HAS_TEXTURES
// surface_color's checker, lane-wise: where g->checker, g's colour becomes the texture's.
HOT void checker_lanes(ShapeLanes* g, const __global Camera* camera, const SurfaceOfLanes* sf,
                       MASKP entering) {
    REAL3 world = TO_REAL3(camera->world);
    REALP nx = entering ? sf->gx : -sf->gx;
    REALP ny = entering ? sf->gy : -sf->gy;
    REALP nz = entering ? sf->gz : -sf->gz;
    REALP size = g->size;
    REALP qx = (sf->px + world.x - (REAL)0.25 * size * nx) / size;
    REALP qy = (sf->py + world.y - (REAL)0.25 * size * ny) / size;
    REALP qz = (sf->pz + world.z - (REAL)0.25 * size * nz) / size;
    REALP cells = floor(qx) + floor(qy) + floor(qz);
    REALP odd = cells - (REAL)2 * floor(cells * (REAL)0.5);
    MASKP second = odd == (REAL)1;
    REALP red = second ? g->red2 : g->red;
    REALP green = second ? g->green2 : g->green;
    REALP blue = second ? g->blue2 : g->blue;
    REALP blend = g->blend;
    g->red = g->checker ? blend * red + ((REAL)1 - blend) * g->red : g->red;
    g->green = g->checker ? blend * green + ((REAL)1 - blend) * g->green : g->green;
    g->blue = g->checker ? blend * blue + ((REAL)1 - blend) * g->blue : g->blue;
}
#endif

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
    SurfaceOfLanes sf = {0};
    MASKP outside = (MASKP)(0);
#if HAS_TRIANGLES
    MASKP triangles = g.kind == (MASKP)(PRIM_TRIANGLE);
    if (lane_mask(triangles)) {
        MASKP wide = (MASKP)(0);
        SurfaceOfLanes v = triangle_surface_lanes(&g, r, h, &wide);
        outside |= triangles & wide;
        take_surface(triangles, &v, &sf);
    }
#endif
#if HAS_SPHERES
    MASKP spheres = g.kind == (MASKP)(PRIM_SPHERE);
    if (lane_mask(spheres)) {
        MASKP wide = (MASKP)(0);
        SurfaceOfLanes v = sphere_surface_lanes(&g, r, h, &wide);
        outside |= spheres & wide;
        take_surface(spheres, &v, &sf);
    }
#endif
#if HAS_PLANES
    MASKP planes = g.kind == (MASKP)(PRIM_PLANE);
    if (lane_mask(planes)) {
        SurfaceOfLanes v = plane_surface_lanes(&g, r, h);
        take_surface(planes, &v, &sf);
    }
#endif
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
