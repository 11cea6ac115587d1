"""A scene's geometry packed at one eye and placed at another (pack_geometry, then pack_scene's
`geometry`): the positions made relative to the new eye and the instances placed anew, the BVH
refitted, not built again. Oracles: a pack made afresh there (its bytes where the build's tree
has the same shape, its image where it does not), the first eye's pack, which placing back must
give, and a walk of the tree for its cost."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import load_mesh_generator

from clray.accel.bvh import TRAVERSAL_COST
from clray.accel.wide import LEAF_SPHERE_SHIFT, LEAF_TRIANGLE_SHIFT, PACKET_WIDTH, tree_cost
from clray.device import bvh_builder
from clray.device.context import queue_for
from clray.device.launch import render_packed
from clray.device.pack import DEVICE_BUILD_MIN, REFIT_COST_LIMIT, pack_geometry, pack_scene
from clray.scene import model as M
from clray.scene.load import load_scene
from clray.scene.transform import place, rotation_matrix
from clray.shapes import SHAPES

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.toml"))
SETTINGS = {"width": 48, "height": 27, "spp": 1, "max_depth": 2, "seed": 0}
# Moves of the eye: a step, and one across the scene.
MOVES = ([0.37, -0.21, 0.55], [3.1, 1.7, -2.2])


def _at(scene: M.Scene, eye: np.ndarray) -> M.Scene:
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera,
                                                                 position=tuple(eye)))


def _moved(scene: M.Scene, move: list[float]) -> M.Scene:
    return _at(scene, np.asarray(scene.camera.position, dtype=np.float64) + move)


def _differing(a: object, b: object) -> list[str]:
    return [name for name, array in a.buffers().items()
            if array.tobytes() != b.buffers()[name].tobytes()]


def _big_mesh(subdivisions: int = 6) -> M.Scene:
    """The bumpy mesh: 81,920 triangles (6), over DEVICE_BUILD_MIN, so that a queue builds its
    tree on the device; 327,680 (7)."""
    vertices, faces, _ = load_mesh_generator().bumpy_mesh(subdivisions)
    assert len(faces) >= DEVICE_BUILD_MIN
    return M.Scene(None, M.RenderOptions(64, 48, 1, 0, (0.0, 0.0, 0.0)),
                   M.Camera((0.3, 0.2, 3.0), (0.0, 0.0, 0.0)), (M.Material("m"),),
                   (M.PointLight((2.0, 3.0, 4.0)),),
                   (M.Mesh(vertices=vertices, faces=faces, material=0),))


# The example scenes whose trees a build at the moved eyes gives the same shape (the binned
# SAH's choices do not turn on the last bits that moving the eye changes; spheres.toml's do):
# there, moving must give a fresh pack's bytes, the nodes' boxes included.
@pytest.mark.parametrize("scene_file", [s for s in SCENES if s != "spheres.toml"])
@pytest.mark.parametrize("move", MOVES)
def test_placed_at_another_eye_is_the_pack_made_there(scene_file, move):
    scene = load_scene(ROOT / "scenes" / scene_file)
    geometry = pack_geometry(scene)
    assert pack_scene(scene, geometry=geometry, **SETTINGS).bvh_s > 0  # the build's time
    placed = pack_scene(_moved(scene, move), geometry=geometry, **SETTINGS)
    fresh = pack_scene(_moved(scene, move), **SETTINGS)
    assert _differing(placed, fresh) == []
    assert placed.bvh_s > 0  # the refit's time alone, in the stats' bvh_s


@pytest.mark.parametrize("scene_file", SCENES)
def test_placed_back_at_the_first_eye_gives_the_first_pack(scene_file):
    scene = load_scene(ROOT / "scenes" / scene_file)
    geometry = pack_geometry(scene)
    pack_scene(_moved(scene, MOVES[1]), geometry=geometry, **SETTINGS)
    back = pack_scene(scene, geometry=geometry, **SETTINGS)
    assert _differing(back, pack_scene(scene, **SETTINGS)) == []


def test_a_device_built_tree_placed_back_gives_the_first_pack(cl_device):
    scene = _big_mesh()
    if not bvh_builder.supports(cl_device, len(scene.objects[0].faces), 4):
        pytest.skip("the device does not build BVHs")
    queue = queue_for(cl_device)
    geometry = pack_geometry(scene, queue=queue)
    pack_scene(_moved(scene, MOVES[0]), geometry=geometry, queue=queue, **SETTINGS)
    back = pack_scene(scene, geometry=geometry, queue=queue, **SETTINGS)
    assert _differing(back, pack_scene(scene, queue=queue, **SETTINGS)) == []


@pytest.mark.parametrize("scene", ["spheres.toml", "mesh"])
def test_a_tree_of_another_shape_placed_renders_the_fresh_image(cl_device, scene):
    # At these eyes a build gives these scenes trees of other shapes (their bytes differ), so
    # the images are the oracle: every ray meets the same primitives through either tree.
    scene = _big_mesh(7) if scene == "mesh" else load_scene(ROOT / "scenes" / scene)
    settings = {**SETTINGS, "width": 96, "height": 54, "spp": 2}
    geometry = pack_geometry(scene)
    for move in MOVES:
        placed = pack_scene(_moved(scene, move), geometry=geometry, **settings)
        fresh = pack_scene(_moved(scene, move), **settings)
        assert "nodes" in _differing(placed, fresh)
        image = render_packed(placed, cl_device)[0]
        assert np.count_nonzero(image) > image.size // 10  # the scene is in view
        np.testing.assert_array_equal(image, render_packed(fresh, cl_device)[0])


def test_a_geometry_is_placed_with_the_width_and_knobs_it_was_packed_with():
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    geometry = pack_geometry(scene, bvh_width=4)
    with pytest.raises(ValueError, match="another BVH width or tuning"):
        pack_scene(scene, geometry=geometry, bvh_width=8, **SETTINGS)


def test_placing_at_the_same_eye_reports_no_bvh_time():
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    geometry = pack_geometry(scene)
    first = pack_scene(scene, geometry=geometry, **SETTINGS)
    again = pack_scene(scene, geometry=geometry, **SETTINGS)
    assert first.bvh_s > 0 and again.bvh_s == 0
    assert _differing(first, again) == []


def test_a_move_that_fails_part_way_is_not_taken_for_the_old_eye(monkeypatch):
    # The planes and shapes were made at the new eye before the refit failed: a later frame at
    # the old eye took the arrays of both eyes as its own.
    from clray.device import pack

    scene = load_scene(ROOT / "scenes" / "primitives.toml")
    geometry = pack_geometry(scene)

    def out_of_memory(*_args: object) -> None:
        raise MemoryError

    with monkeypatch.context() as patch:
        patch.setattr(pack, "refit", out_of_memory)
        with pytest.raises(MemoryError):
            pack_scene(_moved(scene, MOVES[0]), geometry=geometry, **SETTINGS)
    assert _differing(pack_scene(scene, geometry=geometry, **SETTINGS),
                      pack_scene(scene, **SETTINGS)) == []


def _turned(scene: M.Scene, degrees: float) -> M.Scene:
    """The scene with each instance turned about the y axis through the origin (a carousel),
    its own primitives left where they are."""
    turn = rotation_matrix((0.0, degrees, 0.0))
    return dataclasses.replace(scene, objects=tuple(
        dataclasses.replace(obj, matrix=turn @ obj.matrix) if isinstance(obj, M.Instance)
        else obj for obj in scene.objects))


def _with_mesh(scene: M.Scene) -> M.Scene:
    """The scene with a small mesh of its own (beside its groups' triangles)."""
    vertices, faces, _ = load_mesh_generator().bumpy_mesh(2)
    mesh = M.Mesh(vertices=0.5 * vertices + [0.0, 2.5, 1.0], faces=faces, material=0)
    return dataclasses.replace(scene, objects=(*scene.objects, mesh))


def _triangles_of(packed: object) -> np.ndarray:
    """Every triangle of the packets, its corners' nine numbers, in sorted order: the same
    for the same triangles whatever slots a tree gives them."""
    corners = packed.triangle_packets.view(np.float32).reshape(-1, 9, PACKET_WIDTH)
    rows = corners.transpose(0, 2, 1).reshape(-1, 9)
    rows = rows[~np.isnan(rows).any(axis=1)]
    return rows[np.lexsort(rows.T[::-1])]


def test_instances_placed_anew_are_the_pack_made_there(cl_device):
    """Instances moved by a track (clray.sequence): their records and lanes made again, their
    groups' trees and triangle packets kept, the scene's own triangles moved to the eye. At the
    same eye too: a move is the eye's and the instances' places."""
    scene = load_scene(ROOT / "scenes" / "instances.toml")
    geometry = pack_geometry(scene)
    for moved in (_turned(scene, 5.0), _moved(_turned(scene, 5.0), MOVES[0])):
        assert _differing(pack_scene(moved, geometry=geometry, **SETTINGS),
                          pack_scene(moved, **SETTINGS)) == []
    # With a mesh of the scene's own, a build there gives a tree of another shape: the image
    # is the oracle there, and placing back must give the first pack's bytes.
    meshed = _with_mesh(scene)
    geometry = pack_geometry(meshed)
    moved = _moved(_turned(meshed, 5.0), MOVES[0])
    placed, fresh = (pack_scene(moved, geometry=geometry, **SETTINGS),
                     pack_scene(moved, **SETTINGS))
    assert geometry.cost <= REFIT_COST_LIMIT * geometry.built_cost  # refitted, not built
    np.testing.assert_array_equal(_triangles_of(placed), _triangles_of(fresh))
    np.testing.assert_array_equal(render_packed(placed, cl_device)[0],
                                  render_packed(fresh, cl_device)[0])
    assert _differing(pack_scene(meshed, geometry=geometry, **SETTINGS),
                      pack_scene(meshed, **SETTINGS)) == []
    geometry = pack_geometry(scene)
    # A half turn: a build there gives a tree of another shape, whose image is the oracle.
    settings = {**SETTINGS, "width": 96, "height": 54}
    moved = _turned(scene, 180.0)
    placed = pack_scene(moved, geometry=geometry, **settings)
    fresh = pack_scene(moved, **settings)
    assert "nodes" in _differing(placed, fresh)
    assert geometry.cost <= REFIT_COST_LIMIT * geometry.built_cost  # refitted, not built
    image = render_packed(placed, cl_device)[0]
    assert not np.array_equal(image, render_packed(pack_scene(scene, **settings), cl_device)[0])
    np.testing.assert_array_equal(image, render_packed(fresh, cl_device)[0])
    assert _differing(pack_scene(scene, geometry=geometry, **SETTINGS),
                      pack_scene(scene, **SETTINGS)) == []


def _shifted_shapes(scene: M.Scene, step: tuple[float, float, float],
                    kinds: tuple[type, ...]) -> M.Scene:
    """The scene with each plane and shape of `kinds` moved by `step` (a track on their own
    values)."""
    return dataclasses.replace(scene, objects=tuple(
        place(obj, np.eye(3), np.array(step)) if isinstance(obj, kinds) else obj
        for obj in scene.objects))


SHAPE_MODELS = tuple(shape.model for shape in SHAPES)
# A tiny step, which leaves a build's tree its shape, then larger ones, each kind alone too
# (from frame 0's packing: a move at the same eye is any record's change).
SHAPE_MOVES = (((0.0, 1e-3, 0.0), (*SHAPE_MODELS, M.Plane)),
               ((0.0, 0.3, 0.0), (*SHAPE_MODELS, M.Plane)),
               ((0.2, -0.1, 0.4), SHAPE_MODELS), ((0.0, 0.25, 0.0), (M.Plane,)))


@pytest.mark.parametrize("scene_file", ["spheres.toml", "orbit.toml", "primitives.toml",
                                        "tori.toml"])
def test_shapes_moved_in_place_are_the_pack_made_there(cl_device, scene_file):
    """Planes and shapes moved by a track, the packing kept: their records made again, the
    tree refitted to the shapes' new boxes."""
    scene = load_scene(ROOT / "scenes" / scene_file)
    settings = {**SETTINGS, "width": 96, "height": 54}
    records = {"planes", "camera", *(shape.buffer for shape in SHAPES)}
    for step, kinds in SHAPE_MOVES:
        geometry = pack_geometry(scene)
        moved = _shifted_shapes(scene, step, kinds)
        placed = pack_scene(moved, geometry=geometry, **settings)
        fresh = pack_scene(moved, **settings)
        assert geometry.cost <= REFIT_COST_LIMIT * geometry.built_cost  # refitted, not built
        differing = _differing(placed, fresh)
        if step[1] == 1e-3:
            assert differing == []
            continue
        # The records are a fresh pack's; the tree may be of another shape, with its slots
        # in another order (prim_refs, sphere_packets): the image is the oracle for it.
        assert not records & set(differing)
        image = render_packed(placed, cl_device)[0]
        np.testing.assert_array_equal(image, render_packed(fresh, cl_device)[0])
        assert not np.array_equal(image, render_packed(pack_scene(scene, **settings),
                                                       cl_device)[0])
    assert _differing(pack_scene(scene, geometry=geometry, **SETTINGS),
                      pack_scene(scene, **SETTINGS)) == []


def test_other_primitives_are_packed_afresh():
    # One sphere more: the packing's slots are not the frame's, whatever the cost.
    scene = load_scene(ROOT / "scenes" / "orbit.toml")
    geometry = pack_geometry(scene)
    more = dataclasses.replace(scene, objects=(*scene.objects, M.Sphere((0.0, 3.0, 0.0), 0.5,
                                                                        0)))
    assert _differing(pack_scene(more, geometry=geometry, **SETTINGS),
                      pack_scene(more, **SETTINGS)) == []
    assert _differing(pack_scene(scene, geometry=geometry, **SETTINGS),
                      pack_scene(scene, **SETTINGS)) == []


def _ball_grid(order: np.ndarray) -> M.Scene:
    """64 instances of one small sphere's group on an 8 x 8 grid, instance i at place
    order[i]."""
    ball = M.Group("ball", (M.Sphere((0.0, 0.0, 0.0), 0.4, 0),))
    places = [(float(x), 0.0, float(z)) for x in range(8) for z in range(8)]
    instances = tuple(M.Instance(ball, np.hstack([np.eye(3), np.array(places[k])[:, None]]))
                      for k in order)
    return M.Scene(None, M.RenderOptions(48, 27, 1, 0, (0.0, 0.0, 0.0)),
                   M.Camera((3.5, 9.0, 12.0), (3.5, 0.0, 3.5)), (M.Material("m"),),
                   (M.PointLight((2.0, 9.0, 4.0)),), instances)


def test_a_refit_past_the_cost_limit_is_packed_afresh(bvh_builds):
    # The instances change places: frame 0's tree refitted there has every inner box across
    # the grid, and the frame gets a tree of its own.
    scene = _ball_grid(np.arange(64))
    geometry = pack_geometry(scene)
    shuffled = _ball_grid(np.random.default_rng(1).permutation(64))
    bvh_builds.clear()  # frame 0's
    placed = pack_scene(shuffled, geometry=geometry, **SETTINGS)
    assert geometry.cost > REFIT_COST_LIMIT * geometry.built_cost
    assert len(bvh_builds) == 1
    assert _differing(placed, pack_scene(shuffled, **SETTINGS)) == []
    assert _differing(pack_scene(scene, geometry=geometry, **SETTINGS),
                      pack_scene(scene, **SETTINGS)) == []


def _walk_cost(nodes: np.ndarray) -> float:
    """tree_cost's oracle: the tree walked node by node from the root in float64, each used
    lane's box area times a node visit (inner or instance lane) or its leaf's tests."""
    def area(node: np.void, lane: int) -> float:
        e = [float(node[f"hi_{a}"][lane]) - float(node[f"lo_{a}"][lane]) for a in "xyz"]
        return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]

    total, todo = 0.0, [0]
    while todo:
        node = nodes[todo.pop()]
        for lane in range(len(node["child"])):
            child, count = int(node["child"][lane]), int(node["count"][lane])
            if child < 0:
                continue
            if count == 0:
                todo.append(child)
            tests = ((count >> LEAF_TRIANGLE_SHIFT) + ((count >> LEAF_SPHERE_SHIFT) & 0xFF)
                     + (count & 0xFF))
            total += area(node, lane) * (tests if count > 0 else TRAVERSAL_COST)
    used = nodes[0]["child"] >= 0
    lo = [float(nodes[0][f"lo_{a}"][used].min()) for a in "xyz"]
    hi = [float(nodes[0][f"hi_{a}"][used].max()) for a in "xyz"]
    return total / sum((hi[i] - lo[i]) * (hi[j] - lo[j]) for i, j in ((0, 1), (1, 2), (2, 0)))


