"""GPU-shaped launch policy and device limits, checked without a GPU: whole warps a work-group,
a launch's arguments within the device's parameter size, resource errors that say what to
lower, and the device a render picks by default, said by `clray devices`."""

from __future__ import annotations

from types import SimpleNamespace

import pyopencl as cl
import pytest

from clray.device import context, launch
from clray.device.launch import check_argument_bytes, gpu_group_width
from clray.errors import DeviceError
from clray.knobs import Tuning


@pytest.mark.parametrize(("width", "limit", "multiple", "expected"), [
    (64, 1024, 32, 64),  # the default: two NVIDIA warps
    (48, 1024, 32, 32),  # rounded down to whole warps
    (16, 1024, 32, 32),  # at least one warp
    (16, 1024, 64, 64),  # an AMD wavefront
    (128, 96, 32, 96),  # the kernel's limit (already applied to width by the caller) stands
    (16, 24, 32, 16),  # a kernel whose limit is under a warp keeps the knob's width
    (16, 1024, 1, 16),  # no preference
])
def test_gpu_groups_are_whole_warps(width, limit, multiple, expected) -> None:
    assert gpu_group_width(min(width, limit), limit, multiple) == expected


def fake_device(parameter_bytes: int, address_bits: int = 64) -> SimpleNamespace:
    return SimpleNamespace(max_parameter_size=parameter_bytes, address_bits=address_bits,
                           name="Tiny GPU", driver_version="1.0",
                           platform=SimpleNamespace(name="Fake"))


def test_launch_arguments_within_the_parameter_size() -> None:
    check_argument_bytes(60, 1, fake_device(1024))  # 484 bytes
    check_argument_bytes(127, 1, fake_device(1024))  # 1,020 bytes
    with pytest.raises(DeviceError, match=r"128 buffers and 1 ints take 1028 bytes of "
                                          r"arguments, over Tiny GPU .* of 1024"):
        check_argument_bytes(128, 1, fake_device(1024))
    check_argument_bytes(128, 1, fake_device(1024, address_bits=32))


def test_the_render_kernels_arguments_fit_any_device() -> None:
    # OpenCL guarantees 1,024 bytes of arguments on every device: the render kernel with every
    # scene buffer must fit them with 64-bit pointers.
    from clray.device.layout import SCENE_BUFFERS

    check_argument_bytes(len(SCENE_BUFFERS) + 3, 1, fake_device(1024))


def _packed(traversal: str, max_depth: int, **knobs: int) -> SimpleNamespace:
    """What _resource_hint reads of a PackedScene."""
    return SimpleNamespace(config=SimpleNamespace(traversal=traversal),
                           params=[{"max_depth": max_depth}], tuning=Tuning(**knobs))


@pytest.mark.parametrize("code", ["OUT_OF_RESOURCES", "INVALID_WORK_GROUP_SIZE"])
def test_resource_errors_say_what_to_lower(code) -> None:
    err = SimpleNamespace(code=getattr(cl.status_code, code))
    hint = launch._resource_hint(err, _packed("sample_packet", 5), tiles=False)
    assert hint == ("; the kernel needs more registers or private memory than the device has "
                    "for a group: render with a smaller work_group_width (now 64; a tuning "
                    "knob: clray.RenderSettings(tuning=Tuning(work_group_width=N)) in Python, "
                    "or the device's tuning file, docs/tuning.md), a lower --max-depth (now 5), "
                    "or --traversal single")


def test_a_resource_hint_leaves_out_what_the_render_already_does() -> None:
    # Already the single-ray walk, no bounces, one work-item a group: nothing left to lower.
    err = SimpleNamespace(code=cl.status_code.OUT_OF_RESOURCES)
    assert launch._resource_hint(err, _packed("single", 0, work_group_width=1),
                                 tiles=False) == (
        "; the kernel needs more registers or private memory than the device has for a group")
    # Group packets' tile is group_side x group_side, whatever work_group_width says.
    hint = launch._resource_hint(err, _packed("group_packet", 2, group_side=8), tiles=True)
    assert "group_side (now 8" in hint and "work_group_width" not in hint
    assert "group_side" not in launch._resource_hint(err, _packed("group_packet", 2),
                                                     tiles=True)


