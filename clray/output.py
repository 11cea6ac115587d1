"""Output files written whole: a file that is either untouched or complete, never partial,
through symlinks to their targets, and straight into devices and pipes; files that belong
together (an image and its passes, with the command's stats) as a set, none in place unless
all are written (WriteSet). Images (clray.image_io, clray.passes), stats and tuning files
(clray.device.tuning_files) are all written this way; and the one-line error for an output
that cannot be written."""

from __future__ import annotations

import contextlib
import errno
import io
import os
import secrets
import stat
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from clray.errors import ClrayError

if TYPE_CHECKING:
    import matplotlib.figure


def output_target(path: str | Path) -> Path:
    """Where writing `path` lands: a symlink's final target (its folder must take the file),
    else `path` itself, as it is for what is written directly (written_directly). Writing there
    keeps the link a link and never writes elsewhere."""
    path = Path(path)
    try:
        linked = path.is_symlink()
    except (OSError, ValueError):  # a name the system refuses: the writer reports it
        return path
    return Path(os.path.realpath(path)) if linked and not written_directly(path) else path


def written_directly(path: str | Path) -> bool:
    """Whether writing `path` writes into what is there rather than replacing it: one of this
    process's file descriptors (/dev/stdout, whatever it is: `>> log.txt` is appended to, not
    replaced), or, through any symlinks, an existing file that is not a regular file (a device,
    a pipe). Decided before the links are resolved: the resolved name of a descriptor's link is
    no file (`/proc/PID/fd/pipe:[...]`), or one whose rename would drop what it holds."""
    return _own_descriptor(path) is not None or _special_file(path)


# Symlinks followed in search of a descriptor, as the system's own limit (MAXSYMLINKS) on Linux.
_MAX_LINKS = 40


def _own_descriptor(path: str | Path) -> int | None:
    """The file descriptor of this process that `path` names through its symlinks (/dev/stdout
    -> /proc/self/fd/1, /dev/fd/3), or None. Linux's /proc only: elsewhere /dev/fd/N are devices,
    which _special_file finds."""
    fd_folder = f"/proc/{os.getpid()}/fd"
    try:
        current = os.path.abspath(path)
        for _ in range(_MAX_LINKS):
            folder, name = os.path.split(current)
            if name.isdigit() and os.path.realpath(folder) == fd_folder:
                return int(name)
            current = os.path.join(folder, os.readlink(current))  # an absolute target replaces
    except (OSError, ValueError):  # not a link (EINVAL), missing, or a name the system refuses
        return None
    return None