def test_tree_cost_in_closed_form():
    # One sphere: the root's one lane is a leaf of one sphere packet over its own box; one
    # instance: a lane that enters its group, at a node visit's cost; no tree; no area.
    sphere = M.Sphere((0.5, 0.2, -3.0), 0.7, 0)
    one = dataclasses.replace(_ball_grid(np.arange(1)), objects=(sphere,))
    assert tree_cost(pack_geometry(one).wide.nodes) == 1.0
    assert tree_cost(pack_geometry(_ball_grid(np.arange(1))).wide.nodes) == TRAVERSAL_COST
    assert tree_cost(pack_geometry(_ball_grid(np.arange(1))).wide.nodes[:0]) == 0.0
    flat = pack_geometry(one).wide.nodes.copy()
    for axis in "xyz":
        flat[f"hi_{axis}"] = flat[f"lo_{axis}"]
    assert tree_cost(flat) == 0.0


@pytest.mark.parametrize("scene_file", ["spheres.toml", "instances.toml", "cornell_box.toml"])
def test_tree_cost_is_the_walk_over_the_root(scene_file):
    nodes = pack_geometry(load_scene(ROOT / "scenes" / scene_file)).wide.nodes
    assert tree_cost(nodes) == pytest.approx(_walk_cost(nodes), rel=1e-12)
