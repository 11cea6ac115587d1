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

from clray import cli, host_memory
from clray.device import launch, pack
from clray.errors import ClrayError, SceneError
from clray.model_scene import load_model_scene
from clray.scene import assets, ply
from clray.scene.load import load_scene
from tests.test_files import cube_file

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


def _available(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, kib: int) -> None:
    meminfo = tmp_path / "meminfo"
    meminfo.write_text(f"MemTotal:       16384000 kB\nMemFree:          100000 kB\n"
                       f"MemAvailable:   {kib:>9} kB\n")
    monkeypatch.setattr(host_memory, "MEMINFO", meminfo)


def test_the_memory_available_is_read_where_the_system_says_it(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    _available(monkeypatch, tmp_path, 1234)
    assert host_memory.memory_available() == 1234 * 1024
    monkeypatch.setattr(host_memory, "MEMINFO", tmp_path / "missing")  # not Linux
    assert host_memory.memory_available() is None
    host_memory.fits_host_memory(Path("any.ply"), 10 ** 9)  # unknown: nothing refused


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".npz", ".glb"])
def test_a_mesh_beyond_the_memory_available_is_refused_in_one_line(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        suffix: str) -> None:
    # Named by the path as given (two meshes may share a base name), the loader's absolute
    # one shown from the working directory.
    (tmp_path / "sub").mkdir()
    cube_file(tmp_path / "sub" / f"cube{suffix}")
    monkeypatch.chdir(tmp_path)
    _available(monkeypatch, tmp_path, 1)  # 12 triangles need 936 B of the 1 KiB
    assert cli.main(["scene", f"sub/cube{suffix}"]) == 0
    capsys.readouterr()
    _available(monkeypatch, tmp_path, 0)
    assert cli.main(["scene", f"sub/cube{suffix}"]) == 1
    assert capsys.readouterr().err == (
        f"clray: error: sub/cube{suffix}: 12 triangles need about 936 B of host memory to render "
        f"({host_memory.HOST_BYTES_PER_TRIANGLE} B a triangle, docs/scale.md), more than the "
        "0 B available\n")


def test_a_ply_file_beyond_the_memory_available_is_refused_from_its_header(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    path = cube_file(tmp_path / "cube.ply")
    _available(monkeypatch, tmp_path, 0)

    def unread(*args: object) -> None:
        raise AssertionError("the records were read")

    monkeypatch.setattr(ply._Reader, "ascii", unread)
    with pytest.raises(ClrayError, match=r"cube\.ply: 12 triangles need about 936 B"):
        load_model_scene(path)


def test_running_out_of_memory_while_loading_names_the_file(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
        ) -> None:
    (tmp_path / "sub").mkdir()
    cube_file(tmp_path / "sub" / "cube.obj")
    monkeypatch.chdir(tmp_path)

    def exhausted(*args: object) -> None:
        raise MemoryError

    monkeypatch.setattr(assets, "parse_obj", exhausted)
    assert cli.main(["scene", "sub/cube.obj"]) == 1
    assert capsys.readouterr().err == (
        "clray: error: sub/cube.obj: out of memory while loading it\n")


def test_a_truncated_ply_file_is_said_to_be_truncated_not_too_big(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # It declares 10 million faces but holds none: its bytes, not its header, bound the
    # estimate.
    path = tmp_path / "cut.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                     b"property float x\nproperty float y\nproperty float z\n"
                     b"element face 10000000\nproperty list uchar int vertex_indices\n"
                     b"end_header\n" + bytes(36))
    _available(monkeypatch, tmp_path, 1)
    with pytest.raises(SceneError) as info:
        load_model_scene(path)
    assert "memory" not in str(info.value)