def test_other_opencl_errors_have_no_resource_hint() -> None:
    err = SimpleNamespace(code=cl.status_code.INVALID_VALUE)
    assert launch._resource_hint(err, _packed("sample_packet", 5), tiles=False) == ""


def test_the_default_device_and_why(cl_device, monkeypatch) -> None:
    monkeypatch.delenv("CLRAY_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    device, spec, why = context.default_device()
    types = {d.spec: d.type for d in context.list_devices()}
    if any(context.is_discrete_gpu(d) for _, d in context._all_devices()):
        assert types[spec] == "GPU" and context.is_discrete_gpu(device)
    elif "CPU" in types.values():
        cpus = [d for d in context.list_devices() if d.type == "CPU"]
        pocl = [d.spec for d in cpus if d.platform == context.POCL_PLATFORM]
        assert spec == (pocl[0] if pocl else cpus[0].spec)
        assert why.startswith("PoCL's CPU device" if pocl else "the first CPU device")
    assert context.select_device() == device
    monkeypatch.setenv("CLRAY_DEVICE", spec)
    assert context.default_device()[1:] == (spec, f"CLRAY_DEVICE={spec}")


def _listed(*kinds: tuple[str, int, bool]) -> list[tuple[str, SimpleNamespace]]:
    """Devices as _all_devices lists them, from (type, compute units, host unified memory)."""
    flags = {"CPU": cl.device_type.CPU, "GPU": cl.device_type.GPU,
             "ACCELERATOR": cl.device_type.ACCELERATOR, "ALL": cl.device_type.ALL}
    platform = SimpleNamespace(name="Platform", vendor="Vendor", version="OpenCL 3.0")
    return [(f"{i}:0", SimpleNamespace(type=flags[kind], max_compute_units=units,
                                       host_unified_memory=unified, name=f"device {i}",
                                       platform=platform))
            for i, (kind, units, unified) in enumerate(kinds)]


@pytest.mark.parametrize(("kinds", "chosen", "why"), [
    ((("CPU", 16, True), ("GPU", 132, False)), "1:0", "a GPU with its own memory"),
    ((("CPU", 16, True), ("GPU", 24, False), ("GPU", 132, False)), "2:0", "a GPU"),
    ((("GPU", 24, True), ("CPU", 16, True)), "1:0", "the first CPU device"),
    ((("ACCELERATOR", 4, False), ("CPU", 2, True), ("CPU", 8, True)), "1:0", "the first CPU"),
    ((("GPU", 24, True),), "0:0", "the first device: there is no CPU device"),
    # Oclgrind's simulator says it is every type, and shares no memory with the host.
    ((("ALL", 1, False), ("CPU", 2, True)), "0:0", "the first CPU device"),
])
def test_a_gpu_of_its_own_memory_renders_by_default(monkeypatch, kinds, chosen, why) -> None:
    # Issue 41: where a GPU is present and measured faster, a user need not know --device. An
    # integrated GPU (sharing the host's memory) is not measured, and the CPU stays the default.
    monkeypatch.delenv("CLRAY_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    listed = _listed(*kinds)
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    device, spec, reason = context.default_device()
    assert spec == chosen and device is dict(listed)[chosen] and reason.startswith(why)


@pytest.mark.parametrize(("kinds", "spec", "chosen"), [
    # A GPU of its own memory with the most compute units before an integrated one, as by
    # default; the first CPU; the type words in any case, with spaces about them.
    ((("CPU", 16, True), ("GPU", 24, True), ("GPU", 132, False)), "gpu", "2:0"),
    ((("CPU", 16, True), ("GPU", 24, True), ("GPU", 132, False)), " GPU ", "2:0"),
    ((("GPU", 24, True), ("CPU", 16, True), ("CPU", 8, True)), "cpu", "1:0"),
    ((("GPU", 24, True), ("CPU", 16, True)), "gpu", "0:0"),
    ((("CPU", 16, True), ("ACCELERATOR", 4, False)), "Accelerator", "1:0"),
])
def test_a_device_type_names_the_first_device_of_that_type(monkeypatch, kinds, spec,
                                                            chosen) -> None:
    # docs/cli.md's `--device cpu` and docs/distributed.md's CLRAY_DEVICE=gpu: no device's
    # name holds the word.
    listed = _listed(*kinds)
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    assert context.select_device(spec) is dict(listed)[chosen]


def test_a_device_type_that_no_device_has_is_one_line(monkeypatch) -> None:
    monkeypatch.setattr(context, "_all_devices", lambda: _listed(("CPU", 16, True)))
    with pytest.raises(DeviceError, match=r"^no OpenCL GPU device matches 'gpu' \(devices: "
                                          r"0:0 CPU device 0\)$"):
        context.select_device("gpu")


@pytest.mark.parametrize("blank", ["", " ", "\t "])
def test_a_blank_device_spec_is_no_spec(monkeypatch, blank) -> None:
    # Not a substring that every name holds: a blank CLRAY_DEVICE or --device leaves the
    # choice to PYOPENCL_CTX and the default order.
    listed = _listed(("CPU", 16, True), ("CPU", 8, True))
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    monkeypatch.setenv("CLRAY_DEVICE", blank)
    monkeypatch.setenv("PYOPENCL_CTX", "1:0")
    assert context.default_device()[1:] == ("1:0", "PYOPENCL_CTX=1:0")
    assert context.select_device(blank) is listed[1][1]
    monkeypatch.setenv("PYOPENCL_CTX", blank)
    assert context.default_device()[1:] == ("0:0", "the first CPU device")


def test_clray_devices_marks_the_default(cl_device, capsys) -> None:
    from clray import cli

    assert cli.main(["devices"]) == 0
    lines = capsys.readouterr().out.splitlines()
    marked = [line for line in lines if "renders by default" in line]
    assert len(marked) == 1
    # The suite names the test's device in CLRAY_DEVICE.
    assert cl_device.name.strip() in marked[0] and "(CLRAY_DEVICE=" in marked[0]


POCL = "Portable Computing Language"
INTEL = "Intel(R) OpenCL"


def _named(*devices: tuple[str, str, str]) -> list[tuple[str, SimpleNamespace]]:
    """Devices as _all_devices lists them, from (spec, platform name, device name): CPUs, one
    platform object per platform index, PoCL's with its own vendor and version."""
    platforms: dict[str, SimpleNamespace] = {}
    listed = []
    for spec, platform_name, name in devices:
        pocl = platform_name == POCL
        platform = platforms.setdefault(spec.split(":")[0], SimpleNamespace(
            name=platform_name, vendor="The pocl project" if pocl else "Vendor",
            version="OpenCL 3.0 PoCL 5.0" if pocl else "OpenCL 3.0"))
        listed.append((spec, SimpleNamespace(type=cl.device_type.CPU, max_compute_units=2,
                                             host_unified_memory=True, name=name,
                                             platform=platform)))
    return listed


# PoCL's CPU device is named for the CPU's brand, as Intel's CPU runtime's device is.
XEON = (("0:0", POCL, "pthread-skylake-avx512-Intel(R) Xeon(R) Gold 6248"),
        ("1:0", INTEL, "Intel(R) Xeon(R) Gold 6248"))
TWO_CARDS = (("0:0", "NVIDIA CUDA", "NVIDIA GeForce RTX 3080"),
             ("0:1", "NVIDIA CUDA", "NVIDIA GeForce RTX 4090"),
             ("1:0", POCL, "pthread-haswell-AMD EPYC"))


@pytest.mark.parametrize(("devices", "spec", "chosen"), [
    # A platform's name before a device's: `--device intel` is Intel's CPU runtime, which
    # README and docs/acceleration.md measure with it.
    (XEON, "intel", "1:0"), (XEON, "INTEL", "1:0"),
    # `pocl` is in PoCL's vendor and version only.
    (XEON, "pocl", "0:0"), (XEON, "skylake", "0:0"),
    # Several devices of one platform: the first.
    (TWO_CARDS, "nvidia", "0:0"), (TWO_CARDS, "rtx", "0:0"),
    # A bare number is a platform index where that platform is there, else a name's part.
    (TWO_CARDS, "4090", "0:1"), (TWO_CARDS, "1", "1:0"), (TWO_CARDS, "0:1", "0:1"),
])
def test_a_name_prefers_the_platform_then_the_device(monkeypatch, devices, spec,
                                                     chosen) -> None:
    listed = _named(*devices)
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    assert context.select_device(spec) is dict(listed)[chosen]


def test_a_name_that_several_platforms_hold_alike_is_an_error(monkeypatch) -> None:
    monkeypatch.setattr(context, "_all_devices", lambda: _named(*XEON))
    with pytest.raises(DeviceError, match=(
            r"^'xeon' matches devices on several platforms alike: "
            r"0:0 pthread-skylake-avx512-Intel\(R\) Xeon\(R\) Gold 6248 "
            r"\(Portable Computing Language\), 1:0 Intel\(R\) Xeon\(R\) Gold 6248 "
            r"\(Intel\(R\) OpenCL\); expected a spec that names one, such as P:D$")):
        context.select_device("xeon")


def test_a_number_that_no_name_holds_is_quoted_as_typed(monkeypatch) -> None:
    monkeypatch.setattr(context, "_all_devices", lambda: _named(*TWO_CARDS))
    with pytest.raises(DeviceError, match=r"^no OpenCL device matches '7' \(devices: 0:0 "):
        context.select_device("7")


THREE_PLATFORMS = (("0:0", POCL, "pthread-haswell-AMD EPYC"),
                   ("1:0", "AMD Accelerated Parallel Processing", "gfx1100"),
                   ("1:1", "AMD Accelerated Parallel Processing", "gfx1030"),
                   ("2:0", INTEL, "AMD EPYC"))


@pytest.mark.parametrize(("value", "chosen"), [
    # pyopencl's own forms (choose_devices): each part an index where it is an integer in
    # range, else a case-insensitive part of the platform's or the device's name.
    ("Intel:0", "2:0"), ("portable:0", "0:0"), ("1:gfx1030", "1:1"), ("1:GFX1100", "1:0"),
    ("amd accelerated:1", "1:1"), ("1", "1:0"), ("Intel", "2:0"), ("1:", "1:0"),
    ("2:0", "2:0"), ("1:1,0", "1:1"),
])
def test_pyopencl_ctx_is_read_as_pyopencl_reads_it(monkeypatch, value, chosen) -> None:
    listed = _named(*THREE_PLATFORMS)
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    monkeypatch.delenv("CLRAY_DEVICE", raising=False)
    monkeypatch.setenv("PYOPENCL_CTX", value)
    device, spec, why = context.default_device()
    assert (spec, why) == (chosen, f"PYOPENCL_CTX={value}")
    assert device is dict(listed)[chosen]


@pytest.mark.parametrize(("value", "message"), [
    ("nvidia:0", r"^PYOPENCL_CTX='nvidia:0': no OpenCL platform matches 'nvidia' \(platforms: "
                 r"0 Portable Computing Language, 1 AMD Accelerated Parallel Processing, "
                 r"2 Intel\(R\) OpenCL\)$"),
    ("1:7", r"^PYOPENCL_CTX='1:7': no device of platform 1 \(AMD Accelerated Parallel "
            r"Processing\) matches '7' \(devices: 0 gfx1100, 1 gfx1030\)$"),
    ("0:0:0", r"^PYOPENCL_CTX='0:0:0': expected PLATFORM or PLATFORM:DEVICE"),
])
def test_a_pyopencl_ctx_that_names_nothing_is_one_line(monkeypatch, value, message) -> None:
    monkeypatch.setattr(context, "_all_devices", lambda: _named(*THREE_PLATFORMS))
    monkeypatch.delenv("CLRAY_DEVICE", raising=False)
    monkeypatch.setenv("PYOPENCL_CTX", value)
    with pytest.raises(DeviceError, match=message):
        context.default_device()


def test_without_a_gpu_pocls_cpu_device_renders_by_default(monkeypatch) -> None:
    # README: "else on PoCL's CPU device", whichever order the ICD loader lists platforms in.
    monkeypatch.delenv("CLRAY_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    listed = _named(("0:0", INTEL, "Intel(R) Xeon(R) Gold 6248"),
                    ("1:0", POCL, "pthread-skylake-avx512-Intel(R) Xeon(R) Gold 6248"))
    monkeypatch.setattr(context, "_all_devices", lambda: listed)
    device, spec, why = context.default_device()
    assert (spec, device) == ("1:0", listed[1][1]) and why.startswith("PoCL's CPU device")
    assert context.select_device("cpu") is listed[1][1]
