"""Host memory and cores while clray reads, packs and renders big scenes: fresh memory in small
pages, and passes over big arrays a chunk of rows at a time on every core.

numpy advises the kernel to back every large array with transparent huge pages
(madvise(MADV_HUGEPAGE)). On virtual machines whose balloon reports free memory back to the
host (virtio-balloon free page reporting, as on Firecracker), the huge pages a process touches
first are the reported ones: 512 MiB of them took 2.2 to 2.4 s to touch where 4 KiB pages took
0.24 to 0.30 s (docs/scale.md, "Fresh memory"). A 5.24 M-triangle model's load, BVH build and
pack touch about 1 GB of fresh arrays, so clray's big stages run with numpy's advice off
(`small_pages`), and put back whatever was set before when they end. A user who sets
NUMPY_MADVISE_HUGEPAGE chooses for themselves: clray then leaves numpy's setting alone.

Freed arrays of up to 32 MiB stay in the C library's heap, not the kernel's (`trim_heap`):
they go back when the last stage ends, and where the pack has freed many.

A mesh whose render would need more memory than the system has available is refused as soon as
its loader knows its triangles (`fits_host_memory`), not after minutes of swapping or a
MemoryError half-way; a MemoryError while a file loads names the file (`loading`).
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import ParamSpec, TypeVar

import numpy as np

from clray.errors import ClrayError, one_line, shown_path

try:  # numpy 2
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # numpy 1.26
    from numpy.core.multiarray import _set_madvise_hugepage

P = ParamSpec("P")
R = TypeVar("R")

_lock = threading.Lock()
_depth = 0
_before = True


def _glibc() -> ctypes.CDLL | None:
    """The C library where it is glibc (the name confstr gives it), else None."""
    confstr = getattr(os, "confstr", None)  # none on Windows
    try:
        found = (confstr("CS_GNU_LIBC_VERSION") if confstr else None) or ""
    except (ValueError, OSError):  # a system without the name (macOS, musl)
        found = ""
    return ctypes.CDLL(None) if found.startswith("glibc") else None


_LIBC = _glibc()


def trim_heap() -> None:
    """Hands the free pages of glibc's heaps back to the kernel (malloc_trim). glibc serves an
    allocation above its mmap threshold with a mapping of its own, unmapped when it is freed,
    and smaller ones from heaps that shrink only from their top; the threshold starts at
    128 KiB and rises to the size of each mapped block freed, up to 32 MiB. So once a big
    model's first large arrays are gone, its many arrays of 1 to 32 MiB come from the heap,
    and what they held stays with the process when they are freed: 138 MiB after the
    5.24 M-triangle mesh's BVH collapse, held through the rest of the pack and the render
    (docs/scale.md). Called where a stage has freed many such arrays: each call walks the
    heap's free blocks. Other C libraries: nothing to do here."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _enter(advice: bool) -> None:
    global _depth, _before
    with _lock:
        if _depth == 0 and advice:
            _before = _set_madvise_hugepage(False)
        _depth += 1


def _leave(advice: bool) -> None:
    global _depth
    with _lock:
        _depth -= 1
        if _depth == 0:
            if advice:
                _set_madvise_hugepage(_before)
            trim_heap()


def small_pages(stage: Callable[P, R]) -> Callable[P, R]:
    """`stage` runs with numpy's huge-page advice off, unless NUMPY_MADVISE_HUGEPAGE is set.
    Nested and concurrent stages share one switch: the advice returns when the last ends,
    and the heap's free pages go back to the kernel then (trim_heap)."""
    @functools.wraps(stage)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        advice = "NUMPY_MADVISE_HUGEPAGE" not in os.environ
        _enter(advice)
        try:
            return stage(*args, **kwargs)
        finally:
            _leave(advice)
    return run


# Vertices, triangles or child slots that a chunked pass takes at a time: its temporaries stay
# a few MiB however large the mesh (docs/scale.md, Where the memory goes).
CHUNK_ROWS = 1 << 16


