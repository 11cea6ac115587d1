"""Kernel sources + KernelConfig -> built OpenCL program, cached per device and options."""

from __future__ import annotations

import hashlib
import os
import re
import sys
import time
import traceback
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields, make_dataclass
from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path

import pyopencl as cl

from clray.device.context import context_for, device_type, has_fp64
from clray.errors import ClrayError, DeviceError
from clray.knobs import KNOBS, TRAVERSAL_SCHEMES
from clray.shapes import SHAPES

# The top-level kernels/ folder, installed as this package (pyproject.toml's package-dir), so a
# wheel, an sdist and an editable install all read the same files.
KERNEL_PACKAGE = "clray.kernels"
ENTRY_FILE = "render.cl"
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.MULTILINE)

# Build options a study may add; anything else is refused so the cache key stays meaningful.
ALLOWED_BUILD_OPTIONS = frozenset({
    "-cl-mad-enable",
    "-cl-unsafe-math-optimizations",
    "-cl-fast-relaxed-math",
    "-cl-finite-math-only",
    "-cl-no-signed-zeros",
})


# Oclgrind 21.10 (Debian's package, built on a newer LLVM than it knows) cannot run the
# llvm.experimental.noalias.scope.decl that LLVM's inliner leaves where it inlines a function
# returning a struct (the hidden noalias sret pointer). The always_inline helpers (HOT) are
# inlined even at -O0, so for Oclgrind they become plain inline and nothing is optimised: with
# optimisation on, Oclgrind 21.10 crashes (SIGSEGV) while creating the render kernel. Nor can
# it run llvm.vector.reduce.*, which clang's __builtin_reduce_or/min in the sample packets
# become: PORTABLE_REDUCTIONS makes them loops.
OCLGRIND_BUILD_OPTIONS = ("-DHOT=inline", "-cl-opt-disable", "-DPORTABLE_REDUCTIONS")


def is_oclgrind(device: cl.Device) -> bool:
    return device.platform.name.strip() == "Oclgrind"


# Mesa's OpenCL drivers (rusticl; Clover) compile the source with clang for the spir64 target,
# unoptimised, and hand the module to LLVM's SPIR-V translator, which has no SPIR-V for the
# llvm.vector.reduce intrinsics either ("Unexpected llvm intrinsic"): Mesa 22.3's rusticl ended
# the process (exit 8) at the first sample-packet build. Intel's CPU runtime also compiles for
# spir64, but takes the module as it is, and keeps the builtins.
SPIRV_TRANSLATING_PLATFORMS = frozenset({"rusticl", "Clover"})
SPIRV_BUILD_OPTIONS = ("-DPORTABLE_REDUCTIONS",)


def translates_through_spirv(device: cl.Device) -> bool:
    return device.platform.name.strip() in SPIRV_TRANSLATING_PLATFORMS


# A GPU runs a work-group's work-items side by side (kernels/real.h, SERIAL_WORK_ITEMS):
# a pixel a work-item, the renderer inlined, not a group's row segment rendered by its first
# work-item (render_segment). Said by the host, since a
# vendor's compiler need not define the target macros (__NVPTX__, __AMDGCN__) clang's do.
GPU_BUILD_OPTIONS = ("-DSERIAL_WORK_ITEMS=0",)


# OpenCL's default accuracy lets a float division be 2.5 ulp off and a square root 3; the CPU
# drivers round both correctly, and the kernels' error bounds and the tests' float64
# comparisons assume it. A GPU that can round them correctly is asked to (on NVIDIA's driver
# 580 without it, an H100 rendered 31 kernel tests' and depth_of_field's images off the CPU's).
CORRECTLY_ROUNDED = "-cl-fp32-correctly-rounded-divide-sqrt"


def device_build_options(device: cl.Device) -> tuple[str, ...]:
    """Options a device's compiler needs whatever the configuration (and math_ulps_off's,
    while it lasts)."""
    if is_oclgrind(device):
        return OCLGRIND_BUILD_OPTIONS + _as_for_a_gpu + _ulps_off
    spirv = SPIRV_BUILD_OPTIONS if translates_through_spirv(device) else ()
    if not device.type & cl.device_type.GPU:
        return spirv + _as_for_a_gpu + _ulps_off
    return GPU_BUILD_OPTIONS + spirv + \
        ((CORRECTLY_ROUNDED,) if _rounds_division(device) else ()) + _ulps_off


