"""What the benchmark scripts share: argument types that turn a bad value into one usage line
(argparse's error, exit status 2) instead of a traceback or a measurement of nothing, the check
of the output files before the work, the host processor a result names, and the peak memory of
a child process.

The scripts import it as `benchmarks.common`, with the repository's root on the path (benchmarks/
is not a package: it imports as a namespace package, as tests/ does).
"""

from __future__ import annotations

import argparse
import platform
from collections.abc import Callable, Iterable
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def positive_int(text: str) -> int:
    """argparse type: an integer of at least 1 (--repeat, --rounds: a median of no run, or a
    render of no samples, has no value)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def positive_ints(text: str) -> list[int]:
    """argparse type: comma-separated integers of at least 1, at least one of them."""
    values = [positive_int(part) for part in text.split(",") if part.strip()]
    if not values:
        raise argparse.ArgumentTypeError("expected at least one number")
    return values


def distinct_positive_ints(text: str) -> list[int]:
    """argparse type: positive_ints, each at most once (refused, not merged, as names_of's
    names: a repeated value would be measured twice)."""
    return _each_once(positive_ints(text))


def _each_once(values: list) -> list:
    """`values` where none repeats; else argparse's error naming the repeated ones."""
    repeated = sorted({value for value in values if values.count(value) > 1})
    if repeated:
        raise argparse.ArgumentTypeError(
            f"each at most once; repeated: {', '.join(map(str, repeated))}")
    return values


def image_size(text: str) -> tuple[int, int]:
    """argparse type: WxH, both at least 1."""
    width, sep, height = text.lower().partition("x")
    try:
        if not sep:
            raise argparse.ArgumentTypeError("")
        return positive_int(width), positive_int(height)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 96x54, got {text!r}") from None


def names_of(choices: Iterable[str]) -> Callable[[str], list[str]]:
    """argparse type: a comma-separated list of some of `choices`, at least one, each at most
    once (refused, not merged: a repeated name would be measured twice)."""
    allowed = tuple(choices)

    def parse(text: str) -> list[str]:
        names = [name.strip() for name in text.split(",") if name.strip()]
        unknown = [name for name in names if name not in allowed]
        if unknown:
            raise argparse.ArgumentTypeError(f"unknown {', '.join(map(repr, unknown))}; "
                                             f"choose from {', '.join(allowed)}")
        if not names:
            raise argparse.ArgumentTypeError("expected at least one name")
        return _each_once(names)
    return parse


def check_outputs(parser: argparse.ArgumentParser, **paths: Path | str | None) -> None:
    """Create each output's folder and make sure the file can be written, before any work:
    a run of minutes or hours must not end at an unwritable path. Keyword names are the flags
    (json=..., out=...); None is skipped. The file is not truncated: an existing one keeps its
    contents until the result replaces it."""
    for flag, path in paths.items():
        if path is None:
            continue
        path = Path(path)
        option = "--" + flag.replace("_", "-")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            existed = path.exists()
            with path.open("a"):
                pass
            if not existed:
                path.unlink()
        except OSError as err:
            parser.error(f"{option} {path}: cannot write there ({err.strerror or err})")


def cpu_model() -> dict:
    """The host processor's model name (null where neither /proc/cpuinfo nor the platform
    module names it) and whether it has the vector extensions that matter here: `cpu_model`,
    `avx2`, `avx512f`."""
    model, flags = platform.processor() or None, set()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model in (None, "", "x86_64"):
                model = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = set(value.split())
    except OSError:
        pass
    return {"cpu_model": model, "avx2": "avx2" in flags, "avx512f": "avx512f" in flags}


# Source of peak() for a child process run with `python -c`: its peak resident bytes, VmHWM,
# which starts afresh at exec. ru_maxrss does not: it survives fork and exec, so a child that
# stays below its parent's peak reports the parent's (the parent's mesh writer, for a big mesh).
# ru_maxrss only where /proc is missing (not Linux).
PEAK_SOURCE = '''
def peak():
    import resource
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
'''
