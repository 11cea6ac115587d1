"""Device choice and OpenCL contexts. Never interactive."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache

import pyopencl as cl
import pyopencl.characterize

from clray.errors import DeviceError, one_line

NO_PLATFORM_HINT = (
    "no OpenCL platform found: install PoCL (Debian: apt-get install pocl-opencl-icd, or "
    "pip install 'clray[pocl]') and check with `clinfo -l`"
)


@dataclass(frozen=True)
class DeviceInfo:
    spec: str  # "platform:device", as PYOPENCL_CTX takes it
    platform: str
    name: str
    type: str  # "CPU", "GPU", "ACCELERATOR" or "OTHER"
    compute_units: int
    global_mem_bytes: int
    fp64: bool
    version: str
    driver_version: str


def device_type(device: cl.Device) -> str:
    for flag, name in ((cl.device_type.CPU, "CPU"), (cl.device_type.GPU, "GPU"),
                       (cl.device_type.ACCELERATOR, "ACCELERATOR")):
        if device.type & flag:
            return name
    return "OTHER"


def _all_devices() -> list[tuple[str, cl.Device]]:
    try:
        platforms = cl.get_platforms()
    except cl.Error as err:  # pyopencl raises when the ICD loader finds no platform
        raise DeviceError(NO_PLATFORM_HINT) from err
    found = []
    for p_index, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl.Error:
            continue
        found.extend((f"{p_index}:{d_index}", d) for d_index, d in enumerate(devices))
    if not found:
        raise DeviceError(NO_PLATFORM_HINT)
    return found


def opencl_version(device: cl.Device) -> tuple[int, int]:
    """The device's OpenCL version, from its version string ("OpenCL 3.0 CUDA ...")."""
    try:
        major, minor = device.version.split()[1].split(".")[:2]
        return int(major), int(minor)
    except (IndexError, ValueError):
        return (1, 0)


def has_fp64(device: cl.Device) -> bool:
    # CL_DEVICE_DOUBLE_FP_CONFIG is core from OpenCL 1.2 only: an older device without the
    # extension answers the query with CL_INVALID_VALUE.
    if "cl_khr_fp64" in device.extensions.split():
        return True
    return opencl_version(device) >= (1, 2) and device.double_fp_config != 0


_pyopencl_nv_compute_capability = pyopencl.characterize.nv_compute_capability


def _nv_compute_capability(device: cl.Device) -> tuple[int, int] | None:
    """pyopencl's nv_compute_capability, asked only of devices whose
    cl_nv_device_attribute_query defines the query. pyopencl asks every device that is not
    PoCL's on each build (has_src_build_cache) and each kernel's first launch (the argument
    size check), and the others answer CL_INVALID_VALUE: an API error that Oclgrind's
    --check-api reports and a GPU driver may log."""
    if "cl_nv_device_attribute_query" not in device.extensions.split():
        return None
    return _pyopencl_nv_compute_capability(device)


# pyopencl looks the function up in its module at each call (characterize's own callers, and
# the invoker's import inside the function).
pyopencl.characterize.nv_compute_capability = _nv_compute_capability


def list_devices() -> list[DeviceInfo]:
    return [
        DeviceInfo(spec, d.platform.name.strip(), d.name.strip(), device_type(d),
                   d.max_compute_units, d.global_mem_size, has_fp64(d), d.version.strip(),
                   d.driver_version.strip())
        for spec, d in _all_devices()
    ]


# PoCL's platform name: the CPU runtime default_device prefers.
POCL_PLATFORM = "Portable Computing Language"

# The device types a spec may name (device_type's names, in lower case): the first device of
# that type in default_device's order.
TYPE_WORDS = ("cpu", "gpu", "accelerator")


def select_device(spec: str | None = None) -> cl.Device:
    """`spec`: "P:D" indices (PYOPENCL_CTX's form; "P" alone, where platform P is there,
    means its first device), a device type (TYPE_WORDS: cpu, gpu, accelerator; the first of
    that type in default_device's order), or a case-insensitive substring of a name
    (_by_name). Without one (or blank): default_device."""
    spec = (spec or "").strip()
    if not spec:
        return default_device()[0]
    devices = _all_devices()
    for found_spec, device in devices:
        if found_spec == spec:
            return device
    # A bare number is a platform index only where that platform is there: else it is a
    # name's part, as the 4090 of "RTX 4090".
    for found_spec, device in devices:
        if found_spec.split(":")[0] == spec:
            return device
    needle = spec.lower()
    if needle in TYPE_WORDS:
        return _first_of_type(devices, needle.upper(), spec)
    return _by_name(devices, spec)


