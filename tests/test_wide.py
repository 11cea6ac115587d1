"""Binary -> wide BVH collapse (clray.accel.wide): structure, bounds, leaf layout, stack bound."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from conftest import check_unused_lanes, load_mesh_generator
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clray.accel.bvh import build_bvh
from clray.accel.wide import (
    FOLD_PACKETS,
    LEAF_FIELD_MASK,
    LEAF_SPHERE_SHIFT,
    LEAF_TRIANGLE_SHIFT,
    NO_REF,
    PACKET_WIDTH,
    WideBvh,
    collapse,
    fill_nodes,
    refit,
)
from clray.device import layout as L
from clray.device.launch import render_packed
from clray.device.pack import pack_scene
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


def _random_boxes(rng: np.random.Generator, n: int, extent: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """n boxes' centres, uniform in [-10, 10)^3, and half-extents, exponential of mean
    `extent`: the boxes are c - e to c + e."""
    return rng.uniform(-10, 10, (n, 3)), rng.exponential(extent, (n, 3))


def _children(wide: WideBvh, node: int) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """(child, count, lo, hi) of each used slot of a node."""
    rec = wide.nodes[node]
    out = []
    for k in range(wide.width):
        if rec["child"][k] < 0:
            continue
        lo = np.array([rec[f"lo_{a}"][k] for a in AXES])
        hi = np.array([rec[f"hi_{a}"][k] for a in AXES])
        out.append((int(rec["child"][k]), int(rec["count"][k]), lo, hi))
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
    kernel reads them; the stack bound covers the deepest walk; unused lanes as described."""
    assert wide.nodes.dtype == L.bvh_node_dtype(wide.width)
    check_unused_lanes(wide.nodes)
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
    c, e = _random_boxes(rng, n, 0.3)
    kinds = rng.choice([L.PRIM_SPHERE, L.PRIM_BOX, L.PRIM_TRIANGLE, L.PRIM_CONE], n)
    refs = _refs(kinds)
    wide = collapse(build_bvh(c - e, c + e), refs, width)
    check_wide(wide, c - e, c + e, refs)


