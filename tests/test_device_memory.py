"""Renders that cannot fit the device are refused before any buffer is made."""

from __future__ import annotations

import pytest

from clray.device.pack import pack_scene
from clray.errors import DeviceError
from clray.render import check_device_memory
from clray.scene import model as M

MIB = 1 << 20


def _packed(width: int, height: int):
    scene = M.Scene(None, M.RenderOptions(width, height, 1, 0, (0.0, 0.0, 0.0)),
                    M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), vfov=40.0),
                    (M.Material("m"),), (), (M.Sphere((0, 0, 0), 1, 0),))
    return pack_scene(scene, width=width, height=height, spp=1, max_depth=0, seed=0)


def test_image_over_the_largest_allocation_is_refused():
    packed = _packed(1024, 1024)  # 16 MiB per image buffer
    check_device_memory(packed, global_mem=64 * MIB, max_alloc=16 * MIB)
    with pytest.raises(DeviceError, match=r"image buffer needs 16 MiB, over .* \(15 MiB\)"):
        check_device_memory(packed, global_mem=64 * MIB, max_alloc=15 * MIB)


def test_total_over_global_memory_is_refused():
    packed = _packed(1024, 1024)  # two 16 MiB buffers and a small scene
    with pytest.raises(DeviceError, match=r"needs 32 MiB of device memory, over .* 31 MiB"):
        check_device_memory(packed, global_mem=31 * MIB, max_alloc=64 * MIB)
    check_device_memory(packed, global_mem=33 * MIB, max_alloc=64 * MIB)
