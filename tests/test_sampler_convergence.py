"""Every sampled dimension is independent of the others: a pixel's estimate converges to the
pixel's exact value as 1 / sqrt(spp) or faster, for area lights and the thin lens, against
closed forms averaged over the pixel's footprint. A sampler that ties one dimension's strata
to another's (the light's stratum to the pixel's jitter cell, say) leaves each pixel a bias
of its own that no spp removes: the error and the difference between two seeds stop falling.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from clray.reference import camera_rays
from clray.render import RenderSettings, render
from clray.scene import model as M

N = 16  # image side, pixels: 256 pixels make each rms below good to about 5 %
SPPS = (64, 256, 1024, 4096)
SEEDS = (1, 2)
FOOTPRINT_SPP = 4096  # quadrature points per pixel for the exact pixel value (seed apart)
WHITE = M.Material("white", (1.0, 1.0, 1.0), diffuse=1.0)
BLACK = M.Material("black", (0.0, 0.0, 0.0), diffuse=0.0)

# ---------------------------------------------------------------------------------------------
# Area lights over a white Lambertian floor (diffuse 1, no ambient), seen from above by a
# perspective camera whose pixels each span about 0.1 of the floor, over which the irradiance
# changes by several per cent: the light sample's position and the pixel sample's must be
# independent for the estimate to converge.

L = 2.0
H_LIGHT = 1.5


def _rect_irradiance(p: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """E at floor points p (n, 3), normal +y, from a one-sided polygon light of radiance L
    (Lambert's formula): L / 2 sum_i gamma_i n . (v_i x v_i+1) / |v_i x v_i+1|, v_i from p to
    corner i, gamma_i the angle between v_i and v_i+1."""
    v = corners[None, :, :] - p[:, None, :]
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    w = np.roll(v, -1, axis=1)
    cross = np.cross(v, w)
    gamma = np.arccos(np.clip(np.sum(v * w, axis=-1), -1, 1))
    return L / 2 * np.abs(np.sum(gamma * cross[..., 1] / np.linalg.norm(cross, axis=-1),
                                 axis=-1))


def _disc_irradiance(p: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """E from a disc facing down onto a parallel floor (tests/test_area_lights.py)."""
    h2 = (centre[1] - p[:, 1]) ** 2
    r2 = (p[:, 0] - centre[0]) ** 2 + (p[:, 2] - centre[2]) ** 2
    rr = radius * radius
    return np.pi * L / 2 * (1 - (h2 + r2 - rr) / np.sqrt((h2 + r2 + rr) ** 2 - 4 * r2 * rr))


def _sphere_irradiance(p: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """E from a sphere wholly above the floor's horizon: pi L (R / d)^2 cos(alpha), alpha the
    angle between the floor's normal and the direction to the centre."""
    to_c = centre - p
    d = np.linalg.norm(to_c, axis=-1)
    return np.pi * L * (radius / d) ** 2 * to_c[:, 1] / d


RECT_CORNER, RECT_U, RECT_V = np.array([-0.5, H_LIGHT, -0.4]), np.array([0.9, 0, 0]), \
    np.array([0, 0, 0.7])
DISC_CENTRE, DISC_RADIUS = np.array([0.2, H_LIGHT, -0.1]), 0.5
SPHERE_CENTRE, SPHERE_RADIUS = np.array([0.1, H_LIGHT, 0.2]), 0.4

LIGHTS = {
    "rect": (M.RectLight(tuple(RECT_CORNER), tuple(RECT_U), tuple(RECT_V), (L,) * 3),
             lambda p: _rect_irradiance(p, np.array([RECT_CORNER, RECT_CORNER + RECT_U,
                                                     RECT_CORNER + RECT_U + RECT_V,
                                                     RECT_CORNER + RECT_V]))),
    "disc": (M.DiscLight(tuple(DISC_CENTRE), (0, -1, 0), DISC_RADIUS, (L,) * 3),
             lambda p: _disc_irradiance(p, DISC_CENTRE, DISC_RADIUS)),
    "sphere": (M.SphereLight(tuple(SPHERE_CENTRE), SPHERE_RADIUS, (L,) * 3),
               lambda p: _sphere_irradiance(p, SPHERE_CENTRE, SPHERE_RADIUS)),
}


def _light_scene(light: M.Light) -> M.Scene:
    return M.Scene(None, M.RenderOptions(N, N, 1, 0, (0, 0, 0), (0, 0, 0)),
                   M.Camera((0.0, 0.8, 0.0), (0.0, 0.0, 0.0), up=(0.0, 0.0, -1.0), vfov=90.0),
                   (WHITE,), (light,), (M.Plane((0, 0, 0), (0, 1, 0), 0),))


def _footprint(scene: M.Scene) -> tuple[np.ndarray, np.ndarray]:
    """(origins, directions) of FOOTPRINT_SPP pinhole rays per pixel, (N, N, spp, 3): the
    stratified jittered points at which the exact pixel value is averaged."""
    pinhole = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, aperture=0.0))
    o, d, _ = camera_rays(pinhole, spp=FOOTPRINT_SPP, seed=99)
    return o.reshape(N, N, FOOTPRINT_SPP, 3), d.reshape(N, N, FOOTPRINT_SPP, 3)


