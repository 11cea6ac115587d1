"""The device policy (clray.device.policy.device_plan): what a render on each kind of device
builds, and the traversal schemes' table that KernelConfig's build options follow."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from clray.device import program
from clray.device.launch import render_packed
from clray.device.pack import pack_scene
from clray.device.policy import device_plan
from clray.device.program import (
    CORRECTLY_ROUNDED,
    GPU_BUILD_OPTIONS,
    KernelConfig,
    device_build_options,
)
from clray.errors import SettingsError
from clray.knobs import TRAVERSAL_SCHEMES, TRAVERSAL_TABLE, Tuning, TuningError
from clray.render import RenderSettings, pack_for, plan_for, resolved_settings
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent


def stand_in(platform: str, kind: int, floats: tuple[int, int],
             doubles: tuple[int, int]) -> SimpleNamespace:
    """A device as the policy sees it: its platform, type and (preferred, native) widths."""
    return SimpleNamespace(name="stand-in", platform=SimpleNamespace(name=platform), type=kind,
                           preferred_vector_width_float=floats[0],
                           native_vector_width_float=floats[1],
                           preferred_vector_width_double=doubles[0],
                           native_vector_width_double=doubles[1])


DEVICES = {
    "intel_cpu_avx2": stand_in("Intel(R) OpenCL", cl.device_type.CPU, (1, 8), (1, 4)),
    "pocl_avx2": stand_in("Portable Computing Language", cl.device_type.CPU, (8, 8), (4, 4)),
    "pocl_avx512": stand_in("Portable Computing Language", cl.device_type.CPU, (16, 16),
                            (8, 8)),
    "nvidia_gpu": stand_in("NVIDIA CUDA", cl.device_type.GPU, (1, 1), (1, 1)),
}
SPPS = (1, 4, 8, 16)


def choices(device: SimpleNamespace, precision: str, **options: object
            ) -> list[tuple[str, int | None, int]]:
    """(traversal, the build's packet lanes or None, BVH width) at each of SPPS."""
    plans = [device_plan(device, spp=spp, precision=precision, tuning=Tuning(), **options)
             for spp in SPPS]
    return [(p.traversal, p.switches.get("packet_lanes"), p.bvh_width) for p in plans]


# A device's own choices with the default knobs, as render.py's kernel_switches made them
# before the policy moved to clray.device.policy: sample packets on the CPU devices of PoCL
# and Intel's CPU runtime where a pixel's samples fill a packet (16 lanes on 8-wide devices
# from 16 spp), the single-ray walk at 1 spp and on GPUs; 8-wide BVH nodes where the
# arithmetic's vectors are 8 wide.
OWN = {
    ("intel_cpu_avx2", "float"): [("single", None, 8), ("single", None, 8),
                                  ("sample_packet", 8, 8), ("sample_packet", 16, 8)],
    ("intel_cpu_avx2", "double"): [("single", None, 4), ("sample_packet", 4, 4),
                                   ("sample_packet", 4, 4), ("sample_packet", 4, 4)],
    ("pocl_avx2", "float"): [("single", None, 8), ("single", None, 8),
                             ("sample_packet", 8, 8), ("sample_packet", 16, 8)],
    ("pocl_avx2", "double"): [("single", None, 4), ("sample_packet", 4, 4),
                              ("sample_packet", 4, 4), ("sample_packet", 4, 4)],
    ("pocl_avx512", "float"): [("single", None, 8), ("single", None, 8), ("single", None, 8),
                               ("sample_packet", 16, 8)],
    ("pocl_avx512", "double"): [("single", None, 8), ("single", None, 8),
                                ("sample_packet", 8, 8), ("sample_packet", 16, 8)],
    ("nvidia_gpu", "float"): [("single", None, 4)] * 4,
    ("nvidia_gpu", "double"): [("single", None, 4)] * 4,
}


@pytest.mark.parametrize(("device", "precision"), sorted(OWN))
def test_each_kind_of_device_gets_its_own_plan(device: str, precision: str) -> None:
    assert choices(DEVICES[device], precision) == OWN[device, precision]


def test_a_named_traversal_is_built_from_two_samples_a_pixel() -> None:
    # A scheme the settings name is used where a pixel has any samples to pack, on any device;
    # a scheme that packs no samples at every spp.
    intel, gpu = DEVICES["intel_cpu_avx2"], DEVICES["nvidia_gpu"]
    assert choices(intel, "float", traversal="sample_packet") == [
        ("single", None, 8), ("sample_packet", 8, 8), ("sample_packet", 8, 8),
        ("sample_packet", 16, 8)]
    assert choices(gpu, "float", traversal="sample_packet") == [
        ("single", None, 4), ("sample_packet", 4, 4), ("sample_packet", 4, 4),
        ("sample_packet", 4, 4)]
    assert choices(intel, "float", traversal="group_packet") == [("group_packet", None, 8)] * 4
    assert choices(gpu, "float", traversal="single") == [("single", None, 4)] * 4


def test_the_settings_traversal_overrides_the_tunings_and_the_knobs_act() -> None:
    intel = DEVICES["intel_cpu_avx2"]
    tuned = Tuning(traversal="sample_packet", packet_lanes=4, packet_min_lanes=3, bvh_width=4,
                   cl_mad_enable=True, sphere_textbook=True)
    plan = device_plan(intel, spp=16, tuning=tuned)
    assert plan.tuning_source == "given"
    assert (plan.traversal, plan.packet_lanes, plan.bvh_width) == ("sample_packet", 4, 4)
    assert plan.switches == {
        "traversal": "sample_packet", "packet_lanes": 4, "packet_min_lanes": 3,
        "implicit_vectorization": False, "sphere_textbook": True,
        "triangle_moller_trumbore": False, "fresnel_schlick": False,
        "build_options": ("-cl-mad-enable",), "passes": False}
    single = device_plan(intel, spp=16, tuning=tuned, traversal="single", passes=True,
                         variants=(("count_tests", True),))
    assert single.traversal == "single" and "packet_lanes" not in single.switches
    assert single.switches["passes"] and single.switches["count_tests"]
    # Implicit vectorization acts with the single-ray walk, and never with sample packets,
    # which Intel's CPU runtime renders wrongly with it (the device's own walk here at 16 spp).
    packing = Tuning(implicit_vectorization=True)
    assert device_plan(intel, spp=1, tuning=packing).switches["implicit_vectorization"]
    own = device_plan(intel, spp=16, tuning=packing)
    assert own.traversal == "sample_packet" and not own.switches["implicit_vectorization"]
    assert not device_plan(intel, spp=4, tuning=packing, traversal="sample_packet"
                           ).switches["implicit_vectorization"]
    with pytest.raises(SettingsError, match="packet_min_lanes 7 is not below the 4 packet "
                                            "lanes of 'stand-in' in float"):
        device_plan(DEVICES["nvidia_gpu"], spp=1, tuning=Tuning(packet_min_lanes=7),
                    traversal="sample_packet")


def test_every_schemes_build_takes_its_tables_defines() -> None:
    for scheme in TRAVERSAL_TABLE:
        options = KernelConfig(traversal=scheme.name, packet_lanes=16).options()
        assert f"-DTRAVERSAL=TRAVERSAL_{scheme.name.upper()}" in options
        own = {o for o in options if o.startswith("-DPACKET_")}
        assert own == {f"-D{name.upper()}={getattr(KernelConfig(packet_lanes=16), name)}"
                       for name in scheme.defines}, scheme.name
    # The knobs that act only with one scheme are refused with another (knobs.py).
    not_default = {"packet_lanes": 16, "packet_min_lanes": 0, "group_side": 8}
    for scheme in TRAVERSAL_TABLE:
        for name in scheme.knobs:
            for other in set(TRAVERSAL_SCHEMES) - {scheme.name}:
                with pytest.raises(TuningError, match=f"{name} .* acts only with traversal "
                                                      f"{scheme.name}"):
                    Tuning(traversal=other, **{name: not_default[name]})
            Tuning(traversal=scheme.name, **{name: not_default[name]})


def test_a_render_packs_what_its_plan_says(cl_device) -> None:
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    settings = RenderSettings(width=8, height=6, spp=16, aovs=("depth",), stored_tuning=False)
    plan = plan_for(scene, settings, cl_device)
    assert plan.tuning_source == "default" and plan.switches["passes"]
    packed = pack_for(scene, settings, cl_device)
    assert packed.config == pack_scene(scene, **resolved_settings(scene, settings),
                                       **plan.pack_arguments()).config
    assert (packed.config.traversal, packed.config.bvh_width) == (plan.traversal,
                                                                  plan.bvh_width)


def test_gpu_devices_are_built_as_gpus_whatever_their_compiler_defines() -> None:
    # A vendor's compiler need not define clang's __NVPTX__ or __AMDGCN__: the host says so.
    def device(kind: int, platform: str = "NVIDIA CUDA") -> SimpleNamespace:
        return SimpleNamespace(type=kind, platform=SimpleNamespace(name=platform))

    assert device_build_options(device(cl.device_type.GPU)) == GPU_BUILD_OPTIONS
    # Float division and square root correctly rounded where the GPU can do it.
    rounding = SimpleNamespace(type=cl.device_type.GPU, platform=SimpleNamespace(name="NVIDIA"),
                               single_fp_config=cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)
    assert device_build_options(rounding) == (*GPU_BUILD_OPTIONS, CORRECTLY_ROUNDED)

    # A driver that fails the query builds without the option rather than failing the render.
    class Unanswered(SimpleNamespace):
        @property
        def single_fp_config(self) -> int:
            raise cl.Error("clGetDeviceInfo failed: INVALID_VALUE")

    unanswered = Unanswered(type=cl.device_type.GPU, platform=SimpleNamespace(name="NVIDIA"))
    assert device_build_options(unanswered) == GPU_BUILD_OPTIONS
    assert device_build_options(device(cl.device_type.CPU, "Portable Computing Language")) == ()
    assert "-DSERIAL_WORK_ITEMS=0" not in device_build_options(device(cl.device_type.CPU,
                                                                      "Oclgrind"))
    # The tests' --gpu-build and Oclgrind's race check: a CPU device built as a GPU is, once.
    with program.built_as_for_a_gpu():
        assert device_build_options(device(cl.device_type.CPU, "Intel(R) OpenCL")) == \
            GPU_BUILD_OPTIONS
        assert device_build_options(device(cl.device_type.GPU)) == GPU_BUILD_OPTIONS
        assert device_build_options(device(cl.device_type.CPU, "Oclgrind"))[-1] == \
            GPU_BUILD_OPTIONS[0]
    assert device_build_options(device(cl.device_type.CPU, "Intel(R) OpenCL")) == ()


@pytest.mark.parametrize("scene_name, width, height, precision", [
    ("spheres", 64, 36, "float"), ("glass", 64, 36, "float"),
    # Row segments whose last camera rays fill only some of the lanes (kernels/camera.h,
    # row_directions), and the double build's lanes.
    ("spheres", 37, 20, "float"), ("spheres", 37, 20, "double")])
def test_the_gpu_build_renders_the_cpu_builds_image(cl_device: cl.Device, scene_name: str,
                                                     width: int, height: int,
                                                     precision: str) -> None:
    # The render kernel as a GPU builds it (a pixel a work-item, the renderer inlined, each
    # camera ray made alone), run on this CPU device: the same image, bit for bit, as the
    # CPU's build.
    if GPU_BUILD_OPTIONS[0] in device_build_options(cl_device):
        pytest.skip("this device's own build is already a GPU's (a GPU, or --gpu-build): "
                    "nothing to compare it with")
    scene = load_scene(ROOT / "scenes" / f"{scene_name}.toml")
    settings = RenderSettings(width=width, height=height, spp=1, precision=precision)
    cpu_image, _ = render_packed(pack_for(scene, settings, cl_device), cl_device)
    with program.built_as_for_a_gpu():
        gpu_image, _ = render_packed(pack_for(scene, settings, cl_device), cl_device)
    assert any(GPU_BUILD_OPTIONS[0] in options for *_, options in program._programs)
    assert np.array_equal(cpu_image, gpu_image, equal_nan=True)
