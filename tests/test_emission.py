"""Emissive faces: a mesh face whose material emits (MTL Ke) is seen with that radiance and
lights the scene as an area light sampled by area. The kernels match the float64 reference, and
the irradiance under the Cornell box's light matches a numerical integral over the light."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clray.lights.mesh import face_picked
from clray.reference import render_reference
from clray.reference.sampling import light_key, light_pick, permute_stratum
from clray.render import RenderSettings, render
from clray.scene import model as M
from clray.scene.emitters import EACH_FACE_UP_TO, emissive_lights, emissive_triangles, scene_lights
from clray.scene.load import scene_from_dict
from tests.reference_check import Tolerance, assert_kernel_matches_reference

# The Cornell box's light (130 x 105 mm), facing down, 548.7 above a floor; Ke its radiance.
LIGHT_OBJ = """mtllib l.mtl
v 343 548.7 227
v 343 548.7 332
v 213 548.7 332
v 213 548.7 227
usemtl light
f 1 2 3 4
"""
KE = (17.0, 12.0, 4.0)


def light_scene(tmp_path: Path, camera: dict, spp: int, size: tuple[int, int],
                extra: list | None = None) -> M.Scene:
    (tmp_path / "l.obj").write_text(LIGHT_OBJ)
    (tmp_path / "l.mtl").write_text(f"newmtl light\nKd 0 0 0\nKe {' '.join(map(str, KE))}\n"
                                    "illum 1\n")
    data = {"render": {"width": size[0], "height": size[1], "spp": spp, "ambient": [0, 0, 0]},
            "camera": camera,
            "materials": {"floor": {"color": [0.5, 0.5, 0.5], "specular": 0.2}},
            "objects": [{"type": "mesh", "file": "l.obj"},
                        {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                         "material": "floor"}, *(extra or [])]}
    return scene_from_dict(data, tmp_path / "s.toml")


def test_emissive_faces_become_triangle_lights(tmp_path):
    scene = light_scene(tmp_path, {"position": [278, 300, 0], "look_at": [278, 0, 280]}, 1,
                        (8, 6))
    lights = emissive_triangles(scene)
    assert len(lights) == 2 and all(light.color == KE for light in lights)
    areas = [np.linalg.norm(np.cross(np.subtract(v[1], v[0]), np.subtract(v[2], v[0]))) / 2
             for v in (light.vertices for light in lights)]
    assert sum(areas) == pytest.approx(130 * 105)
    assert scene.lights == ()  # the scene's own lights stay as given


def test_faces_parallel_to_float32_precision_light_nothing(tmp_path):
    # The second face's edges (3, 0, 3) and (3, 0, 3.0000001) span 1.5e-7 in float64, but
    # the float32 copies the kernels get are equal: their float32 normal would be zero, so
    # neither renderer lights with the face. The first face is an ordinary one.
    mesh = M.Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [3, 0, 3], [3, 0, 3.0000001]]),
                  np.array([[0, 2, 1], [0, 3, 4]]), 0)
    scene = M.Scene(None, M.RenderOptions(8, 6), M.Camera((0.0, 2.0, 3.0), (0.0, 0.0, 0.0)),
                    (M.Material("glow", emission=(1.0, 1.0, 1.0)),), (), (mesh,))
    assert [light.vertices[1] for light in emissive_triangles(scene)] == [(0.0, 0.0, 1.0)]


def test_floor_irradiance_under_the_light_matches_the_integral(cl_device, tmp_path):
    # Straight down at the floor under the light's centre from below the light: the middle
    # pixel sees floor radiance Kd * E (clray's diffuse term has no 1/pi), E the irradiance.
    below = [278.0, 0.0, 279.5]
    scene = light_scene(tmp_path, {"position": [278, 500, 279.5], "look_at": below,
                                   "up": [0, 0, 1], "vfov": 1}, 1024, (3, 3))
    scene = M.Scene(scene.path, scene.render, scene.camera,
                    tuple(M.Material(m.name, color=m.color, emission=m.emission)
                          for m in scene.materials), (), scene.objects)
    pixel = render(scene).image[1, 1].astype(np.float64)
    np.testing.assert_allclose(pixel, 0.5 * np.array(KE) * _irradiance_under(below), rtol=0.02)


def _irradiance_under(below: list[float]) -> float:
    """The irradiance the Cornell box's light (radiance 1) gives the floor point `below`, by the
    midpoint rule over a fine grid of the light: E = sum cos cos' / r^2 dA."""
    n = 400
    x = 213 + (np.arange(n) + 0.5) * 130 / n
    z = 227 + (np.arange(n) + 0.5) * 105 / n
    gx, gz = np.meshgrid(x - below[0], z - below[2])
    h = 548.7
    r2 = gx**2 + gz**2 + h**2
    return float(np.sum(h * h / (r2 * r2)) * (130 / n) * (105 / n))


