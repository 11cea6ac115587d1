// Camera rays (docs/rendering.md, Camera): a pinhole's, an orthographic camera's and a thin
// lens's, for a pixel sample (sample_ray); a pinhole's rays lane-wise for sample packets and
// for the single-ray render's row segments.
#ifndef CLRAY_CAMERA_H
#define CLRAY_CAMERA_H

#include "real.h"
#include "clray_types.h"
#include "rng.h"
#include "sampling.h"
#include "ray.h"
#include "lanes.h"

// Image point `sample` (pixel units) as (x, y) in [-1, 1] on the image plane, y up.
// Both divisions as one vector division: the same quotients.
static inline REAL2 image_plane_point(REAL2 sample, int width, int height) {
    REAL2 q = (REAL)2 * sample / (REAL2)((REAL)width, (REAL)height);
    return (REAL2)(q.x - (REAL)1, (REAL)1 - q.y);
}

static inline REAL3 camera_direction(const __global Camera* camera, REAL2 sample, int width,
                                     int height) {
    REAL2 p = image_plane_point(sample, width, height);
    REAL3 d = TO_REAL3(camera->forward) + p.x * TO_REAL3(camera->right) +
              p.y * TO_REAL3(camera->up);
    return normalize3(d);
}

// camera_direction before normalize3, lane by lane (T: a vector of REAL; DOT: DEFINE_DOT's for
// it): the image points (sx, sy) in pixel units through image_plane_point's quotients to the
// direction, and its squared length, in the single ray's expressions, so each lane's numbers
// are its. The sample packets' camera rays and the row segments' share it.
#define DEFINE_CAMERA_AIM_LANES(T, DOT, NAME)                                                   \
    HOT void NAME(const __global Camera* camera, T sx, T sy, int width, int height, T* ax,    \
                  T* ay, T* az, T* dd) {                                                       \
        T px = (REAL)2 * sx / (REAL)width - (REAL)1;                                           \
        T py = (REAL)1 - (REAL)2 * sy / (REAL)height;                                          \
        REAL3 forward = TO_REAL3(camera->forward), right = TO_REAL3(camera->right),            \
              up = TO_REAL3(camera->up);                                                       \
        *ax = (T)(forward.x) + px * right.x + py * up.x;                                       \
        *ay = (T)(forward.y) + px * right.y + py * up.y;                                       \
        *az = (T)(forward.z) + px * right.z + py * up.z;                                       \
        *dd = DOT(*ax, *ay, *az, *ax, *ay, *az);                                               \
    }

// The single-ray render's row segments (ray_tree.h, render_segment) make the camera rays of
// CAMERA_AHEAD pixels before their walks; a pinhole's, at one sample a pixel, a pixel a vector
// lane (CAMERA_ROW_LANES: row_directions), where each pixel's direction had been a chain of two
// divisions and a square root of its own.
#if RENDER_SEGMENTS
#define CAMERA_AHEAD 16
#endif
#define CAMERA_ROW_LANES (RENDER_SEGMENTS && !HAS_THIN_LENS && !HAS_ORTHOGRAPHIC)

#if CAMERA_ROW_LANES
// One REAL a lane, CAMERA_AHEAD lanes, and what comparing two of them gives.
#ifdef USE_DOUBLE
typedef double16 REALROW;
typedef long16 MASKROW;
#define TO_REALROW convert_double16
#define TO_MASKROW convert_long16
#else
typedef float16 REALROW;
typedef int16 MASKROW;
#define TO_REALROW convert_float16
#define TO_MASKROW convert_int16
#endif
DEFINE_DOT(HOT, REALROW, dot_row)
DEFINE_PLAIN_SQUARED_LENGTH(HOT, REALROW, MASKROW, plain_squared_length_row)
DEFINE_CAMERA_AIM_LANES(REALROW, dot_row, camera_aim_row)

// camera_direction at the centres of pixels x .. x + count - 1 of row y (count <=
// CAMERA_AHEAD), lane i for pixel x + i, into dx, dy, dz: its expressions lane by lane, so
// its directions. False where one of them has a squared length outside [2^-90, 2^90], where
// normalize3 takes the builtin, which scales: the caller then makes them pixel by pixel.
HOT bool row_directions(const __global Camera* camera, int x, int y, int count, int width,
                        int height, REAL* dx, REAL* dy, REAL* dz) {
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    // sample_position's centre.
    REALROW sx = TO_REALROW(x + lane) + REAL_C(0.5), sy = (REALROW)((REAL)y + REAL_C(0.5));
    REALROW ax, ay, az, dd;
    camera_aim_row(camera, sx, sy, width, height, &ax, &ay, &az, &dd);
    MASKROW own = TO_MASKROW(lane < count);
    if (any(own & ~plain_squared_length_row(dd))) return false;
    REALROW len = sqrt(dd);
    vstore16(ax / len, 0, dx);
    vstore16(ay / len, 0, dy);
    vstore16(az / len, 0, dz);
    return true;
}
#endif

