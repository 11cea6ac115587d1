"""Shadow rays aimed from where they start: a point light lying on a surface."""

from __future__ import annotations

import numpy as np
import pytest

from clray.reference import render_reference
from clray.render import RenderSettings, render
from clray.scene import model as M

W, H = 64, 48


def _light_on_floor(light_y: float) -> M.Scene:
    """A sphere above a floor, lit from below by a point light lying in the floor plane (or,
    for the control, a little above it)."""
    materials = (M.Material("floor", (0.8, 0.8, 0.8), ambient=0.1, diffuse=0.8),
                 M.Material("ball", (0.9, 0.3, 0.2), ambient=0.1, diffuse=0.8))
    objects = (M.Plane((0, 0, 0), (0, 1, 0), 0), M.Sphere((0, 0.9, 0), 0.6, 1))
    lights = (M.PointLight((0.3, light_y, 0.4), (1.0, 1.0, 1.0), (1.0, 0.0, 0.0)),)
    camera = M.Camera((0.0, 0.12, 2.2), (0.0, 0.7, 0.0), vfov=50.0)
    return M.Scene(None, M.RenderOptions(W, H, 1, 0, (0.0, 0.0, 0.0)), camera, materials,
                   lights, objects)


@pytest.mark.parametrize("light_y", [0.0, 1e-3])
def test_point_light_in_a_surface_lights_what_faces_it(cl_device, light_y):
    # The ball's underside faces the light. Aimed along the direction from the un-offset hit
    # point, a shadow ray passes beside a light lying in the floor and crosses the floor just
    # before it: a black band. Aimed from its own origin it ends short of the light.
    scene = _light_on_floor(light_y)
    image = render(scene, RenderSettings()).image
    expected = render_reference(scene)
    lit = expected.max(axis=-1) > 0.12  # the light adds to the ambient term (at most 0.09)
    assert lit.sum() > 100
    off = np.abs(image - expected).max(axis=-1) > 2 / 255
    assert not np.any(off & lit), f"{int((off & lit).sum())} lit pixels differ"