def _rounds_division(device: cl.Device) -> bool:
    """Whether the device offers correctly rounded float division and square root. A driver
    that does not answer the query (a stand-in without it, or an OpenCL error) is taken as
    not offering them: the build then keeps OpenCL's own bounds, never fails for it."""
    try:
        config = device.single_fp_config
    except (AttributeError, cl.Error):
        return False
    return bool(config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)


def ulps_off_option(direction: int) -> str:
    """The build option of kernels/real.h's MATH_ULPS_OFF: the transcendental builtins off by
    OpenCL's whole error bounds for them, upwards (1) or downwards (-1), and the geometric
    builtins' products fused."""
    return f"-DMATH_ULPS_OFF={direction}"


# math_ulps_off's option while it lasts, else none.
_ulps_off: tuple[str, ...] = ()


@contextmanager
def math_ulps_off(direction: int) -> Iterator[None]:
    """While it lasts, every kernel this process builds has its transcendental builtins off by
    OpenCL's bounds in `direction` (ulps_off_option): for the tests' --opencl-ulps and
    scripts/gpu_check_steps.py's references, which show what a device as inaccurate as
    OpenCL allows would render. Never set by a render."""
    global _ulps_off
    outer, _ulps_off = _ulps_off, (ulps_off_option(direction),)
    try:
        yield
    finally:
        _ulps_off = outer


# built_as_for_a_gpu's options while it lasts, else none.
_as_for_a_gpu: tuple[str, ...] = ()


@contextmanager
def built_as_for_a_gpu() -> Iterator[None]:
    """While it lasts, every kernel this process builds on a CPU device or Oclgrind takes
    GPU_BUILD_OPTIONS, so that it runs the code a GPU's work-items run (a pixel each, no row
    segments): for the tests' --gpu-build and Oclgrind's data-race check of that code
    (tests/oclgrind_run.py). Never set by a render."""
    global _as_for_a_gpu
    outer, _as_for_a_gpu = _as_for_a_gpu, GPU_BUILD_OPTIONS
    try:
        yield
    finally:
        _as_for_a_gpu = outer


# The analytic shapes' switches (HAS_SPHERES, ..., HAS_TORI: Shape.switch), fields of every
# KernelConfig made from the registry, so that a new shape needs no line here.
_ShapeSwitches = make_dataclass("_ShapeSwitches", [(shape.switch, "bool", False)
                                                   for shape in SHAPES], frozen=True)
_ShapeSwitches.__module__ = __name__  # pickled by reference, as KernelConfig is


