"""The cold build compiles the single-ray renderer once (issue 42, docs/acceleration.md: The
kernel's body compiled once). PoCL inlines a kernel into its work-item loop and that loop into
two work-group functions, so a renderer inlined into the render kernel was compiled three
times at the first launch; the row-segment loop `render_segment`, out of line with the
renderer inlined into it, is compiled once (The single-ray render's row segments). Checked in the
machine code PoCL keeps: a cold build and first launch of the spheres scene in a new process
with an empty kernel cache (benchmarks/cold_build.py's child), then the symbols of the
render kernel's `render.so`."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pyopencl as cl
import pytest

from clray.device import program as program_module
from clray.device.context import context_for
from clray.device.program import KernelConfig, build_program, kernel_source

ROOT = Path(__file__).resolve().parent.parent


def _symbol_sizes(library: Path) -> dict[str, int]:
    """name -> bytes of each sized symbol, as `nm -S` lists them."""
    out = subprocess.run(["nm", "-S", str(library)], capture_output=True, text=True,
                         check=True).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4:
            sizes[parts[3]] = int(parts[1], 16)
    return sizes


def test_single_ray_renderer_is_compiled_once(cl_device: cl.Device, tmp_path: Path) -> None:
    if cl_device.platform.name.strip() != "Portable Computing Language":
        pytest.skip("the work-group functions and their kept files are PoCL's")
    if shutil.which("nm") is None:
        pytest.skip("needs nm (binutils)")
    env = dict(os.environ, POCL_CACHE_DIR=str(tmp_path),
               POCL_LEAVE_KERNEL_COMPILER_TEMP_FILES="1")
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "cold_build.py"),
                           "--child", str(ROOT / "scenes" / "spheres.toml")],
                          capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    assert "TRAVERSAL=TRAVERSAL_SINGLE" in " ".join(json.loads(done.stdout.splitlines()[-1])
                                                    ["options"])
    libraries = list(tmp_path.glob("*/*/render/*/render.so"))
    assert len(libraries) == 1, libraries
    sizes = _symbol_sizes(libraries[0])
    assert "render_segment" in sizes, "the renderer was inlined into the render kernel"
    kernels = {name: size for name, size in sizes.items()
               if name.startswith("_pocl_kernel_render")}
    assert len(kernels) >= 2, sizes
    # Each of PoCL's functions holds the work-item loop and a call, not a copy of the
    # renderer: 460 to 920 bytes against render_segment's 8,921 on PoCL 3.1 (AVX-512).
    for name, size in kernels.items():
        assert size < sizes["render_segment"] / 4, (name, size, sizes["render_segment"])


def test_hot_helpers_leave_no_copy_in_the_program(cl_device: cl.Device) -> None:
    """A HOT helper is static (kernels/real.h): once clang's -O2 at clBuildProgram has inlined
    it, it is dropped, not kept, optimised and written beside its inlined copies (issue 42,
    docs/acceleration.md: The cold build's optimiser). Checked in the program's binary, which on
    PoCL is its program.bc: an out-of-line helper's name is there, an inlined HOT one's is not."""
    if cl_device.platform.name.strip() != "Portable Computing Language":
        pytest.skip("the program's binary is PoCL's program.bc")
    source = (kernel_source("real.h") +
              "\nHOT int hot_probe(int x) { return x * 3; }\n"
              "OUT_OF_LINE int kept_probe(int x) { return x + 1; }\n"
              "__kernel void probe(__global int* a) { a[0] = kept_probe(hot_probe(a[0])); }\n")
    program = cl.Program(context_for(cl_device), source).build()
    binary = bytes(program.get_info(cl.program_info.BINARIES)[0])
    assert b"kept_probe" in binary, "the binary holds no function names: the check is blind"
    assert b"hot_probe" not in binary, "an inlined HOT helper was kept in program.bc"


def test_a_render_build_has_no_intersect_rays(cl_device: cl.Device) -> None:
    """intersect_rays is in the intersection build only (KernelConfig.intersect_rays): in a
    render's program clang optimised it at clBuildProgram for nothing (issue 42)."""
    config = KernelConfig(has_spheres=True, has_triangles=True, max_depth=2)
    render, _ = build_program(cl_device, config)
    assert render.get_info(cl.program_info.KERNEL_NAMES).split(";") == ["render"]
    both, _ = build_program(cl_device, dataclasses.replace(config, intersect_rays=True))
    assert sorted(both.get_info(cl.program_info.KERNEL_NAMES).split(";")) == [
        "intersect_rays", "render"]


def _program_binary(device: cl.Device, config: KernelConfig) -> bytes:
    """PoCL's binary of the kernels built with `config`: its program.bc, clang's -O2 output,
    with its functions' names."""
    if device.platform.name.strip() != "Portable Computing Language":
        pytest.skip("the program's binary is PoCL's program.bc")
    program = cl.Program(context_for(device), kernel_source()).build(options=config.options())
    return bytes(program.get_info(cl.program_info.BINARIES)[0])


def test_packet_chains_build_has_no_ray_tree(cl_device: cl.Device) -> None:
    """Without refraction the sample packets trace each sample's chain to its end, at any spp
    (kernels/packet_trace.h): the build holds no ray-by-ray tree, which was 8,858 of
    cornell_box's 72,874 bytes of code compiled at the first launch (issue 42). With refraction
    a sample's tree can branch and goes on ray by ray after its packet."""
    config = KernelConfig(has_spheres=True, has_planes=True, has_area_lights=True, max_depth=3,
                          traversal="sample_packet")
    chains = _program_binary(cl_device, config)
    assert b"trace_sample_packet" in chains, "the binary holds no function names: blind check"
    assert b"sample_tree_radiance" not in chains
    trees = _program_binary(cl_device, dataclasses.replace(config, has_refraction=True,
                                                           has_transmission=True))
    assert b"sample_tree_radiance" in trees



def test_large_leaf_builds_keep_leaf_shadow_tests_and_pixels_out_of_line(
        cl_device: cl.Device) -> None:
    """leaf_transmission and pixel_radiance are functions of their own in builds whose leaves
    hold boxes, cylinders, cones, tori or instances (LARGE_LEAF_TESTS, kernels/bvh.h: their cold
    builds shorter, docs/acceleration.md), and inlined where they hold triangles and spheres
    alone, as the spheres' and the mesh's renders were measured."""
    config = KernelConfig(has_spheres=True, has_triangles=True, has_planes=True, max_depth=2)
    inlined = _program_binary(cl_device, config)
    assert b"render_segment" in inlined, "the binary holds no function names: blind check"
    assert b"leaf_transmission" not in inlined
    assert b"pixel_radiance" not in inlined
    for switches in ({"has_boxes": True}, {"has_tori": True}, {"has_instances": True}):
        kept = _program_binary(cl_device, dataclasses.replace(config, **switches))
        assert b"leaf_transmission" in kept, switches
        assert b"pixel_radiance" in kept, switches


def test_a_failing_binary_cache_falls_back_to_a_plain_build(
        cl_device: cl.Device, monkeypatch: pytest.MonkeyPatch) -> None:
    """pyopencl builds without its binary cache when the cache fails (another process holding
    its lock, an unwritable folder), but only where PYOPENCL_CACHE_FAILURE_FATAL is set:
    unset, it raised KeyError instead (clray/device/program.py sets it empty)."""
    import pyopencl.cache
    import pyopencl.characterize

    def failing(*args, **kwargs):
        raise OSError("the cache's lock is held by another process")

    # pyopencl uses its cache where the driver keeps none of its own (Intel's runtime; not PoCL).
    monkeypatch.setattr(pyopencl.characterize, "has_src_build_cache", lambda device: False)
    monkeypatch.setattr(pyopencl.cache, "retrieve_from_cache", failing)
    monkeypatch.setattr(program_module, "_programs", {})
    # One line: what failed, the exception's last line, and how to run without the cache.
    with pytest.warns(UserWarning, match=r"^pyopencl's binary cache failed, built without it "
                      r"\(OSError: the cache's lock is held by another process\); set "
                      r"PYOPENCL_NO_CACHE=1") as caught:
        built, seconds = build_program(cl_device, KernelConfig(has_spheres=True, max_depth=1))
    assert seconds > 0 and built.get_info(cl.program_info.NUM_KERNELS) >= 1
    assert all("\n" not in str(w.message) for w in caught)
