"""Binary -> wide BVH collapse (clray.accel.wide): structure, bounds, leaf layout, stack bound."""

from __future__ import annotations

import itertools
from fractions import Fraction
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clray.accel.bvh import build_bvh
from clray.accel.wide import (
    LEAF_FIELD_MASK,
    LEAF_SPHERE_SHIFT,
    LEAF_TRIANGLE_SHIFT,
    NO_REF,
    PACKET_WIDTH,
    WideBvh,
    child_boxes,
    collapse,
    grid_bounds,
    quantise,
)
from clray.device import layout as L
from clray.device.context import has_fp64
from clray.device.pack import pack_scene
from clray.device.program import KernelConfig, kernel_source
from clray.render import render_packed
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent

AXES = "xyz"


def _refs(kinds: np.ndarray) -> np.ndarray:
    """A reference per primitive: its kind in the top bits, its index among that kind below."""
    refs = np.empty(kinds.size, dtype=np.int64)
    for kind in np.unique(kinds):
        where = np.flatnonzero(kinds == kind)
        refs[where] = (int(kind) << L.PRIM_TYPE_SHIFT) | np.arange(where.size)
    return refs


def _children(wide: WideBvh, node: int) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """(child, count, lo, hi) of each used slot of a node: its exact quantised box, rounded
    outwards to float64."""
    rec = wide.nodes[node:node + 1]
    lo, hi = child_boxes(rec)
    out = []
    for k in range(wide.width):
        if rec["child"][0, k] < 0:
            continue
        out.append((int(rec["child"][0, k]), int(rec["count"][0, k]), lo[0, k], hi[0, k]))
    return out


def _leaf_sections(wide: WideBvh, slot: int, count: int) -> list[np.ndarray]:
    """A leaf's triangle-packet, sphere-packet and other slots."""
    sizes = [(count >> LEAF_TRIANGLE_SHIFT) * PACKET_WIDTH,
             ((count >> LEAF_SPHERE_SHIFT) & LEAF_FIELD_MASK) * PACKET_WIDTH,
             count & LEAF_FIELD_MASK]
    ends = np.cumsum([0, *sizes]) + slot
    return [wide.prim_refs[a:b] for a, b in itertools.pairwise(ends)]


def check_wide(wide: WideBvh, lo: np.ndarray, hi: np.ndarray, refs: np.ndarray) -> None:
    """Every primitive in exactly one leaf, inside every box on its path; leaves laid out as the
    kernel reads them; the stack bound covers the deepest walk."""
    assert wide.nodes.dtype == L.bvh_node_dtype(wide.width)
    seen: list[int] = []
    index_of = {int(r): i for i, r in enumerate(refs)}
    deepest = 0
    visited = set()
    # (node, pushed entries a walk holds on arriving there, boxes on the path)
    walk = [(0, 0, [])]
    while walk:
        node, pushed, path = walk.pop()
        assert node not in visited  # a tree: each node reached once
        visited.add(node)
        children = _children(wide, node)
        assert children, "a node with no children"
        deepest = max(deepest, pushed + len(children) - 1 + 1)
        for child, count, clo, chi in children:
            boxes = [*path, (clo, chi)]
            if count == 0:
                assert 0 < child < wide.nodes.size
                walk.append((child, pushed + len(children) - 1, boxes))
                continue
            assert child % PACKET_WIDTH == 0
            tri, sph, rest = _leaf_sections(wide, child, count)
            real = []
            for packet, kind in ((tri, L.PRIM_TRIANGLE), (sph, L.PRIM_SPHERE)):
                filled = packet[packet != NO_REF]
                # Padding only at the end of the last packet; each kind only in its packets.
                assert np.all(packet[:filled.size] == filled)
                assert packet.size - filled.size < PACKET_WIDTH
                assert np.all((filled >> L.PRIM_TYPE_SHIFT) == kind)
                real += filled.tolist()
            kinds = rest >> L.PRIM_TYPE_SHIFT
            assert np.all((kinds != L.PRIM_TRIANGLE) & (kinds != L.PRIM_SPHERE))
            for ref in [*real, *rest.tolist()]:
                seen.append(ref)
                i = index_of[ref]
                for blo, bhi in boxes:
                    assert np.all(blo <= lo[i]) and np.all(bhi >= hi[i])
    assert len(visited) == wide.nodes.size
    assert sorted(seen) == sorted(refs.tolist())
    assert wide.stack_size >= deepest


