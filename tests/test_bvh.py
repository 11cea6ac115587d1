"""BVH builder: structural invariants over random primitive sets, and a traversal oracle."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from conftest import load_mesh_generator
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from clray.accel import bvh as bvh_module
from clray.accel.bvh import (
    BINARY_NODE,
    N_BINS,
    SAH_PACKET,
    TRAVERSAL_COST,
    Bvh,
    build_bvh,
    checked_bounds,
    max_leaf_count,
    packets,
    sah_cost,
)
from clray.accel.wide import PACKET_WIDTH, collapse
from clray.device import bvh_builder
from clray.device.bvh_builder import build_bvh_on
from clray.device.context import queue_for

mesh_gen = load_mesh_generator()


def check_bvh(bvh: Bvh, lo: np.ndarray, hi: np.ndarray, max_leaf_size: int) -> None:
    """Assert every structural invariant of a built BVH over primitives with bounds lo, hi."""
    n = lo.shape[0]
    nodes, order = bvh.nodes, bvh.order
    assert nodes.dtype == BINARY_NODE
    assert order.dtype == np.int32
    assert np.array_equal(np.sort(order), np.arange(n))
    if n == 0:
        assert nodes.size == 0
        return
    count = nodes["count"].astype(np.int64)
    first = nodes["first"].astype(np.int64)
    nlo = nodes["lo"].astype(np.float64)
    nhi = nodes["hi"].astype(np.float64)

    # Depth-first layout: a preorder walk from the root (left child = next node, right child =
    # `first`) must visit exactly 0, 1, 2, ... n-1, so every node is reachable exactly once.
    visited = []
    stack = [0]
    while stack:
        i = stack.pop()
        visited.append(i)
        if count[i] == 0:
            assert i + 1 < first[i] < nodes.size
            stack += [int(first[i]), i + 1]
    assert visited == list(range(nodes.size))

    leaf = count > 0
    assert np.all(count[leaf] <= max_leaf_count(max_leaf_size))
    assert np.all(count >= 0)
    # Leaves tile `order`: each primitive is in exactly one leaf.
    covered = np.zeros(n, dtype=np.int64)
    for i in np.flatnonzero(leaf):
        covered[first[i]:first[i] + count[i]] += 1
    assert np.all(covered == 1)

    for i in np.flatnonzero(~leaf):
        left, right = i + 1, first[i]
        for child in (left, right):
            assert np.all(nlo[child] >= nlo[i]) and np.all(nhi[child] <= nhi[i])
        # An inner node's bounds are exactly the union of its children's.
        assert np.array_equal(nodes["lo"][i], np.minimum(nodes["lo"][left], nodes["lo"][right]))
        assert np.array_equal(nodes["hi"][i], np.maximum(nodes["hi"][left], nodes["hi"][right]))

    for i in np.flatnonzero(leaf):
        prims = order[first[i]:first[i] + count[i]]
        plo = lo[prims].min(axis=0)
        phi = hi[prims].max(axis=0)
        # Contain the float64 bounds exactly, and tightly: the next float32 inwards would not.
        assert np.all(nlo[i] <= plo) and np.all(nhi[i] >= phi)
        assert np.all(np.nextafter(nodes["lo"][i], np.float32(np.inf)).astype(np.float64) > plo)
        assert np.all(np.nextafter(nodes["hi"][i], np.float32(-np.inf)).astype(np.float64) < phi)


def _boxes(draw_centres: np.ndarray, extents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return draw_centres - extents, draw_centres + extents


# Coordinates from a small pool so duplicates and shared planes are common, plus values that
# are not float32-representable (0.1, 1/3) so the outward rounding is exercised.
_COORD = st.sampled_from([0.0, 0.1, -0.1, 1 / 3, 1.0, -2.5, 7.0, 1e-30, 123456.789])
_EXTENT = st.sampled_from([0.0, 0.0, 1e-7, 0.01, 0.5, 3.0])


@settings(max_examples=150, deadline=None)
@given(
    centres=hnp.arrays(np.float64, st.tuples(st.integers(0, 60), st.just(3)), elements=_COORD),
    data=st.data(),
    max_leaf_size=st.sampled_from([1, 2, 4, 8, 20]),
)
def test_invariants_small_sets(centres, data, max_leaf_size):
    extents = data.draw(hnp.arrays(np.float64, centres.shape, elements=_EXTENT))
    lo, hi = _boxes(centres, extents)
    check_bvh(build_bvh(lo, hi, max_leaf_size), lo, hi, max_leaf_size)


def _random_set(kind: str, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if kind == "uniform":
        c = rng.uniform(-10, 10, (n, 3))
        e = rng.exponential(0.2, (n, 3))
    elif kind == "points":
        c = rng.uniform(-1, 1, (n, 3))
        e = np.zeros((n, 3))
    elif kind == "same_centroid":
        c = np.full((n, 3), 0.3)
        e = rng.uniform(0, 2, (n, 3))
    elif kind == "duplicates":
        c = rng.uniform(-1, 1, (max(1, n // 10), 3))[rng.integers(0, max(1, n // 10), n)]
        e = np.full((n, 3), 0.05)
    elif kind == "flat":
        c = rng.uniform(-5, 5, (n, 3))
        c[:, 1] = 0.1
        e = rng.uniform(0, 0.3, (n, 3))
        e[:, 1] = 0
    elif kind == "segment":
        # Boxes of no area on one line (degenerate triangles along an axis): every node's box
        # is a segment.
        c = np.zeros((n, 3))
        c[:, 0] = rng.uniform(-5, 5, n)
        e = np.zeros((n, 3))
        e[:, 0] = rng.exponential(1e-3, n)
    elif kind == "segment_and_boxes":
        # A quarter boxes, the rest segments on a line through them: nodes of both kinds.
        lo, hi = _random_set("segment", n, rng)
        lo[: n // 4], hi[: n // 4] = _random_set("uniform", n // 4, rng)
        return lo, hi
    elif kind == "clustered_scales":
        # Tiny clusters far apart: extents near float32 spacing at the cluster positions.
        c = rng.choice([-1e4, 0.0, 1e4], (n, 3)) + rng.normal(0, 1e-3, (n, 3))
        e = rng.exponential(1e-4, (n, 3))
    else:
        raise AssertionError(kind)
    return _boxes(c, e)


KINDS = ["uniform", "points", "same_centroid", "duplicates", "flat", "clustered_scales",
         "segment", "segment_and_boxes"]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kind=st.sampled_from(KINDS),
    n=st.one_of(st.integers(0, 3), st.integers(4, 200), st.integers(1000, 4000)),
    seed=st.integers(0, 2**32 - 1),
    max_leaf_size=st.sampled_from([1, 4, 16]),
)
def test_invariants_random_sets(kind, n, seed, max_leaf_size):
    lo, hi = _random_set(kind, n, np.random.default_rng(seed))
    check_bvh(build_bvh(lo, hi, max_leaf_size), lo, hi, max_leaf_size)


def test_empty_and_single():
    empty = build_bvh(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.nodes.size == 0 and empty.order.size == 0
    one = build_bvh(np.array([[0.1, 0.2, 0.3]]), np.array([[1.0, 2.0, 3.0]]))
    assert one.nodes.size == 1
    assert one.nodes["count"][0] == 1 and one.nodes["first"][0] == 0
    assert one.order.tolist() == [0]


def test_coincident_primitives_are_split_to_bounded_leaves():
    lo = np.zeros((1000, 3))
    bvh = build_bvh(lo, lo + 1.0, max_leaf_size=4)
    check_bvh(bvh, lo, lo + 1.0, 4)


def _depth(nodes: np.ndarray) -> int:
    """Deepest node of a depth-first tree (the root at depth 0)."""
    depth = np.zeros(nodes.size, dtype=np.int64)
    for i in np.flatnonzero(nodes["count"] == 0):
        depth[i + 1] = depth[nodes["first"][i]] = depth[i] + 1
    return int(depth.max())


@pytest.mark.parametrize("width", [4, 8])
def test_boxes_of_no_area_build_a_balanced_tree(width):
    # Every candidate split of a node of segments has zero area: costed by area, all tie and
    # each split peels off the first bin.
    # By length, the tree is as shallow as over the same segments given a little thickness.
    n = 20000
    lo, hi = _random_set("segment", n, np.random.default_rng(4))
    segments = build_bvh(lo, hi)
    thick = build_bvh(lo, hi + np.array([0, 1e-6, 1e-6]))
    assert _depth(segments.nodes) <= _depth(thick.nodes) <= 2 * math.ceil(math.log2(n))
    assert (collapse(segments, 5 << 28, width).stack_size
            <= collapse(thick, 5 << 28, width).stack_size)


@pytest.mark.parametrize(("lo", "hi"), [
    (np.zeros((3, 2)), np.zeros((3, 2))),
    (np.zeros((3, 3)), np.zeros((4, 3))),
    (np.ones((2, 3)), np.zeros((2, 3))),
    (np.full((2, 3), np.nan), np.zeros((2, 3))),
    (np.zeros((2, 3)), np.full((2, 3), np.inf)),
    (np.zeros((2, 3)), np.full((2, 3), 1e39)),
])
def test_rejects_bad_bounds(lo, hi):
    with pytest.raises(ValueError):
        build_bvh(lo, hi)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize(("value", "where", "message"), [
    (np.nan, "lo", "finite"), (-np.inf, "lo", "finite"), (np.inf, "hi", "finite"),
    (-1e39, "lo", "float32 range"), (2.0, "lo", "lo > hi"),
])
def test_rejects_one_bad_bound_past_the_first_rows(dtype, value, where, message):
    """One bad value among many good ones, near the end (the checks go a block of rows at
    a time): named for what is wrong, with the primitive's index and bounds."""
    n = 3 * (1 << 16) + 5
    bounds = {"lo": np.zeros((n, 3), dtype), "hi": np.ones((n, 3), dtype)}
    if value == -1e39 and dtype == np.float32:
        value = -np.inf  # float32 cannot hold it: its rounding is the case
    bounds[where][-2, 1] = value
    with pytest.raises(ValueError, match=message) as raised:
        checked_bounds(bounds["lo"], bounds["hi"], 4, None)
    lo, hi = bounds["lo"][-2], bounds["hi"][-2]
    assert str(raised.value).startswith(f"primitive {n - 2}'s bounds ")
    assert str(raised.value).endswith(f"lo (0.0, {lo[1]}, 0.0), hi (1.0, {hi[1]}, 1.0)")


