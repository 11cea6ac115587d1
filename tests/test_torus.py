"""The ray-torus crossings of kernels/torus.h (work in progress on the torus branch, issue 42): built
alone with pyopencl and checked against a float64 oracle (the textbook quartic's companion
eigenvalues, polished by Newton steps on the distance form) and closed forms, in the float and
double builds: thick and thin tori (minor/major 1 to 1e-4), far from the origin (1e4), rays
parallel to the axis. Every crossing found must lie within two roundings (of the ray origin's
scale) of the surface, and no crossing may be lost but on rays whose chord through the tube is
shorter than float resolution can decide (near-tangent)."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from pathlib import Path

K = Path(__file__).resolve().parent.parent / "kernels"
SRC = r'''
#include "real.h"
#include "clray_types.h"
#include "ray.h"
#include "torus.h"
__kernel void probe(__global const float* o, __global const float* d, __global const Torus* tr,
                    __global REAL* out, __global int* count) {
    int i = get_global_id(0);
    Ray r = make_ray((REAL3)(o[3*i], o[3*i+1], o[3*i+2]), (REAL3)(d[3*i], d[3*i+1], d[3*i+2]));
    REAL t[4];
    count[i] = torus_crossings(tr, &r, t);
    for (int k = 0; k < 4; ++k) out[4*i+k] = t[k];
}
'''
def build(double=False):
    ctx = cl.create_some_context(interactive=False)
    opts = [f"-I{K}", "-DHAS_TORI=1", "-DHAS_TRIANGLES=0", "-DBVH_WIDTH=8", "-DPACKET_LANES=8", "-cl-std=CL1.2"]
    if double: opts.append("-DUSE_DOUBLE")
    prg = cl.Program(ctx, '#include "scene.h"\n' if False else SRC).build(options=opts)
    return ctx, prg

def run(o, d, centre, axis, R, r, double=False):
    ctx, prg = build(double)
    q = cl.CommandQueue(ctx)
    rec = np.zeros(1, dtype=np.dtype([("c", np.float32, 4), ("a", np.float32, 4), ("m", np.int32), ("p", np.int32, 3)]))
    rec["c"][0, :3] = centre; rec["c"][0, 3] = R; rec["a"][0, :3] = axis; rec["a"][0, 3] = r
    n = len(o)
    mf = cl.mem_flags
    bo = cl.Buffer(ctx, mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(o, np.float32))
    bd = cl.Buffer(ctx, mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(d, np.float32))
    bt = cl.Buffer(ctx, mf.COPY_HOST_PTR, hostbuf=rec)
    rt = np.float64 if double else np.float32
    out = np.empty((n, 4), rt); cnt = np.empty(n, np.int32)
    bout = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes); bc = cl.Buffer(ctx, mf.WRITE_ONLY, cnt.nbytes)
    prg.probe(q, (n,), None, bo, bd, bt, bout, bc)
    cl.enqueue_copy(q, out, bout); cl.enqueue_copy(q, cnt, bc); q.finish()
    return out, cnt


def g(o, u, axis, R, r, s):
    p = o + s[..., None] * u
    z = p @ axis
    rho = np.linalg.norm(p - z[..., None] * axis, axis=-1)
    return (rho - R) ** 2 + z ** 2 - r * r

def torus_roots(o, d, centre, axis, R, r):
    """Float64: textbook quartic in s (unit direction) from the bounding-sphere entry, roots by
    companion eigenvalues, polished by Newton on the distance form. Returns list of arrays of t."""
    o = np.asarray(o, np.float64) - centre
    d = np.asarray(d, np.float64)
    axis = np.asarray(axis, np.float64); axis = axis / np.linalg.norm(axis)
    L = np.linalg.norm(d, axis=1)
    u = d / L[:, None]
    out = []
    for oi, ui, li in zip(o, u, L):
        # shift to the nearest point of the line to the centre
        s0 = -oi @ ui
        q = oi + s0 * ui
        S = q @ q + R * R - r * r
        qa, ua = q @ axis, ui @ axis
        # |p|^2 = s^2 + 2 (q.u) s + q.q with q.u = 0
        # rho^2 = |p|^2 - (qa + s ua)^2
        c4 = 1.0
        c3 = 0.0
        c2 = 2 * S - 4 * R * R * (1 - ua * ua)
        c1 = -4 * R * R * (-2 * qa * ua)
        c0 = S * S - 4 * R * R * (q @ q - qa * qa)
        # (s^2 + S)^2 - 4R^2 (s^2 + qq - (qa + s ua)^2)
        c1 = 8 * R * R * qa * ua
        roots = np.roots([c4, c3, c2, c1, c0])
        roots = np.sort(roots[np.abs(roots.imag) < 1e-6 * (R + r + abs(s0) * 0)].real)
        pol = []
        for s in roots:
            for _ in range(50):
                gs = g(q, ui, axis, R, r, np.array(s))
                h = 1e-7 * max(r, 1e-300)
                dg = (g(q, ui, axis, R, r, np.array(s + h)) - g(q, ui, axis, R, r, np.array(s - h))) / (2 * h)
                if dg == 0: break
                step = gs / dg
                s = s - step
                if abs(step) < 1e-15 * (abs(s) + r): break
            pol.append(s)
        t = (np.array(pol) + s0) / li
        out.append(np.sort(t[t > 0]))
    return out


RNG_SEED = 1


def aimed(rng, centre, axis, major, minor, n, dist, spread):
    """Rays from `dist` away, each aimed at a point within spread * minor of the circle."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    e1 = np.cross(axis, [1, 0, 0] if abs(axis[0]) < .9 else [0, 1, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi, th = rng.uniform(0, 2 * np.pi, (2, n))
    rad = minor * spread * np.sqrt(rng.uniform(0, 1, n))
    ring = major + rad * np.cos(th)
    target = (centre + (ring * np.cos(phi))[:, None] * e1 + (ring * np.sin(phi))[:, None] * e2
              + (rad * np.sin(th))[:, None] * axis)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    return target - dist * dirs, dirs * rng.uniform(0.5, 2, n)[:, None]


