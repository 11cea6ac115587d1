"""Opening the files a scene names (the scene itself, meshes, textures) without hanging.

A scene may name any path. Reading a FIFO or a character device would block or never end, so
only regular files are read; they are opened non-blocking so that a FIFO is refused at once
instead of waiting for a writer, and their size is checked before reading.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO


class UnreadableFile(Exception):
    """A one-line reason, for the caller to put into a SceneError with its key."""


def open_regular(path: Path, max_bytes: int) -> tuple[BinaryIO, os.stat_result]:
    """Open `path` for reading if it is a regular file of at most `max_bytes` bytes."""
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
        if info.st_size > max_bytes:
            raise UnreadableFile(f"{info.st_size} bytes is over the limit of {max_bytes} bytes")
        os.set_blocking(fd, True)  # O_NONBLOCK was for the open; reads may block as usual
        return os.fdopen(fd, "rb"), info
    except BaseException:
        os.close(fd)
        raise


def read_at_most(stream: BinaryIO, max_bytes: int) -> bytes:
    """The rest of `stream`, if it is at most `max_bytes` long (a file may have grown since
    open_regular looked at its size)."""
    try:
        data = stream.read(max_bytes + 1)
    except OSError as exc:
        raise UnreadableFile(exc.strerror or str(exc)) from None
    if len(data) > max_bytes:
        raise UnreadableFile(f"over the limit of {max_bytes} bytes")
    return data


def read_regular(path: Path, max_bytes: int) -> bytes:
    """The contents of a regular file of at most `max_bytes` bytes."""
    stream, _ = open_regular(path, max_bytes)
    with stream:
        return read_at_most(stream, max_bytes)
