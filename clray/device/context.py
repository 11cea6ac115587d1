"""Device choice and OpenCL contexts. Never interactive."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cache

import pyopencl as cl

from clray.errors import DeviceError

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


def has_fp64(device: cl.Device) -> bool:
    return "cl_khr_fp64" in device.extensions.split() or device.double_fp_config != 0


def list_devices() -> list[DeviceInfo]:
    return [
        DeviceInfo(spec, d.platform.name.strip(), d.name.strip(), device_type(d),
                   d.max_compute_units, d.global_mem_size, has_fp64(d), d.version.strip(),
                   d.driver_version.strip())
        for spec, d in _all_devices()
    ]


def select_device(spec: str | None = None) -> cl.Device:
    """`spec`: "P:D" indices (PYOPENCL_CTX syntax, "P" alone means its first device) or a
    case-insensitive substring of the platform or device name. Without one: CLRAY_DEVICE, then
    PYOPENCL_CTX, then the first CPU device, then the first device."""
    spec = spec or os.environ.get("CLRAY_DEVICE") or os.environ.get("PYOPENCL_CTX") or None
    devices = _all_devices()
    if spec is None:
        cpus = [d for _, d in devices if d.type & cl.device_type.CPU]
        return cpus[0] if cpus else devices[0][1]
    spec = spec.strip()
    if ":" not in spec and spec.isdigit():
        spec = f"{spec}:0"
    for found_spec, device in devices:
        if found_spec == spec:
            return device
    needle = spec.lower()
    for _, device in devices:
        platform = device.platform
        names = (device.name, platform.name, platform.vendor, platform.version)
        if any(needle in n.lower() for n in names):
            return device
    known = ", ".join(f"{s} {d.name.strip()}" for s, d in devices)
    raise DeviceError(f"no OpenCL device matches {spec!r} (devices: {known})")


@cache
def context_for(device: cl.Device) -> cl.Context:
    return cl.Context([device])


@cache
def queue_for(device: cl.Device) -> cl.CommandQueue:
    return cl.CommandQueue(context_for(device),
                           properties=cl.command_queue_properties.PROFILING_ENABLE)


def describe(device: cl.Device) -> str:
    platform = device.platform.name.strip()
    return f"{device.name.strip()} ({platform}, {device.driver_version.strip()})"