@pytest.mark.parametrize("width", [4, 8])
@pytest.mark.parametrize("n", [1, 2, 7, 100, 3000])
def test_collapse_of_random_boxes(width, n):
    rng = np.random.default_rng(n * 10 + width)
    c = rng.uniform(-10, 10, (n, 3))
    e = rng.exponential(0.3, (n, 3))
    kinds = rng.choice([L.PRIM_SPHERE, L.PRIM_BOX, L.PRIM_TRIANGLE, L.PRIM_CONE], n)
    refs = _refs(kinds)
    wide = collapse(build_bvh(c - e, c + e), refs, width)
    check_wide(wide, c - e, c + e, refs)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(1, 400), seed=st.integers(0, 2**32 - 1), width=st.sampled_from([4, 8]),
       leaf=st.sampled_from([1, 4, 16]), tri_share=st.sampled_from([0.0, 0.5, 1.0]))
def test_collapse_invariants(n, seed, width, leaf, tri_share):
    rng = np.random.default_rng(seed)
    # Few distinct centres: duplicates and coincident boxes are common.
    c = rng.integers(-3, 3, (n, 3)).astype(np.float64)
    e = rng.choice([0.0, 0.5, 2.0], (n, 3))
    kinds = np.where(rng.uniform(size=n) < tri_share, L.PRIM_TRIANGLE,
                     rng.choice([L.PRIM_SPHERE, L.PRIM_BOX], n))
    refs = _refs(kinds)
    check_wide(collapse(build_bvh(c - e, c + e, leaf), refs, width), c - e, c + e, refs)


@pytest.mark.parametrize("width", [4, 8])
def test_wide_nodes_are_full_unless_only_leaves_are_left(width):
    # The collapse opens inner children until a node is full: a node with a free slot has
    # nothing left to open, so all its children are leaves.
    rng = np.random.default_rng(1)
    c = rng.uniform(-1, 1, (20000, 3))
    wide = collapse(build_bvh(c - 1e-3, c + 1e-3), _refs(np.full(20000, L.PRIM_SPHERE)), width)
    used = (wide.nodes["child"] >= 0).sum(axis=1)
    has_inner = ((wide.nodes["child"] >= 0) & (wide.nodes["count"] == 0)).any(axis=1)
    assert used[0] == width
    assert not np.any(has_inner & (used < width))
    assert np.all(used >= 2)