def _special_file(path: str | Path) -> bool:
    """An existing file, through any symlinks, that is not a regular file: a device, a pipe."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # ValueError: a NUL byte in the name; the writer reports it
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _write_descriptor(fd: int, payload: bytes) -> None:
    """`payload` written to `fd`, one of this process's own, after what Python's own streams on
    it hold."""
    for stream in (sys.stdout, sys.stderr):
        # None where the stream was closed at start; a stream replaced has no descriptor.
        with contextlib.suppress(AttributeError, OSError, ValueError):
            if stream.fileno() == fd:
                stream.flush()
    _write_all(fd, payload)


def _write_all(fd: int, payload: bytes) -> None:
    view = memoryview(payload)
    while view:
        view = view[os.write(fd, view):]


def _write_directly(path: str | Path, payload: bytes) -> None:
    """`payload` into what `path` names that is written directly (written_directly)."""
    fd = _own_descriptor(path)
    if fd is not None:
        _write_descriptor(fd, payload)
        return
    with open(path, "wb") as stream:
        stream.write(payload)


class WriteSet:
    """Files written as one, none in place unless all are written: an image and its passes'
    files, and the command's stats beside them.

    add and add_written write each file whole to a temporary name in its own folder (so that
    its rename stays on one file system) and fsync it; commit then renames them in the order
    added, so that a finished file is on disk before its name appears, and the last added
    appears last (the image: where it exists, so do its passes). A failure before the commit
    leaves no file of the set replaced, and discard removes the temporaries not renamed, also
    after an interrupt (write_set does both). Through a symlink the target is replaced, not the
    link. What is written directly (written_directly: a device, a pipe, this process's standard
    output) cannot be renamed onto: it is held until the commit and written before the renames,
    so that its failure (`/dev/full`) leaves no file of the set either. Errors name the file
    being written, never its temporary name."""

    def __init__(self) -> None:
        self._renames: list[tuple[Path, Path]] = []  # (temporary name, file's name), in order
        self._direct: list[tuple[str | Path, bytes]] = []

    def add(self, path: str | Path, payload: bytes) -> None:
        """`payload` to be the file at `path`."""
        if written_directly(path):
            self._direct.append((path, payload))
        else:
            self._stage(path, lambda fd, _: _write_all(fd, payload))

    def add_written(self, path: str | Path, write: Callable[[str], None]) -> None:
        """The file that `write(name)` writes at the file name it is given, to be the file at
        `path`: for a writer that takes a name, not bytes (OpenEXR's package)."""
        if written_directly(path):
            self._direct.append((path, _bytes_written(write, path)))
        else:
            self._stage(path, lambda _, tmp: write(os.fspath(tmp)))

    def _stage(self, path: str | Path, fill: Callable[[int, Path], None]) -> None:
        """A temporary file beside `path`'s target, filled by `fill(descriptor, its name)`."""
        target = output_target(path)
        tmp = temporary_name(target, "tmp")
        try:
            if os.path.isdir(target):  # the rename would fail only at the commit
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR))
            replaced = _regular_file_mode(target)
            # Created with 0o666 rather than through mkstemp so that a new file gets the usual
            # umask-derived permissions.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            self._renames.append((tmp, target))  # discard's to remove from here on
            try:
                # After the temporary file, whose failure tells a folder's problem in the
                # system's words (a read-only file system), which the file's mode would not.
                refuse_read_only(target)
                if replaced is not None:
                    # The file replaced keeps its permissions (a 0o640 image stays private);
                    # the rename makes a new file, which would have the umask's.
                    os.fchmod(fd, replaced)
                fill(fd, tmp)
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as err:
            raise _naming(err, target) from None

    def commit(self) -> None:
        """What is written directly (write_direct), then each temporary file renamed to its
        name, in the order added."""
        self.write_direct()
        while self._renames:
            tmp, target = self._renames[0]
            try:
                os.replace(tmp, target)
            except OSError as err:
                raise _naming(err, target) from None
            del self._renames[0]

    def write_direct(self) -> None:
        """What is written directly, written now, in the order added: commit's first step, for
        a caller that sends more of its own (an image to standard output) between the files'
        writes and their renames."""
        while self._direct:
            path, payload = self._direct[0]
            try:
                _write_directly(path, payload)
            except OSError as err:
                raise _naming(err, path) from None
            del self._direct[0]

    def discard(self) -> None:
        """The temporary files not renamed removed, and nothing left to write."""
        for tmp, _ in self._renames:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        self._renames.clear()
        self._direct.clear()


@contextlib.contextmanager
def write_set() -> Iterator[WriteSet]:
    """A WriteSet for the block to add to: committed when the block ends (unless the block has
    committed it), discarded where the block or the commit raises, an interrupt included."""
    files = WriteSet()
    try:
        yield files
        files.commit()
    finally:
        files.discard()


def _bytes_written(write: Callable[[str], None], path: str | Path) -> bytes:
    """What `write(name)` writes, as bytes, for `path`, which is written directly: a writer that
    seeks in its file (OpenEXR's) cannot write into a pipe. Through a private temporary file in
    the system's temporary folder, the one file of a set written outside its own folder."""
    try:
        with tempfile.TemporaryDirectory(prefix="clray-") as folder:
            name = os.path.join(folder, "file")
            write(name)
            return Path(name).read_bytes()
    except OSError as err:
        raise _naming(err, path) from None