def usable_cores() -> int:
    """The cores this process may run on: its affinity where the system has one (Linux), else
    the cores Python counts (macOS and Windows have no sched_getaffinity)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    count = getattr(os, "process_cpu_count", os.cpu_count)()  # process_cpu_count: 3.13+
    return count or 1  # None where the count is unknown


def by_chunks(n: int, work: Callable[[slice], None], row_items: int = 1) -> None:
    """work(rows) for each chunk of range(n), on as many threads as the process may run at
    once: numpy's gathers, minima and copies let go of the GIL, and a chunk writes its own rows
    alone, so the passes over a big mesh use every core, as the device build does.

    A chunk holds CHUNK_ROWS items: rows of `row_items` items each (a packet's slots, a wide
    node's children) come CHUNK_ROWS // row_items at a time. Each thread's temporaries stay in
    the C library's heap for that thread when freed, where malloc_trim does not reach (glibc
    trims only the main heap's top): chunks of 65,536 packets held 46 MiB there through the
    5.24 M-triangle mesh's pack (docs/scale.md)."""
    step = max(1, CHUNK_ROWS // row_items)
    parts = [slice(at, min(at + step, n)) for at in range(0, n, step)]
    threads = min(len(parts), usable_cores()) if len(parts) > 1 else 1
    if threads <= 1:
        for part in parts:
            work(part)
        return
    with ThreadPoolExecutor(threads) as pool:
        for _ in pool.map(work, parts):  # drained, so that a chunk's error is raised here
            pass


def aligned_empty(shape: tuple[int, ...], dtype: np.dtype | type, alignment: int) -> np.ndarray:
    """np.empty(shape, dtype) starting at a multiple of `alignment` bytes. numpy's large
    arrays start 16 bytes into a page: a buffer of records wider than that (the wide BVH
    nodes, 128 or 256 bytes) lay across the cache lines otherwise than in a device's own
    allocation, so a CPU device copied it rather than read it in place (read_only_buffer):
    49 MiB more while a 5.24 M-triangle mesh rendered."""
    dtype = np.dtype(dtype)
    nbytes = math.prod(shape) * dtype.itemsize
    raw = np.empty(nbytes + alignment, dtype=np.uint8)
    start = -raw.ctypes.data % alignment
    return raw[start:start + nbytes].view(dtype).reshape(shape)


# Host bytes a triangle at the peak of a mesh's render (the device BVH build), over what the
# process held before the model: docs/scale.md measured 1,667 MiB at 20.97 M triangles and
# 513 MiB at 5.24 M, less the 121 MiB the process holds before any scene: 77 and 78 B. Those
# meshes have half as many vertices as triangles; meshes with more vertices, or several
# materials, take more, and the other meshes of a scene are not counted: an estimate on the
# low side, so that what is refused would not have fitted.
HOST_BYTES_PER_TRIANGLE = 78
MEMINFO = Path("/proc/meminfo")


def memory_available() -> int | None:
    """The bytes the system can give without swapping (Linux's MemAvailable, which counts the
    page cache it can drop); None where it is not known (other systems)."""
    try:
        with MEMINFO.open("rb") as info:
            for line in info:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024  # in kB
    except (OSError, ValueError, IndexError):
        pass
    return None


def fits_host_memory(path: Path, triangles: int) -> None:
    """ClrayError (exit code 1) if rendering `triangles` more triangles from the file `path`
    would need more host memory than is available (HOST_BYTES_PER_TRIANGLE)."""
    needed = triangles * HOST_BYTES_PER_TRIANGLE
    available = memory_available()
    if available is not None and needed > available:
        raise ClrayError(one_line(
            f"{shown_path(path)}: {triangles:,} triangles need about {_bytes(needed)} of host "
            f"memory to render ({HOST_BYTES_PER_TRIANGLE} B a triangle, docs/scale.md), more "
            f"than the {_bytes(available)} available"))


@contextmanager
def loading(path: Path) -> Iterator[None]:
    """A MemoryError within, as a ClrayError naming the file (exit code 1): Python's own names
    nothing, and a scene may name many files."""
    try:
        yield
    except MemoryError:
        raise ClrayError(one_line(f"{shown_path(path)}: out of memory while loading it")) from None


def _bytes(count: int) -> str:
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if count >= size:
            return f"{count / size:.1f} {unit}"
    return f"{count} B"