def test_bounds_near_float32s_limits_build_without_warnings():
    # Centroids from -3e38 to 3e38 span more than float32 holds: the node is not binned, and
    # the build says nothing about the overflow on the way.
    c = np.zeros((8, 3))
    c[:4, 0], c[4:, 0] = -3e38, 3e38
    c[:, 1] = np.arange(8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bvh = build_bvh(c, c + 1, 1)
    check_bvh(bvh, c, c + 1, 1)


def test_values_checked_skips_the_value_scans_but_not_the_shape_checks():
    # The caller's word (bounds made from checked values) stands in for the scans of every
    # value; shapes and leaf sizes are still checked.
    lo, hi = np.zeros((5, 3)), np.full((5, 3), np.nan)
    with pytest.raises(ValueError, match="finite"):
        checked_bounds(lo, hi, 4, None)
    assert checked_bounds(lo, hi, 4, None, values_checked=True)[2] == max_leaf_count(4)
    with pytest.raises(ValueError, match="shape"):
        checked_bounds(lo[:, :2], hi[:, :2], 4, None, values_checked=True)


def test_rejects_bad_leaf_size():
    with pytest.raises(ValueError):
        build_bvh(np.zeros((2, 3)), np.ones((2, 3)), max_leaf_size=0)


# --- device build -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def cl_queue(cl_device):
    if not bvh_builder.supports(cl_device, 1):
        pytest.skip("the device build needs float64")
    return queue_for(cl_device)


def assert_same_tree(a: Bvh, b: Bvh) -> None:
    # Field by field, then byte for byte: both builds make every zero +0.0 as the bounds come
    # in, so no minimum or maximum meets both 0.0 and -0.0 (whose pick depends on the order).
    for field in BINARY_NODE.names:
        assert np.array_equal(a.nodes[field], b.nodes[field]), field
    assert a.nodes.tobytes() == b.nodes.tobytes()
    assert np.array_equal(a.order, b.order)


@settings(max_examples=60, deadline=None)
@given(
    centres=hnp.arrays(np.float64, st.tuples(st.integers(0, 60), st.just(3)), elements=_COORD),
    data=st.data(),
    max_leaf_size=st.sampled_from([1, 2, 4, 8, 20]),
)
def test_device_build_is_the_host_build_small_sets(cl_queue, centres, data, max_leaf_size):
    extents = data.draw(hnp.arrays(np.float64, centres.shape, elements=_EXTENT))
    lo, hi = _boxes(centres, extents)
    bvh = build_bvh_on(cl_queue, lo, hi, max_leaf_size)
    check_bvh(bvh, lo, hi, max_leaf_size)
    assert_same_tree(bvh, build_bvh(lo, hi, max_leaf_size))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", [5, 300, 20000])
@pytest.mark.parametrize("max_leaf_size", [1, 4])
def test_device_build_is_the_host_build(cl_queue, kind, n, max_leaf_size):
    lo, hi = _random_set(kind, n, np.random.default_rng(n + len(kind)))
    bvh = build_bvh_on(cl_queue, lo, hi, max_leaf_size)
    check_bvh(bvh, lo, hi, max_leaf_size)
    assert_same_tree(bvh, build_bvh(lo, hi, max_leaf_size))


def test_device_build_of_a_lopsided_set(cl_queue):
    # Centroids at powers of two: every split peels a few primitives off the far end, so the
    # tree is about as deep as it is wide and never offers enough subtrees to stop the
    # one-level launches before their cap.
    c = np.zeros((120, 3))
    c[:, 0] = 2.0 ** np.arange(120)
    lo, hi = c - 0.25, c + 0.25
    bvh = build_bvh_on(cl_queue, lo, hi, 1)
    check_bvh(bvh, lo, hi, 1)
    assert_same_tree(bvh, build_bvh(lo, hi, 1))


def test_float32_bounds_build_the_float64_tree(cl_queue):
    # A mesh's bounds come as float32 (its corners are floats): both builds take them as they
    # are and build the tree of their float64 copies. A float32 sum for the centroids would
    # overflow near the largest floats (where halving it is otherwise exact).
    rng = np.random.default_rng(5)
    c = rng.uniform(-1e6, 1e6, (5000, 3)).astype(np.float32)
    e = rng.exponential(0.3, (5000, 3)).astype(np.float32)
    lo, hi = c - e, c + e
    lo[:8], hi[:8] = np.float32(3e38), np.float32(3.2e38)
    wide_lo, wide_hi = lo.astype(np.float64), hi.astype(np.float64)
    # The rounded boxes and centroids the host build bins, the same numbers from either.
    assert np.array_equal(bvh_module._round_out(lo, hi), bvh_module._round_out(wide_lo, wide_hi))
    expected = build_bvh(wide_lo, wide_hi)
    assert_same_tree(build_bvh(lo, hi), expected)
    assert_same_tree(build_bvh_on(cl_queue, lo, hi), expected)
    assert bvh_builder.build_buffer_bytes(5000, 4)["lo"] == 12 * 5000
    assert bvh_builder.build_buffer_bytes(5000, 4)["prims"] == 32 * 5000


def test_device_layout_collapses_to_the_same_wide_tree(cl_queue):
    # The device build's own layout (children in pairs, each subtree's nodes in its own range of
    # slots) holds the depth-first tree: renumbered, it is the host's, and the collapse, which
    # reads only the nodes it reaches, makes the same wide tree from it as from the host's.
    lo, hi = _random_set(KINDS[0], 20000, np.random.default_rng(9))
    refs = (5 << 28) | np.arange(20000)
    own = build_bvh_on(cl_queue, lo, hi, pairs=True)
    host = build_bvh(lo, hi)
    assert own.pairs and own.nodes.size == 2 * 20000 - 1
    assert_same_tree(bvh_builder.build(cl_queue, [lo, hi], 4, max_leaf_count(4)), host)
    a, b = collapse(own, refs, 8), collapse(host, refs, 8)
    assert a.nodes.tobytes() == b.nodes.tobytes()
    assert np.array_equal(a.prim_refs, b.prim_refs) and a.stack_size == b.stack_size


def test_signed_zeros_give_the_same_bytes_from_either_build(cl_queue):
    # -0.0 and +0.0 compare equal, so which one a minimum or maximum keeps depends on the order
    # of the reduction, which differs between the builds: bounds with both (an OBJ file's
    # "-0.000000") gave nodes equal as numbers but not as bytes. Every zero comes in as +0.0.
    rng = np.random.default_rng(13)
    c = rng.random((20000, 3))
    c[:, 1] = np.where(rng.random(20000) < 0.5, -0.0, 0.0)
    for lo, hi in ((c, c), (c.astype(np.float32), c.astype(np.float32))):
        device, host = build_bvh_on(cl_queue, lo, hi), build_bvh(lo, hi)
        assert device.nodes.tobytes() == host.nodes.tobytes()
        assert np.array_equal(device.order, host.order)
        assert not np.signbit(host.nodes["lo"][:, 1]).any()


def test_signed_zeros_pack_the_same_bytes_from_either_build(cl_queue):
    # A 20,000-triangle floor at y = 0 as an OBJ file writes it (some "-0.000000"): the pack's
    # buffers from the device build are the host build's, byte for byte.
    from clray.device.pack import pack_scene
    from clray.scene.load import scene_from_dict

    rng = np.random.default_rng(14)
    n = 20000
    v = rng.random((3 * n, 3)) * 10 - 5
    v[:, 1] = np.where(rng.random(3 * n) < 0.5, -0.0, 0.0)
    scene = scene_from_dict({
        "render": {"width": 8, "height": 8},
        "camera": {"position": [0, 0, -20], "look_at": [0, 0, 0]},
        "materials": {"m": {"color": [1, 1, 1]}}, "lights": [],
        "objects": [{"type": "mesh", "vertices": v.tolist(),
                     "faces": np.arange(3 * n).reshape(-1, 3).tolist(), "material": "m"}]})
    settings = {"width": 8, "height": 8, "spp": 1, "max_depth": 1, "seed": 0}
    host = pack_scene(scene, **settings).buffers()
    device = pack_scene(scene, **settings, queue=cl_queue).buffers()
    assert host.keys() == device.keys()
    assert [k for k in host if host[k].tobytes() != device[k].tobytes()] == []


def test_device_rounding_at_the_edges_of_float32(cl_queue):
    # One primitive per leaf, so every primitive's outward-rounded box is a node: values that
    # round to a signed zero or to a subnormal, exact float32 values, and large ones (whose
    # differences still fit in float32, as the builds' centroid extents must).
    edges = np.array([0.0, -0.0, 1e-300, -1e-300, 1e-45, -1e-45, 2.0**-149, -(2.0**-149),
                      2.0**-126, 0.1, -0.1, 1 / 3, 1e38, -1e38])
    rng = np.random.default_rng(3)
    lo = rng.choice(edges, (400, 3))
    hi = np.maximum(lo, rng.choice(edges, (400, 3)))
    bvh = build_bvh_on(cl_queue, lo, hi, 1)
    check_bvh(bvh, lo, hi, 1)
    assert_same_tree(bvh, build_bvh(lo, hi, 1))


def test_device_build_runs_on_the_device(cl_queue, monkeypatch):
    # Above max_leaf_size primitives on a device that supports it, build_bvh_on does not fall
    # back to the host build (which would make the comparisons above vacuous).
    def device_build(*args: object, **kwargs: object) -> None:
        raise RuntimeError("device build")

    monkeypatch.setattr(bvh_builder, "build", device_build)
    lo = np.random.default_rng(0).uniform(-1, 1, (10, 3))
    with pytest.raises(RuntimeError, match="device build"):
        build_bvh_on(cl_queue, lo, lo + 0.1, 4)
    assert build_bvh_on(cl_queue, lo[:4], lo[:4] + 0.1, 4).nodes.size == 1


class _StandInDevice:
    """The test's device with other memory limits (CL_DEVICE_MAX_MEM_ALLOC_SIZE,
    CL_DEVICE_GLOBAL_MEM_SIZE)."""

    def __init__(self, device: object, max_alloc: int, global_mem: int) -> None:
        self.device = device
        self.max_mem_alloc_size = max_alloc
        self.global_mem_size = global_mem

    def __getattr__(self, name: str) -> object:
        return getattr(self.device, name)


def test_device_build_only_where_node_slots_fit_in_ints(cl_queue):
    roomy = _StandInDevice(cl_queue.device, 1 << 50, 1 << 52)
    assert bvh_builder.supports(roomy, 2**30)
    assert not bvh_builder.supports(roomy, 2**30 + 1)


def test_device_build_only_where_its_buffers_fit_the_device(cl_queue):
    # 5.24 M triangles: the padded node slots (2N - 1 of 32 bytes, 320 MiB) are the largest
    # buffer, and all of them take about 1.1 GiB.
    n = 5_242_880
    sizes = bvh_builder.build_buffer_bytes(n)
    assert max(sizes, key=sizes.get) == "nodes"
    assert sizes["nodes"] == 32 * (2 * n - 1)
    largest, total = sizes["nodes"], sum(sizes.values())
    device = cl_queue.device
    assert bvh_builder.supports(_StandInDevice(device, largest, total), n)
    assert not bvh_builder.supports(_StandInDevice(device, largest - 1, total), n)
    assert not bvh_builder.supports(_StandInDevice(device, largest, total - 1), n)


def test_device_build_over_the_largest_allocation_builds_on_the_host(cl_queue, monkeypatch):
    # A device whose largest allocation cannot hold the build's buffers: the host builds the
    # same tree, and the device build is never tried (its buffers would fail to allocate).
    def device_build(*args: object, **kwargs: object) -> None:
        raise RuntimeError("device build")

    monkeypatch.setattr(bvh_builder, "build", device_build)
    lo = np.random.default_rng(1).uniform(-1, 1, (300, 3))
    small = _StandInDevice(cl_queue.device, 1 << 10, 1 << 30)
    queue = type("Queue", (), {"device": small})()
    assert_same_tree(build_bvh_on(queue, lo, lo + 0.1, 4), build_bvh(lo, lo + 0.1, 4))


def _float_prims(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = bvh_builder.float_prims(n)
    c = np.random.default_rng(seed).uniform(-1, 1, (n, 3))
    lo[:], hi[:] = c, c + 0.01
    return lo, hi


def test_device_build_leaves_its_bounds_as_they_were(cl_queue):
    # Bounds made by float_prims are the device build's records only where the caller lets it
    # consume them: a CPU device partitions those in place.
    lo, hi = _float_prims(5000, 6)
    was = lo.copy(), hi.copy()
    bvh = build_bvh_on(cl_queue, lo, hi)
    assert np.array_equal(lo, was[0]) and np.array_equal(hi, was[1])
    assert_same_tree(bvh, build_bvh(*was))


def test_device_build_may_consume_the_records_of_float_prims(cl_queue, monkeypatch):
    # Consumed, the records are the build's first buffer: no copy of them rounded in.
    lo, hi = _float_prims(5000, 7)
    expected = build_bvh(lo, hi)
    if not bvh_builder.is_oclgrind(cl_queue.device):
        monkeypatch.setattr(bvh_builder, "_round_in", None)
    bvh = bvh_builder.build_bvh_from(cl_queue, [lo, hi], consume=True)
    assert_same_tree(bvh, expected)


def test_device_build_of_mesh_triangles(cl_queue):
    vertices, faces, _ = mesh_gen.bumpy_mesh(5)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    assert_same_tree(build_bvh_on(cl_queue, lo, hi), build_bvh(lo, hi))


# --- build quality ---------------------------------------------------------------------------


def _half_area(lo: np.ndarray, hi: np.ndarray) -> float:
    e = np.maximum(hi - lo, 0.0)
    return float(e[0] * e[1] + e[1] * e[2] + e[2] * e[0])


def _measure(lo: np.ndarray, hi: np.ndarray, by_length: bool) -> float:
    """The SAH's measure of a box: half area, or length in a node of no area."""
    return float(np.maximum(hi - lo, 0.0).sum()) if by_length else _half_area(lo, hi)


def _packets(n: int) -> int:
    """Packet tests of a leaf of n primitives, counted on their own: ceil(n / 4)."""
    return math.ceil(n / 4)


def reference_sah_cost(lo: np.ndarray, hi: np.ndarray, max_leaf_size: int) -> float:
    """SAH cost (as `sah_cost` counts it) of the textbook recursive binned-SAH build: one node
    at a time, in float64, with the builder's bins, axis choice and leaf rules."""
    sah_max_leaf = max_leaf_count(max_leaf_size)
    total = 0.0
    stack = [np.arange(lo.shape[0])]
    while stack:
        idx = stack.pop()
        area = _half_area(lo[idx].min(axis=0), hi[idx].max(axis=0))
        split = _reference_split(lo[idx], hi[idx], area) if idx.size > max_leaf_size else None
        if split is None or (split[1] and idx.size <= sah_max_leaf):
            total += _packets(idx.size) * area
            continue
        total += TRAVERSAL_COST * area
        stack += [idx[~split[0]], idx[split[0]]]
    return total / _half_area(lo.min(axis=0), hi.max(axis=0))


def _reference_split(lo: np.ndarray, hi: np.ndarray, area: float):
    """(goes right, SAH prefers a leaf) for one node, or None when its centroids coincide."""
    by_length = area == 0
    if by_length:
        area = _measure(lo.min(axis=0), hi.max(axis=0), True)
    c = 0.5 * (lo + hi)
    ext = c.max(axis=0) - c.min(axis=0)
    axis = int(np.argmax(ext))
    n = lo.shape[0]
    if ext[axis] == 0:
        return (np.arange(n) >= n // 2), True
    b = np.clip(((c[:, axis] - c[:, axis].min()) * (N_BINS / ext[axis])).astype(int), 0,
                N_BINS - 1)
    best, best_cost = 0, math.inf
    for k in range(N_BINS - 1):
        left = b <= k
        if left.all() or not left.any():
            continue
        cost = (_measure(lo[left].min(axis=0), hi[left].max(axis=0), by_length)
                * _packets(left.sum())
                + _measure(lo[~left].min(axis=0), hi[~left].max(axis=0), by_length)
                * _packets((~left).sum()))
        if cost < best_cost:
            best, best_cost = k, cost
    return b > best, TRAVERSAL_COST * area + best_cost >= _packets(n) * area


@pytest.mark.parametrize("kind", ["uniform", "duplicates", "flat", "clustered_scales",
                                  "segment_and_boxes"])
@pytest.mark.parametrize("seed", [1, 2])
def test_sah_cost_matches_a_recursive_reference(kind, seed):
    lo, hi = _random_set(kind, 3000, np.random.default_rng(seed))
    built = sah_cost(build_bvh(lo, hi, 4).nodes)
    # The build bins float32-rounded centroids, so a few splits may land one bin apart.
    assert built == pytest.approx(reference_sah_cost(lo, hi, 4), rel=0.01)


def test_sah_cost_of_a_mesh_matches_a_recursive_reference():
    vertices, faces, _ = mesh_gen.bumpy_mesh(3)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    assert sah_cost(build_bvh(lo, hi).nodes) == pytest.approx(reference_sah_cost(lo, hi, 4),
                                                              rel=0.01)


def test_sah_cost_of_one_leaf_and_of_two():
    lo = np.array([[0.0, 0, 0], [2, 0, 0]])
    hi = lo + 1
    # One leaf: one packet test over the root's area.
    assert sah_cost(build_bvh(lo, hi, 2).nodes) == pytest.approx(1.0)
    # Two primitives fit one packet: even with leaves of one, SAH keeps them together.
    assert sah_cost(build_bvh(lo, hi, 1).nodes) == pytest.approx(1.0)
    # Split: two groups of four coincident unit cubes far apart. The root visit plus one packet
    # test per group, 3 / 203 of the root's area each, beats one leaf of two packets (2).
    lo = np.array([[0.0, 0, 0]] * 4 + [[100.0, 0, 0]] * 4)
    assert sah_cost(build_bvh(lo, lo + 1).nodes) == pytest.approx(TRAVERSAL_COST + 2 * 3 / 203)


# --- traversal oracle ----------------------------------------------------------------------

_SLAB_WIDEN = 1.0 + 2.0 * (3 * 2.0**-24) / (1 - 3 * 2.0**-24)  # 1 + 2*gamma(3), float32 gamma


def _sphere_t(o, d, c, r, tmin, tmax):
    """Nearest root in (tmin, tmax) of the ray against a sphere, or None (stable form, unit d)."""
    f = (o[0] - c[0], o[1] - c[1], o[2] - c[2])
    b = f[0] * d[0] + f[1] * d[1] + f[2] * d[2]
    lx, ly, lz = f[0] - b * d[0], f[1] - b * d[1], f[2] - b * d[2]
    ll = math.sqrt(lx * lx + ly * ly + lz * lz)
    disc = (r - ll) * (r + ll)
    if disc < 0:
        return None
    q = -(b + math.copysign(math.sqrt(disc), b))
    if q == 0:
        return None
    cc = f[0] * f[0] + f[1] * f[1] + f[2] * f[2] - r * r
    t0, t1 = sorted((cc / q, q))
    for t in (t0, t1):
        if tmin < t < tmax:
            return t
    return None


def _traverse(nodes, order, spheres, o, d, tmin):
    """Closest hit (t, sphere index) through the BVH, the slab test written as the kernels do."""
    inv = tuple(1.0 / x if x != 0 else math.copysign(math.inf, x) for x in d)
    best_t, best_i = math.inf, -1
    stack = [0]
    while stack:
        i = stack.pop()
        lo, first, hi, count = nodes[i]
        t0, t1 = tmin, best_t
        for k in range(3):
            # (lo - o) * inf is NaN when the origin lies on a slab plane; the compare-selects
            # below ignore a NaN rather than letting it turn a hit into a miss.
            tn = (lo[k] - o[k]) * inv[k]
            tf = (hi[k] - o[k]) * inv[k]
            if tn > tf:
                tn, tf = tf, tn
            tf *= _SLAB_WIDEN
            t0 = tn if tn > t0 else t0
            t1 = tf if tf < t1 else t1
        if t0 > t1:
            continue
        if count == 0:
            stack += [first, i + 1]
            continue
        for k in range(first, first + count):
            s = order[k]
            t = _sphere_t(o, d, spheres[s][:3], spheres[s][3], tmin, best_t)
            if t is not None:
                best_t, best_i = t, s
    return best_t, best_i


def _brute_force(spheres, origins, dirs, tmin):
    """Closest hit of every ray against every sphere, the same formula in numpy float64."""
    t_best = np.full(len(origins), np.inf)
    i_best = np.full(len(origins), -1)
    for s, (cx, cy, cz, r) in enumerate(spheres):
        f = origins - (cx, cy, cz)
        b = np.einsum("ij,ij->i", f, dirs)
        ll = np.linalg.norm(f - b[:, None] * dirs, axis=1)
        disc = (r - ll) * (r + ll)
        with np.errstate(invalid="ignore", divide="ignore"):
            q = -(b + np.copysign(np.sqrt(disc), b))
            cc = np.einsum("ij,ij->i", f, f) - r * r
            roots = np.sort(np.stack([cc / q, q], axis=1), axis=1)
        valid = (disc >= 0) & (q != 0)
        t = np.where(valid & (roots[:, 0] > tmin), roots[:, 0],
                     np.where(valid & (roots[:, 1] > tmin), roots[:, 1], np.inf))
        closer = t < t_best
        t_best[closer] = t[closer]
        i_best[closer] = s
    return t_best, i_best


def test_traversal_matches_brute_force():
    rng = np.random.default_rng(7)
    n_spheres, n_rays = 400, 3000
    centres = rng.uniform(-10, 10, (n_spheres, 3))
    radii = rng.exponential(0.5, n_spheres) + 0.01
    spheres = np.column_stack([centres, radii])
    bvh = build_bvh(centres - radii[:, None], centres + radii[:, None], max_leaf_size=4)
    check_bvh(bvh, centres - radii[:, None], centres + radii[:, None], 4)

    origins = rng.uniform(-14, 14, (n_rays, 3))
    dirs = rng.normal(size=(n_rays, 3))
    # Axis-parallel rays: infinite reciprocals, and origins placed exactly on node slab planes,
    # where the slab test meets 0 * inf.
    axis_par = rng.random(n_rays) < 0.2
    dirs[axis_par, rng.integers(0, 3, axis_par.sum())] = 0.0
    dirs[axis_par, rng.integers(0, 3, axis_par.sum())] = 0.0
    dirs[np.all(dirs == 0, axis=1), 0] = 1.0
    on_plane = np.flatnonzero(axis_par)[::2]
    node_pick = rng.integers(0, bvh.nodes.size, on_plane.size)
    for ray, node in zip(on_plane, node_pick, strict=True):
        k = int(np.flatnonzero(dirs[ray] == 0)[0])
        origins[ray, k] = bvh.nodes["lo"][node][k]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # Some rays aimed straight at sphere centres, so plenty of them hit.
    aimed = rng.random(n_rays) < 0.3
    target = centres[rng.integers(0, n_spheres, aimed.sum())]
    dirs[aimed] = target - origins[aimed]
    dirs[aimed] /= np.linalg.norm(dirs[aimed], axis=1, keepdims=True)

    tmin = 1e-9
    nodes = [(tuple(map(float, nd["lo"])), int(nd["first"]), tuple(map(float, nd["hi"])),
              int(nd["count"])) for nd in bvh.nodes]
    order = bvh.order.tolist()
    sph = [tuple(map(float, s)) for s in spheres]
    t_ref, i_ref = _brute_force(spheres, origins, dirs, tmin)
    assert (i_ref >= 0).sum() > n_rays // 4
    for ray in range(n_rays):
        t, i = _traverse(nodes, order, sph, tuple(map(float, origins[ray])),
                         tuple(map(float, dirs[ray])), tmin)
        # Same formula, but numpy sums and norms round differently from the scalar code.
        assert i == i_ref[ray], ray
        assert t == pytest.approx(t_ref[ray], rel=1e-12), ray


# --- benchmark mesh generator ----------------------------------------------------------------

@pytest.mark.parametrize("subdivisions", [0, 1, 3])
def test_icosphere_is_a_closed_unit_sphere(subdivisions):
    vertices, faces = mesh_gen.icosphere(subdivisions)
    assert faces.shape == (20 * 4**subdivisions, 3)
    assert vertices.shape == (10 * 4**subdivisions + 2, 3)
    assert np.allclose(np.linalg.norm(vertices, axis=1), 1.0)
    # Closed 2-manifold: every edge is shared by exactly two faces, in opposite directions.
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    assert np.unique(directed, axis=0).shape[0] == directed.shape[0]
    assert np.array_equal(np.unique(directed, axis=0), np.unique(directed[:, ::-1], axis=0))
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    outward = np.einsum("ij,ij->i", np.cross(v1 - v0, v2 - v0), v0 + v1 + v2)
    assert np.all(outward > 0)


def test_bumpy_mesh_is_deterministic_and_bumpy():
    vertices, faces, normals = mesh_gen.bumpy_mesh(3, center=(0.0, 1.0, 0.0), radius=2.0)
    again = mesh_gen.bumpy_mesh(3, center=(0.0, 1.0, 0.0), radius=2.0)
    assert all(np.array_equal(a, b) for a, b in zip((vertices, faces, normals), again, strict=True))
    r = np.linalg.norm(vertices - (0.0, 1.0, 0.0), axis=1)
    assert r.min() >= 2.0 * (1 - mesh_gen.BUMP_AMPLITUDE) - 1e-12
    assert r.max() <= 2.0 * (1 + mesh_gen.BUMP_AMPLITUDE) + 1e-12
    assert r.max() - r.min() > 2.0 * mesh_gen.BUMP_AMPLITUDE
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", normals, vertices - (0.0, 1.0, 0.0)) > 0)


def test_bvh_over_mesh_triangles():
    vertices, faces, _ = mesh_gen.bumpy_mesh(4)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    check_bvh(build_bvh(lo, hi), lo, hi, 4)


def test_scene_files_written(tmp_path):
    import tomllib

    mesh_gen.main(["--out", str(tmp_path), "--subdivisions", "1"])
    scene = tomllib.loads((tmp_path / "bumpy.toml").read_text())
    assert (scene["render"]["width"], scene["render"]["height"]) == (1280, 720)
    assert [o["type"] for o in scene["objects"]] == ["plane", "mesh"]
    assert scene["objects"][1]["file"] == "bumpy.obj"
    lines = (tmp_path / "bumpy.obj").read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == 42
    assert sum(line.startswith("vn ") for line in lines) == 42
    faces = [line for line in lines if line.startswith("f ")]
    assert len(faces) == 80
    a, b, c = (int(x.split("//")[0]) for x in faces[0].split()[1:])
    assert faces[0] == f"f {a}//{a} {b}//{b} {c}//{c}"


def test_sah_packet_is_the_kernels_packet_width():
    assert SAH_PACKET == PACKET_WIDTH


def test_leaves_fill_their_packets():
    # Leaves cost their packet count, so SAH cuts 8 triangles into 4 + 4, not 3 + 5: most
    # packets are full. Leaves costed per primitive left a fifth of the lanes empty here.
    vertices, faces, _ = mesh_gen.bumpy_mesh(4)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    count = build_bvh(lo, hi).nodes["count"]
    leaves = count[count > 0].astype(np.int64)
    assert leaves.sum() == len(faces)
    lanes = packets(leaves).sum() * PACKET_WIDTH
    assert len(faces) / lanes > 0.9


def test_largest_leaf_caps_the_leaves_sah_may_choose() -> None:
    rng = np.random.default_rng(3)
    lo = rng.uniform(-1, 1, (300, 3))
    hi = lo + 0.01  # tiny boxes: SAH alone would keep many in a leaf
    counts = build_bvh(lo, hi, max_leaf_size=1, largest_leaf=1).nodes["count"]
    assert counts.max() == 1 and (counts == 1).sum() == 300
    assert build_bvh(lo, hi, max_leaf_size=1).nodes["count"].max() > 1
    with pytest.raises(ValueError, match="largest_leaf"):
        build_bvh(lo, hi, max_leaf_size=4, largest_leaf=2)
