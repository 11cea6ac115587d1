"""Device policy: what a render on a device builds. device_plan decides, once per render, the
knobs (the settings' or the device's tuning file's), the traversal, a sample packet's lanes and
the BVH's width for the device, the arithmetic and the samples a pixel, and assembles the
KernelConfig switches they make; the packer adds the scene's (clray.device.pack).

The traversal schemes themselves, their knobs and their build's defines are one table,
clray.knobs.TRAVERSAL_TABLE; this module decides which of them a device renders with."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import pyopencl as cl

from clray.device.context import POCL_PLATFORM, device_type
from clray.device.tuning_files import chosen_tuning
from clray.errors import SettingsError
from clray.knobs import BUILD_KNOBS, DEFAULT_TUNING, IMAGE_KNOBS, TRAVERSAL_SCHEMES, Tuning


def vector_width(device: cl.Device, precision: str = "float") -> int:
    """The vector width of the arithmetic's type that a work-item's own vectors get: the
    device's preferred width, or its native one where that is wider. A driver that packs
    work-items into a vector's lanes reports a preferred width of 1 (Intel's CPU runtime), but
    the render kernels ask it for one work-item a thread (KernelConfig.implicit_vectorization),
    whose vectors then have the hardware's native width (8 floats on AVX2)."""
    if precision == "double":
        return max(device.preferred_vector_width_double, device.native_vector_width_double)
    return max(device.preferred_vector_width_float, device.native_vector_width_float)


def bvh_width_for(device: cl.Device, precision: str = "float") -> int:
    """Children per BVH node for this device and arithmetic: 8 where its vectors of that type
    are 8 wide or more (float on AVX CPUs), else 4 (double on AVX2, GPUs). Either width is
    correct on any device; the node's slab test runs on vectors of this width."""
    return 8 if vector_width(device, precision) >= 8 else 4


# The drivers whose CPU device renders faster with sample packets, by platform name, at 16 spp,
# 1280 x 720 (docs/acceleration.md, Sample packets): PoCL, 1.63x (spheres) and 1.34x (mesh), at
# 8 spp 1.59x and 1.17x; Intel's CPU runtime, 1.50x (spheres, with the chains) and 1.08x to
# 1.31x (mesh).
SAMPLE_PACKET_PLATFORMS = (POCL_PLATFORM, "Intel(R) OpenCL")


def traversal_for(device: cl.Device) -> str:
    """The traversal a device renders with where neither the settings nor the tuning name
    one: sample packets on the CPU devices of SAMPLE_PACKET_PLATFORMS, where they measured
    faster; the single-ray walk elsewhere. On a GPU a work-item's lanes are work-items
    already, and a packet's private state would cut occupancy. `clray tune` tries both and
    stores the faster for the device. With one sample a pixel every device renders with the
    single-ray build, and a device's own sample packets only where a pixel's samples fill a
    packet (device_plan)."""
    if (device.platform.name.strip() in SAMPLE_PACKET_PLATFORMS
            and device_type(device) == "CPU"):
        return "sample_packet"
    return "single"


def packet_lanes_for(device: cl.Device, precision: str = "float", spp: int | None = None) -> int:
    """Rays in a sample packet: the device's vector width of the arithmetic type (vector_width:
    8 floats on AVX2, 16 on AVX-512), within 4 to 16; 16 on a device 8 wide too where a pixel's
    `spp` samples fill them. A packet of two vectors shares each node's interval test, each
    leaf's shape boxes and the lane bookkeeping among twice the rays, and each lane-wise test
    costs two vector operations instead of one: at 16 spp (1280 x 720, AVX2) 16 lanes were
    1.09x (spheres) and 1.28x (mesh) faster than 8 on PoCL 3.1, 1.19x and 1.10x on Intel's
    CPU runtime (docs/acceleration.md, Sample packets)."""
    width = vector_width(device, precision)
    lanes = 16 if width >= 16 else (8 if width >= 8 else 4)
    if lanes == 8 and spp is not None and spp >= 16:
        return 16
    return lanes


def _misfit(device: cl.Device, tuning: Tuning, traversal: str | None, precision: str,
            spp: int) -> str | None:
    """Why `tuning` cannot build a render of these settings on `device`, or None: a
    packet_min_lanes not below the packet lanes the device has for this arithmetic (16 floats
    but 8 doubles on AVX-512), checked whatever the spp, as a tuning that cannot build is
    wrong at 1 spp too."""
    chosen = traversal or tuning.traversal or traversal_for(device)
    lanes = tuning.packet_lanes or packet_lanes_for(device, precision, spp)
    if TRAVERSAL_SCHEMES[chosen].packs_samples and tuning.packet_min_lanes >= lanes:
        return (f"packet_min_lanes {tuning.packet_min_lanes} is not below the {lanes} packet "
                f"lanes of {device.name.strip()!r} in {precision}")
    return None