def _name_rank(device: cl.Device, needle: str) -> int | None:
    """Where `needle` is in the device's names, best first, or None: its platform's name, its
    own name, then its platform's vendor and version. PoCL's CPU device is named for the CPU's
    brand ("pthread-skylake-avx512-Intel(R) Xeon(R) ..."), so that `intel` would otherwise
    pick PoCL where it means Intel's CPU runtime; PoCL's platform is named "Portable Computing
    Language", and `pocl` is in its vendor and version only."""
    platform = device.platform
    for rank, names in enumerate(((platform.name,), (device.name,),
                                  (platform.vendor, platform.version))):
        if any(needle in name.lower() for name in names):
            return rank
    return None


def _by_name(devices: list[tuple[str, cl.Device]], spec: str) -> cl.Device:
    """The device whose names hold `spec` best (_name_rank), the first of its platform's that
    do. Devices of several platforms that hold it alike are an error: which one a user meant
    is not to be guessed."""
    needle = spec.lower()
    ranked = [(rank, s, d) for s, d in devices if (rank := _name_rank(d, needle)) is not None]
    if not ranked:
        known = ", ".join(f"{s} {d.name.strip()}" for s, d in devices)
        raise DeviceError(f"no OpenCL device matches {spec!r} (devices: {known})")
    best = min(rank for rank, _, _ in ranked)
    matches = [(s, d) for rank, s, d in ranked if rank == best]
    if len({s.split(":")[0] for s, _ in matches}) > 1:
        listed = ", ".join(f"{s} {d.name.strip()} ({d.platform.name.strip()})"
                           for s, d in matches)
        raise DeviceError(f"{spec!r} matches devices on several platforms alike: {listed}; "
                          "expected a spec that names one, such as P:D")
    return matches[0][1]


def _pyopencl_choice(part: str, names: list[str]) -> int | None:
    """One part of PYOPENCL_CTX as pyopencl's choose_devices reads it: an index where it is an
    integer in range, else the first name (case-insensitive) that holds it; None where none
    does. An empty part holds in every name: the first."""
    try:
        index = int(part)
    except ValueError:
        pass
    else:
        if 0 <= index < len(names):
            return index
    return next((i for i, name in enumerate(names) if part.lower() in name.lower()), None)


def _pyopencl_ctx_device(devices: list[tuple[str, cl.Device]], value: str) -> cl.Device:
    """The device PYOPENCL_CTX names, read as pyopencl reads it (choose_devices), so that a
    value written for pyopencl means the same device here: "PLATFORM[:DEVICE]", each part an
    index or a part of the platform's or the device's name. pyopencl takes the last platform
    whose name holds the part, and so does this. A comma-separated device part asks pyopencl
    for a context of several devices: clray renders on one, the first."""
    parts = value.split(":")
    if len(parts) > 2:
        raise DeviceError(f"PYOPENCL_CTX={value!r}: expected PLATFORM or PLATFORM:DEVICE, "
                          "each an index or a part of a name")
    by_platform: dict[int, list[cl.Device]] = {}
    for spec, device in devices:
        by_platform.setdefault(int(spec.split(":")[0]), []).append(device)
    indices = sorted(by_platform)
    platform_names = [by_platform[i][0].platform.name.strip() for i in indices]
    # pyopencl indexes every platform, one without devices too: the spec's own index.
    platform = int(parts[0]) if parts[0].strip().isdigit() else None
    if platform not in by_platform:
        found = _pyopencl_choice(parts[0], platform_names[::-1])
        platform = None if found is None else indices[::-1][found]
    if platform is None:
        known = ", ".join(f"{i} {name}" for i, name in zip(indices, platform_names, strict=True))
        raise DeviceError(f"PYOPENCL_CTX={value!r}: no OpenCL platform matches {parts[0]!r} "
                          f"(platforms: {known})")
    on_platform = by_platform[platform]
    part = parts[1].split(",")[0] if len(parts) > 1 else ""
    found = _pyopencl_choice(part, [d.name.strip() for d in on_platform])
    if found is None:
        known = ", ".join(f"{i} {d.name.strip()}" for i, d in enumerate(on_platform))
        raise DeviceError(f"PYOPENCL_CTX={value!r}: no device of platform {platform} "
                          f"({on_platform[0].platform.name.strip()}) matches {part!r} "
                          f"(devices: {known})")
    return on_platform[found]


# The order default_device takes, for --device's help and the like to name.
DEFAULT_DEVICE_ORDER = ("CLRAY_DEVICE, PYOPENCL_CTX, then a GPU with memory of its own, then "
                        "PoCL's CPU device, then the first CPU device, then the first device")