def test_empty_and_leaf_root():
    empty = collapse(build_bvh(np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(0, np.int64), 8)
    assert empty.nodes.size == 0 and empty.prim_refs.size == 0
    lo = np.array([[0.0, 0, 0]])
    refs = _refs(np.array([L.PRIM_TRIANGLE]))
    one = collapse(build_bvh(lo, lo + 1), refs, 4)
    check_wide(one, lo, lo + 1, refs)
    assert one.nodes.size == 1
    assert one.nodes["count"][0, 0] == 1 << LEAF_TRIANGLE_SHIFT
    assert one.prim_refs.tolist() == [int(refs[0]), NO_REF, NO_REF, NO_REF]


def test_rejects_other_widths():
    lo = np.zeros((3, 3))
    with pytest.raises(ValueError, match="width"):
        collapse(build_bvh(lo, lo + 1), np.arange(3), 16)


@pytest.mark.parametrize("scene_file", ["spheres.toml", "glass.toml", "primitives.toml",
                                        "textured.toml"])
def test_both_widths_render_the_same_image(cl_device, scene_file):
    # The same binary tree collapsed to 4 or 8 children: every ray meets the same primitives,
    # so closest hits agree exactly; shadow filters may multiply in another order (glass).
    scene = load_scene(ROOT / "scenes" / scene_file)
    images = []
    for width in (4, 8):
        packed = pack_scene(scene, width=96, height=64, spp=1, max_depth=3, seed=0,
                            bvh_width=width)
        images.append(render_packed(packed, cl_device)[0])
    assert np.all(np.isfinite(images[0]))
    np.testing.assert_allclose(images[0], images[1], rtol=0, atol=1e-6)


# --- quantised child bounds ------------------------------------------------------------------

_EDGE_FLOATS = [0.0, -0.0, 2.0**-149, -(2.0**-149), 2.0**-127, -(2.0**-127), 2.0**-126,
                -(2.0**-126), 1.0, -1.0, 3e38, -3e38, 1e30, -1e-30, 16777216.0, 16777217.0]


def _exact_grid(origin: np.ndarray, exp: np.ndarray, q: np.ndarray) -> np.ndarray:
    """origin + q * 2^exp as exact fractions, (n, width, 3) of objects."""
    n, width, _ = q.shape
    out = np.empty(q.shape, dtype=object)
    for i, k, a in itertools.product(range(n), range(width), range(3)):
        out[i, k, a] = (Fraction(float(origin[i, a]))
                        + int(q[i, k, a]) * Fraction(2) ** int(exp[i, a]))
    return out


def _quantise_and_check(lo: np.ndarray, hi: np.ndarray, used: np.ndarray) -> tuple:
    """quantise() the boxes and assert, in exact arithmetic, that each used box's grid box
    holds it."""
    origin, exp, q_lo, q_hi = quantise(lo, hi, used)
    assert origin.dtype == np.float32 and exp.dtype == np.int8
    assert np.all((exp >= -126) & (exp <= 127))
    # The kernels read the origin as a number: never a denormal a device could flush.
    assert np.all((origin == 0) | (np.abs(origin) >= 2.0**-126))
    grid_lo, grid_hi = _exact_grid(origin, exp, q_lo), _exact_grid(origin, exp, q_hi)
    for i, k, a in zip(*np.nonzero(np.broadcast_to(used[..., None], lo.shape)), strict=True):
        assert grid_lo[i, k, a] <= Fraction(float(lo[i, k, a])), "a lower bound cuts in"
        assert grid_hi[i, k, a] >= Fraction(float(hi[i, k, a])), "an upper bound cuts in"
    return origin, exp, q_lo, q_hi


@settings(max_examples=200, deadline=None)
@given(data=st.data(), width=st.sampled_from([4, 8]), n=st.integers(1, 4))
def test_quantised_bounds_hold_the_exact_bounds(data, width, n):
    # float32 boxes anywhere in range, denormals and values far from their neighbours included.
    value = st.one_of(st.floats(width=32, allow_nan=False, allow_infinity=False),
                      st.sampled_from(_EDGE_FLOATS),
                      st.floats(-4.0, 4.0, width=32))
    a = np.array(data.draw(st.lists(value, min_size=n * width * 3, max_size=n * width * 3)),
                 dtype=np.float32).reshape(n, width, 3)
    b = np.array(data.draw(st.lists(value, min_size=n * width * 3, max_size=n * width * 3)),
                 dtype=np.float32).reshape(n, width, 3)
    used = np.array(data.draw(st.lists(st.booleans(), min_size=n * width,
                                       max_size=n * width)), dtype=bool).reshape(n, width)
    used[:, 0] = True
    _quantise_and_check(np.minimum(a, b), np.maximum(a, b), used)


def test_quantised_bounds_are_tight_and_can_fail():
    rng = np.random.default_rng(5)
    # Small boxes far from the origin, where the sum's rounding is coarsest against the grid.
    centre = rng.uniform(-1e4, 1e4, (500, 1, 3))
    lo = (centre + rng.uniform(-1, 1, (500, 8, 3))).astype(np.float32)
    hi = (lo + rng.exponential(0.1, (500, 8, 3))).astype(np.float32)
    used = np.ones((500, 8), dtype=bool)
    origin, exp, q_lo, q_hi = _quantise_and_check(lo, hi, used)
    # Within a grid step or two of the box, past what the sum's rounding adds.
    step = np.ldexp(1.0, exp.astype(np.int64))[:, None, :]
    box_lo, box_hi = (grid_bounds(origin[:, None, :], exp[:, None, :], q)[0]
                      for q in (q_lo, q_hi))
    slack = 2 * step + 1e-3
    assert np.all(lo - box_lo <= slack) and np.all(box_hi - hi <= slack)
    # Rounding to the nearest step instead of outwards cuts into boxes: the check sees it.
    nearest = np.rint((lo.astype(np.float64) - origin[:, None, :]) / step).astype(np.uint8)
    cut = grid_bounds(origin[:, None, :], exp[:, None, :], nearest)[0] > lo
    assert cut.any()


def _crosses(o: np.ndarray, d: np.ndarray, lo: list, hi: list, tmax: float) -> bool:
    """Exactly: some t in [0, tmax] has o + t d in the box [lo, hi] (fractions)."""
    t0, t1 = Fraction(0), Fraction(tmax)
    for a in range(3):
        oa, da = Fraction(float(o[a])), Fraction(float(d[a]))
        if da == 0:
            if not lo[a] <= oa <= hi[a]:
                return False
            continue
        near, far = sorted(((lo[a] - oa) / da, (hi[a] - oa) / da))
        t0, t1 = max(t0, near), min(t1, far)
    return t0 <= t1


@pytest.mark.parametrize("width", [4, 8])
@pytest.mark.parametrize("precision", ["float", "double"])
def test_node_children_never_miss_a_crossed_child(cl_ctx, width, precision):
    # Rays from all around aimed at the corners, edges and faces of quantised child boxes:
    # node_children (bvh.h) must report every child whose exact box a ray crosses.
    if precision == "double" and not has_fp64(cl_ctx.devices[0]):
        pytest.skip("no fp64 on this device")
    rng = np.random.default_rng(width + (precision == "double"))
    n_nodes = 6
    scale = 10.0 ** rng.integers(-3, 4, (n_nodes, 1, 1))
    centre = rng.normal(0, 1, (n_nodes, 1, 3)) * scale * 20
    lo = (centre + rng.normal(0, 1, (n_nodes, width, 3)) * scale).astype(np.float32)
    hi = (lo + rng.exponential(1, lo.shape) * scale).astype(np.float32)
    used = np.ones((n_nodes, width), dtype=bool)
    origin, exp, q_lo, q_hi = quantise(lo, hi, used)
    nodes = np.zeros(n_nodes, dtype=L.bvh_node_dtype(width))
    for a, axis in enumerate(AXES):
        nodes[f"origin_{axis}"], nodes[f"exp_{axis}"] = origin[:, a], exp[:, a]
        nodes[f"lo_{axis}"], nodes[f"hi_{axis}"] = q_lo[..., a], q_hi[..., a]
    nodes["child"] = np.arange(width)
    grid_lo, grid_hi = _exact_grid(origin, exp, q_lo), _exact_grid(origin, exp, q_hi)
    box_lo, box_hi = child_boxes(nodes)
    # Per ray: its node, an origin and a target on the boundary of one child's box (each axis
    # at lo, hi or between), with zero direction components now and then.
    n_rays = 400
    node = rng.integers(0, n_nodes, n_rays)
    k = rng.integers(0, width, n_rays)
    pick = rng.integers(0, 3, (n_rays, 3))
    f = rng.uniform(0, 1, (n_rays, 3))
    target = np.where(pick == 0, box_lo[node, k], np.where(
        pick == 1, box_hi[node, k], box_lo[node, k] + f * (box_hi[node, k] - box_lo[node, k])))
    real = np.float64 if precision == "double" else np.float32
    target = target.astype(real)
    span = (box_hi[node].max(axis=1) - box_lo[node].min(axis=1))
    o = (target + rng.normal(0, 1, (n_rays, 3)) * span * 2).astype(real)
    flat = rng.uniform(size=(n_rays, 3)) < 0.1
    o = np.where(flat, target, o)
    d = (target - o).astype(real)
    d[np.all(d == 0, axis=1), 0] = 1
    tmax = np.full(n_rays, 2.0)
    config = KernelConfig(has_triangles=True, bvh_width=width, precision=precision)
    source = kernel_source() + """
__kernel void children_probe(__global const BvhNode* nodes, __global const int* node,
                             __global const REAL* o, __global const REAL* d,
                             __global const REAL* tmax, __global int* bits) {
    int i = get_global_id(0);
    Ray r = make_ray(vload3(i, o), vload3(i, d));
    REAL tnear[BVH_WIDTH];
    bits[i] = node_children(nodes + node[i], &r, tmax[i], tnear);
}
"""
    program = cl.Program(cl_ctx, source).build(options=config.options())
    queue = cl.CommandQueue(cl_ctx)
    mf = cl.mem_flags
    bufs = [cl.Buffer(cl_ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
            for x in (nodes, node.astype(np.int32), o, d, tmax.astype(real))]
    bits = np.zeros(n_rays, dtype=np.int32)
    out = cl.Buffer(cl_ctx, mf.WRITE_ONLY, bits.nbytes)
    program.children_probe(queue, (n_rays,), None, *bufs, out)
    cl.enqueue_copy(queue, bits, out)
    crossed = 0
    for i in range(n_rays):
        for c in range(width):
            if _crosses(o[i], d[i], list(grid_lo[node[i], c]), list(grid_hi[node[i], c]), 2.0):
                crossed += 1
                assert bits[i] >> c & 1, f"ray {i} crosses child {c} but was not sent there"
    assert crossed >= n_rays  # every ray crosses the child it was aimed at