@dataclass(frozen=True)
class KernelConfig(_ShapeSwitches):
    """Only switches that remove code or fix loop bounds; everything else is a kernel
    argument, so a new scene rarely means a new build. Besides the shapes' switches:"""

    has_planes: bool = False
    has_triangles: bool = False
    has_vertex_normals: bool = False
    has_vertex_uvs: bool = False
    has_vertex_colors: bool = False  # a mesh's vertex colours tint its faces
    # Every triangle's material word is the same and no vertex attributes: the device keeps one.
    has_one_triangle_material: bool = False
    has_textures: bool = False
    has_transmission: bool = False  # some material transmits: shadow rays filter
    has_refraction: bool = False
    has_spot_lights: bool = False
    # Rect, disc, sphere, triangle (an emissive face) and mesh lights: sampled per pixel sample.
    has_area_lights: bool = False
    # Many emissive faces as one light, a sample picking a face; its code is area lights', so
    # alone (the compile checks' configurations) it builds none.
    has_mesh_lights: bool = False
    has_fresnel: bool = False  # some transmissive material splits by Fresnel
    has_thin_lens: bool = False  # camera aperture > 0
    has_orthographic: bool = False
    has_background_gradient: bool = False
    has_background_image: bool = False
    has_instances: bool = False  # groups placed by transforms, walked in their own frames
    max_depth: int = 0
    # The wide BVH's children per node (4 or 8) and a traversal stack deep enough for its tree
    # (clray.accel.wide), rounded up by the packer so similar trees share a build.
    bvh_width: int = 8
    bvh_stack_size: int = 32
    precision: str = "float"  # "float" | "double"
    # How rays walk the BVH (clray.knobs.TRAVERSAL_TABLE, which names the fields each scheme's
    # build takes as -D; docs/acceleration.md): "single", every ray alone, "sample_packet", a
    # pixel's samples in packets of packet_lanes vector lanes, lanes going on ray by ray where
    # at most packet_min_lanes of them reach a subtree, or "group_packet", a work-group's
    # pixels together (the launch's tiles: the group_side knob). Knobs of the table
    # (clray.knobs); clray.device.policy.device_plan sets them for the device.
    traversal: str = "single"
    packet_lanes: int = 8
    packet_min_lanes: int = KNOBS["packet_min_lanes"].default
    # Whether a driver may pack work-items into a vector's lanes (the knob of that name).
    implicit_vectorization: bool = KNOBS["implicit_vectorization"].default
    # Study variants (clray study): the textbook formulas the defaults replace.
    sphere_textbook: bool = False
    offset_fixed_eps: bool = False
    triangle_no_fp64_fallback: bool = False
    triangle_moller_trumbore: bool = False
    fresnel_schlick: bool = False  # Schlick's approximation for Fresnel materials
    # Set by the packer from clray.scene.scale, not a study variant: spheres in double.
    fp64_spheres: bool = False
    # The instrumented build: render_packed then reports box and primitive tests.
    count_tests: bool = False
    # The passes build (RenderSettings.aovs): render_passes too, beside the render kernel. A
    # render without passes builds without it, the very program it built before passes.
    passes: bool = False
    # The intersection build (clray.device.launch.intersect_rays, for tests and tools): the
    # intersect_rays kernel too, beside render. A render builds without it: clang's -O2 at
    # clBuildProgram optimised its copy of the closest-hit walk in every render's cold build
    # (issue 42: textured 0.06 CPU-s; docs/acceleration.md, The cold build's optimiser).
    intersect_rays: bool = False
    # The stage-profiling build (benchmarks/stages.py): the renderer's stages (STAGE in
    # kernels/real.h) stay functions of their own, for a profiler to count.
    stage_profile: bool = False
    build_options: tuple[str, ...] = ()

    def options(self) -> list[str]:
        defines = []
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool):
                defines.append(f"-D{f.name.upper()}={int(value)}")
        defines.append(f"-DMAX_DEPTH={self.max_depth}")
        defines.append(f"-DBVH_WIDTH={self.bvh_width}")
        defines.append(f"-DBVH_STACK_SIZE={self.bvh_stack_size}")
        defines.append(f"-DTRAVERSAL=TRAVERSAL_{self.traversal.upper()}")
        defines += [f"-D{name.upper()}={getattr(self, name)}"
                    for name in TRAVERSAL_SCHEMES[self.traversal].defines]
        if self.precision == "double":
            defines.append("-DUSE_DOUBLE=1")
        return sorted(defines) + sorted(self.build_options)


# The switches that take code in or out (every bool but the study variants and the counting
# build).
FEATURE_SWITCHES = tuple(f.name for f in fields(KernelConfig) if f.type == "bool"
                         and f.name.startswith("has_"))

# What a GPU keeps in registers per work-item: 255 32-bit registers on NVIDIA GPUs, 256 vector
# registers per lane on AMD's: about 1 KiB. Private arrays indexed at run time (the ray and
# BVH stacks) live in registers only below that; above it they spill to slow off-chip memory.
GPU_REGISTER_BYTES = 1024
MEDIA_DEPTH = 4  # kernels/ray_tree.h: the media a ray task carries


