"""Scenes from Python (clray.scene_from_dict with numpy arrays, the model's dataclasses checked
by clray.scene.check) are untrusted input as scene files are: whatever a field or key holds,
a bad value is one SceneError naming where, never another exception, and a loaded scene keeps
no array its caller can still change."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from clray.errors import SceneError
from clray.scene import model as M
from clray.scene.check import check_scene

CAMERA = M.Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0))
SPHERE = M.Sphere((0.0, 0.0, 0.0), 1.0, 0)


def _scene(**fields: Any) -> M.Scene:
    base: dict[str, Any] = {"path": None, "render": M.RenderOptions(width=8, height=6),
                            "camera": CAMERA, "materials": (M.Material("m"),), "lights": (),
                            "objects": (SPHERE,)}
    return M.Scene(**(base | fields))


def _refused(scene: Any, message: str) -> None:
    with pytest.raises(SceneError) as info:
        check_scene(scene)
    assert str(info.value).startswith(message), str(info.value)


# -- the dataclasses: names -----------------------------------------------------------------

def test_a_nameless_material_does_not_take_the_place_of_one_named_like_its_fallback() -> None:
    red = M.Material("material 1", color=(1.0, 0.0, 0.0), ambient=1.0, diffuse=0.0)
    green = M.Material("", color=(0.0, 1.0, 0.0), ambient=1.0, diffuse=0.0)
    checked = check_scene(_scene(materials=(red, green)))
    assert [m.color for m in checked.materials] == [red.color, green.color]
    assert checked.objects[0].material == 0


def test_a_group_named_like_another_groups_fallback_is_kept() -> None:
    one = M.Group("group 1", (M.Sphere((0.0, 0.0, 0.0), 1.0, 0),))
    unnamed = M.Group("", (M.Sphere((0.0, 0.0, 0.0), 2.0, 0),))
    place = np.eye(3, 4)
    checked = check_scene(_scene(objects=(M.Instance(one, place), M.Instance(unnamed, place))))
    assert [obj.group.objects[0].radius for obj in checked.objects] == [1.0, 2.0]
