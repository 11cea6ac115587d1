"""The cl_device fixture's contract: code that picks the default device lands on the test's."""

from __future__ import annotations

import pyopencl as cl

from clray.device.context import describe, select_device
from clray.render import RenderSettings, render
from clray.scene import model as M


def test_default_device_is_the_parametrised_device(cl_device: cl.Device) -> None:
    assert select_device() == cl_device
    scene = M.Scene(None, M.RenderOptions(4, 3, 1, 0), M.Camera((0, 0, 5), (0, 0, 0)),
                    (M.Material("m"),), (), (M.Sphere((0, 0, 0), 1.0, 0),))
    assert render(scene, RenderSettings()).stats["device"] == describe(cl_device)
