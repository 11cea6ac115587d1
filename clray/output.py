"""Output files written whole: a file that is either untouched or complete, never partial,
through symlinks to their targets, and straight into devices and pipes. Images (clray.image_io),
stats and tuning files (clray.device.tuning_files) are all written this way; and the one-line
error for an output that cannot be written."""

from __future__ import annotations

import io
import os
import secrets
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any

from clray.errors import ClrayError

if TYPE_CHECKING:
    import matplotlib.figure


def output_target(path: str | Path) -> Path:
    """Where writing `path` lands: a symlink's final target (its folder must take the file),
    else `path` itself. Writing there keeps the link a link and never writes elsewhere."""
    path = Path(path)
    try:
        linked = path.is_symlink()
    except (OSError, ValueError):  # a name the system refuses: the writer reports it
        return path
    return Path(os.path.realpath(path)) if linked else path


def is_special_file(path: Path) -> bool:
    """An existing file that is not a regular file: a device (/dev/stdout), a pipe."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # ValueError: a NUL byte in the name; the writer reports it
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def write_bytes_atomically(path: str | Path, payload: bytes) -> None:
    """Write `payload` so that `path` is either untouched or complete, never partial.

    Through a symlink the target is replaced, not the link. A device or pipe cannot be
    replaced by a rename (it would become a regular file): it is written directly."""
    path = output_target(path)
    if is_special_file(path):
        with open(path, "wb") as stream:
            stream.write(payload)
        return
    # Same directory, so os.replace is a rename on one file system; created with 0o666 rather
    # than through mkstemp so the finished file gets the usual umask-derived permissions.
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with os.fdopen(fd, "wb") as stream:
                stream.write(payload)
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    except OSError as err:
        if err.errno is None:
            raise
        # The temporary name is this function's own: the error names the file being written,
        # as writing it directly would, for callers that show err.filename. OSError() picks
        # the errno's subclass again (FileNotFoundError, IsADirectoryError).
        raise OSError(err.errno, err.strerror, os.fspath(path)) from None


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
