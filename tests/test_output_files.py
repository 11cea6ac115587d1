"""Outputs never destroy what they should not: symlinks are written through, pipes directly."""

from __future__ import annotations

import contextlib
import errno
import os
import resource
import signal
import stat
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from clray import image_io
from clray.cli import main
from clray.image_io import read_pfm, write_image
from clray.output import write_bytes_atomically
from clray.render import RenderResult

ROOT = Path(__file__).resolve().parent.parent


def test_a_symlink_stays_a_link_and_its_target_is_written(tmp_path):
    target = tmp_path / "elsewhere" / "real.txt"
    target.parent.mkdir()
    target.write_bytes(b"old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    write_bytes_atomically(link, b"new")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_bytes() == b"new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["real.txt"]  # no temp left


def test_a_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / "link.txt"
    link.symlink_to(tmp_path / "made.txt")
    write_bytes_atomically(link, b"data")
    assert link.is_symlink()
    assert (tmp_path / "made.txt").read_bytes() == b"data"


@pytest.mark.parametrize("where", ["missing/x.png", "folder"])
def test_an_error_names_the_file_not_its_temporary_name(tmp_path, where):
    (tmp_path / "folder").mkdir()
    path = tmp_path / where
    with pytest.raises(OSError) as info:
        write_bytes_atomically(path, b"data")
    assert info.value.filename == str(path) and info.value.filename2 is None
    assert info.value.errno in (errno.ENOENT, errno.EISDIR)
    assert str(info.value).endswith(f": {str(path)!r}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder"]
    assert list((tmp_path / "folder").iterdir()) == []


def test_a_result_with_passes_names_the_pass_file_it_cannot_write(tmp_path):
    result = RenderResult(np.zeros((2, 2, 3), np.float32), {},
                          aovs={"depth": np.ones((2, 2), np.float32)})
    with pytest.raises(FileNotFoundError) as info:
        result.save(tmp_path / "missing" / "x.png")
    assert info.value.filename == str(tmp_path / "missing" / "x.depth.pfm")


def _with_passes() -> RenderResult:
    return RenderResult(np.zeros((2, 2, 3), np.float32), {},
                        aovs={"depth": np.ones((2, 2), np.float32),
                              "normal": np.zeros((2, 2, 3), np.float32)})


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
def test_an_image_that_cannot_be_written_leaves_no_pass_file(tmp_path):
    # The passes and previews were written first, to their own names, and stayed beside no
    # image.
    (tmp_path / "a.png").symlink_to("/dev/full")
    with pytest.raises(OSError) as info:
        _with_passes().save(tmp_path / "a.png", previews=True)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "a.png")
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_an_interrupt_while_the_image_is_encoded_leaves_no_file(tmp_path, monkeypatch):
    # Once the passes' files are written, the image's encoder is interrupted: neither they nor
    # their temporary files stay.
    def interrupted(*_: object, **__: object) -> bytes:
        raise KeyboardInterrupt

    monkeypatch.setattr(image_io, "png_bytes", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _with_passes().save(tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


def test_each_file_is_on_disk_before_any_name_appears_and_the_image_last(tmp_path,
                                                                        monkeypatch):
    events = []
    fsync, replace = os.fsync, os.replace

    def fsync_noted(fd: int) -> None:
        events.append(("fsync", os.fstat(fd).st_ino))
        fsync(fd)

    def replace_noted(src: str | Path, dst: str | Path) -> None:
        events.append(("rename", os.stat(src).st_ino))
        replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync_noted)
    monkeypatch.setattr(os, "replace", replace_noted)
    _with_passes().save(tmp_path / "a.png", previews=True)
    names = ["a.depth.pfm", "a.depth.png", "a.normal.pfm", "a.normal.png", "a.png"]
    inodes = [(tmp_path / name).stat().st_ino for name in names]
    assert events == [("fsync", inode) for inode in inodes] + [("rename", inode)
                                                             for inode in inodes]


@contextlib.contextmanager
def _files_at_most(size: int) -> Iterator[None]:
    """Files this process writes end at `size` bytes, as on a full disk: a write past it fails
    with EFBIG (SIGXFSZ ignored) rather than killing the process."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)


def test_an_exr_write_cut_short_is_an_os_error_naming_the_image(tmp_path):
    # OpenEXR's own failure was a RuntimeError, which the command told as a traceback.
    pytest.importorskip("OpenEXR")
    image = np.random.default_rng(3).uniform(size=(64, 64, 3)).astype(np.float32)
    result = RenderResult(image, {}, aovs={"depth": np.ones((64, 64), np.float32)})
    path = tmp_path / "a.exr"
    with _files_at_most(4096), pytest.raises(OSError) as info:
        result.save(path)
    assert info.value.errno == errno.EIO and info.value.filename == str(path)
    # OpenEXR's words, without the temporary name they held.
    assert info.value.strerror.startswith("OpenEXR: ") and "File too large" in str(info.value)
    assert str(tmp_path) not in info.value.strerror
    assert list(tmp_path.iterdir()) == []


def test_exr_is_written_in_its_own_folder_not_the_temporary_folder(tmp_path, monkeypatch):
    # OpenEXR wrote a private file in /tmp and its bytes were copied: a full /tmp failed the
    # image, and the image took twice its size in memory.
    pytest.importorskip("OpenEXR")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no-such-folder"))
    path = tmp_path / "a.exr"
    path.write_bytes(b"old")
    path.chmod(0o640)
    image = np.arange(12, dtype=np.float32).reshape(2, 2, 3)
    write_image(path, image)
    assert np.array_equal(_exr_rgb(path), image)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640  # OpenEXR wrote into the staged file
    assert [p.name for p in tmp_path.iterdir()] == ["a.exr"]


def test_an_exr_into_a_pipe_is_written_whole(tmp_path):
    # OpenEXR seeks in the file it writes, which a pipe refuses: its file is made first.
    pytest.importorskip("OpenEXR")
    fifo = tmp_path / "a.exr"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    image = np.arange(12, dtype=np.float32).reshape(2, 2, 3)
    write_image(fifo, image)
    reader.join(timeout=10)
    copy = tmp_path / "copy.exr"
    copy.write_bytes(received[0])
    assert np.array_equal(_exr_rgb(copy), image)


def _exr_rgb(path: Path) -> np.ndarray:
    import OpenEXR

    return OpenEXR.File(str(path)).channels()["RGB"].pixels


def _read_only(monkeypatch: pytest.MonkeyPatch, *paths: Path) -> None:
    """`paths` not writable by this process, as for anyone but root with mode 0o444 (root may
    write any file, and the tests run as root in places)."""
    access = os.access
    locked = {os.path.realpath(path) for path in paths}

    def access_but_locked(path: str | Path, mode: int, **options: object) -> bool:
        if mode & os.W_OK and os.path.realpath(path) in locked:
            return False
        return access(path, mode, **options)

    monkeypatch.setattr(os, "access", access_but_locked)


@pytest.mark.parametrize("locked", ["a.png", "a.depth.pfm"])
def test_a_read_only_file_is_not_replaced(tmp_path, monkeypatch, locked):
    # The rename needs only the folder's permission: a 0o444 image was replaced, exit 0.
    for name in ("a.png", "a.depth.pfm"):
        (tmp_path / name).write_bytes(b"old")
    _read_only(monkeypatch, tmp_path / locked)
    with pytest.raises(PermissionError) as info:
        _with_passes().save(tmp_path / "a.png")
    assert info.value.filename == str(tmp_path / locked)
    assert info.value.strerror == "Permission denied (read-only file)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.depth.pfm", "a.png"]
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "a.depth.pfm").read_bytes() == b"old"


def test_a_read_only_image_is_found_before_rendering(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("clray.cli.render", _not_rendered)
    (tmp_path / "a.png").write_bytes(b"old")
    (tmp_path / "link.png").symlink_to("a.png")
    _read_only(monkeypatch, tmp_path / "a.png")
    code = main(["render", str(ROOT / "scenes" / "spheres.toml"), "-o", "link.png"])
    assert code == 1
    target = os.path.realpath(tmp_path / "a.png")  # through the link, its target is named
    assert capsys.readouterr().err == (f"clray: error: cannot write {target}: Permission denied "
                                       "(read-only file)\n")
    assert (tmp_path / "a.png").read_bytes() == b"old"


def _not_rendered(*_: object, **__: object) -> None:
    raise AssertionError("rendered although the output could not be written")


def test_a_pipe_is_written_not_replaced(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    write_bytes_atomically(fifo, b"through the pipe")
    reader.join(timeout=10)
    assert received == [b"through the pipe"]
    assert not fifo.is_file() and fifo.exists()  # still a pipe, not a regular file


def test_render_through_a_symlinked_output(cl_device, tmp_path):
    target = tmp_path / "out" / "image.pfm"
    target.parent.mkdir()
    link = tmp_path / "image.pfm"
    link.symlink_to(target)
    code = main(["render", str(ROOT / "scenes" / "spheres.toml"), "-W", "16", "-H", "12", "-q",
                 "-o", str(link)])
    assert code == 0
    assert link.is_symlink()
    image = read_pfm(target)
    assert image.shape == (12, 16, 3) and np.all(np.isfinite(image))


@pytest.mark.parametrize("args", [
    ["render", "-W", "8", "-H", "6", "-o", "a\0b.png"],
    ["render", "-W", "8", "-H", "6", "-o", "ok.png", "--stats-json", "a\0b.json"],
    ["tune", "--out", "a\0b"],
    ["study", "--out", "a\0b"],
], ids=["render-o", "stats-json", "tune-out", "study-out"])
def test_a_nul_byte_in_an_output_name_is_a_one_line_error(cl_device, capsys, monkeypatch,
                                                          tmp_path, args):
    # os.stat raises ValueError, not OSError, for such a name.
    monkeypatch.chdir(tmp_path)
    code = main([args[0], str(ROOT / "scenes" / "spheres.toml"), *args[1:]])
    err = capsys.readouterr().err.splitlines()
    assert code == 1
    assert len(err) == 1 and err[0].startswith("clray: error: cannot write a\\x00b")
    assert err[0].endswith(": embedded null byte")
    assert list(tmp_path.iterdir()) == []


def test_a_link_to_a_descriptor_of_a_file_appends_to_it(tmp_path):
    # `clray ... --stats-json /dev/stdout >> log.txt`: the log keeps what it held, and stays
    # the same file (a rename onto the link's resolved name would have replaced it).
    log = tmp_path / "log.txt"
    log.write_bytes(b"earlier\n")
    inode = log.stat().st_ino
    fd = os.open(log, os.O_WRONLY | os.O_APPEND)
    try:
        link = tmp_path / "out.json"
        link.symlink_to(f"/dev/fd/{fd}")
        write_bytes_atomically(link, b"new\n")
    finally:
        os.close(fd)
    assert log.read_bytes() == b"earlier\nnew\n"
    assert log.stat().st_ino == inode
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.txt", "out.json"]


def test_a_link_to_a_descriptor_of_a_pipe_is_written(tmp_path):
    # `--stats-json /dev/stdout | reader`: the link's resolved name, /proc/PID/fd/pipe:[N], is
    # no file, and used to fail the write.
    read_end, write_end = os.pipe()
    try:
        link = tmp_path / "out.json"
        link.symlink_to(f"/proc/self/fd/{write_end}")
        write_bytes_atomically(link, b"through the pipe")
        os.close(write_end)
        write_end = -1
        assert os.read(read_end, 100) == b"through the pipe"
    finally:
        os.close(read_end)
        if write_end >= 0:
            os.close(write_end)


def test_a_replaced_file_keeps_its_permissions(tmp_path):
    path = tmp_path / "image.png"
    path.write_bytes(b"old")
    path.chmod(0o640)
    write_bytes_atomically(path, b"new")
    assert path.read_bytes() == b"new"
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


@pytest.mark.parametrize("name", ["a" * 240 + ".png", "é" * 120 + ".png"], ids=["ascii", "utf8"])
def test_a_name_as_long_as_a_name_may_be_is_written(tmp_path, name):
    # 244 bytes: the temporary name, the whole name with 24 bytes more, was too long.
    path = tmp_path / name
    write_bytes_atomically(path, b"data")
    assert path.read_bytes() == b"data"
    assert [p.name for p in tmp_path.iterdir()] == [name]