@dataclass(frozen=True)
class DevicePlan:
    """What a render on one device builds and packs, decided once (device_plan)."""

    tuning: Tuning
    tuning_source: str  # "given", "default", or "tuning file PATH" (chosen_tuning)
    traversal: str  # the walk the kernel is built with (KernelConfig.traversal)
    # Rays in a sample packet, the tuning's or the device's for these samples a pixel: what a
    # sample-packet build of the render takes, whether or not this one is.
    packet_lanes: int
    bvh_width: int  # children per BVH node, the tuning's or the device's
    precision: str
    # The KernelConfig fields the device, the settings and the tuning set (the scene's are the
    # packer's): the traversal and its defines, the kernel and build knobs, passes, variants.
    switches: dict[str, object]

    def pack_arguments(self) -> dict[str, object]:
        """pack_scene's keyword arguments of the plan (with the scene's sizes and a queue
        from the caller): the arithmetic, the BVH width, the knobs and the switches."""
        return {"precision": self.precision, "bvh_width": self.bvh_width,
                "tuning": self.tuning, **self.switches}


def device_plan(device: cl.Device, *, spp: int, precision: str = "float",
                traversal: str | None = None, tuning: Tuning | None = None,
                stored_tuning: bool = True, passes: bool = False,
                variants: tuple[tuple[str, object], ...] = ()) -> DevicePlan:
    """The plan of a render on `device` at `spp` samples a pixel. `traversal` (the settings')
    overrides the tuning's knob, which overrides the device's own (traversal_for); `tuning`
    None takes the device's tuning file where `stored_tuning` and one exists, else the knob
    table's defaults; a tuning file that cannot build this render (_misfit) is ignored for it
    with a warning, and a given tuning that cannot raises SettingsError. `passes` builds the
    passes kernel in; `variants` are extra KernelConfig fields (studies), applied last.

    A scheme that packs a pixel's samples is built only where it has samples to pack: with
    one sample a pixel the single-ray build renders, as the packet build's code costs the same
    rays 21 to 29 % more instructions (docs/acceleration.md, Where a sample's instructions
    go); and a device's own sample packets (neither the settings nor the tuning name a
    traversal) only where a pixel's samples fill a packet: on Intel's CPU runtime 4 samples
    in 8 lanes measured slower than the single-ray walk."""
    if tuning is None:
        tuning, source = chosen_tuning(device, stored_tuning)
    else:
        source = "given"
    misfit = _misfit(device, tuning, traversal, precision, spp)
    if misfit is not None and source == "given":
        raise SettingsError(f"tuning: {misfit}")
    if misfit is not None:
        # A tuning file is a speed choice, never an error: one that this render cannot build
        # (a double render's fewer lanes) gives way to the defaults, for this render alone.
        warnings.warn(f"ignoring {source} for this render: {misfit}", stacklevel=2)
        tuning, source = DEFAULT_TUNING, "default"
    named = traversal or tuning.traversal
    chosen = named or traversal_for(device)
    lanes = tuning.packet_lanes or packet_lanes_for(device, precision, spp)
    switches: dict[str, object] = {"traversal": chosen,
                                   "implicit_vectorization": tuning.implicit_vectorization}
    if TRAVERSAL_SCHEMES[chosen].packs_samples:
        if spp == 1 or (named is None and spp < lanes):
            switches["traversal"] = "single"
        else:
            switches.update(packet_lanes=lanes, packet_min_lanes=tuning.packet_min_lanes)
    if TRAVERSAL_SCHEMES[str(switches["traversal"])].vector_lanes:
        # Not packed on top of the walk's own vector lanes, whatever the tuning says: a tuning
        # made at 1 spp (the single-ray walk) may hold it on (clray.knobs.TraversalScheme).
        switches["implicit_vectorization"] = False
    switches.update({name: getattr(tuning, name) for name in IMAGE_KNOBS
                     if name not in BUILD_KNOBS})
    if tuning.build_options():
        switches["build_options"] = tuning.build_options()
    switches["passes"] = passes
    switches.update(variants)
    return DevicePlan(tuning=tuning, tuning_source=source,
                      traversal=str(switches["traversal"]), packet_lanes=lanes,
                      bvh_width=tuning.bvh_width or bvh_width_for(device, precision),
                      precision=precision, switches=switches)
