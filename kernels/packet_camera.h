// A sample packet's camera rays, drawn lane-wise (TRAVERSAL_SAMPLE_PACKET): sample_ray's
// arithmetic (sample_position, camera_direction, make_ray) for all of the packet's samples at
// once, straight into the packet's lanes (docs/acceleration.md, Sample packets). For the pinhole
// camera; the lens and orthographic cameras draw their rays lane by lane.
#ifndef CLRAY_PACKET_CAMERA_H
#define CLRAY_PACKET_CAMERA_H

#include "real.h"
#include "clray_types.h"
#include "rng.h"
#include "camera.h"
#include "packet.h"

#define CAMERA_LANES (!HAS_THIN_LENS && !HAS_ORTHOGRAPHIC)

#if CAMERA_LANES
// rng_uniform(seed, pixel, sample[j], dim) in lane j; pixel_key: the pixel's first two hashes,
// pcg_hash(pcg_hash(seed) ^ pixel). The integer arithmetic is pcg_hash's, lane-wise.
HOT REALP rng_uniform_lanes(uint pixel_key, UINTP sample, uint dim) {
    UINTP x = (UINTP)(pixel_key) ^ ((UINTP)(4u) * sample + (UINTP)(dim));
    UINTP state = x * (UINTP)(747796405u) + (UINTP)(2891336453u);
    UINTP word = ((state >> ((state >> (UINTP)(28u)) + (UINTP)(4u))) ^ state) *
                 (UINTP)(277803737u);
    UINTP bits = (word >> (UINTP)(22u)) ^ word;
    return TO_REALP(bits >> (UINTP)(8u)) * (REAL)(1.0 / 16777216.0);
}

// sample_ray for samples first .. first + lanes - 1 of pixel (x, y), one a lane (the lanes past
// the last hold copies of the first), into *p. False where the pixel has one sample (its
// centre) or a direction's squared length is outside [2^-90, 2^90], where normalize() scales
// against overflow and underflow and is no longer d * rsqrt(d . d): the caller then draws
// lane by lane.
HOT bool camera_ray_lanes(const __global Camera* camera, const __global Params* params, int x,
                          int y, int first, int lanes, uint pixel, RayPacket* p) {
    int spp = params->spp;
    if (spp == 1) return false;
    // sample_position's grid of nx x ny cells.
    int nx = 1;
    while (nx * nx < spp) nx++;
    int ny = (spp + nx - 1) / nx;
    uint sample[PACKET_LANES];
    REAL column[PACKET_LANES], row[PACKET_LANES];
    // The packet's samples are consecutive: their cells follow the first's along its row, one
    // integer division a packet rather than one a lane.
    int first_column = first % nx, first_row = first / nx;
    int c = first_column, r = first_row;
    for (int j = 0; j < PACKET_LANES; ++j) {
        bool own = j < lanes;
        sample[j] = (uint)(own ? first + j : first);
        column[j] = (REAL)(own ? c : first_column);
        row[j] = (REAL)(own ? r : first_row);
        if (++c == nx) {
            c = 0;
            ++r;
        }
    }
    UINTP samples = VLOADP(0, sample);
    uint pixel_key = pcg_hash(pcg_hash(params->seed) ^ pixel);
    REALP r0 = rng_uniform_lanes(pixel_key, samples, 0u);
    REALP r1 = rng_uniform_lanes(pixel_key, samples, 1u);
    REALP sx = (REAL)x + (VLOADP(0, column) + r0) / (REAL)nx;
    REALP sy = (REAL)y + (VLOADP(0, row) + r1) / (REAL)ny;
    // image_plane_point, then camera_direction.
    REALP px = (REAL)2 * sx / (REAL)params->width - (REAL)1;
    REALP py = (REAL)1 - (REAL)2 * sy / (REAL)params->height;
    REAL3 forward = TO_REAL3(camera->forward), right = TO_REAL3(camera->right),
          up = TO_REAL3(camera->up);
    REALP dx = (REALP)(forward.x) + px * right.x + py * up.x;
    REALP dy = (REALP)(forward.y) + px * right.y + py * up.y;
    REALP dz = (REALP)(forward.z) + px * right.z + py * up.z;
    REALP dd = dot_lanes(dx, dy, dz, dx, dy, dz);
    if (lane_mask(~((dd >= (REAL)0x1p-90) & (dd <= (REAL)0x1p90)))) return false;
    REALP scale = rsqrt(dd);
    REAL3 o = TO_REAL3(camera->position);
    *p = make_ray_packet((REALP)(o.x), (REALP)(o.y), (REALP)(o.z), dx * scale, dy * scale,
                         dz * scale, (1 << lanes) - 1);
    return true;
}
#endif

#endif
