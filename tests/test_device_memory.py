"""Images of any size render within the device's limits, in bands of rows; scenes that cannot
fit the device are refused before any buffer is made."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from clray.device.launch import band_capacity
from clray.device.pack import pack_scene
from clray.errors import DeviceError
from clray.render import RenderSettings, render
from clray.scene import model as M

MIB = 1 << 20
# `clray.render` the attribute is the function; the module is needed for monkeypatching.
launch_module = importlib.import_module("clray.device.launch")


def _scene(width: int, height: int) -> M.Scene:
    return M.Scene(None, M.RenderOptions(width, height, 1, 0, (0.0, 0.0, 0.0)),
                   M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), vfov=40.0),
                   (M.Material("m"),), (M.PointLight((2.0, 3.0, 4.0)),),
                   (M.Sphere((0, 0, 0), 1, 0),))


def _packed(width: int, height: int):
    return pack_scene(_scene(width, height), width=width, height=height, spp=1, max_depth=0,
                      seed=0)


def test_band_fits_the_largest_allocation():
    packed = _packed(1024, 1024)  # 16 KiB a row per output buffer
    assert band_capacity(packed, global_mem=64 * MIB, max_alloc=16 * MIB) == 1024
    assert band_capacity(packed, global_mem=64 * MIB, max_alloc=15 * MIB) == 960


def test_band_fits_beside_the_scene_in_global_memory():
    packed = _packed(1024, 1024)
    room = 8 * MIB + sum(packed.device_bytes().values())
    # Two output buffers (radiance, ray counts) of 16 KiB a row share the 8 MiB.
    assert band_capacity(packed, global_mem=room, max_alloc=64 * MIB) == 256


def test_band_capacity_is_bounded_for_huge_images(monkeypatch):
    monkeypatch.setattr(launch_module, "MAX_BAND_BYTES", 1 * MIB)
    packed = _packed(16384, 16384)
    assert band_capacity(packed, global_mem=1 << 40, max_alloc=1 << 40) == 4


def test_scene_over_the_device_is_refused():
    packed = _packed(64, 64)
    scene_bytes = sum(packed.device_bytes().values())
    largest = max(packed.device_bytes().values())
    with pytest.raises(DeviceError, match=r"buffer needs .* over the device's largest"):
        band_capacity(packed, global_mem=1 << 30, max_alloc=largest - 1)
    with pytest.raises(DeviceError, match=r"scene needs .* leave for rendering"):
        band_capacity(packed, global_mem=scene_bytes + 100, max_alloc=1 << 30)


def test_image_in_small_bands_is_identical(cl_device, monkeypatch):
    scene = _scene(96, 40)
    whole = render(scene, RenderSettings(spp=2))
    # Three rows of 96 pixels a band: the bands, not the launches' timing, split the image.
    monkeypatch.setattr(launch_module, "MAX_BAND_BYTES", 3 * 96 * 16)
    banded = render(scene, RenderSettings(spp=2))
    assert banded.stats["launches"] >= 14
    np.testing.assert_array_equal(banded.image, whole.image)
    assert banded.stats["rays"] == whole.stats["rays"]