def _union_below(wide: WideBvh, node: int, lo: np.ndarray, hi: np.ndarray
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each used lane's box of `node`, found by walking down to the primitives: the union of
    the boxes (lo, hi by a primitive's place in refs) of every primitive below the lane."""
    boxes = []
    for child, count, _, _ in _children(wide, node):
        if count == 0:
            below = _union_below(wide, child, lo, hi)
            boxes.append((np.min([b[0] for b in below], axis=0),
                          np.max([b[1] for b in below], axis=0)))
            continue
        refs = np.concatenate(_leaf_sections(wide, child, count))
        refs = refs[refs != NO_REF] & L.PRIM_INDEX_MASK
        boxes.append((lo[refs].min(axis=0), hi[refs].max(axis=0)))
    return boxes


@pytest.mark.parametrize("width", [4, 8])
@pytest.mark.parametrize("n", [1, 9, 300, 3000])
def test_refit_makes_each_box_the_union_of_the_moved_primitives(width, n):
    rng = np.random.default_rng(n + width)
    c, e = _random_boxes(rng, n, 0.3)
    # References that are each primitive's index (one kind), so a slot's ref indexes the boxes.
    refs = (L.PRIM_TRIANGLE << L.PRIM_TYPE_SHIFT) + np.arange(n)
    wide = collapse(build_bvh(c - e, c + e, 4), refs, width)
    moved = np.concatenate([[[0.0, 0.0, 0.0]], rng.uniform(-0.5, 0.5, (n - 1, 3))]) + 3.0
    lo, hi = ((c + moved - e).astype(np.float32), (c + moved + e).astype(np.float32))
    used = wide.prim_refs != NO_REF
    slots = np.where(used, wide.prim_refs & L.PRIM_INDEX_MASK, 0)
    slot_lo = np.where(used[:, None], lo[slots], np.inf).astype(np.float32)
    slot_hi = np.where(used[:, None], hi[slots], -np.inf).astype(np.float32)
    nodes = wide.nodes.copy()
    refit(nodes, slot_lo, slot_hi, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
    fitted = WideBvh(nodes, wide.prim_refs, width, wide.stack_size)
    for node in range(len(nodes)):
        expected = _union_below(fitted, node, lo, hi)
        for (_, _, got_lo, got_hi), (want_lo, want_hi) in zip(_children(fitted, node),
                                                              expected, strict=True):
            np.testing.assert_array_equal(got_lo, want_lo)
            np.testing.assert_array_equal(got_hi, want_hi)
    np.testing.assert_array_equal(nodes["child"], wide.nodes["child"])
    np.testing.assert_array_equal(nodes["count"], wide.nodes["count"])
    check_unused_lanes(nodes)


@pytest.mark.parametrize("width", [4, 8])
def test_a_run_of_references_given_by_its_first_is_the_run_itself(width):
    # The pack hands a mesh alone's references as their first (L.PRIM_TRIANGLE << shift):
    # the tree must be the one of the references written out.
    rng = np.random.default_rng(width)
    c = rng.uniform(-10, 10, (3000, 3))
    e = rng.exponential(0.3, (3000, 3))
    first = L.PRIM_TRIANGLE << L.PRIM_TYPE_SHIFT
    bvh = build_bvh(c - e, c + e)
    run, written = collapse(bvh, first, width), collapse(bvh, first + np.arange(3000), width)
    assert np.array_equal(run.prim_refs, written.prim_refs)
    assert run.nodes.tobytes() == written.nodes.tobytes()
    check_wide(run, c - e, c + e, first + np.arange(3000))


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


@pytest.mark.parametrize("width", [4, 8])
@pytest.mark.parametrize("n", [1, 2, 9, 300])
def test_filled_nodes_keep_every_primitive_under_boxes_that_hold_it(width, n):
    c, e = _random_boxes(np.random.default_rng(n + width), n, 0.5)
    refs = _refs(np.full(n, L.PRIM_INSTANCE))
    wide = collapse(build_bvh(c - e, c + e, max_leaf_size=1, largest_leaf=1), refs, width)
    filled = fill_nodes(wide)
    check_wide(filled, c - e, c + e, refs)
    assert filled.nodes.size <= wide.nodes.size


@pytest.mark.parametrize(("width", "rows"), [(4, 16), (8, 32)])
def test_filled_nodes_of_a_balanced_tree_are_fuller(width, rows):
    # A grid of 32 x rows equal boxes, one a leaf: the binary tree is balanced, 9 or 10 levels
    # deep, and the greedy collapse leaves a bottom level of two-child nodes (9 levels is no
    # multiple of log2 4 = 2, nor 10 of log2 8 = 3).
    x, z = np.meshgrid(np.arange(32.0), np.arange(float(rows)))
    c = np.stack([x.ravel() * 2, np.zeros(x.size), z.ravel() * 2], axis=1)
    refs = _refs(np.full(x.size, L.PRIM_INSTANCE))
    wide = collapse(build_bvh(c - 0.5, c + 0.5, max_leaf_size=1, largest_leaf=1), refs, width)
    filled = fill_nodes(wide)
    check_wide(filled, c - 0.5, c + 0.5, refs)
    used = (filled.nodes["child"] >= 0).sum(axis=1)
    assert used.mean() > 0.75 * width > (wide.nodes["child"] >= 0).sum(axis=1).mean()


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


@pytest.mark.parametrize(("kind", "most", "name"), [
    (L.PRIM_TRIANGLE, 131068, "triangles"), (L.PRIM_SPHERE, 1020, "spheres"),
    (L.PRIM_BOX, 255, "other primitives")])
def test_rejects_a_leaf_its_count_cannot_hold(kind, most, name):
    # The triangle packets fill the count's bits above the sign: one packet more would make
    # the count negative, which the kernels read as an instance's marker.
    lo = np.zeros((most + 1, 3))
    for n in (most, most + 1):
        bvh = build_bvh(lo[:n], lo[:n] + 1, max_leaf_size=n)
        if n == most:
            assert collapse(bvh, kind << L.PRIM_TYPE_SHIFT, 4).nodes["count"][0, 0] > 0
            continue
        with pytest.raises(ValueError, match=f"a leaf of {n} {name} exceeds {most}"):
            collapse(bvh, kind << L.PRIM_TYPE_SHIFT, 4)


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


@pytest.mark.parametrize("scene_file", ["primitives.toml", "instances.toml"])
def test_leaves_test_no_plane_sphere_or_triangle_one_by_one(scene_file):
    # A build without boxes, cylinders, cones and tori compiles no loop over a leaf's
    # one-by-one section (kernels/shapes.h: HAS_ONE_BY_ONE_SHAPES): planes must stay out of
    # the BVH, spheres and triangles in their leaves' packets.
    packed = pack_scene(load_scene(ROOT / "scenes" / scene_file), width=8, height=8, spp=1,
                        max_depth=1, seed=0)
    wide = WideBvh(packed.nodes, packed.prim_refs, 8, 0)
    leaves = (packed.nodes["count"] > 0) & (packed.nodes["child"] >= 0)
    kinds = np.concatenate([_leaf_sections(wide, int(slot), int(count))[2]
                            for slot, count in zip(packed.nodes["child"][leaves],
                                                   packed.nodes["count"][leaves], strict=True)])
    kinds = set((kinds >> L.PRIM_TYPE_SHIFT).tolist())
    assert kinds & {L.PRIM_BOX, L.PRIM_CYLINDER, L.PRIM_CONE}, "no one-by-one shape: blind"
    assert not kinds & {L.PRIM_PLANE, L.PRIM_SPHERE, L.PRIM_TRIANGLE}, kinds


@pytest.mark.parametrize("width", [4, 8])
def test_small_nodes_of_leaves_are_folded_into_one_leaf(width, monkeypatch):
    # Below the root, no wide node holds only leaves that one leaf of FOLD_PACKETS packet tests
    # could cover: such a node is that leaf of its parent instead.
    vertices, faces, _ = load_mesh_generator().bumpy_mesh(4)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    refs = _refs(np.full(len(faces), L.PRIM_TRIANGLE))
    bvh = build_bvh(lo, hi)

    def small_nodes(wide: WideBvh) -> int:
        child, count = wide.nodes["child"], wide.nodes["count"]
        only_leaves = ~((child >= 0) & (count == 0)).any(axis=1)
        packets = np.where(child >= 0, count >> LEAF_TRIANGLE_SHIFT, 0).sum(axis=1)
        return int((only_leaves & (packets <= FOLD_PACKETS))[1:].sum())

    wide = collapse(bvh, refs, width)
    check_wide(wide, lo, hi, refs)
    assert small_nodes(wide) == 0
    # Without folding there are such nodes, and one node more for each.
    folds = FOLD_PACKETS
    monkeypatch.setattr("clray.accel.wide.FOLD_PACKETS", 0)
    unfolded = collapse(bvh, refs, width)
    monkeypatch.setattr("clray.accel.wide.FOLD_PACKETS", folds)
    check_wide(unfolded, lo, hi, refs)
    assert small_nodes(unfolded) > 0
    assert unfolded.nodes.size > wide.nodes.size