#if HAS_THIN_LENS || HAS_ORTHOGRAPHIC
// The camera ray of sample s at image point `sample` (pixel units): from the eye (a
// perspective camera) or from the image point on the view plane (orthographic), then, with a
// lens, from a point of the lens towards the same point of the focus plane.
static inline void camera_ray(const __global Camera* camera, REAL2 sample, int width, int height,
                              int s, int spp, uint seed, uint pixel, REAL3* o, REAL3* d) {
    REAL2 p = image_plane_point(sample, width, height);
    REAL3 across = p.x * TO_REAL3(camera->right) + p.y * TO_REAL3(camera->up);
    // aim: from the origin to the ray's point on the focus plane, per unit of focus distance
    // (its component along forward is 1).
#if HAS_ORTHOGRAPHIC
    *o = TO_REAL3(camera->position) + across;
    REAL3 aim = TO_REAL3(camera->forward);
#else
    *o = TO_REAL3(camera->position);
    REAL3 aim = TO_REAL3(camera->forward) + across;
#endif
#if HAS_THIN_LENS
    REAL2 l = lens_sample(s, spp, seed, pixel);
    REAL3 lens = l.x * TO_REAL3(camera->lens_u) + l.y * TO_REAL3(camera->lens_v);
    // aim's component along forward is 1 and the lens lies across forward, so this is at
    // least 1 long; the loader keeps lens / focus distance below 1e6, well inside float32.
    *d = normalize3(aim - TO_REAL(camera->lens_u.w) * lens);
    *o += lens;
#else
    *d = normalize3(aim);
#endif
}
#endif

// The primary ray of pixel sample `sample`.
STAGE void sample_ray(const __global Camera* camera, const __global Params* params, int x,
                      int y, int sample, uint pixel, REAL3* o, REAL3* d) {
    int spp = params->spp;
    REAL2 pos = sample_position(x, y, sample, spp, params->seed, pixel);
#if HAS_THIN_LENS || HAS_ORTHOGRAPHIC
    camera_ray(camera, pos, params->width, params->height, sample, spp, params->seed, pixel, o,
               d);
#else
    *o = TO_REAL3(camera->position);
    *d = camera_direction(camera, pos, params->width, params->height);
#endif
}

#if SAMPLE_PACKETS
#define CAMERA_LANES (!HAS_THIN_LENS && !HAS_ORTHOGRAPHIC)

#if CAMERA_LANES
DEFINE_JITTER(REALP, jitter_lanes)
DEFINE_CAMERA_AIM_LANES(REALP, dot_lanes, camera_aim_lanes)

// sample_ray for samples first .. first + lanes - 1 of pixel (x, y), one a lane (the lanes past
// the last hold copies of the first), into *p. False where the pixel has one sample (its
// centre) or a direction's squared length is outside [2^-90, 2^90], where normalize3 takes the
// builtin, which scales against overflow and underflow: the caller then draws
// lane by lane.
HOT bool camera_ray_lanes(const __global Camera* camera, const __global Params* params, int x,
                          int y, int first, int lanes, uint pixel, RayPacket* p) {
    int spp = params->spp;
    if (spp == 1) return false;
    // sample_position's strata (sampling.h, DEFINE_JITTER).
    int nx = grid_columns(spp);
    uint sample[PACKET_LANES];
    REAL column[PACKET_LANES], start[PACKET_LANES], cells[PACKET_LANES];
    // The packet's samples are consecutive: their strata follow the first's along its row, one
    // integer division a packet rather than one a lane.
    int first_column = first % nx, first_row = first / nx;
    int c = first_column, r = first_row;
    for (int j = 0; j < PACKET_LANES; ++j) {
        bool own = j < lanes;
        int row = own ? r : first_row;
        sample[j] = (uint)(own ? first + j : first);
        column[j] = (REAL)(own ? c : first_column);
        start[j] = (REAL)(row * nx);
        cells[j] = (REAL)row_cells(row, nx, spp);
        if (++c == nx) {
            c = 0;
            ++r;
        }
    }
    UINTP samples = VLOADP(0, sample);
    uint pixel_key = pcg_hash(pcg_hash(params->seed) ^ pixel);
    REALP r0 = rng_uniform_lanes(pixel_key, samples, 0u);
    REALP r1 = rng_uniform_lanes(pixel_key, samples, 1u);
    REALP row_cells_p = VLOADP(0, cells);
    REALP sx = (REAL)x + jitter_lanes(VLOADP(0, column), r0, (REALP)(1), row_cells_p);
    REALP sy = (REAL)y + jitter_lanes(VLOADP(0, start), r1, row_cells_p, (REALP)((REAL)spp));
    REALP dx, dy, dz, dd;
    camera_aim_lanes(camera, sx, sy, params->width, params->height, &dx, &dy, &dz, &dd);
    if (lane_mask(~plain_squared_length_lanes(dd))) return false;
    REALP len = sqrt(dd);
    REAL3 o = TO_REAL3(camera->position);
    *p = make_ray_packet((REALP)(o.x), (REALP)(o.y), (REALP)(o.z), dx / len, dy / len, dz / len,
                         (1 << lanes) - 1);
    return true;
}
#endif
#endif

#endif
