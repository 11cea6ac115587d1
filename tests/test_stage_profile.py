"""The stage-profiling build (KernelConfig.stage_profile, benchmarks/stages.py) counts the
renderer's stages as functions of their own: it must render what the normal build renders, or
its counts would describe another computation."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from conftest import module_from_file

from clray.device.launch import render_packed
from clray.device.pack import pack_scene
from clray.device.program import kernel_source
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[1]


def _stages() -> tuple[str, ...]:
    return module_from_file(ROOT / "benchmarks" / "stages.py", "stages").STAGES


def test_every_counted_stage_is_a_stage_function():
    # benchmarks/stages.py looks these names up in the profile: each must be marked STAGE, or
    # it would be inlined in the profiling build too and counted as nothing. OUT_OF_LINE ones
    # (the sample packets' walks, out of line in every build for the cold build) count too.
    source = kernel_source()
    for stage in _stages():
        assert re.search(rf"^(STAGE|OUT_OF_LINE) \w+ {stage}\(", source, re.MULTILINE), stage


def test_every_stage_function_is_counted():
    # The other way round: a function marked STAGE that stages.py does not name would be a
    # function of its own in the profiling build, its instructions counted by no stage.
    marked = set(re.findall(r"^STAGE \w+ (\w+)\(", kernel_source(), re.MULTILINE))
    assert marked and marked <= set(_stages()), sorted(marked - set(_stages()))


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize("traversal", ["single", "sample_packet"])
@pytest.mark.parametrize("name", ["spheres", "textured"])
def test_stage_profile_build_renders_the_same_image(cl_device: cl.Device, name: str,
                                                    traversal: str):
    if not cl_device.platform.name.startswith("Portable Computing Language"):
        # A compiler may contract a * b + c into fma differently once a stage is no longer
        # inlined into its caller; PoCL does not contract.
        pytest.skip("bit-exact equality of the two builds is checked on PoCL")
    scene = load_scene(ROOT / "scenes" / f"{name}.toml")
    packed = pack_scene(scene, width=24, height=16, spp=4, max_depth=scene.render.max_depth,
                        seed=scene.render.seed, traversal=traversal)
    profiled = dataclasses.replace(packed, config=dataclasses.replace(packed.config,
                                                                      stage_profile=True))
    normal_image, normal_stats = render_packed(packed, cl_device)
    profiled_image, profiled_stats = render_packed(profiled, cl_device)
    assert normal_stats["rays"]["total"] > normal_stats["rays"]["primary"]
    assert normal_stats["rays"] == profiled_stats["rays"]
    assert np.array_equal(normal_image, profiled_image)