def test_emissive_faces_match_the_reference(cl_device, tmp_path):
    box = {"type": "box", "min": [200, 0, 200], "max": [300, 150, 300],
           "material": {"color": [0.2, 0.6, 0.9], "reflect": 0.3}}
    scene = light_scene(tmp_path, {"position": [278, 400, -500], "look_at": [278, 200, 280]},
                        4, (48, 36), [box])
    # Four times the measured (rmse 3.5e-8, largest error 3.2e-7; PoCL 3.1, AMD EPYC).
    assert_kernel_matches_reference(scene, Tolerance(rmse=1.5e-7, err=1.3e-6))


# --- Mesh lights: many emissive faces of one material in one mesh, sampled as one light -----

def _grid_lamp(nx: int, nz: int, *, tiny: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The Cornell box's light (LIGHT_OBJ's rectangle, facing down) as 2 nx nz triangles over
    an uneven grid, so that faces differ in area; with `tiny`, a sliver of a face whose share
    of the area rounds to no picks is added first."""
    x = 213 + 130 * np.linspace(0, 1, nx + 1) ** 1.5
    z = 227 + 105 * np.linspace(0, 1, nz + 1) ** 0.7
    gx, gz = np.meshgrid(x, z, indexing="ij")
    vertices = np.stack([gx.ravel(), np.full(gx.size, 548.7), gz.ravel()], axis=1)
    at = np.arange(gx.size).reshape(nx + 1, nz + 1)
    a, b, c, d = at[:-1, :-1], at[1:, :-1], at[1:, 1:], at[:-1, 1:]
    # Wound so that cross(v1 - v0, v2 - v0) points down, the side that emits.
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    if tiny:
        vertices = np.vstack([vertices, [[300.0, 548.7, 300.0], [300.0 + 1e-6, 548.7, 300.0],
                                         [300.0 + 1e-6, 548.7, 300.0 + 1e-3]]])
        n = len(vertices)
        faces = np.vstack([[[n - 3, n - 2, n - 1]], faces])
    return vertices, faces


def _lamp_scene(lamp: tuple[np.ndarray, np.ndarray], camera: dict, spp: int,
                size: tuple[int, int], extra: list | None = None,
                specular: float = 0.2) -> M.Scene:
    vertices, faces = lamp
    data = {"render": {"width": size[0], "height": size[1], "spp": spp, "ambient": [0, 0, 0]},
            "camera": camera,
            "materials": {"floor": {"color": [0.5, 0.5, 0.5], "specular": specular},
                          "lamp": {"color": [0, 0, 0], "diffuse": 0, "emission": list(KE)}},
            "objects": [{"type": "mesh", "vertices": vertices.tolist(),
                         "faces": faces.tolist(), "material": "lamp"},
                        {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                         "material": "floor"}, *(extra or [])]}
    return scene_from_dict(data)


def _strip_scene(n_glow: int) -> tuple[M.Scene, M.Mesh]:
    """A strip of n_glow + 2 faces of area 1/2: faces 0 and 3 of material `other`, the rest of
    `glow`, both emissive."""
    n = n_glow + 2
    vertices = np.array([[i, 0.0, 0.0] for i in range(n + 1)] +
                        [[i, 0.0, 1.0] for i in range(n + 1)])
    faces = np.array([[i, i + n + 1, i + 1] for i in range(n)])
    mesh = M.Mesh(vertices, faces, 0, face_materials=np.array([int(i in (0, 3))
                                                              for i in range(n)]))
    materials = (M.Material("glow", emission=(1.0, 2.0, 3.0)),
                 M.Material("other", emission=(3.0, 2.0, 1.0)))
    return M.Scene(None, M.RenderOptions(8, 6), M.Camera((0.0, 2.0, 3.0), (0.0, 0.0, 0.0)),
                   materials, (), (mesh,)), mesh


def test_faces_beyond_the_limit_become_one_mesh_light():
    scene, _ = _strip_scene(EACH_FACE_UP_TO)
    assert emissive_lights(scene) == emissive_triangles(scene)  # each face its own light
    scene, mesh = _strip_scene(EACH_FACE_UP_TO + 1)
    lights = emissive_lights(scene)
    # One mesh light in the place of glow's first face (face 1), the other material's faces
    # (0 and 3) each in its own.
    assert [type(light) for light in lights] == [M.TriangleLight, M.MeshLight, M.TriangleLight]
    glow = [i for i in range(len(mesh.faces)) if i not in (0, 3)]
    np.testing.assert_array_equal(lights[1].corners, mesh.vertices[mesh.faces[glow]])
    assert lights[1].color == (1.0, 2.0, 3.0)
    faces = emissive_triangles(scene)
    assert [lights[0].vertices, lights[2].vertices] == [faces[0].vertices, faces[3].vertices]
    assert lights[0].color == lights[2].color == (3.0, 2.0, 1.0)


def test_picks_take_faces_by_area():
    vertices, faces = _grid_lamp(3, 2, tiny=True)
    lamp = M.MeshLight(vertices[faces])
    areas = lamp.areas
    thresholds = lamp.thresholds
    widths = np.diff(np.concatenate([[0], thresholds])).astype(np.float64)
    assert thresholds[-1] == 2**32 and widths[0] == 0  # the sliver: no picks at all
    np.testing.assert_allclose(widths / 2**32, areas / areas.sum(), atol=2**-32)
    # Each face's first and last pick take it; the sliver is never taken.
    picks = np.concatenate([[0], thresholds[:-1], thresholds[1:] - 1]).astype(np.uint64)
    face, weight = face_picked(lamp, picks)
    expected = np.concatenate([[1], np.arange(1, len(faces)), np.arange(1, len(faces))])
    np.testing.assert_array_equal(face, expected)
    np.testing.assert_array_equal(weight, 2**32 / widths[expected])


# About four times the measured (rmse 3.6e-8, largest error 3.1e-7 with each traversal; PoCL
# 3.1 and Intel's CPU runtime 2026.2, AMD EPYC): float32 rounding, the same face and point of
# it picked for every sample by the kernels and the reference.
MESH_LIGHT_TOLERANCE = Tolerance(rmse=1.5e-7, err=1.3e-6)


@pytest.mark.parametrize("traversal", ["single", "sample_packet", "group_packet"])
def test_mesh_light_matches_the_reference(cl_device, traversal):
    box = {"type": "box", "min": [200, 0, 200], "max": [300, 150, 300],
           "material": {"color": [0.2, 0.6, 0.9], "reflect": 0.3}}
    scene = _lamp_scene(_grid_lamp(6, 5, tiny=True),
                        {"position": [278, 400, -500], "look_at": [278, 200, 280]}, 8, (48, 36),
                        [box])
    assert [type(light) for light in scene_lights(scene)] == [M.MeshLight]
    assert_kernel_matches_reference(scene, MESH_LIGHT_TOLERANCE,
                                    RenderSettings(traversal=traversal))


def test_mesh_light_irradiance_matches_the_integral(cl_device):
    # As test_floor_irradiance_under_the_light_matches_the_integral, the light in 60 faces of
    # unequal areas sampled as one: each sample's one shadow ray estimates the same irradiance.
    below = [278.0, 0.0, 279.5]
    scene = _lamp_scene(_grid_lamp(6, 5), {"position": [278, 500, 279.5], "look_at": below,
                                           "up": [0, 0, 1], "vfov": 1}, 1024, (3, 3),
                        specular=0.0)
    result = render(scene)
    pixel = result.image[1, 1].astype(np.float64)
    np.testing.assert_allclose(pixel, 0.5 * np.array(KE) * _irradiance_under(below), rtol=0.02)
    # One shadow ray a sample for the 60 faces, not 60.
    assert result.stats["rays"]["shadow"] <= 9 * 1024


def _threshold_strip(pick: int, above: int) -> tuple[np.ndarray, np.ndarray]:
    """A strip of 17 faces 2 above the floor, all of width 1 but the first, whose width puts
    its threshold at pick + above."""
    share = (pick + above + 0.5) / 2**32
    x = np.concatenate([[0.0], 16 * share / (1 - share) + np.arange(17.0)])
    vertices = np.array([[xi, 2.0, z] for xi in x for z in (0.0, 1.0)])
    return vertices, np.array([[2 * k, 2 * k + 2, 2 * k + 1] for k in range(17)])


def test_a_pick_on_a_threshold_takes_the_next_face(cl_device):
    # The strip's first threshold is the very pick of the one pixel's one sample (seed 0,
    # pixel 0, sample 0, light 0): the pick takes face 1, the next, in the kernels as in the
    # reference (a pick takes the first face whose threshold is above it).
    pick = int(light_pick(0, np.array([0]), np.array([0]), 1, 0)[0])

    def strip_scene(above: int) -> M.Scene:
        vertices, faces = _threshold_strip(pick, above)
        assert M.MeshLight(vertices[faces]).thresholds[0] == pick + above
        below = [float(vertices[2, 0] + 0.5), 0.0, 0.5]  # under face 1
        return _lamp_scene((vertices, faces), {"position": [below[0], 1.0, -1.0],
                                               "look_at": below}, 1, (1, 1), specular=0.0)

    scene = strip_scene(0)
    assert face_picked(scene_lights(scene)[0], np.array([pick]))[0][0] == 1
    expected = render_reference(scene)
    np.testing.assert_allclose(render(scene).image, expected, rtol=1e-5)
    # One pick more of face 0 makes the sample face 0's: the floor point is lit otherwise, so
    # the comparison above tells the two faces apart.
    other = render_reference(strip_scene(1))
    assert expected[0, 0, 0] > 0 and other[0, 0, 0] > 0
    assert abs(other[0, 0, 0] / expected[0, 0, 0] - 1) > 0.1


@pytest.mark.parametrize("spp", [1, 5, 16, 64])
def test_picks_take_each_stratum_once(spp: int):
    # Each pixel's spp picks fall one in each 1/spp of the picks (so the samples share the
    # faces out by area), in an order of their own for every pixel and light.
    pixels = np.repeat(np.arange(50), spp)
    samples = np.tile(np.arange(spp), 50)
    strata = {}
    for light in (0, 3):
        picks = light_pick(7, pixels, samples, spp, light).astype(np.uint64)
        strata[light] = (picks * np.uint64(spp)) >> np.uint64(32)
        assert all(sorted(row) == list(range(spp))
                   for row in strata[light].reshape(50, spp).tolist())
        if spp >= 16:
            # An order of its own: a sample's pick stratum is not its square's (a shared
            # permutation would tie each part of the faces to one part of each face).
            square = permute_stratum(samples, spp, light_key(7, pixels, light))
            assert np.mean(strata[light] == square) < 0.2
    orders = strata[0].reshape(50, spp).argsort(axis=1)
    assert spp == 1 or len({tuple(row) for row in orders.tolist()}) > 1
    assert spp == 1 or np.mean(strata[0] == strata[3]) < 0.5


def test_a_last_face_holding_every_pick_weighs_one(cl_device):
    # 17 faces whose share of the area is under 2^-32 before one large face: every threshold
    # below the last is 0, the last face takes every pick with probability 1 (its width all
    # 2^32, which in uint32 arithmetic would wrap to 0 and weigh the sample 2^32 / 0).
    tiny = np.array([[[x, 548.7, 300.0], [x + 1e-4, 548.7, 300.0], [x, 548.7, 300.0 + 1e-4]]
                     for x in 213.0 + np.arange(17)])
    big = np.array([[[213.0, 548.7, 227.0], [343.0, 548.7, 227.0], [343.0, 548.7, 332.0]]])
    corners = np.concatenate([tiny, big])
    lamp = M.MeshLight(corners)
    assert list(lamp.thresholds) == [0] * 17 + [2**32]
    faces = np.arange(3 * len(corners)).reshape(-1, 3)
    vertices = corners.reshape(-1, 3)
    below = [300.0, 0.0, 250.0]
    scene = _lamp_scene((vertices, faces), {"position": [300, 300, 250], "look_at": below,
                                            "up": [0, 0, 1], "vfov": 1}, 4, (3, 3),
                        specular=0.0)
    assert [len(light.corners) for light in scene_lights(scene)] == [18]
    image = render(scene).image.astype(np.float64)
    expected = render_reference(scene)
    assert 0 < expected[1, 1, 0] < 1
    np.testing.assert_allclose(image, expected, rtol=1e-4, atol=1e-7)
