"""Host arrays as buffers the kernels only read: in place where the device can read host
memory as fast as its own, else a copy."""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from clray.device.program import is_oclgrind


def read_only_buffer(ctx: cl.Context, array: np.ndarray) -> cl.Buffer:
    """A buffer the kernels only read. A CPU device reads the array in place (USE_HOST_PTR;
    pyopencl keeps the array alive with the buffer): a copy took the scene's bytes a second
    time in host memory, 343 MiB for the 5.24 M-triangle mesh (docs/scale.md). Elsewhere a
    copy: a GPU's memory, and Oclgrind, which takes a USE_HOST_PTR buffer's contents for
    uninitialised. In place, the array must outlive every kernel enqueued on the buffer."""
    # OpenCL has no zero-sized buffers: an empty array becomes one zeroed element.
    data = np.ascontiguousarray(array if array.size else np.zeros(1, dtype=array.dtype))
    device = ctx.devices[0]
    # In place only where the elements (records, or rows of a float4 array) lie across the
    # cache lines as in the device's own allocation (aligned to a line at least): a wide node
    # over five lines where it would span four, or a float4 off its 16 bytes, would cost the
    # kernels. numpy's large arrays start 16 bytes into a page: the nodes (256-byte records
    # of the 8-wide tree) are copied, the other large buffers read in place.
    element = data.nbytes // len(data)
    in_place = (reads_host_memory(device)
                and data.ctypes.data % math.gcd(element, device.global_mem_cacheline_size) == 0)
    where = cl.mem_flags.USE_HOST_PTR if in_place else cl.mem_flags.COPY_HOST_PTR
    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | where, hostbuf=data)


def reads_host_memory(device: cl.Device) -> bool:
    """Whether the device's kernels read a USE_HOST_PTR buffer's host memory as it is: a CPU
    device's memory is the host's. Not Oclgrind, which takes the contents of such a buffer for
    uninitialised."""
    return bool(device.type & cl.device_type.CPU) and not is_oclgrind(device)