def _light_exact(scene: M.Scene, irradiance) -> np.ndarray:
    o, d = _footprint(scene)
    p = o - (o[..., 1:2] / d[..., 1:2]) * d
    return irradiance(p.reshape(-1, 3)).reshape(N, N, FOOTPRINT_SPP).mean(axis=-1)


# ---------------------------------------------------------------------------------------------
# The thin lens: a white background half hidden by a black half-plane (an infinitely thin
# triangle) across the view at depth Z_EDGE, its edge at 30 degrees, the lens focused at
# F_FOCUS. A pinhole ray's point q on the half-plane's plane becomes, through lens point l,
# q + l (1 - Z_EDGE / F_FOCUS): the lens disc scaled to the circle of confusion, radius rho.
# The pixel's value is 1 minus the part of that disc on the black side, averaged over the
# pixel's footprint.

Z_EDGE, F_FOCUS, APERTURE = 3.0, 1.0, 0.8
EDGE_NORMAL = np.array([-np.sin(np.radians(30)), np.cos(np.radians(30))])  # black where > 0


def _lens_scene() -> M.Scene:
    t = 1000 * np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    far = 1000 * EDGE_NORMAL
    tri = M.Triangle(((t[0], t[1], -Z_EDGE), (-t[0], -t[1], -Z_EDGE),
                      (far[0], far[1], -Z_EDGE)), 0)
    return M.Scene(None, M.RenderOptions(N, N, 1, 0, (1, 1, 1), (0, 0, 0)),
                   M.Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), vfov=40.0, aperture=APERTURE,
                            focus_distance=F_FOCUS),
                   (BLACK,), (M.PointLight((0, 0, 5)),), (tri,))


def _lens_exact(scene: M.Scene) -> np.ndarray:
    o, d = _footprint(scene)
    q = o + (Z_EDGE / -d[..., 2:3]) * d
    rho = APERTURE / 2 * abs(1 - Z_EDGE / F_FOCUS)
    # The part of the unit disc with n . u > s, s = -(n . q) / rho.
    s = np.clip(-(q[..., :2] @ EDGE_NORMAL) / rho, -1, 1)
    black = (np.arccos(s) - s * np.sqrt(1 - s * s)) / np.pi
    return 1 - black.mean(axis=-1)


def _exact_and_scene(case: str) -> tuple[np.ndarray, M.Scene]:
    if case == "lens":
        scene = _lens_scene()
        return _lens_exact(scene), scene
    light, irradiance = LIGHTS[case]
    scene = _light_scene(light)
    return _light_exact(scene, irradiance), scene


@pytest.mark.parametrize("case", ["rect", "disc", "sphere", "lens"])
def test_pixel_error_falls_as_one_over_sqrt_spp(cl_device, case: str) -> None:
    exact, scene = _exact_and_scene(case)
    # Pixels whose estimate varies: all of them under a light; in the lens's blur band only.
    varies = (exact > 1e-3) & (exact < 1 - 1e-3) if case == "lens" else exact > 0
    assert varies.sum() >= 100
    errors, seed_gaps = [], []
    for spp in SPPS:
        images = [render(scene, RenderSettings(spp=spp, seed=s)).image[..., 0].astype(np.float64)
                  for s in SEEDS]
        errors.append(np.sqrt(np.mean((images[0] - exact)[varies] ** 2)))
        seed_gaps.append(np.sqrt(np.mean((images[0] - images[1])[varies] ** 2)))
    errors, seed_gaps = np.array(errors), np.array(seed_gaps)
    report = f"rms error {errors}, two seeds' rms difference {seed_gaps} at spp {SPPS}"
    # 1 / sqrt(spp) is a fall of 2x per 4x spp; stratification may do better, never worse.
    # Each ratio is good to about 7 % (256 pixels), so 1.6 is far below 2 by chance alone.
    assert np.all(errors[:-1] / errors[1:] > 1.6), report
    assert np.all(seed_gaps[:-1] / seed_gaps[1:] > 1.6), report
