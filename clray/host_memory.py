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
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import ParamSpec, TypeVar

try:  # numpy 2
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # numpy 1.26
    from numpy.core.multiarray import _set_madvise_hugepage

P = ParamSpec("P")
R = TypeVar("R")

_lock = threading.Lock()
_depth = 0
_before = True


def _enter() -> None:
    global _depth, _before
    with _lock:
        if _depth == 0:
            _before = _set_madvise_hugepage(False)
        _depth += 1


def _leave() -> None:
    global _depth
    with _lock:
        _depth -= 1
        if _depth == 0:
            _set_madvise_hugepage(_before)


def small_pages(stage: Callable[P, R]) -> Callable[P, R]:
    """`stage` runs with numpy's huge-page advice off, unless NUMPY_MADVISE_HUGEPAGE is set.
    Nested and concurrent stages share one switch: the advice returns when the last ends."""
    @functools.wraps(stage)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
            return stage(*args, **kwargs)
        _enter()
        try:
            return stage(*args, **kwargs)
        finally:
            _leave()
    return run


# Rows (vertices, triangles, packets, wide nodes) that a chunked pass takes at a time: its
# temporaries stay a few MiB however large the mesh (docs/scale.md, Where the memory goes).
CHUNK_ROWS = 1 << 16


def by_chunks(n: int, work: Callable[[slice], None]) -> None:
    """work(rows) for each CHUNK_ROWS of range(n), on as many threads as the process may run
    at once: numpy's gathers, minima and copies let go of the GIL, and a chunk writes its own
    rows alone, so the passes over a big mesh use every core, as the device build does."""
    parts = [slice(at, min(at + CHUNK_ROWS, n)) for at in range(0, n, CHUNK_ROWS)]
    threads = min(len(parts), len(os.sched_getaffinity(0)))
    if threads <= 1:
        for part in parts:
            work(part)
        return
    with ThreadPoolExecutor(threads) as pool:
        for _ in pool.map(work, parts):  # drained, so that a chunk's error is raised here
            pass