CASES = [((0, 0, 0), (0.3, 1, 0.2), major, minor, 3 * (major + minor))
         for major, minor in [(1, 0.25), (1, 1), (1, 0.5), (1, 1e-2), (1, 1e-3), (1, 1e-4),
                              (100, 1e-2)]]
CASES += [((1e4, -1e4, 1e4), (0, 0, 1), 1, minor, 5.0) for minor in (0.25, 1e-2)]


@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
@pytest.mark.parametrize("centre,axis,major,minor,dist", CASES)
def test_crossings_lie_on_the_torus_and_none_is_lost(centre, axis, major, minor, dist, double):
    rng = np.random.default_rng(RNG_SEED)
    centre = np.asarray(centre, float)
    o, d = aimed(rng, centre, axis, major, minor, 1500, dist, 1.5)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    try:
        out, cnt = run(o, d, centre, axis, major, minor, double)
    except cl.RuntimeError as e:
        pytest.skip(f"no build: {e}")
    f32 = lambda v: np.asarray(v, np.float32).astype(float)  # noqa: E731 - what the device holds
    axis32 = f32(axis) / np.linalg.norm(f32(axis))
    ref = torus_roots(f32(o), f32(d), f32(centre), axis32, float(np.float32(major)),
                      float(np.float32(minor)))
    eps = np.finfo(np.float64 if double else np.float32).eps
    lost, worst = [], 0.0
    for i, (t, c, e) in enumerate(zip(out, cnt, ref)):
        length = np.linalg.norm(f32(d[i]))
        scale = np.max(np.abs(o[i] - centre)) + major + minor
        chord = np.min(np.diff(e)) * length if len(e) > 1 else np.inf
        if c != len(e):
            if chord >= np.sqrt(8 * minor * 16 * eps * scale):
                lost.append((i, t[:c], e))
            continue
        if c:
            p = f32(o[i]) + t[:c, None].astype(float) * f32(d[i])
            q = p - f32(centre)
            z = q @ axis32
            rho = np.linalg.norm(q - z[:, None] * axis32, axis=1)
            dist_surface = np.abs(np.hypot(rho - float(np.float32(major)), z)
                                  - float(np.float32(minor)))
            worst = max(worst, np.max(dist_surface) / (eps * (np.max(np.abs(o[i])) + major + minor)))
    assert not lost, f"{len(lost)} rays lost crossings, e.g. {lost[:3]}"
    assert worst <= 2.0, f"a crossing {worst:.1f} roundings off the surface"
    assert (cnt > 0).mean() > 0.5  # the rays were aimed at the tube: most must hit


@pytest.mark.parametrize("double", [False, True], ids=["float", "double"])
def test_rays_parallel_to_the_axis_match_the_closed_form(double):
    """At distance rho0 from the axis the ray crosses the tube at z = +-sqrt(r^2 - (rho0 - R)^2)
    and passes through the hole (rho0 < R - r) or outside without a crossing."""
    major, minor = 1.0, 0.25
    rho0 = np.linspace(0, 1.3, 2001)
    o = np.stack([rho0, np.zeros_like(rho0), np.full_like(rho0, -3)], 1)
    d = np.tile([0, 0, 1.0], (len(rho0), 1))
    out, cnt = run(o, d, np.zeros(3), [0, 0, 1], major, minor, double)
    rho32 = rho0.astype(np.float32).astype(float)
    w2 = minor ** 2 - (rho32 - major) ** 2
    decided = np.abs(w2) > 1e-5  # rays through the tube's rim are tangent
    assert np.array_equal(cnt[decided], np.where(w2 > 0, 2, 0)[decided])
    hit = decided & (w2 > 0)
    w = np.sqrt(w2[hit])
    tol = 8 * np.finfo(np.float64 if double else np.float32).eps * 4 / np.sqrt(np.min(w2[hit]))
    assert np.allclose(out[hit, 0], 3 - w, atol=tol, rtol=0)
    assert np.allclose(out[hit, 1], 3 + w, atol=tol, rtol=0)
