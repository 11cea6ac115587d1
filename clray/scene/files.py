"""Opening the files a scene names (the scene itself, meshes, textures) without hanging, and
keeping them for an animation's frames.

A scene may name any path. Reading a FIFO or a character device would block or never end, so
only regular files are read; they are opened non-blocking so that a FIFO is refused at once
instead of waiting for a writer, and their size is checked before reading.

Within KeptFiles.used(), each file is read whole once and kept by its absolute path, and opened
again from memory: an animation (clray.sequence) keeps the files its scene read as it was
loaded and checked, and makes each frame's scene from them, wherever that is (a Dask worker
without those files, or in another working directory). What a mesh, MTL or image file's bytes
parse to is kept beside them (kept_parse), so that each frame does not parse the same bytes
again.
"""

from __future__ import annotations

import contextlib
import io
import os
import stat
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from pathlib import Path
from typing import Any, BinaryIO, TypeVar

T = TypeVar("T")


class UnreadableFile(Exception):
    """A one-line reason, for the caller to put into a SceneError with its key."""


def open_regular(path: Path, max_bytes: int) -> tuple[BinaryIO, os.stat_result]:
    """Open `path` for reading if it is a regular file of at most `max_bytes` bytes (from the
    files kept, within KeptFiles.used())."""
    noted = _READS.get()
    if noted is not None:
        noted.add(os.path.abspath(path))
    kept = _KEPT.get()
    if kept is not None:
        return kept.open(path, max_bytes)
    stream, info = _open(path)
    try:
        _fits(info.st_size, max_bytes)
    except UnreadableFile:
        stream.close()
        raise
    return stream, info


@contextlib.contextmanager
def noting_reads() -> Iterator[set[str]]:
    """The absolute names of the files that open_regular is asked for within the block (those
    that could not be opened too): the command line refuses an output that would replace a file
    its scene reads (a texture named like the image)."""
    names: set[str] = set()
    token = _READS.set(names)
    try:
        yield names
    finally:
        _READS.reset(token)


