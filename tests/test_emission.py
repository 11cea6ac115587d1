"""Emissive faces: a mesh face whose material emits (MTL Ke) is seen with that radiance and
lights the scene as an area light sampled by area. The kernels match the float64 reference, and
the irradiance under the Cornell box's light matches a numerical integral over the light."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clray.render import render
from clray.scene import model as M
from clray.scene.emitters import emissive_triangles
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
    # Midpoint rule over a fine grid of the light: E = L * sum cos cos' / r^2 dA.
    n = 400
    x = 213 + (np.arange(n) + 0.5) * 130 / n
    z = 227 + (np.arange(n) + 0.5) * 105 / n
    gx, gz = np.meshgrid(x - below[0], z - below[2])
    h = 548.7
    r2 = gx**2 + gz**2 + h**2
    irradiance = np.sum(h * h / (r2 * r2)) * (130 / n) * (105 / n)
    np.testing.assert_allclose(pixel, 0.5 * np.array(KE) * irradiance, rtol=0.02)


def test_emissive_faces_match_the_reference(cl_device, tmp_path):
    box = {"type": "box", "min": [200, 0, 200], "max": [300, 150, 300],
           "material": {"color": [0.2, 0.6, 0.9], "reflect": 0.3}}
    scene = light_scene(tmp_path, {"position": [278, 400, -500], "look_at": [278, 200, 280]},
                        4, (48, 36), [box])
    # Four times the measured (rmse 3.5e-8, largest error 3.2e-7; PoCL 3.1, AMD EPYC).
    assert_kernel_matches_reference(scene, Tolerance(rmse=1.5e-7, err=1.3e-6))