def private_stack_bytes(config: KernelConfig) -> dict[str, int]:
    """Bytes per work-item of the kernel's private stacks: the ray stack (RayTask entries,
    MAX_DEPTH + 1 of them with refraction, else 1) and the BVH traversal stacks, BVH_STACK_SIZE
    levels of (child, count, entry t) for closest hits and of (child, count) for shadow rays,
    as kernels/ray_tree.h, packet_trace.h and bvh.h declare them; sample packets without
    refraction add their chains' radiance to the ray stack (three numbers for every lane,
    whatever the depth: packet_trace.h's SamplePacket); group packets add the group's stack
    (child, count, the group's and the work-item's entry t; kernels/group.h), the single-ray
    walks testing its leaves (each told by its TraversalScheme's packs_samples and tiles). A
    3-vector takes four elements' room. The rest of the kernel's private memory does not grow
    with the settings (benchmarks/private_memory.py measures it)."""
    real = 8 if config.precision == "double" else 4
    task = 3 * 4 * real + 4 + 4 + 4 * MEDIA_DEPTH
    task = -(-task // (4 * real)) * (4 * real)  # aligned to its REAL3
    scheme = TRAVERSAL_SCHEMES[config.traversal]
    ray = task * (config.max_depth + 1 if config.has_refraction else 1)
    if scheme.packs_samples and not config.has_refraction:
        ray += 3 * config.packet_lanes * real
    bvh = config.bvh_stack_size * ((4 + 4 + real) + (4 + 4))
    if scheme.tiles:  # a tile's work-items walk together on the group's own stack
        bvh += config.bvh_stack_size * (4 + 4 + 2 * real)
    return {"ray_stack": ray, "bvh_stack": bvh, "total": ray + bvh}


def private_memory_warning(config: KernelConfig, device_type: str) -> str | None:
    """One line where a GPU would keep this configuration's stacks off-chip, else None."""
    if device_type != "GPU":
        return None
    stacks = private_stack_bytes(config)
    if stacks["total"] <= GPU_REGISTER_BYTES:
        return None
    return (f"{stacks['total']} bytes of private stacks per work-item (ray "
            f"{stacks['ray_stack']}, BVH {stacks['bvh_stack']}; max_depth {config.max_depth}, "
            f"{config.precision}) exceed the {GPU_REGISTER_BYTES} a GPU keeps in registers: "
            "expect spills to slow memory")


def source_digest(source: str) -> str:
    """The sha256 of a kernel source text: build_program's cache key, and what a tuning file
    was measured against (clray.device.tuning_files)."""
    return hashlib.sha256(source.encode()).hexdigest()


# A file's stamp: what says, without reading it, that it is unchanged; None where the package
# is not plain files (a zip import), which has no stat and is read again every time.
_Stamp = tuple[int, int] | None
# kernel_source's texts by (kernel folder, entry file), with the stamp of every file that went
# into each: expanding the includes took about 7-13 ms, which every render (an animation's each
# frame) paid, and a stat of the ~35 files costs well under a millisecond.
_expanded: dict[tuple[str, str], tuple[tuple[tuple[Traversable, _Stamp], ...], str]] = {}


def _stamp(file: Traversable) -> _Stamp:
    if not isinstance(file, Path):
        return None
    info = file.stat()
    # The size as well as the time: a filesystem with coarse timestamps can keep the time of an
    # edit made within the same tick.
    return info.st_mtime_ns, info.st_size


def kernel_source(name: str = ENTRY_FILE) -> str:
    """The entry file with its quoted includes inlined (each once), with #line markers so
    build logs name the right file. Inlining keeps every cache keyed on the full text. The
    text is kept for the process, and expanded again when any file that went into it changes
    on disk (a kernel edited while a notebook or an animation runs)."""
    folder = files(KERNEL_PACKAGE)
    key = (str(folder), name)
    cached = _expanded.get(key)
    if cached is not None:
        read, text = cached
        try:
            if all(stamp is not None and _stamp(file) == stamp for file, stamp in read):
                return text
        except OSError:  # a file gone: expanding again reports it as a first read would
            pass
    seen: set[str] = set()
    read_files: list[tuple[Traversable, _Stamp]] = []

    def expand(fname: str) -> str:
        if fname in seen:
            return ""
        seen.add(fname)
        file = folder.joinpath(fname)
        # Stamped before reading: an edit landing between the two makes the next call expand
        # again, never keeps a stale text.
        read_files.append((file, _stamp(file)))
        text = file.read_text(encoding="utf-8")
        out = [f'#line 1 "{fname}"']
        for lineno, line in enumerate(text.splitlines(), start=1):
            match = _INCLUDE.match(line)
            if match:
                out.append(expand(match.group(1)))
                out.append(f'#line {lineno + 1} "{fname}"')
            else:
                out.append(line)
        return "\n".join(out)

    text = expand(name)
    _expanded[key] = (tuple(read_files), text)
    return text


_programs: dict[tuple[int, str, tuple[str, ...]], cl.Program] = {}

# pyopencl (2026.1.4) builds without its binary cache when the cache fails (a lock that another
# process holds, a cache folder that cannot be written), unless this variable is set non-empty;
# it reads the variable without a default, so unset, a cache failure raised KeyError
# ('PYOPENCL_CACHE_FAILURE_FATAL') instead (seen in CI while other processes built).
os.environ.setdefault("PYOPENCL_CACHE_FAILURE_FATAL", "")
# The start of the warning pyopencl gives then, with the whole traceback after it.
_CACHE_FAILED = "PyOpenCL compiler caching failed"
NO_CACHE_HINT = "set PYOPENCL_NO_CACHE=1 to run without pyopencl's caches"


def build_cached(program: cl.Program, options: list[str]) -> cl.Program:
    """`program` built; pyopencl's warning that its binary cache failed (it builds without
    it) told in one line, the exception's last, not as its whole traceback."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        built = program.build(options=options)
    for warning in caught:
        text = str(warning.message)
        if text.startswith(_CACHE_FAILED):
            lines = [line for line in text.splitlines()
                     if line.strip() and line.strip() != "[end exception]"]
            warnings.warn(f"pyopencl's binary cache failed, built without it ({lines[-1]}); "
                          f"{NO_CACHE_HINT}", stacklevel=2)
        else:  # the build's own (a CompilerWarning), to the caller's filters
            warnings.warn_explicit(warning.message, warning.category, warning.filename,
                                   warning.lineno, source=warning.source)
    return built


def _ignore_unraisable(_: object) -> None:
    return None


@contextmanager
def cache_folder_errors() -> Iterator[None]:
    """A process's first kernel object makes pyopencl's invoker cache, whose folder
    ($XDG_CACHE_HOME/pytools) it cannot make where a file or a denied folder is in the way: an
    OSError, here one line naming it."""
    try:
        yield
    except OSError as err:
        message = (f"cannot use pyopencl's cache folder {err.filename or ''}: "
                   f"{err.strerror or err}: move what is in the way, or {NO_CACHE_HINT}")
        # The half-made cache object goes with the traceback's frames, and its __del__ fails
        # on what its __init__ never set: a second traceback ("Exception ignored") otherwise.
        hook, sys.unraisablehook = sys.unraisablehook, _ignore_unraisable
        try:
            traceback.clear_frames(err.__traceback__)
        finally:
            sys.unraisablehook = hook
        raise ClrayError(message) from None


# The end of build_program's refusal of a double build on a device without doubles (many GPUs):
# the test suite skips, by it, the tests whose oracle is the double build (tests/conftest.py).
NO_FP64 = "has no cl_khr_fp64"


def build_program(device: cl.Device, config: KernelConfig) -> tuple[cl.Program, float]:
    """(program, seconds spent building; 0.0 when it came from this process's cache)."""
    if config.precision == "double" and not has_fp64(device):
        raise DeviceError(f"--precision double: device {device.name.strip()!r} {NO_FP64}")
    unknown = set(config.build_options) - ALLOWED_BUILD_OPTIONS
    if unknown:
        raise DeviceError(f"unsupported build option(s): {', '.join(sorted(unknown))}")
    source = kernel_source()
    options = tuple(config.options()) + device_build_options(device)
    key = (device.int_ptr, source_digest(source), options)
    if key in _programs:
        return _programs[key], 0.0
    # The context comes before the clock: a process makes it once, whatever it builds
    # (clray.profile's context_s times it apart).
    context = context_for(device)
    start = time.perf_counter()
    try:
        program = build_cached(cl.Program(context, source), list(options))
    except cl.RuntimeError as err:
        log = str(err).strip().splitlines()
        detail = " | ".join(line.strip() for line in log if "error" in line.lower())[:2000]
        raise DeviceError(f"kernel build failed ({' '.join(options)}): "
                          f"{detail or log[-1] if log else err}") from err
    _programs[key] = program
    warning = private_memory_warning(config, device_type(device))
    if warning:
        warnings.warn(warning, stacklevel=2)
    return program, time.perf_counter() - start
