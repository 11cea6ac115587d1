"""clray/host_memory.py: the big stages run with numpy's huge-page advice off, put it back
after, and leave it alone where the user set NUMPY_MADVISE_HUGEPAGE; they hand glibc's free
heap pages back when they end."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clray import host_memory
from clray.device import launch, pack
from clray.scene.load import load_scene

try:  # numpy 2
    from numpy._core.multiarray import _get_madvise_hugepage, _set_madvise_hugepage
except ImportError:  # numpy 1.26
    from numpy.core.multiarray import _get_madvise_hugepage, _set_madvise_hugepage

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def advice_on(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    before = _set_madvise_hugepage(True)
    yield
    _set_madvise_hugepage(before)


class _Seen(Exception):
    """Raised from inside a stage with the advice it saw."""

    def __init__(self, advice: bool) -> None:
        super().__init__(advice)
        self.advice = advice


def _probe(*_args, **_kwargs):
    raise _Seen(_get_madvise_hugepage())


def test_a_stage_runs_without_the_advice_and_puts_it_back(advice_on: None) -> None:
    seen = []
    inner = host_memory.small_pages(lambda: seen.append(_get_madvise_hugepage()))
    outer = host_memory.small_pages(lambda: (inner(), seen.append(_get_madvise_hugepage())))
    outer()
    assert seen == [False, False]
    assert _get_madvise_hugepage() is True


def test_the_advice_returns_when_a_stage_raises(advice_on: None) -> None:
    with pytest.raises(_Seen) as seen:
        host_memory.small_pages(_probe)()
    assert seen.value.advice is False
    assert _get_madvise_hugepage() is True


def test_a_users_setting_is_left_alone(advice_on: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")
    with pytest.raises(_Seen) as seen:
        host_memory.small_pages(_probe)()
    assert seen.value.advice is True


def test_loading_packing_and_rendering_run_in_small_pages(
        advice_on: None, monkeypatch: pytest.MonkeyPatch) -> None:
    scene_file = ROOT / "scenes" / "spheres.toml"
    monkeypatch.setattr("clray.scene.load.ObjectParser", _probe)
    with pytest.raises(_Seen) as seen:
        load_scene(scene_file)
    assert seen.value.advice is False
    monkeypatch.undo()
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    scene = load_scene(scene_file)
    with monkeypatch.context() as patched:
        patched.setattr(pack, "_by_kind", _probe)
        with pytest.raises(_Seen) as seen:
            pack.pack_scene(scene, width=8, height=8, spp=1, max_depth=1, seed=0)
        assert seen.value.advice is False
    monkeypatch.setattr(launch, "band_capacity", _probe)
    packed = pack.pack_scene(scene, width=8, height=8, spp=1, max_depth=1, seed=0, passes=True)
    for stage in (launch.render_packed, launch.render_passes_packed):
        with pytest.raises(_Seen) as seen:
            stage(packed, SimpleNamespace(global_mem_size=1 << 30, max_mem_alloc_size=1 << 28))
        assert seen.value.advice is False
    assert _get_madvise_hugepage() is True


# Run in a process of its own: the heap of a process that other tests have used has free
# blocks of theirs in which the arrays below may land, so what a trim gives back there
# depends on the tests that ran before (it failed after tests/test_device_memory.py). Its
# malloc settings are set, not inherited: a child of the whole suite gave back 1.7 MB.
_HEAP_STAGE = """
import os
import numpy as np
from clray import host_memory

MIB = 1 << 20


def resident():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


# What a big model's pack meets once glibc's mmap threshold has risen (to 32 MiB at most),
# set here rather than left to the heap's history: arrays below it come from the heap, and
# freed ones stay there until a trim (the automatic trim of the heap's top, off).
host_memory._LIBC.mallopt(-3, 32 * MIB)  # M_MMAP_THRESHOLD
host_memory._LIBC.mallopt(-1, 1 << 30)  # M_TRIM_THRESHOLD


def stage():
    held = [np.ones(16 * MIB, np.uint8) for _ in range(4)]
    above = np.ones(8 * MIB, np.uint8)  # held beyond the stage
    del held
    return above, resident()


above, during = host_memory.small_pages(stage)()
print(during - resident(), int(above.sum()))
"""


@pytest.mark.skipif(host_memory._LIBC is None or not Path("/proc/self/statm").exists(),
                    reason="glibc's heap, read from /proc")
def test_a_stage_hands_the_heaps_free_pages_back() -> None:
    # Arrays below glibc's mmap threshold come from the heap, which shrinks only from its top:
    # freed beneath an array still held, their pages stayed with the process (141 MiB after
    # the 5.24 M-triangle mesh's collapse, docs/scale.md) until the stage gave them back.
    done = subprocess.run([sys.executable, "-c", _HEAP_STAGE], capture_output=True, text=True,
                          cwd=ROOT, check=True)
    given_back, above = (int(x) for x in done.stdout.split())
    assert given_back > 48 * (1 << 20)
    assert above == 8 << 20


@pytest.mark.parametrize("row_items", [1, 16, host_memory.CHUNK_ROWS * 2])
def test_chunks_cover_the_rows_once_with_chunk_rows_items_each(row_items: int) -> None:
    n = 3 * host_memory.CHUNK_ROWS // max(1, row_items // 2) + 5
    seen = np.zeros(n, dtype=np.int64)
    parts: list[slice] = []

    def work(part: slice) -> None:
        parts.append(part)
        seen[part] += 1

    host_memory.by_chunks(n, work, row_items=row_items)
    assert np.all(seen == 1)
    assert max(p.stop - p.start for p in parts) == max(1, host_memory.CHUNK_ROWS // row_items)


@pytest.mark.parametrize("counted", [3, None])
def test_chunks_run_where_the_system_has_no_affinity(
        monkeypatch: pytest.MonkeyPatch, counted: int | None) -> None:
    # macOS and Windows have no os.sched_getaffinity: the count of cores stands for it.
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    monkeypatch.delattr(os, "process_cpu_count", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: counted)
    assert host_memory.usable_cores() == (counted or 1)
    for n in (5, 3 * host_memory.CHUNK_ROWS):  # one chunk, and several
        seen = np.zeros(n, dtype=np.int64)

        def work(part: slice, seen: np.ndarray = seen) -> None:
            seen[part] += 1

        host_memory.by_chunks(n, work)
        assert np.all(seen == 1)