def _open(path: Path) -> tuple[BinaryIO, os.stat_result]:
    """`path` open for reading, if it is a regular file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise UnreadableFile("file not found") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
        raise UnreadableFile(getattr(exc, "strerror", None) or str(exc)) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnreadableFile("not a regular file")
        os.set_blocking(fd, True)  # O_NONBLOCK was for the open; reads may block as usual
        return os.fdopen(fd, "rb"), info
    except BaseException:
        os.close(fd)
        raise


def _fits(size: int, max_bytes: int) -> None:
    if size > max_bytes:
        raise UnreadableFile(f"{size} bytes is over the limit of {max_bytes} bytes")


# Bytes read at a time once a file turns out longer than its size said (it grew since).
_GROWN_READ = 1 << 20


def read_at_most(stream: BinaryIO, max_bytes: int) -> bytes:
    """The rest of `stream`, if it is at most `max_bytes` long (a file may have grown since
    open_regular looked at its size)."""
    try:
        return _read_at_most(stream, max_bytes)
    except OSError as exc:
        raise UnreadableFile(exc.strerror or str(exc)) from None


def _read_at_most(stream: BinaryIO, max_bytes: int) -> bytes:
    left = _bytes_left(stream)
    if left is None:
        # An in-memory stream (KeptFiles): its read takes no more than it holds.
        data = stream.read(max_bytes + 1)
    else:
        # Not read(max_bytes + 1): CPython allocates the whole of a read's size before it
        # shrinks the result: 1 GiB for every PLY file, whatever its size (its limit). The
        # file's size and one byte more, to see a file that grew since it was looked at.
        want = min(max_bytes, left) + 1
        parts = [stream.read(want)]
        total = len(parts[0])
        while len(parts[-1]) == want and total <= max_bytes:  # it grew: the rest in parts
            want = min(_GROWN_READ, max_bytes + 1 - total)
            parts.append(stream.read(want))
            total += len(parts[-1])
        data = parts[0] if len(parts) == 1 else b"".join(parts)
    if len(data) > max_bytes:
        raise UnreadableFile(f"over the limit of {max_bytes} bytes")
    return data


def _bytes_left(stream: BinaryIO) -> int | None:
    """The bytes from the stream's position to the end of its file, as the file's status says
    now; None for a stream without a file."""
    try:
        return max(0, os.fstat(stream.fileno()).st_size - stream.tell())
    except (AttributeError, io.UnsupportedOperation):
        return None


def read_regular(path: Path, max_bytes: int) -> bytes:
    """The contents of a regular file of at most `max_bytes` bytes."""
    stream, _ = open_regular(path, max_bytes)
    with stream:
        return read_at_most(stream, max_bytes)


class KeptFiles:
    """Files read whole, by absolute path: each file's bytes and status, or why it could not
    be opened (a missing material library is a warning, and must stay one). Picklable: a Dask
    worker gets them with the animation, without what they parsed to (`parsed`, which each
    worker makes again, once)."""

    def __init__(self) -> None:
        # A file, once kept, is never read again nor replaced: what is parsed from it by its
        # name (`parsed`) is what its kept bytes parse to.
        self.files: dict[str, tuple[bytes, os.stat_result] | str] = {}
        # kept_parse's results, by (kind, absolute path).
        self.parsed: dict[tuple[str, str], Any] = {}

    def __getstate__(self) -> dict[str, Any]:
        # The bytes alone: parsed meshes and decoded images would double what a worker is
        # sent.
        return {"files": self.files}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.files = state["files"]
        self.parsed = {}

    @contextlib.contextmanager
    def used(self) -> Iterator[None]:
        """open_regular opens the files kept, and keeps each file it reads first."""
        token = _KEPT.set(self)
        try:
            yield
        finally:
            _KEPT.reset(token)

    def open(self, path: Path, max_bytes: int) -> tuple[BinaryIO, os.stat_result]:
        """open_regular's answer for `path`, from memory; read and kept first if new."""
        # Not resolved: a name is relative to the folder it was named in, through any link,
        # as the system opens it (clray.scene.include), and a worker may lack the links.
        name = os.path.abspath(path)
        if name not in self.files:
            try:
                stream, info = _open(path)
            except UnreadableFile as exc:
                self.files[name] = str(exc)
                raise
            with stream:
                # Over the limit, nothing is kept: it is said again for each open.
                _fits(info.st_size, max_bytes)
                self.files[name] = read_at_most(stream, max_bytes), info
        kept = self.files[name]
        if isinstance(kept, str):
            raise UnreadableFile(kept)
        data, info = kept
        _fits(len(data), max_bytes)  # kept for another opener's limit, which may be larger
        # Its read() of the whole returns `data` itself, not a copy (CPython's BytesIO).
        return io.BytesIO(data), info


def kept_parse(path: Path, kind: str, parse: Callable[[], T]) -> T:
    """parse(): the file at `path` (and any it names, kept too) parsed as `kind`. Within
    KeptFiles.used(), once: its result is kept beside the bytes it came from, and given again
    for the same kind and absolute path. It is shared between scenes, so the caller makes it
    read-only; an exception keeps nothing. `kind` must name everything besides the files that
    changes the result."""
    kept = _KEPT.get()
    if kept is None:
        return parse()
    key = (kind, os.path.abspath(path))
    if key not in kept.parsed:
        kept.parsed[key] = parse()
    return kept.parsed[key]


def parses_kept() -> bool:
    """Whether kept_parse keeps what it parses here (within KeptFiles.used())."""
    return _KEPT.get() is not None


_KEPT: ContextVar[KeptFiles | None] = ContextVar("clray_kept_files", default=None)
_READS: ContextVar[set[str] | None] = ContextVar("clray_files_read", default=None)


def lf_line_ends(data: bytes) -> bytes:
    """Text whose lines end in a CR alone (classic Mac OS files) with LF line ends instead, the
    same length (byte offsets, and so line numbers, unchanged); other text as it is. Only
    where the text holds no LF: a CR then ends every line, and the line readers (OBJ, MTL),
    which split at LF, read such a file as one line."""
    if b"\r" in data and b"\n" not in data:
        return data.replace(b"\r", b"\n")
    return data
