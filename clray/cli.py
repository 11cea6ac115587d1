"""The `clray` command (also `python -m clray`): `clray render SCENE ...`, `clray study SCENE...
--out DIR` and `clray devices`.

Exit codes: 0 ok, 1 runtime error, 2 usage, 3 scene error, 4 OpenCL error, 130 interrupted.
Every error a user can cause is one `clray: error: ...` line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import secrets
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

import pyopencl as cl

from clray import __version__
from clray.device.context import list_devices
from clray.errors import EXIT_OK, EXIT_RUNTIME, EXIT_USAGE, ClrayError, one_line
from clray.image_io import (
    EXPOSURE_RULE,
    FLOAT_SUFFIXES,
    PNG_BITS,
    SUFFIXES,
    check_suffix,
    check_writer,
    clipped_pixels,
    is_exposure,
    is_special_file,
    output_target,
    write_bytes_atomically,
)
from clray.metrics import nonfinite_count
from clray.render import RenderSettings, render
from clray.scene import limits
from clray.scene.load import load_scene

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report it
SEED_MAX = limits.MAX_SEED
MAX_REPEAT = 1000


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line, like every other clray error."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"clray: error: {one_line(message)} (see '{self.prog} --help')\n")


def _shown(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _int_in(low: int, high: int) -> Callable[[str], int]:
    # Every count has a maximum: past it the kernels' int32 arithmetic would overflow, long
    # before the render would end.
    def parse(text: str) -> int:
        try:
            value = int(text) if len(text) <= 40 else None
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"expected an integer in [{low}, {high}], got {_shown(text)}"
            )
        return value

    return parse


def _file_path(text: str) -> Path:
    """A path to write a file to: it must name a file, not a directory."""
    if not text:
        raise argparse.ArgumentTypeError("expected a file name, got ''")
    path = Path(text)
    if text.endswith(("/", os.sep)) or path.name in ("", ".", ".."):
        raise argparse.ArgumentTypeError(f"expected a file name, got the directory {_shown(text)}")
    return path


def _image_path(text: str) -> Path:
    try:
        check_suffix(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err
    return _file_path(text)


def _exposure(text: str) -> float:
    try:
        value = float(text) if len(text) <= 40 else None
    except ValueError:
        value = None
    if not is_exposure(value):
        raise argparse.ArgumentTypeError(f"expected {EXPOSURE_RULE}, got {_shown(text)}")
    return value


def _build_parser() -> _Parser:
    parser = _Parser(prog="clray", description="Whitted ray tracer running as OpenCL kernels.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = commands.add_parser(
        "render", help="render a scene file to an image",
        description="Render SCENE. Flags override the scene file's [render] values.")
    r.add_argument("scene", type=Path, metavar="SCENE", help="scene file (.toml or .json)")
    r.add_argument("-o", "--output", type=_image_path, metavar="OUT",
                   help=f"output image, by suffix: {', '.join(SUFFIXES)} (.png is 8- or "
                        "16-bit, sRGB unless --linear, clamped to [0, 1] after --exposure; .pfm "
                        "and .exr are float32 linear radiance, every value kept; .exr needs "
                        "pip install 'clray[exr]'); default: SCENE's stem + .png in the current "
                        "directory")
    size = _int_in(1, limits.MAX_IMAGE_SIZE)
    r.add_argument("-W", "--width", type=size, metavar="N", help="image width in pixels")
    r.add_argument("-H", "--height", type=size, metavar="N", help="image height in pixels")
    r.add_argument("--spp", type=_int_in(1, limits.MAX_SPP), metavar="N",
                   help="samples per pixel")
    r.add_argument("--max-depth", type=_int_in(0, limits.MAX_DEPTH), metavar="N",
                   help="reflection/refraction bounces after the primary hit")
    r.add_argument("--seed", type=_int_in(0, SEED_MAX), metavar="N",
                   help="seed of the sample jitter")
    r.add_argument("--device", metavar="SPEC",
                   help="OpenCL device: 'P:D' indices as in PYOPENCL_CTX, or a name substring "
                        "(default: CLRAY_DEVICE, PYOPENCL_CTX, then the first CPU device)")
    r.add_argument("--precision", choices=("float", "double"), default="float",
                   help="arithmetic in the kernels (double needs cl_khr_fp64; default: float)")
    encoding = r.add_mutually_exclusive_group()
    encoding.add_argument("--linear", dest="linear", action="store_true", default=None,
                          help="write PNG values linear, tagged gamma 1.0 (default: the sRGB "
                               "curve, tagged sRGB, unless the scene's [render] linear = true)")
    encoding.add_argument("--srgb", dest="linear", action="store_false",
                          help="write PNG values sRGB-encoded, overriding [render] linear")
    r.add_argument("--exposure", type=_exposure, metavar="STOPS",
                   help="scale PNG values by 2^STOPS before each channel is clipped to "
                        "[0, 1] (stats: clipped_pixels); default: [render] exposure, else 0. "
                        "PFM and EXR keep the radiance as rendered")
    r.add_argument("--png-bits", type=int, choices=PNG_BITS,
                   help="bits a PNG sample (default: [render] png_bits, else 8)")
    r.add_argument("--stats-json", type=_file_path, metavar="PATH",
                   help="write timings, sizes and ray counts as JSON")
    talk = r.add_mutually_exclusive_group()
    talk.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    talk.add_argument("-v", "--verbose", action="store_true",
                      help="print progress, compiler warnings and the stats summary")
    r.set_defaults(run=_render)

    st = commands.add_parser(
        "study", help="kernel time against error for variants of the kernel",
        description="Render each SCENE with every kernel variant (float/double, build options, "
                    "textbook formulas) and compare with the double build: writes "
                    "DIR/results.json, DIR/report.md and a time-vs-error PNG per scene "
                    "(needs matplotlib, the 'plot' extra; skipped with a note otherwise).")
    st.add_argument("scenes", type=Path, nargs="+", metavar="SCENE",
                    help="scene files (.toml or .json)")
    st.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    st.add_argument("--repeat", type=_int_in(1, MAX_REPEAT), default=3, metavar="N",
                    help="timed runs per variant after a warm-up; the median is reported "
                         "(default: 3)")
    st.add_argument("-W", "--width", type=size, metavar="N",
                    help="image width for every scene (default: each scene's own)")
    st.add_argument("-H", "--height", type=size, metavar="N",
                    help="image height for every scene (default: each scene's own)")
    st.add_argument("--device", metavar="SPEC", help="OpenCL device, as for render")
    st.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    st.set_defaults(run=_study)

    d = commands.add_parser("devices", help="list OpenCL devices, one per line",
                            description="List OpenCL devices: spec, type, name, platform, "
                                        "compute units, fp64 support, driver version.")
    d.set_defaults(run=_devices)
    return parser


def _parse(argv: list[str] | None) -> argparse.Namespace:
    parser = _build_parser()
    args = parser.parse_args(argv)
    if args.command == "render":
        if args.output is None:
            args.output = Path(args.scene.stem + ".png")
        if args.stats_json is not None and _same_file(args.stats_json, args.output):
            parser.error(f"--stats-json and the output image are the same file: {args.output}")
        png_only = [flag for flag, given in (("--srgb", args.linear is False),
                                              ("--exposure", args.exposure is not None),
                                              ("--png-bits", args.png_bits is not None)) if given]
        if png_only and args.output.suffix.lower() in FLOAT_SUFFIXES:
            parser.error(f"{', '.join(png_only)} applies to PNG output only; "
                         f"{args.output.suffix} holds the linear radiance as rendered")
    return args


def _same_file(a: Path, b: Path) -> bool:
    return os.path.abspath(a) == os.path.abspath(b)


def _say(message: str) -> None:
    print(f"clray: {one_line(message)}", file=sys.stderr)


def _check_writable(path: Path) -> None:
    """Before rendering, so that a typo in -o or a read-only folder does not cost a whole
    render: the folder must exist and take a new file, which a probe file (removed at once)
    shows more reliably than permission bits (root, read-only mounts, ACLs)."""
    path = output_target(path)
    if is_special_file(path):
        if not os.access(path, os.W_OK):
            raise ClrayError(f"cannot write {path}: permission denied")
        return
    folder = path.parent
    probe = folder / f".{path.name[:100]}.{os.getpid()}.{secrets.token_hex(4)}.probe"
    try:
        if not folder.is_dir():
            raise ClrayError(f"cannot write {path}: directory {folder} does not exist")
        if path.is_dir():
            raise ClrayError(f"cannot write {path}: it is a directory")
        # The name itself may be refused (too long, a NUL byte) where the probe's is not.
        os.stat(path)
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as err:
        raise ClrayError(f"cannot write {path}: {getattr(err, 'strerror', None) or err}") from err
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as err:
        raise ClrayError(f"cannot write {path}: {err.strerror or err}") from err


def _write(path: Path, write: Callable[[], None]) -> None:
    try:
        write()
    except OSError as err:
        raise ClrayError(f"cannot write {path}: {err.strerror or err}") from err


class _Progress:
    """Prints `rendering: N%` at every tenth of the launches, so logs stay short."""

    def __init__(self) -> None:
        self.shown = -1

    def __call__(self, done: int, total: int) -> None:
        tenth = 10 * done // max(total, 1)
        if tenth > self.shown:
            self.shown = tenth
            _say(f"rendering: {10 * tenth}% ({done}/{total} launches)")


def _format_stat(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}={_format_stat(v)}" for k, v in value.items())
    return str(value)


@contextlib.contextmanager
def _warnings_as_lines(*, quiet: bool, verbose: bool) -> Iterator[None]:
    """Python warnings (numpy's, Pillow's, PoCL's) told as `clray: warning:` lines like the
    scene's own, so that stderr holds nothing but clray's lines; also when the block fails."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        if not verbose:
            # PoCL repeats its build warnings on every cached build; they are noise here.
            warnings.simplefilter("ignore", cl.CompilerWarning)
        try:
            yield
        finally:
            if not quiet:
                for warning in caught:
                    _say(f"warning: {warning.message}")


def _render(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    output: Path = args.output
    _check_writable(output)
    check_writer(output)
    if args.stats_json is not None:
        _check_writable(args.stats_json)

    with _warnings_as_lines(quiet=args.quiet, verbose=args.verbose):
        scene = load_scene(args.scene)
        load_s = time.perf_counter() - started
        if not args.quiet:
            for warning in scene.warnings:
                _say(f"warning: {warning}")
        settings = RenderSettings(
            width=args.width, height=args.height, spp=args.spp, max_depth=args.max_depth,
            seed=args.seed, device=args.device, precision=args.precision,
            progress=_Progress() if args.verbose else None, linear=args.linear,
            exposure=args.exposure, png_bits=args.png_bits)
        result = render(scene, settings)

    write_started = time.perf_counter()
    _write(output, lambda: result.save(output))
    height, width, _ = result.image.shape
    stats = {
        **result.stats,
        "scene": str(args.scene),
        "output": str(output),
        "load_s": load_s,
        "render_s": result.stats["total_s"],
        "write_s": time.perf_counter() - write_started,
        "total_s": time.perf_counter() - started,
        "nonfinite_pixels": nonfinite_count(result.image),
    }
    if output.suffix.lower() == ".png":
        stats["clipped_pixels"] = clipped_pixels(result.image, result.encoding.exposure)
    if args.stats_json is not None:
        text = json.dumps(stats, indent=2, default=str) + "\n"
        _write(args.stats_json,
               lambda: write_bytes_atomically(args.stats_json, text.encode("utf-8")))

    if not args.quiet and stats["nonfinite_pixels"]:
        kept = "kept" if output.suffix.lower() in FLOAT_SUFFIXES else "written black"
        _say(f"warning: {stats['nonfinite_pixels']} pixels are NaN or infinite ({kept})")
    if args.verbose:
        for key, value in stats.items():
            print(one_line(f"  {key}: {_format_stat(value)}"), file=sys.stderr)
    if not args.quiet:
        _say(f"wrote {output} ({width}x{height}, {stats['spp']} spp, "
             f"kernel {stats['kernel_s']:.3g} s)")
    return EXIT_OK


def _study(args: argparse.Namespace) -> int:
    from clray.study import run_study  # matplotlib and friends only when studying

    if args.out.exists() and not args.out.is_dir():
        raise ClrayError(f"--out {args.out} exists and is not a directory")
    records = run_study(args.scenes, args.out, repeat=args.repeat, width=args.width,
                        height=args.height, device=args.device,
                        say=(lambda _: None) if args.quiet else _say)
    if not args.quiet:
        failed = sum(r["status"] == "FAIL" for r in records)
        _say(f"wrote {args.out / 'report.md'} ({len(records)} renders, {failed} failing)")
    return EXIT_OK


def _devices(args: argparse.Namespace) -> int:
    rows = [(d.spec, d.type, d.name, d.platform, f"{d.compute_units} CU",
             f"fp64 {'yes' if d.fp64 else 'no'}", f"driver {d.driver_version}")
            for d in list_devices()]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parse(argv)
    except SystemExit as done:  # argparse exits for --help and for usage errors
        return int(done.code or 0)
    try:
        return args.run(args)
    except ClrayError as err:
        _say(f"error: {err}")
        return err.exit_code
    except KeyboardInterrupt:
        _say("error: interrupted")
        return EXIT_INTERRUPTED
    except MemoryError:
        _say("error: out of memory")
        return EXIT_RUNTIME
