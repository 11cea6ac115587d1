"""The hard-case suite: every case renders in the default float build and the double build,
with no non-finite pixel, within a time limit, meeting its own analytic expectation, and within
its stated float-vs-double allowance. Cases the loader cannot render well must warn."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from cases import CASES, HardCase, export_scenes

from clray import metrics
from clray.errors import SceneError
from clray.render import RenderSettings, render
from clray.scene.load import scene_from_dict
from clray.scene.model import Scene

# No case is anywhere near this on 2 cores; a hang (an unbounded loop in a kernel) is a failure.
RENDER_TIMEOUT_S = 120
STUDY_SCENES = Path(__file__).resolve().parents[2] / "docs" / "study" / "scenes"


def _render(scene: Scene, precision: str) -> np.ndarray:
    with ThreadPoolExecutor(max_workers=1) as pool:
        future = pool.submit(render, scene, RenderSettings(precision=precision))
        return future.result(timeout=RENDER_TIMEOUT_S).image


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize("case", [pytest.param(c, id=c.name, marks=[pytest.mark.slow]
                                               if c.slow else []) for c in CASES])
def test_hard_case(case: HardCase, cl_device: cl.Device) -> None:
    scene = scene_from_dict(case.scene)
    if case.warns is None:
        assert scene.warnings == (), scene.warnings
    else:
        assert any(case.warns in w for w in scene.warnings), scene.warnings
    image = _render(scene, "float")
    assert metrics.nonfinite_count(image) == 0
    double = _render(scene, "double")
    assert metrics.nonfinite_count(double) == 0
    case.check(double, scene)
    if case.float_checked:
        case.check(image, scene)
    if case.max_off >= 0:
        off = metrics.count_over(image, double, 2 / 255)
        assert off <= case.max_off, f"float vs double: {off} pixels off by > 2/255"


@pytest.mark.parametrize(("kind", "key", "value"), [
    ("sphere", "radius", 0), ("cylinder", "height", 0), ("cone", "height", 0),
    ("plane", "normal", [0, 0, 0]), ("cylinder", "axis", [0, 0, 0]),
])
def test_degenerate_inputs_are_scene_errors(kind: str, key: str, value: object) -> None:
    spec = {"sphere": {"center": [0, 0, 0], "radius": 1},
            "plane": {"point": [0, 0, 0], "normal": [0, 1, 0]},
            "cylinder": {"base": [0, 0, 0], "axis": [0, 1, 0], "radius": 1, "height": 1},
            "cone": {"apex": [0, 0, 0], "axis": [0, 1, 0], "angle": 30, "height": 1}}[kind]
    data = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
            "objects": [{"type": kind, **spec, key: value}]}
    with pytest.raises(SceneError, match=key):
        scene_from_dict(data)


def test_study_scene_files_match_the_cases(tmp_path: Path) -> None:
    # The shipped report renders these files; they must be the scenes this suite checks.
    for path in export_scenes(tmp_path):
        shipped = STUDY_SCENES / path.name
        assert shipped.exists(), f"regenerate docs/study/scenes: {path.name} is missing"
        assert json.loads(shipped.read_text()) == json.loads(path.read_text()), path.name