def default_device() -> tuple[cl.Device, str, str]:
    """(device, spec, why): the device a render uses where neither --device nor the settings
    name one: DEFAULT_DEVICE_ORDER, where the GPU is the one with the most compute units and
    the CPU devices go as _cpus orders them. The one GPU measured, an H100, ran
    every example scene's kernel 1.1 to 91 times as fast as a 2-core CPU's PoCL and the
    1080p spheres render in 15 ms (docs/gpu.md); a GPU that shares the host's memory is an
    integrated one, often slower than the CPU beside it, and not measured: it is chosen by
    name only."""
    devices = _all_devices()
    for variable in ("CLRAY_DEVICE", "PYOPENCL_CTX"):
        # A blank value is unset, as for --device: not a substring that every name holds.
        value = os.environ.get(variable, "").strip()
        if value:
            if variable == "CLRAY_DEVICE":
                try:
                    chosen = select_device(value)
                except DeviceError as err:
                    # Named as PYOPENCL_CTX's errors are: the spec is no flag the user typed,
                    # and the variable is what to mend.
                    raise DeviceError(f"{variable}={value!r}: {err}") from None
            else:
                chosen = _pyopencl_ctx_device(devices, value)
            spec = next(s for s, d in devices if d == chosen)
            return chosen, spec, f"{variable}={value}"
    gpus = _discrete_gpus(devices)
    if gpus:
        spec, device = gpus[0]
        return device, spec, "a GPU with its own memory: faster than CPUs where measured"
    cpus = _cpus(devices)
    if cpus:
        spec, device = cpus[0]
        if _is_pocl(device):
            return device, spec, "PoCL's CPU device: there is no GPU with its own memory"
        return device, spec, "the first CPU device"
    return devices[0][1], devices[0][0], "the first device: there is no CPU device"


def _discrete_gpus(devices: list[tuple[str, cl.Device]]) -> list[tuple[str, cl.Device]]:
    """The GPUs with memory of their own, the one default_device takes first (the most
    compute units)."""
    gpus = [(s, d) for s, d in devices if is_discrete_gpu(d)]
    return sorted(gpus, key=lambda sd: -sd[1].max_compute_units)


def _is_pocl(device: cl.Device) -> bool:
    return device.platform.name.strip() == POCL_PLATFORM


def _cpus(devices: list[tuple[str, cl.Device]]) -> list[tuple[str, cl.Device]]:
    """The CPU devices, the one default_device takes first: PoCL's, then the others in the
    loader's order. README promises PoCL's (the CPU runtime a pip install brings), and the
    ICD loader lists platforms in its folder's directory order, which is no one's choice."""
    cpus = [(s, d) for s, d in devices if d.type & cl.device_type.CPU]
    return sorted(cpus, key=lambda sd: not _is_pocl(sd[1]))


def _first_of_type(devices: list[tuple[str, cl.Device]], kind: str, spec: str) -> cl.Device:
    """The device of type `kind` (device_type's name) that default_device's order puts first:
    for GPUs one with its own memory and the most compute units, else the first."""
    of_kind = [(s, d) for s, d in devices if device_type(d) == kind]
    if kind == "GPU":
        of_kind = _discrete_gpus(of_kind) + of_kind
    elif kind == "CPU":
        of_kind = _cpus(of_kind)
    if not of_kind:
        known = ", ".join(f"{s} {device_type(d)} {d.name.strip()}" for s, d in devices)
        raise DeviceError(f"no OpenCL {kind} device matches {spec!r} (devices: {known})")
    return of_kind[0][1]


def is_discrete_gpu(device: cl.Device) -> bool:
    """A GPU with memory of its own (CL_DEVICE_HOST_UNIFIED_MEMORY false, a query OpenCL 2.0
    deprecated but every driver still answers; one that does not is taken for discrete). A
    GPU by device_type: not Oclgrind's simulator, whose type has every bit set."""
    if device_type(device) != "GPU":
        return False
    try:
        return not device.host_unified_memory
    except cl.Error:
        return True


@contextmanager
def opencl_errors(device: cl.Device, doing: str) -> Iterator[None]:
    """OpenCL's errors while `doing` on `device` as a DeviceError (exit 4) naming the device
    and the error: a driver that lists a device it cannot open, or runs out of its memory,
    is the device's trouble, not a bug to show a traceback for."""
    try:
        yield
    except cl.Error as err:
        raise DeviceError(f"{describe(device)}: {doing}: {opencl_error_text(err)}") from err


def opencl_error_text(err: cl.Error) -> str:
    """OpenCL's error in one line: its first (a build's log follows on later lines)."""
    first = next((line.strip() for line in str(err).splitlines() if line.strip()), "")
    return one_line(first or repr(err))


@cache
def context_for(device: cl.Device) -> cl.Context:
    with opencl_errors(device, "cannot open the device"):
        return cl.Context([device])


@cache
def queue_for(device: cl.Device) -> cl.CommandQueue:
    with opencl_errors(device, "cannot open the device"):
        return cl.CommandQueue(context_for(device),
                               properties=cl.command_queue_properties.PROFILING_ENABLE)


def describe(device: cl.Device) -> str:
    platform = device.platform.name.strip()
    return f"{device.name.strip()} ({platform}, {device.driver_version.strip()})"