def _naming(err: OSError, path: str | Path) -> OSError:
    """`err` naming `path`, the file being written, as writing it by its own name would, for
    callers that show err.filename: not the temporary name. OSError() picks the errno's
    subclass again (FileNotFoundError, IsADirectoryError, BrokenPipeError)."""
    if err.errno is None:
        return err
    return OSError(err.errno, err.strerror, os.fspath(path))


def write_bytes_atomically(path: str | Path, payload: bytes) -> None:
    """Write `payload` so that `path` is either untouched or complete, never partial: a
    WriteSet of one file."""
    with write_set() as files:
        files.add(path, payload)


# Bytes of the file's name that its temporary name keeps: with the rest (24 bytes at most) it
# stays within the 255 bytes a name may have (NAME_MAX) however long the file's own is.
_NAME_KEPT = 100


def temporary_name(path: Path, kind: str) -> Path:
    """A name in `path`'s folder, hidden, of this process and unlikely to be anyone else's, for
    a file that becomes `path` (kind "tmp") or shows that `path` could (kind "probe"): never
    longer than a name may be, however long `path`'s own is."""
    kept = os.fsdecode(os.fsencode(path.name)[:_NAME_KEPT])  # a character cut in two is bytes
    return path.with_name(f".{kept}.{os.getpid()}.{secrets.token_hex(4)}.{kind}")


def refuse_read_only(path: str | Path) -> None:
    """PermissionError naming `path` where it is, through any symlinks, a regular file that
    this process may not write (its mode, an ACL): replacing a file takes only its folder's
    permission, and would overwrite what its owner made read-only."""
    if _regular_file_mode(path) is not None and not os.access(path, os.W_OK):
        raise PermissionError(errno.EACCES, f"{os.strerror(errno.EACCES)} (read-only file)",
                              os.fspath(path))


def _regular_file_mode(path: str | Path) -> int | None:
    """The permission bits of the regular file at `path`, or None where there is none."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # none there, or a name the system refuses: os.open says
        return None
    return stat.S_IMODE(mode) if stat.S_ISREG(mode) else None


def error_words(err: OSError | ValueError) -> str:
    """What went wrong, in the system's words: an OSError's strerror ("Is a directory"), else
    the error's text (a ValueError: a name the system refuses, a NUL byte in it)."""
    return getattr(err, "strerror", None) or str(err)


def cannot_write(path: str | Path, why: str | OSError | ValueError, note: str = "") -> ClrayError:
    """The error for an output that cannot be written, `cannot write PATH: why (note)`: `why`
    the words, or an error (error_words)."""
    if not isinstance(why, str):
        why = error_words(why)
    return ClrayError(f"cannot write {path}: {why}" + (f" ({note})" if note else ""))


def refuse_a_folder(path: str | Path) -> None:
    """cannot_write where a folder stands where the file `path` goes: a look, before the work
    whose result the file holds, rather than a failed write after it."""
    if os.path.isdir(path):
        raise cannot_write(path, "it is a directory")


def write_output(path: str | Path, payload: bytes) -> None:
    """write_bytes_atomically, with an OSError (a full disk, a folder in the way) as
    cannot_write's one line naming `path`."""
    try:
        write_bytes_atomically(path, payload)
    except OSError as err:
        raise cannot_write(path, err) from err


def figure_png(fig: matplotlib.figure.Figure, **options: Any) -> bytes:
    """`fig` as PNG bytes (matplotlib's savefig `options`), and closed: bytes, so that the plot
    goes whole into its file through write_output, as every output does."""
    import matplotlib.pyplot as plt

    png = io.BytesIO()
    try:
        fig.savefig(png, format="png", **options)
    finally:
        plt.close(fig)
    return png.getvalue()
