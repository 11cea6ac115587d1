"""The `clray` command (also `python -m clray`): `clray render SCENE ...`, `clray study SCENE...
--out DIR`, `clray tune SCENE...`, `clray profile SCENE` and `clray devices`.

Exit codes: 0 ok, 1 runtime error, 2 usage, 3 scene error, 4 OpenCL error, 130 interrupted.
Every error a user can cause is one `clray: error: ...` line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import functools
import json
import os
import select
import signal
import stat
import struct
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import pyopencl as cl

from clray import __version__
from clray.denoise import check_denoiser
from clray.device.context import (
    DEFAULT_DEVICE_ORDER,
    default_device,
    list_devices,
    opencl_error_text,
)
from clray.distributed import (
    CONNECT_TIMEOUT_S,
    LOCAL_WORKERS,
    connect,
    import_distributed,
    render_sequence,
    render_still,
    study_scenes,
)
from clray.errors import (
    EXIT_OK,
    EXIT_OPENCL,
    EXIT_RUNTIME,
    EXIT_USAGE,
    ClrayError,
    SceneError,
    SettingsError,
    one_line,
    plural,
)
from clray.image_io import (
    FLOAT_SUFFIXES,
    SUFFIXES,
    check_suffix,
    check_writer,
    clipped_pixels,
    image_bytes,
    image_host_bytes,
)
from clray.knobs import TRAVERSALS
from clray.metrics import nonfinite_count
from clray.model_scene import (
    DEFAULT_UP,
    DEFAULT_VIEW,
    MESH_FILE,
    UP_ROTATIONS,
    VIEWS,
    is_mesh_file,
    load_model_scene,
    model_scene_data,
    probe_camera,
    to_toml,
)
from clray.output import (
    WriteSet,
    cannot_write,
    error_words,
    output_target,
    refuse_a_folder,
    refuse_read_only,
    temporary_name,
    write_set,
    written_directly,
)
from clray.passes import (
    PASS_NAMES,
    pass_paths,
    pass_problem,
    passes_host_bytes,
    stage_with_passes,
)
from clray.render import RenderResult, RenderSettings, render
from clray.scene import limits
from clray.scene.animation import MAX_FRAMES
from clray.scene.files import noting_reads
from clray.scene.load import load_scene
from clray.scene.model import Scene

if TYPE_CHECKING:
    from clray.sequence import Sequence

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report it
# Signals that end the command as Ctrl-C does (_Signalled), with 128 + the signal.
_ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
# Output folders this command made, so that a command that fails leaves no trace of them: its
# checks make them before the work.
_MADE_FOLDERS: list[Path] = []
SEED_MAX = limits.MAX_SEED
MAX_REPEAT = 1000


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line, like every other clray error."""

    # The top-level parser's commands by name, so that the checks after parsing say which
    # command's --help to see.
    commands: dict[str, argparse.ArgumentParser]

    def error(self, message: str) -> NoReturn:
        if message == "argument --up: expected one argument":
            # `--up -z`: argparse takes a word that starts with - for a flag.
            message += " (a negative axis is written --up=-z)"
        self.exit(EXIT_USAGE, f"clray: error: {one_line(message)} (see '{self.prog} --help')\n")


def _shown(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _flag_value(convert: Callable[[str], Any], problem_of: Callable[[object], str | None]
                ) -> Callable[[str], Any]:
    """A flag's parser: `convert` the text, then the scene file's and RenderSettings' rule in
    their words (clray.scene.limits)."""
    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except ValueError:
            value = text
        problem = problem_of(value)
        if problem:
            raise argparse.ArgumentTypeError(f"{problem}, got {_shown(text)}")
        return value

    return parse


def _int_in(low: int, high: int) -> Callable[[str], int]:
    # Every count has a maximum: past it the kernels' int32 arithmetic would overflow, long
    # before the render would end.
    return _flag_value(int, lambda v: limits.integer_problem(v, low, high))


def _number_in(low: float, high: float) -> Callable[[str], float]:
    return _flag_value(float, lambda v: limits.number_problem(v, low, high))


def _choice_in(allowed: tuple[int, ...]) -> Callable[[str], int]:
    return _flag_value(int, lambda v: limits.choice_problem(v, allowed))


def _scene_path(text: str) -> Path:
    # Path("") is the current directory, and would name the default output ".png".
    if not text:
        raise argparse.ArgumentTypeError("expected a scene file name, got ''")
    return Path(text)


def _file_path(text: str) -> Path:
    """A path to write a file to: it must name a file, not a directory."""
    if not text:
        raise argparse.ArgumentTypeError("expected a file name, got ''")
    path = Path(text)
    if text.endswith(("/", os.sep)) or path.name in ("", ".", ".."):
        raise argparse.ArgumentTypeError(f"expected a file name, got the directory {_shown(text)}")
    return path


# `-o -` and `--stats-json -` write to standard output (the image as PNG); clray's own lines
# go to stderr, so stdout carries nothing else.
STDOUT = Path("-")


def _image_path(text: str) -> Path:
    if text == "-":
        return STDOUT
    try:
        check_suffix(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err
    return _file_path(text)


def _stats_path(text: str) -> Path:
    if text == "-":
        return STDOUT
    path = _file_path(text)
    # `./-` is a file named -, which as a Path equals STDOUT: its absolute name does not.
    return path.absolute() if path == STDOUT else path


def _frames(text: str) -> range:
    from clray.sequence import parse_frames

    try:
        return parse_frames(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).removeprefix("--frames: ")) from None


def _build_parser() -> _Parser:
    parser = _Parser(prog="clray", description="Whitted ray tracer running as OpenCL kernels.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_command in (_render_command, _study_command, _scene_command, _tune_command,
                        _profile_command, _devices_command):
        add_command(commands)
    parser.commands = commands.choices
    return parser


# Image sizes a command takes (-W, -H).
_image_size = _int_in(1, limits.MAX_IMAGE_SIZE)
# A turntable's frames (clray scene --turntable): a turn needs two views at least.
_turntable_frames = _int_in(2, MAX_FRAMES)


def _render_command(commands: Any) -> None:
    """`clray render`."""
    r = commands.add_parser(
        "render", help="render a scene file to an image",
        description="Render SCENE. Flags override the scene file's [render] values.")
    r.add_argument("scene", type=_scene_path, metavar="SCENE",
                   help=f"scene file (.toml or .json), or a {MESH_FILE} to render with an "
                        "automatic camera and lights")
    _model_flags(r)
    r.add_argument("-o", "--output", type=_image_path, metavar="OUT",
                   help=f"output image, by suffix: {', '.join(SUFFIXES)} (.png is 8- or "
                        "16-bit, sRGB unless --linear, clamped to [0, 1] after --exposure; .pfm "
                        "and .exr are float32 linear radiance, every value kept; .exr needs "
                        "pip install 'clray[exr]'); '-' writes PNG to standard output (not a "
                        "terminal); default: "
                        "SCENE's stem + .png in the current directory")
    _render_settings_flags(r)
    _kernel_flags(r)
    _image_flags(r)
    r.add_argument("--stats-json", type=_stats_path, metavar="PATH",
                   help="write timings, sizes and ray counts as JSON ('-': standard output)")
    _talk_flags(r)
    _animation_flags(r)
    r.set_defaults(run=_render)


def _render_settings_flags(r: argparse.ArgumentParser) -> None:
    """The image's size and the trace's samples, depth, seed and ray weight."""
    r.add_argument("-W", "--width", type=_image_size, metavar="N", help="image width in pixels")
    r.add_argument("-H", "--height", type=_image_size, metavar="N", help="image height in pixels")
    r.add_argument("--spp", type=_int_in(1, limits.MAX_SPP), metavar="N",
                   help="samples per pixel")
    r.add_argument("--max-depth", type=_int_in(0, limits.MAX_DEPTH), metavar="N",
                   help="reflection/refraction bounces after the primary hit")
    r.add_argument("--seed", type=_int_in(0, SEED_MAX), metavar="N",
                   help="seed of the sample jitter")
    r.add_argument("--min-weight", type=_number_in(*limits.MIN_WEIGHT_RANGE), metavar="W",
                   help="do not trace reflected or refracted rays of a weight below W (POV-Ray's "
                        "adc_bailout; default 0: every ray to --max-depth). Inside glass the ray "
                        "tree doubles at every bounce: set W (e.g. 0.004) for depths above ~20")


def _kernel_flags(r: argparse.ArgumentParser) -> None:
    """The device that renders, and its kernels' arithmetic and BVH walk."""
    _device_flag(r)
    r.add_argument("--precision", choices=limits.PRECISIONS, default="float",
                   help="arithmetic in the kernels (double needs cl_khr_fp64; default: float)")
    r.add_argument("--traversal", choices=TRAVERSALS, default=None,
                   help="how rays walk the BVH: 'single' (every ray alone), 'sample_packet' "
                        "(a pixel's samples together) or 'group_packet' (a work-group's tile "
                        "of pixels together), each the same image; default: the tuning's "
                        "traversal knob, else the device's own: sample_packet on the CPU devices "
                        "of PoCL and Intel's runtime, single elsewhere (GPUs); with sample "
                        "packets 1 spp is always single "
                        "(docs/acceleration.md)")


def _quiet_flag(r: Any, not_even: str = "") -> None:
    """-q/--quiet (args.quiet), the same flag in every command that has it, on its parser or
    on a group of it (render's, beside -v); `not_even` names what else the command leaves
    unsaid (render's progress bar)."""
    r.add_argument("-q", "--quiet", action="store_true",
                   help="print nothing on success" + (f", not even {not_even}" if not_even else ""))


def _talk_flags(r: argparse.ArgumentParser) -> None:
    """-q and -v: what a render says as it goes and at the end."""
    talk = r.add_mutually_exclusive_group()
    _quiet_flag(talk, not_even="the progress bar or scene warnings")
    talk.add_argument("-v", "--verbose", action="store_true",
                      help="print progress lines where stderr is not a terminal (a terminal "
                           "always gets a progress bar), compiler warnings and a table of "
                           "timings, ray counts and device memory")


def _animation_flags(r: argparse.ArgumentParser) -> None:
    """--frames, --resume and the Dask flags."""
    cluster = r.add_argument_group("animation and Dask (docs/distributed.md)")
    cluster.add_argument("--frames", type=_frames, metavar="A:B",
                         help="render frames A to B-1 of the scene's [animation] ('A:' to the "
                              "last, 'N' one frame) to -o with a frame number, e.g. "
                              "-o out/frame_%%04d.png (default: SCENE's stem + _%%04d.png)")
    cluster.add_argument("--resume", action="store_true",
                         help="with --frames: skip frames whose file and pass files exist "
                              "(files are written whole or not at all)")
    _dask_flags(cluster, "render on a Dask cluster: a still in tiles, frames one task each; at "
                         "ADDRESS (tcp://host:8786), else on a local cluster of --dask-workers "
                         "processes. Needs pip install 'clray[dask]'")


def _study_command(commands: Any) -> None:
    """`clray study`."""
    st = commands.add_parser(
        "study", help="kernel time against error for variants of the kernel",
        description="Render each SCENE with every kernel variant (float/double, build options, "
                    "textbook formulas) and compare with the double build: writes "
                    "DIR/results.json, DIR/report.md and a time-vs-error PNG per scene "
                    "(needs matplotlib, the 'plot' extra; skipped with a note otherwise).")
    st.add_argument("scenes", type=_scene_path, nargs="+", metavar="SCENE",
                    help="scene files (.toml or .json)")
    st.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    st.add_argument("--repeat", type=_int_in(1, MAX_REPEAT), default=5, metavar="N",
                    help="timed runs per variant after a warm-up, in interleaved rounds; the "
                         "median is reported (default: 5)")
    st.add_argument("-W", "--width", type=_image_size, metavar="N",
                    help="image width for every scene (default: each scene's own)")
    st.add_argument("-H", "--height", type=_image_size, metavar="N",
                    help="image height for every scene (default: each scene's own)")
    _device_flag(st)
    _dask_flags(st, "render on a Dask cluster, one task a scene (each scene's variants on one "
                    "worker, so that their times compare), as for render")
    _quiet_flag(st)
    st.set_defaults(run=_study)


def _scene_command(commands: Any) -> None:
    """`clray scene`."""
    sc = commands.add_parser(
        "scene", help="write the automatic scene of a mesh file as TOML",
        description="Write to standard output the scene `clray render MODEL` renders: an "
                    "editable TOML file that loads and renders the same. Its mesh file name is "
                    "MODEL as given, relative to the working directory: save the scene there "
                    "(or edit the name).")
    sc.add_argument("model", type=_scene_path, metavar="MODEL",
                    help=MESH_FILE)
    _model_flags(sc)
    # The camera frames the model in the image's size, so the scene is written for it.
    sc.add_argument("-W", "--width", type=_image_size, metavar="N",
                    help="image width in pixels (default 640, or a glTF camera's)")
    sc.add_argument("-H", "--height", type=_image_size, metavar="N",
                    help="image height in pixels (default 480, or from a glTF camera's "
                         "aspect ratio)")
    sc.add_argument("--turntable", type=_turntable_frames, metavar="N",
                    help="an animation of N frames in which the model turns once about its "
                         "vertical axis, the camera still: render it with --frames 0:N")
    sc.set_defaults(run=_scene)


def _tune_command(commands: Any) -> None:
    """`clray tune`."""
    t = commands.add_parser(
        "tune", help="search the performance knobs for the fastest configuration on a device",
        description="Try configurations of the performance knobs (docs/tuning.md) on each "
                    "SCENE with Kernel Tuner, each verified against the default's image; "
                    "store the fastest as the device's tuning file, which later renders use, "
                    "and write DIR/report.md, DIR/results.json, DIR/tune.png and Kernel "
                    "Tuner's cache files (a second run continues). Needs pip install "
                    "'clray[tune]'.")
    t.add_argument("scenes", type=_scene_path, nargs="+", metavar="SCENE",
                   help="scene files (.toml or .json)")
    _device_flag(t)
    t.add_argument("--strategy", default="brute_force", metavar="S",
                   help="Kernel Tuner's search strategy over the kernel and launch knobs of "
                        "each host configuration: brute_force (default), random_sample, "
                        "greedy_ils, genetic_algorithm, bayes_opt, ...")
    t.add_argument("--budget", type=_number_in(0.0, 86400.0), default=120.0, metavar="SECONDS",
                   help="tuning time, shared equally by the scenes; the confirming renders "
                        "after it are not counted (default: 120)")
    t.add_argument("--allow-error", type=_number_in(0.0, 1.0), metavar="E",
                   help="accept configurations whose pixels differ from the default's by up to "
                        "E (default: the scene's float tolerance, 2/255)")
    t.add_argument("--out", type=Path, default=Path("clray-tune"), metavar="DIR",
                   help="output folder (default: clray-tune)")
    t.add_argument("-W", "--width", type=_image_size, metavar="N",
                   help="image width for every scene (default: each scene's own)")
    t.add_argument("-H", "--height", type=_image_size, metavar="N",
                   help="image height for every scene (default: each scene's own)")
    t.add_argument("--search-every-host", action="store_true",
                   help="search the kernel and launch knobs again for every host configuration "
                        "(default: with the first, the default; later host configurations keep "
                        "the best found so far, one build each)")
    t.add_argument("--no-save", dest="save", action="store_false",
                   help="store nothing as the device's tuning file")
    _quiet_flag(t)
    t.set_defaults(run=_tune)


def _profile_command(commands: Any) -> None:
    """`clray profile`."""
    pr = commands.add_parser(
        "profile", help="where a scene's render time goes: rays, tests and time by ray kind",
        description="Profile SCENE: rays by kind, Mrays/s and kernel time by kind (from "
                    "renders without lights and bounces, differenced), box and primitive tests "
                    "per ray (the COUNT_TESTS build), kernel build time cold and warm, and the "
                    "scene's device bytes.")
    pr.add_argument("scene", type=_scene_path, metavar="SCENE",
                    help=f"scene file (.toml or .json), or a {MESH_FILE} with render's "
                         "automatic camera and lights")
    # A mesh file's automatic scene as `clray render MODEL` makes it without view flags (_load).
    pr.set_defaults(view=None, ground=False, up=None)
    _device_flag(pr)
    pr.add_argument("-W", "--width", type=_image_size, metavar="N", help="image width in pixels")
    pr.add_argument("-H", "--height", type=_image_size, metavar="N", help="image height in pixels")
    pr.add_argument("--spp", type=_int_in(1, limits.MAX_SPP), metavar="N",
                    help="samples per pixel (default: the scene's [render] spp)")
    pr.add_argument("--traversal", choices=TRAVERSALS, default=None,
                    help="how rays walk the BVH, as for render (default: the tuning's "
                         "traversal knob, else the device's own)")
    pr.add_argument("--repeat", type=_int_in(1, MAX_REPEAT), default=3, metavar="N",
                    help="timed renders of each variant after a warm-up; medians (default: 3)")
    pr.add_argument("--no-tuning", dest="stored_tuning", action="store_false",
                    help="profile the knob table's defaults, not the device's tuning file")
    pr.add_argument("--json", action="store_true", help="print the profile as JSON on stdout")
    pr.set_defaults(run=_profile)


def _devices_command(commands: Any) -> None:
    """`clray devices`."""
    d = commands.add_parser("devices", help="list OpenCL devices, one per line",
                            description="List OpenCL devices: spec, type, name, platform, "
                                        "compute units, fp64 support, driver version, "
                                        "whether `clray tune` left a tuning file for it, and "
                                        "which one renders by default (without --device), "
                                        "and why.")
    d.set_defaults(run=_devices)


def _image_flags(r: argparse.ArgumentParser) -> None:
    """`clray render`'s flags for what is written: the PNG encoding, passes, the denoiser."""
    encoding = r.add_mutually_exclusive_group()
    encoding.add_argument("--linear", dest="linear", action="store_true", default=None,
                          help="write PNG values linear, tagged gamma 1.0 (default: the sRGB "
                               "curve, tagged sRGB, unless the scene's [render] linear = true)")
    encoding.add_argument("--srgb", dest="linear", action="store_false",
                          help="write PNG values sRGB-encoded, overriding [render] linear")
    r.add_argument("--exposure", type=_number_in(*limits.RENDER_NUMBERS["exposure"]),
                   metavar="STOPS",
                   help="scale PNG values by 2^STOPS before each channel is clipped to "
                        "[0, 1] (stats: clipped_pixels); default: [render] exposure, else 0. "
                        "PFM and EXR keep the radiance as rendered")
    r.add_argument("--png-bits", type=_choice_in(limits.PNG_BITS), metavar="8|16",
                   help="bits a PNG sample (default: [render] png_bits, else 8)")
    r.add_argument("--no-tuning", dest="stored_tuning", action="store_false",
                   help="render with the knob table's defaults, not the device's tuning file "
                        "that `clray tune` wrote (docs/tuning.md)")
    r.add_argument("--denoise", action="store_true",
                   help="denoise the image with Intel Open Image Denoise, guided by the albedo "
                        "and normal passes, before it is written (pip install "
                        "'clray[denoise]'; docs/denoising.md)")
    r.add_argument("--aov", type=_flag_value(lambda text: tuple(text.split(",")), pass_problem),
                   metavar="PASSES",
                   help=f"also render these passes, comma-separated: {','.join(PASS_NAMES)} "
                        "(docs/passes.md); written as layers of an .exr output, else one PFM "
                        "a pass beside the image (out.depth.pfm)")
    r.add_argument("--aov-preview", action="store_true",
                   help="with --aov: also a false-colour PNG of each pass beside the image "
                        "(out.depth.png)")


def _dask_flags(group: Any, dask_help: str) -> None:
    """--dask, --dask-workers and --dask-timeout (docs/distributed.md)."""
    group.add_argument("--dask", nargs="?", const="", metavar="ADDRESS", help=dask_help)
    group.add_argument("--dask-workers", type=_int_in(1, 256), metavar="N",
                       help=f"worker processes of the local cluster (default: {LOCAL_WORKERS})")
    # Default None, not 10: a flag of --dask's given without it is refused, and so must be seen.
    group.add_argument("--dask-timeout", type=_number_in(0.1, 3600), metavar="S",
                       help="seconds to wait for the scheduler "
                            f"(default: {CONNECT_TIMEOUT_S:g})")


def _model_flags(parser: argparse.ArgumentParser) -> None:
    # Default None, not DEFAULT_VIEW: render refuses --view with a scene file, whose own
    # [camera] sets the view, and so must see whether it was given.
    parser.add_argument("--view", choices=tuple(VIEWS), default=None,
                        help="a mesh file's automatic camera: where it looks from "
                             f"(default: {DEFAULT_VIEW})")
    parser.add_argument("--ground", action="store_true",
                        help="a mesh file's automatic scene: add a ground plane under it")
    parser.add_argument("--up", choices=tuple(UP_ROTATIONS), default=None,
                        help="a mesh file's automatic scene: the model's axis that points up "
                             f"(default: {DEFAULT_UP}; scans are often z; a negative axis "
                             "with =, --up=-z)")


def _load(args: argparse.Namespace) -> Scene:
    """The scene file, or a mesh file's automatic scene."""
    if is_mesh_file(args.scene):
        # The image size too: the camera frames the model in it (a portrait image is
        # narrower than the view is high).
        return load_model_scene(args.scene, args.view or DEFAULT_VIEW, args.ground,
                                args.up or DEFAULT_UP, args.width, args.height)
    return load_scene(args.scene)


def _scene(args: argparse.Namespace) -> int:
    _check_stdout()
    if not is_mesh_file(args.model):
        raise SceneError(args.model, None, f"expected a {MESH_FILE}")
    name = args.model.as_posix()
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        # Python holds the name's bytes that are not UTF-8 as lone surrogates; a TOML file is
        # UTF-8 and has no escape for them, so the scene written could not name the file.
        raise SceneError(args.model, None, "the file name is not UTF-8, which a TOML scene "
                         "file cannot hold: rename the file") from None
    view = args.view or DEFAULT_VIEW
    up = args.up or DEFAULT_UP
    with _warnings_as_lines(quiet=False, verbose=False):
        data = model_scene_data(args.model, view, args.ground, up, args.width, args.height,
                                args.turntable)
    # --view only where it sets the view (a glTF file's camera sets it otherwise, and --view
    # is refused with it); -W and -H where given, as the camera frames the model in them.
    flags = [*([f"--view {view}"] if probe_camera(args.model) is None else []),
             *(["--ground"] if args.ground else []), *([f"--up={up}"] if args.up else []),
             *([f"-W {args.width}"] if args.width else []),
             *([f"-H {args.height}"] if args.height else []),
             *([f"--turntable {args.turntable}"] if args.turntable else [])]
    # The name as error messages show it: a control character in a comment is not TOML.
    header = (f"The automatic scene of {one_line(name)} "
              f"(clray scene{''.join(' ' + flag for flag in flags)}).")
    _to_stdout(to_toml(data, header).encode("utf-8"))
    return EXIT_OK


def _parse(argv: list[str] | None) -> argparse.Namespace:
    top = _build_parser()
    # Known arguments first: argparse's own parse_args says of a flag no command has "see
    # 'clray --help'", which lists the commands, not the flags of the one given.
    args, unknown = top.parse_known_args(argv)
    parser = top.commands[args.command]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.command in ("render", "study"):
        _check_dask_flags(parser, args)
    if args.command in ("render", "scene"):
        _check_view_with_camera(parser, args.scene if args.command == "render" else args.model,
                                args.view)
    if args.command == "render":
        _output_name(parser, args)
        _check_render_flags(parser, args)
    return args


def _check_dask_flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """--dask-workers and --dask-timeout are refused without --dask, and --dask-workers with
    a cluster's ADDRESS."""
    if args.dask is None:
        given = [flag for flag, value in (("--dask-workers", args.dask_workers),
                                          ("--dask-timeout", args.dask_timeout))
                 if value is not None]
        if given:
            parser.error(f"{' and '.join(given)} "
                         f"{'applies' if len(given) == 1 else 'apply'} to --dask")
    elif args.dask and args.dask_workers is not None:
        parser.error("--dask-workers applies to a local cluster (--dask without ADDRESS)")


def _output_name(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """-o as given, checked as a still's name or a frames' pattern, else the default from the
    scene's stem; args.output_given says which."""
    from clray.sequence import frame_path

    # For the errors that name the output: the default is no name the user gave.
    args.output_given = args.output is not None
    if args.output is None:
        # The scene's stem is a name, not a pattern: a % in it (50%done.toml) is no frame
        # number, and --frames' pattern holds it as %%.
        stem = args.scene.stem
        args.output = Path(f"{stem.replace('%', '%%')}_%04d.png" if args.frames is not None
                           else f"{stem}.png")
    elif args.output != STDOUT:
        try:
            # Before any work, as every usage error; frame_path cannot fail after this.
            frame_path(args.output, 0)
        except SettingsError as err:
            parser.error(str(err))
        if (args.frames is None
                and frame_path(args.output, 0) != frame_path(args.output, 1)):
            parser.error(f"-o {args.output} holds a frame number: give --frames A:B to "
                         "render frames, or a name without % for a still")


def _check_render_flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """`clray render`'s usage errors between flags: frames and standard output, flags for a
    mesh file or PNG output only, the stats file beside the image and scene, and the passes."""
    if args.frames is not None and STDOUT in (args.output, args.stats_json):
        parser.error("--frames writes files: give -o and --stats-json file names")
    if args.resume and args.frames is None:
        parser.error("--resume applies to --frames")
    if args.frames is not None and is_mesh_file(args.scene):
        parser.error(f"--frames renders a scene file's [animation] table; {args.scene} is a "
                     f"{MESH_FILE}, which has none")
    _check_still_output(parser, args)
    if args.stats_json == STDOUT and args.output == STDOUT:
        parser.error("-o - and --stats-json - would both write to standard output")
    if args.output == STDOUT and sys.stdout is not None and sys.stdout.isatty():
        # A PNG's bytes on a terminal are noise, and can leave it in a state that needs a
        # reset; gzip and curl refuse the same.
        parser.error("-o - writes the PNG to standard output, which is a terminal: "
                     "redirect it (> out.png) or pipe it, or give -o a file name")
    if args.stats_json is not None and _same_file(args.stats_json, args.output):
        parser.error(f"--stats-json and the output image are the same file: {args.output}")
    if args.stats_json not in (None, STDOUT) and _same_file(args.stats_json, args.scene):
        parser.error(f"--stats-json {args.stats_json} is the scene file {args.scene}, "
                     "which the stats would replace: give another name")
    png_only = [flag for flag, given in (("--srgb", args.linear is False),
                                          ("--exposure", args.exposure is not None),
                                          ("--png-bits", args.png_bits is not None)) if given]
    if png_only and args.output.suffix.lower() in FLOAT_SUFFIXES:
        parser.error(f"{', '.join(png_only)} applies to PNG output only; "
                     f"{args.output.suffix} holds the linear radiance as rendered")
    _check_pass_flags(parser, args)


def _check_still_output(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Flags that a render would otherwise accept and ignore are refused with the reason."""
    if not is_mesh_file(args.scene):
        given = [flag for flag, on in (("--view", args.view is not None),
                                       ("--ground", args.ground),
                                       ("--up", args.up is not None)) if on]
        if given:
            verb = "applies" if len(given) == 1 else "apply"
            parser.error(f"{' and '.join(given)} {verb} to a {MESH_FILE}; "
                         f"{args.scene} is a scene file, whose [camera] and objects are its own")


def _check_view_with_camera(parser: argparse.ArgumentParser, path: Path,
                            view: str | None) -> None:
    """--view with a glTF file that has a camera is refused: the file's camera sets the view,
    and the flag would be ignored (as --view is refused with a scene file)."""
    if view is None or not is_mesh_file(path):
        return
    try:
        found = probe_camera(path)
    except SceneError:
        return  # the file cannot be read: the load says so, as without --view
    if found is not None:
        where = f" ({found.where})" if found.where else ""
        parser.error(f"--view: {path} has a camera of its own{where}, which sets the view; "
                     "leave out --view, or remove the camera from the file")


def _check_pass_flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """--aov writes the passes into files beside the image (each frame's with --frames):
    refused where there are none, or where the render has no passes (a Dask still's tiles),
    as is --denoise, whose guides are passes."""
    if args.denoise and args.dask is not None and args.frames is None:
        parser.error("--denoise: a still rendered in tiles on Dask has no passes to guide the "
                     "denoiser; render it without --dask (frames with --frames are denoised)")
    if args.aov_preview and not args.aov:
        parser.error("--aov-preview applies to --aov")
    if not args.aov:
        return
    if args.output == STDOUT:
        parser.error("--aov writes the passes to files beside the image, not with -o -")
    if args.dask is not None and args.frames is None:
        parser.error("--aov: a still rendered in tiles on Dask has no passes; render it "
                     "without --dask (frames with --frames have theirs)")
    for path in pass_paths(args.output, args.aov, args.aov_preview):
        if args.stats_json is not None and _same_file(args.stats_json, path):
            parser.error(f"--stats-json and the {path.name} pass file are the same file")


def _same_file(a: Path, b: Path) -> bool:
    """Whether writing `a` would write `b`: the same name once symlinks are followed, as the
    writes follow them (a link to the image, whose target need not exist yet). Hard links are
    no clash: each write renames a new file onto its own name."""
    return _real(a) == _real(b)


def _real(path: str | Path) -> str:
    """`path`'s absolute name once symlinks are followed, for _same_file."""
    try:
        return os.path.realpath(path)
    except ValueError:  # a NUL byte in a name, which no link holds: its write reports it
        return os.path.abspath(path)


def _pass_outputs(image: Path, aovs: tuple[str, ...], previews: bool, where: str
                  ) -> list[tuple[str, Path, str]]:
    """The pass files written with `image`, each with the words that name it `where` it is,
    and the flag that names it (-o, as the image's)."""
    if image == STDOUT:
        return []
    return [(f"the {path.name.split('.')[-2]} {'preview' if path.suffix == '.png' else 'pass'} "
             f"file {path} ({where})", path, "-o")
            for path in pass_paths(image, aovs, previews)]


def _refuse_replacing_reads(read: set[str], outputs: list[tuple[str, Path | None, str]]
                            ) -> None:
    """SettingsError (a usage error, as an output naming another output is) where an output,
    given with the words that name it and the flag that sets its name, would replace a file
    that loading the scene read (`read`, clray.scene.files.noting_reads): `clray render tri.obj`
    whose tri.mtl names the texture tri.png. After the load, which alone knows the files, and
    before anything is written."""
    reads = {_real(name) for name in read}
    for words, path, flag in outputs:
        if path not in (None, STDOUT) and _real(path) in reads:
            raise SettingsError(f"{words}: the scene reads this file, which writing the output "
                                f"would replace: give {flag} another name")


def _stdout_error(err: OSError) -> ClrayError:
    return ClrayError(f"cannot write standard output: {error_words(err)}")


def _check_stdout() -> None:
    """ClrayError where standard output was closed at start (`>&-`), where Python's is None: a
    command that writes there says so before its work."""
    if sys.stdout is None:
        raise _stdout_error(OSError(errno.EBADF, os.strerror(errno.EBADF)))


@contextlib.contextmanager
def _writing_stdout() -> Iterator[None]:
    """Around a write to standard output: its failure (a full disk, a closed descriptor) as one
    line, ClrayError; BrokenPipeError as it is, for the caller to end quietly (its reader has
    gone). Either way nothing is left in its buffers to fail again at the exit."""
    _check_stdout()
    try:
        yield
    except OSError as err:
        _quiet_stdout()
        if isinstance(err, BrokenPipeError):
            raise
        raise _stdout_error(err) from err


def _print_out(text: str) -> None:
    """`text` on standard output, flushed, so that a failure is the command's, told as one
    line (_writing_stdout), not a traceback at the exit."""
    with _writing_stdout():
        sys.stdout.write(text)
        sys.stdout.flush()


def _to_stdout(payload: bytes) -> None:
    with _writing_stdout():
        sys.stdout.flush()
        sys.stdout.buffer.write(payload)
        sys.stdout.buffer.flush()
        try:
            fd = sys.stdout.fileno()
        except OSError:  # io.UnsupportedOperation: stdout replaced by an object without a file
            return
        _wait_until_read(fd)


def _wait_until_read(fd: int) -> None:
    """Into a pipe, return once the reader has taken every byte; raise BrokenPipeError where it
    closed the pipe first. A write succeeds as soon as the bytes fit the pipe's buffer (64 KiB
    on Linux), so without this `-o - | head -c 10` would exit 0 and `-o - | true` 1, by timing
    alone; now both are the same closed pipe, exit 1. Elsewhere (a file, a terminal, a system
    without FIONREAD) the write itself is the answer."""
    if not stat.S_ISFIFO(os.fstat(fd).st_mode) or not hasattr(select, "poll"):
        return
    import fcntl
    import termios

    watch = select.poll()
    watch.register(fd, select.POLLERR)  # a pipe's write end reports POLLERR once unread
    while True:
        unread = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4))[0]
        if unread == 0:
            return
        if watch.poll(50):
            raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))


def _say(message: str) -> None:
    print(f"clray: {one_line(message)}", file=sys.stderr)


def _check_writable(path: Path) -> None:
    """Before rendering, so that a typo in -o or a read-only folder does not cost a whole
    render: the folder (made where missing) must take a new file, which a probe file (removed
    at once) shows more reliably than permission bits (root, read-only mounts, ACLs), and a
    file there must not be read-only."""
    if written_directly(path):
        try:
            os.stat(path)  # a closed descriptor: /dev/stdout names no file
        except OSError as err:
            raise cannot_write(path, err) from err
        if not os.access(path, os.W_OK):
            raise cannot_write(path, "permission denied")
        return
    path = output_target(path)
    folder = path.parent
    _make_folder(path, folder)
    refuse_a_folder(path)
    probe = temporary_name(path, "probe")
    try:
        # The name itself may be refused (too long, a NUL byte) where the probe's is not.
        os.stat(path)
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as err:
        raise cannot_write(path, err) from err
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
        refuse_read_only(path)  # after the probe, for a read-only file system's own words
    except OSError as err:
        raise cannot_write(path, err) from err


def _make_folder(path: Path, folder: Path) -> None:
    """The output's folder, made with its parents where missing (`-o out/frame_%04d.png` in a
    fresh checkout), as users of other renderers expect; what stands in the way is named.
    Each folder this command makes is noted in _MADE_FOLDERS as it is made, for main to take
    back if the command fails; one that exists is never noted (`new/../kept` names `kept`)."""
    for level in (*reversed(folder.parents), folder):  # from the top down
        try:
            os.mkdir(level)
        except (OSError, ValueError) as err:  # ValueError: a NUL byte in the name
            # os.path's tests, not Path's: they answer False for a name too long.
            if os.path.isdir(level):
                continue
            if isinstance(err, FileExistsError):
                what = "a broken symbolic link" if os.path.islink(level) else "a file"
                raise cannot_write(path, f"{level} is {what}, not a directory") from None
            raise cannot_write(path, f"cannot make directory {level}: {error_words(err)}"
                               ) from None
        _MADE_FOLDERS.append(level.absolute())


def _device_flag(parser: argparse.ArgumentParser) -> None:
    """--device, the same for every command that renders."""
    parser.add_argument("--device", metavar="SPEC",
                        help="OpenCL device: 'P:D' indices as in PYOPENCL_CTX, a type (cpu, "
                             f"gpu, accelerator) or a name substring (default: "
                             f"{DEFAULT_DEVICE_ORDER})")


def _commit_with_stats(files: WriteSet, path: Path | None, stats: dict,
                       streamed: bytes | None = None) -> None:
    """The `files` staged (an image and its passes) put in place, with --stats-json's stats as
    JSON at `path`: one more file of the set, so that none is in place unless all are written,
    or after them to standard output ('-'), which cannot be taken back. `streamed`, the image
    for standard output (-o -), is sent once the stats file is written to its temporary name
    (or, for a device or pipe, written), and before it is renamed into place: a stats file that
    cannot be written fails before any of the image goes, and an image that does not arrive
    leaves no stats file."""
    payload = (json.dumps(stats, indent=2, default=str) + "\n").encode("utf-8")
    if path not in (None, STDOUT):
        _write(path, lambda: files.add(path, payload))
    try:
        if streamed is not None:
            files.write_direct()
            _write(STDOUT, lambda: _to_stdout(streamed))
        files.commit()
    except OSError as err:  # WriteSet's errors name the file that failed
        raise cannot_write(err.filename, err) from err
    if path == STDOUT:
        _write(path, lambda: _to_stdout(payload))


def _write(path: Path, write: Callable[[], None]) -> None:
    try:
        if path != STDOUT:
            # Made again: another clray that made the same new folder and failed has taken it
            # back (renders started side by side into one new folder).
            _make_folder(path, output_target(path).parent)
        write()
    except OSError as err:
        if path == STDOUT:  # a reader that went away: the image or stats did not arrive
            raise _stdout_error(err) from err
        # The file the error names: an image's write writes its pass files too, and the one
        # that failed is the one to name (clray.output.WriteSet names each file it writes).
        raise cannot_write(err.filename or path, err) from err


class _ProgressLines:
    """For -v without a terminal (logs): a `rendering: N%` line at each tenth of the
    pixel-samples, with the time so far and the time left, so logs stay short."""

    def __init__(self) -> None:
        self.shown = 0
        self.started = 0.0
        self.tiles = ""

    def note_tiles(self, done: int, submitted: int) -> None:
        self.tiles = f", {done} of {plural(submitted, 'tile')}"

    def __call__(self, done: int, total: int) -> None:
        if done == 0:
            self.started = time.perf_counter()
        tenth = 10 * done // total
        if tenth > self.shown:
            self.shown = tenth
            elapsed = time.perf_counter() - self.started
            left = elapsed * (total - done) / done
            _say(f"rendering: {10 * tenth}% ({done:,} of {total:,} pixel-samples{self.tiles}, "
                 f"{elapsed:.1f} s, {left:.1f} s left)")


class _ProgressBar:
    """A tqdm bar on stderr, made at the first report so that it measures the launches only."""

    def __init__(self, desc: str = "clray: rendering", unit: str = "samples",
                 unit_scale: bool = True) -> None:
        self.bar: Any = None  # a tqdm bar
        self.desc = desc
        self.unit = unit
        self.unit_scale = unit_scale  # 1.2M samples, but 3/14 steps

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            # Imported here: only a terminal shows the bar, and the import costs every command
            # about 25 ms.
            from tqdm import tqdm

            # leave=False: the bar is erased when it closes, and the summary line says it all.
            self.bar = tqdm(total=total, desc=self.desc, unit=self.unit,
                            unit_scale=self.unit_scale, file=sys.stderr, leave=False,
                            dynamic_ncols=True)
        self.bar.update(done - self.bar.n)

    def note_tiles(self, done: int, submitted: int) -> None:
        # A distributed render's tiles, as they arrive from the cluster's workers.
        if self.bar is not None:
            self.bar.set_postfix_str(f"{done}/{plural(submitted, 'tile')}")

    def step(self, done: int, total: int, what: str) -> None:
        """`clray profile`'s steps, each named as it starts."""
        if self.bar is not None:  # named with the count, in one refresh
            self.bar.set_postfix_str(what, refresh=False)
        self(done, total)
        self.bar.set_postfix_str(what)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@contextlib.contextmanager
def _progress(*, quiet: bool, verbose: bool) -> Iterator[Callable[[int, int], None] | None]:
    """The render's progress callback: a bar when stderr is a terminal, lines with -v when it is
    not, nothing with -q. The bar is closed when the block ends, also on failure, so that the
    `clray: ...` lines after it start on a clean line."""
    if quiet or not (verbose or sys.stderr.isatty()):
        yield None
    elif not sys.stderr.isatty():
        yield _ProgressLines()
    else:
        bar = _ProgressBar()
        try:
            yield bar
        finally:
            bar.close()


def _format_stat(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}={_format_stat(v)}" for k, v in value.items())
    return str(value)


_TIMES = (("load_s", "load"), ("device_s", "select device"), ("bvh_s", "bvh"),
          ("pack_s", "pack"), ("build_s", "build"), ("kernel_s", "kernel"),
          ("render_s", "render"), ("write_s", "write"), ("total_s", "total (wall)"))


def _size(n: int) -> str:
    if n < 1 << 10:
        return f"{n} B"
    if n < 1 << 20:
        return f"{n / (1 << 10):.1f} KiB"
    return f"{n / (1 << 20):.1f} MiB"


def _stats_table(stats: dict) -> list[str]:
    """The stats for -v as aligned `label  value` rows: what was rendered, then where the time
    went in order, then the work done; keys this table does not know come last as they are."""
    rows = [("scene", stats["scene"]), ("output", stats["output"]), ("device", stats["device"]),
            ("image", f"{stats['width']}x{stats['height']}, {stats['spp']} spp, max depth "
                      f"{stats['max_depth']}, min weight {stats['min_weight']:g}, "
                      f"seed {stats['seed']}, {stats['precision']}")]
    if "tuning" in stats:  # a Dask render's workers each take their own device's
        tuning = stats["tuning"]
        rows.append(("tuning", f"{tuning['label']} ({tuning['source']}; BVH width "
                               f"{tuning['bvh_width']})"))
    if "traversal" in stats:
        rows.append(("traversal", stats["traversal"]))
    for key, label in _TIMES:
        note = {"kernel_s": f"  ({plural(stats['launches'], 'launch', 'launches')}, "
                            "device time)",
                "render_s": "  (bvh to read-back)"}.get(key, "")
        rows.append((label, f"{stats[key]:8.3f} s{note}"))
    rays = stats["rays"]
    digits = len(f"{rays['total']:,}")
    rows += [(f"rays {kind}", f"{count:>{digits},}") for kind, count in rays.items()]
    if stats["mrays_per_s"] is not None:
        rows.append(("Mrays/s", f"{stats['mrays_per_s']:.3g}  (rays / kernel time)"))
    used = sorted(((v, k) for k, v in stats["device_bytes"].items() if v), reverse=True)
    rows.append(("scene on device", f"{_size(sum(v for v, _ in used))}: " + ", ".join(
        f"{k} {_size(v)}" for v, k in used)))
    rows.append(("non-finite pixels", f"{stats['nonfinite_pixels']:,}"))
    if "clipped_pixels" in stats:
        rows.append(("clipped pixels", f"{stats['clipped_pixels']:,}  (a channel over 1)"))
    known = {"scene", "output", "device", "tuning", "traversal", "width", "height", "spp",
             "max_depth", "min_weight", "seed", "precision", "clipped_pixels", "launches",
             "rays", "mrays_per_s", "device_bytes", "nonfinite_pixels",
             *(key for key, _ in _TIMES)}
    rows += [(key, _format_stat(value)) for key, value in stats.items() if key not in known]
    width = max(len(label) for label, _ in rows)
    return [one_line(f"  {label:<{width}}  {value}") for label, value in rows]


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
    _check_render_outputs(args)
    if args.denoise:
        check_denoiser()  # before any work: says how to install the binding where it is missing
    if args.dask is not None:
        import_distributed()  # before any work: says how to install Dask where it is missing
    if args.frames is not None:
        return _render_frames(args, started)
    result, load_s = _render_still(args)
    stats = _write_still(args, result, load_s, started)
    if not args.quiet:
        _warn_nonfinite(stats, output)
    if args.verbose:
        _say("stats:")
        for line in _stats_table(stats):
            print(line, file=sys.stderr)
    if not args.quiet:
        _say_still(args, stats, result)
    return EXIT_OK


def _check_render_outputs(args: argparse.Namespace) -> None:
    """Before any work: standard output usable where it takes the image or stats, and the
    image's, passes' and stats' files writable."""
    output: Path = args.output
    if STDOUT in (output, args.stats_json):
        _check_stdout()
    if output != STDOUT:
        check_writer(output)
    # With --frames, -o is a pattern, whose folder may hold the frame number too
    # (shot_%02d/img.png): _render_frames checks each frame's own files instead.
    if output != STDOUT and args.frames is None:
        _check_writable(output)
        for path in pass_paths(output, args.aov or (), args.aov_preview):
            _check_writable(path)
    if args.stats_json not in (None, STDOUT):
        _check_writable(args.stats_json)


def _render_still(args: argparse.Namespace) -> tuple[RenderResult, float]:
    """The still rendered, here or on Dask, and the seconds its scene took to load; the
    scene's warnings said (as lines) before it renders."""
    with _warnings_as_lines(quiet=args.quiet, verbose=args.verbose):
        scene, load_s = _load_still(args)
        with _progress(quiet=args.quiet, verbose=args.verbose) as progress:
            settings = _settings(args, progress)
            if args.dask is None:
                # Handed over: render holds the scene alone, and a big model's mesh goes once
                # it is packed (clray.render.render).
                hand_over = [scene]
                del scene
                result = render(hand_over.pop, settings)
            else:
                with _cluster(args) as client:
                    result = render_still(client, scene, settings, on_tile=getattr(
                        progress, "note_tiles", None))
    return result, load_s


def _load_still(args: argparse.Namespace) -> tuple[Scene, float]:
    """The still's scene and the seconds it took to load, refused where an output would
    replace a file it read; its warnings and a large image's memory said."""
    output: Path = args.output
    # Timed alone: the checks before it take no time, but importing Dask for --dask about a
    # second, which is not the scene's loading.
    load_started = time.perf_counter()
    with noting_reads() as read:
        scene = _load(args)
    load_s = time.perf_counter() - load_started
    image = (f"-o {output}" if args.output_given
             else f"the output {output} (the scene's name, as no -o is given)")
    _refuse_replacing_reads(read, [
        (image, output, "-o"),
        *_pass_outputs(output, args.aov or (), args.aov_preview, f"beside {image}"),
        (f"--stats-json {args.stats_json}", args.stats_json, "--stats-json")])
    if not args.quiet:
        for warning in scene.warnings:
            _say(f"warning: {warning}")
        _note_image_memory(args, scene)
    return scene, load_s


def _write_still(args: argparse.Namespace, result: RenderResult, load_s: float,
                 started: float) -> dict:
    """The image (and passes) written to -o, or sent to standard output, with the stats file;
    the still's stats."""
    output: Path = args.output
    write_started = time.perf_counter()
    with write_set() as files:
        streamed = None
        if output == STDOUT:
            # Sent by _commit_with_stats once the stats file is ready: an image sent cannot be
            # taken back, so a stats file that cannot be written must fail before it goes.
            streamed = image_bytes(".png", result.image, result.encoding)
        else:
            _write(output, lambda: stage_with_passes(files, output, result.image,
                                                     result.encoding, result.aovs,
                                                     args.aov_preview))
        stats = {
            **result.stats,
            "scene": str(args.scene),
            "output": str(output),
            "load_s": load_s,
            "render_s": result.stats["total_s"],
            "write_s": time.perf_counter() - write_started,
            "total_s": time.perf_counter() - started,
            **_image_figures(result, output),
        }
        _commit_with_stats(files, args.stats_json, stats, streamed)
    return stats


def _say_still(args: argparse.Namespace, stats: dict, result: RenderResult) -> None:
    """The lines that say what the still's render wrote, and where on Dask."""
    output: Path = args.output
    height, width, _ = result.image.shape
    if "dask" in stats:
        _say_dask(stats["dask"], "tiles")
    _say(f"wrote {output} ({width}x{height}, {stats['spp']} spp, "
         f"wall {stats['total_s']:.3g} s, kernel {stats['kernel_s']:.3g} s)")
    if args.aov:
        files = ", ".join(p.name for p in pass_paths(output, args.aov, args.aov_preview))
        if output.suffix.lower() == ".exr":
            files = f"layers of {output.name}" + (f"; previews {files}" if files else "")
        _say(f"wrote passes {','.join(args.aov)}: {files}")


def _image_figures(result: RenderResult, output: Path) -> dict:
    """The stats of the image written to `output`: its non-finite pixels, and where it is a
    PNG, the pixels the PNG clips."""
    figures = {"nonfinite_pixels": nonfinite_count(result.image)}
    if output == STDOUT or output.suffix.lower() == ".png":
        figures["clipped_pixels"] = clipped_pixels(result.image, result.encoding.exposure)
    return figures


def _warn_nonfinite(stats: dict, output: Path, where: str = "") -> None:
    """The warning for an image with NaN or infinite pixels (`where`: which frame's)."""
    n = stats["nonfinite_pixels"]
    if n:
        kept = "kept" if output.suffix.lower() in FLOAT_SUFFIXES else "written black"
        _say(f"warning: {where}{plural(n, 'pixel')} {'is' if n == 1 else 'are'} NaN or "
             f"infinite ({kept})")


def _frame_line(record: dict) -> str:
    """-v's line of a frame's stats: the still's table in a line."""
    clipped = (f", {record['clipped_pixels']:,} clipped" if "clipped_pixels" in record
               else "")
    mrays = "" if record["mrays_per_s"] is None else f", {record['mrays_per_s']:.3g} Mrays/s"
    return one_line(
        f"  frame {record['frame']}: {record['output']} ({record['width']}x{record['height']}, "
        f"{record['spp']} spp), load {record['load_s']:.3f} s, render {record['render_s']:.3f} "
        f"s, kernel {record['kernel_s']:.3f} s, write {record['write_s']:.3f} s, "
        f"{record['rays']['total']:,} rays{mrays}, {record['nonfinite_pixels']:,} non-finite"
        f"{clipped}")


# Above this much host memory for the image, render says how much before it starts.
LARGE_IMAGE_BYTES = 2 << 30


def _note_image_memory(args: argparse.Namespace, scene: Scene) -> None:
    """One line before a render whose image takes more than LARGE_IMAGE_BYTES of host memory:
    a 16384 x 16384 image takes several GiB, and a machine short of it should hear so first."""
    width = args.width or scene.render.width
    height = args.height or scene.render.height
    suffix = ".png" if args.output == STDOUT else check_suffix(args.output)
    aovs = tuple(args.aov or ())
    need = (image_host_bytes(width, height, suffix, args.png_bits or scene.render.png_bits)
            + width * height * passes_host_bytes(aovs, args.denoise, suffix))
    if need > LARGE_IMAGE_BYTES:
        passes = ", its passes" if aovs or args.denoise else ""
        _say(f"note: a {width} x {height} image takes about {need / (1 << 30):.1f} GiB of host "
             f"memory (the float image{passes} and its {suffix[1:].upper()} encoding)")


def _settings(args: argparse.Namespace, progress: Callable[[int, int], None] | None
              ) -> RenderSettings:
    return RenderSettings(
        width=args.width, height=args.height, spp=args.spp, max_depth=args.max_depth,
        seed=args.seed, min_weight=args.min_weight, device=args.device,
        precision=args.precision, traversal=args.traversal, progress=progress,
        linear=args.linear, exposure=args.exposure, png_bits=args.png_bits,
        stored_tuning=args.stored_tuning, denoise=args.denoise, aovs=args.aov or ())


def _cluster(args: argparse.Namespace) -> contextlib.AbstractContextManager:
    return connect(args.dask or None, workers=args.dask_workers or LOCAL_WORKERS,
                   timeout=args.dask_timeout or CONNECT_TIMEOUT_S)


def _say_dask(stats: dict, unit: str) -> None:
    _say(f"dask: {plural(stats[unit], unit[:-1], unit)} on {plural(stats['workers'], 'worker')} "
         f"at {stats['scheduler']}, "
         f"scene {_size(stats['scene_bytes'])} sent to each ({_size(stats['bytes_sent'])}), "
         f"{_size(stats['result_bytes'])} of images back")


def _render_frames(args: argparse.Namespace, started: float) -> int:
    """--frames: each frame of the scene's [animation] to its own file, skipping those complete
    (image and pass files) with --resume; locally one after another, or one Dask task each."""
    from clray.sequence import frames_in, load_sequence

    with _warnings_as_lines(quiet=args.quiet, verbose=args.verbose):
        # Every file of every frame: the animation's keyframes are loaded here (load_sequence).
        with noting_reads() as read:
            sequence = load_sequence(args.scene)
        frames = frames_in(args.frames, sequence.animation)
        todo = _check_frame_outputs(args, frames, read)
        first = sequence.scene(frames[0])
        if not args.quiet:
            for warning in first.warnings:
                _say(f"warning: {warning}")
            if todo:  # the frames are one size, and one at a time in this process
                _note_image_memory(args, first)
        records, dask_stats = _render_and_write_frames(args, sequence, first, todo)
    stats = {"scene": str(args.scene), "frames": sorted(records, key=lambda r: r["frame"]),
             "skipped": len(frames) - len(todo), "total_s": time.perf_counter() - started}
    if dask_stats is not None:
        stats["dask"] = dask_stats
    if args.stats_json is not None:
        with write_set() as files:
            _commit_with_stats(files, args.stats_json, stats)
    _say_frames(args, frames, stats)
    return EXIT_OK


def _check_frame_outputs(args: argparse.Namespace, frames: range, read: set[str]) -> list[int]:
    """The frames still to render (all but those complete, with --resume), once -o's pattern
    and every frame's files are found fit to write: none a file the scene read, a folder, or
    the stats file."""
    from clray.sequence import check_pattern, frame_files, frames_to_render

    aovs: tuple[str, ...] = args.aov or ()
    check_pattern(args.output, len(frames))
    _check_stats_not_a_frame(args, frames, aovs)
    for path in frame_files(args.output, frames[0], aovs, args.aov_preview):
        _check_writable(path)
    todo = frames_to_render(frames, args.output, args.resume, aovs, args.aov_preview)
    _refuse_replacing_reads(read, [
        *((f"frame {frame}'s file {path}", path, "-o") for frame in todo
          for path in frame_files(args.output, frame, aovs, args.aov_preview)),
        (f"--stats-json {args.stats_json}", args.stats_json, "--stats-json")])
    # A folder where a later frame's file goes would fail the command only once the frames
    # before it are rendered; a look at each name is cheap beside a probe file each.
    for frame in todo:
        for path in frame_files(args.output, frame, aovs, args.aov_preview):
            refuse_a_folder(path)
    return todo


def _render_and_write_frames(args: argparse.Namespace, sequence: Sequence, first: Scene,
                             todo: list[int]) -> tuple[list[dict], dict | None]:
    """The frames `todo` rendered (here, or on Dask from `first`'s size), each written to its
    file as it is done: the frames' records in the order they were done (the caller sorts
    them), and the Dask stats (None without Dask)."""
    from clray.sequence import frame_path, render_frames

    records: list[dict] = []
    with _progress(quiet=args.quiet, verbose=args.verbose) as progress:
        # In this process each frame's render reports its pixel-samples after those of the
        # frames before it (render_frames); on Dask each frame's are heard as it arrives.
        settings = _settings(args, progress)

        def done(frame: int, result: RenderResult) -> None:
            path = frame_path(args.output, frame)
            write_started = time.perf_counter()
            _write(path, lambda: result.save(path, previews=args.aov_preview))
            write_s = time.perf_counter() - write_started
            # The still's record, but that total_s is the frame's own: its scene made,
            # rendered and written (the command's is the top level's).
            render_s = result.stats["total_s"]
            records.append({"frame": frame, "output": str(path), **result.stats,
                            "render_s": render_s, "write_s": write_s,
                            "total_s": result.stats["load_s"] + render_s + write_s,
                            **_image_figures(result, path)})

        if args.dask is None or not todo:  # none left (--resume): no cluster to start
            render_frames(sequence, todo, settings, done)
            return records, None
        samples = ((args.width or first.render.width)
                   * (args.height or first.render.height)
                   * (args.spp or first.render.spp))

        def arrived(frame: int, result: RenderResult) -> None:
            done(frame, result)
            if progress is not None:
                progress(len(records) * samples, len(todo) * samples)

        if progress is not None:
            progress(0, len(todo) * samples)
        with _cluster(args) as client:
            return records, render_sequence(client, sequence, todo, settings, arrived)


def _say_frames(args: argparse.Namespace, frames: range, stats: dict) -> None:
    """The lines after the frames: their non-finite pixels, -v's stats, and what was written
    (and where on Dask)."""
    records = stats["frames"]
    if not args.quiet:
        for record in records:
            _warn_nonfinite(record, Path(record["output"]), f"frame {record['frame']}: ")
    if args.verbose and records:
        _say("stats:")
        for record in records:
            print(_frame_line(record), file=sys.stderr)
    if not args.quiet:
        if "dask" in stats:
            _say_dask(stats["dask"], "frames")
        skipped = f", {stats['skipped']} complete already" if stats["skipped"] else ""
        span = (f"frame {frames.start}" if len(frames) == 1
                else f"frames {frames.start}-{frames.stop - 1}")
        _say(f"wrote {plural(len(records), 'frame')} of {span} to "
             f"{args.output}{skipped} (wall {stats['total_s']:.3g} s)")


def _check_stats_not_a_frame(args: argparse.Namespace, frames: range,
                             aovs: tuple[str, ...]) -> None:
    """SettingsError (a usage error) where --stats-json names one of the frames' files, which
    the stats would replace: `-o f_%d.png --stats-json f_0.png`. Known only once the animation
    says which frames `A:` takes; _parse compares the still's files."""
    from clray.sequence import frame_files

    if args.stats_json is None:
        return
    for frame in frames:
        for path in frame_files(args.output, frame, aovs, args.aov_preview):
            if _same_file(args.stats_json, path):
                raise SettingsError(f"--stats-json and frame {frame}'s file are the same file: "
                                    f"{path}")


def _check_out_folder(out: Path, names: Iterable[str]) -> None:
    """`clray study`'s and `clray tune`'s --out, before minutes of work: a folder, made where
    missing (and taken back if the command fails before writing in it), that takes each file
    of `names`, with no folder where one of them goes."""
    if out.exists() and not out.is_dir():
        raise ClrayError(f"--out {out} exists and is not a directory")
    for name in names:
        _check_writable(out / name)


def _study(args: argparse.Namespace) -> int:
    from clray.study import run_study  # matplotlib and friends only when studying

    problem = _check_distinct_stems(args.scenes)
    if problem is not None:
        _say(f"error: {problem}")
        return EXIT_USAGE
    _check_out_folder(args.out, ("results.json", "report.md",
                                 *(f"{path.stem}.png" for path in args.scenes)))
    study = functools.partial(run_study, args.scenes, args.out, repeat=args.repeat,
                              width=args.width, height=args.height, device=args.device,
                              say=(lambda _: None) if args.quiet else _say)
    if args.dask is None:
        records = study()
    else:

        import_distributed()
        with _cluster(args) as client:
            records = study(run_scenes=functools.partial(study_scenes, client))
    if not args.quiet:
        failed = sum(r["status"] == "FAIL" for r in records)
        _say(f"wrote {args.out / 'report.md'} ({plural(len(records), 'render')}, "
             f"{failed} failing)")
    return EXIT_OK


def _check_distinct_stems(paths: list[Path]) -> str | None:
    """The usage error, where two scene files share a name without its suffix (a/spheres.toml
    and b/spheres.toml, or one file given twice): the results and caches of `clray tune` and
    `clray study` are keyed by it, and the second scene's would be the first's. Names that
    differ only in case count as the same, as they do on a case-insensitive file system."""
    seen: dict[str, Path] = {}
    for path in paths:
        first = seen.get(path.stem.casefold())
        if first is not None:
            if _same_file(first, path):
                return f"SCENE: {path} is given twice"
            return (f"SCENE: {first} and {path} have the same name {path.stem!r}, under which "
                    "their results are kept: rename one")
        seen[path.stem.casefold()] = path
    return None


def _tune(args: argparse.Namespace) -> int:
    from clray.tuning.tuner import check_strategy, import_kernel_tuner

    problem = _check_distinct_stems(args.scenes)
    if problem is not None:
        _say(f"error: {problem}")
        return EXIT_USAGE
    # Before any work: says how to install Kernel Tuner where it is missing.
    strategies = import_kernel_tuner().strategy_map
    if args.strategy not in strategies:
        _say(f"error: --strategy: expected one of {', '.join(sorted(strategies))}, got "
             f"{args.strategy!r}")
        return EXIT_USAGE
    check_strategy(args.strategy)
    from clray.tuning.command import run_tune

    _check_out_folder(args.out, ("report.md",))  # run_tune checks its other files' names
    with _warnings_as_lines(quiet=args.quiet, verbose=False):
        run_tune(args.scenes, args.out, device=args.device, strategy=args.strategy,
                 budget_s=args.budget, allow_error=args.allow_error,
                 size=(args.width, args.height), save=args.save,
                 search_every_host=args.search_every_host,
                 show_progress=not args.quiet and sys.stderr.isatty(),
                 say=(lambda _: None) if args.quiet else _say)
    if not args.quiet:
        _say(f"wrote {args.out / 'report.md'}")
    return EXIT_OK


def _profile(args: argparse.Namespace) -> int:
    from clray.profile import part_text, profile_scene

    _check_stdout()
    with _warnings_as_lines(quiet=False, verbose=False):
        settings = RenderSettings(width=args.width, height=args.height, spp=args.spp,
                                  device=args.device, stored_tuning=args.stored_tuning,
                                  traversal=args.traversal)
        scene = _load(args)
        # On a terminal, as a render's: the profile's builds and renders take minutes on a
        # large scene, and without it nothing showed until the end.
        bar = (_ProgressBar("clray: profiling", " steps", unit_scale=False)
               if sys.stderr.isatty() else None)
        try:
            prof = profile_scene(args.scene, settings, args.repeat, scene,
                                 progress=None if bar is None else bar.step)
        finally:
            if bar is not None:
                bar.close()
    if args.json:
        _print_out(json.dumps(prof, indent=2) + "\n")
        return EXIT_OK
    rays, tests = prof["rays"], prof["tests_per_ray"]
    lines = [f"{prof['scene']}: {prof['width']}x{prof['height']}, {prof['spp']} spp on "
             f"{prof['device']} (tuning: {prof['tuning']}, traversal: {prof['traversal']})",
             f"rays: {rays['total']:,} ({rays['primary']:,} primary, {rays['secondary']:,} "
             f"secondary, {rays['shadow']:,} shadow); kernel {prof['kernel_s'] * 1e3:.3g} ms, "
             f"{prof['mrays_per_s']:.3g} Mrays/s (median of {prof['repeat']})"]
    lines += [f"  {part_text(name, part)}" for name, part in prof["time_split"]["parts"].items()]

    def per(value: float | None) -> str:
        return "-" if value is None else f"{value:.3g}"

    lines += [f"tests per closest-hit ray: {per(tests['closest_boxes_per_ray'])} boxes, "
              f"{per(tests['closest_prims_per_ray'])} primitives; per shadow ray: "
              f"{per(tests['shadow_boxes_per_ray'])} boxes, "
              f"{per(tests['shadow_prims_per_ray'])} primitives",
              f"kernel build: {prof['build_cold_s']:.3g} s cold, {prof['build_warm_s']:.3g} s "
              "warm (new processes)",
              f"scene on device: {_size(prof['device_bytes_total'])}: " + ", ".join(
                  f"{k} {_size(v)}" for k, v in sorted(prof["device_bytes"].items(),
                                                       key=lambda kv: -kv[1]) if v)]
    _print_out("".join(f"{line}\n" for line in lines))
    return EXIT_OK


def _tuned(spec: str) -> str:
    from clray.device.context import select_device
    from clray.device.tuning_files import load_tuning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        found = load_tuning(select_device(spec))
    if found is not None:
        return f"tuned ({found[0].label()})"
    return "tuning file stale or invalid" if caught else "not tuned"


def _devices(args: argparse.Namespace) -> int:
    # A CLRAY_DEVICE or PYOPENCL_CTX that names no device is what a user runs `clray devices`
    # to mend: the list still comes, the error after it.
    problem: ClrayError | None = None
    try:
        _, default_spec, why = default_device()
    except ClrayError as err:
        problem, default_spec, why = err, "", ""
    rows = [(d.spec, d.type, d.name, d.platform, f"{d.compute_units} CU",
             f"fp64 {'yes' if d.fp64 else 'no'}", f"driver {d.driver_version}", _tuned(d.spec),
             f"renders by default ({why})" if d.spec == default_spec else "")
            for d in list_devices()]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    _print_out("".join("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True))
                       .rstrip() + "\n" for row in rows))
    if problem is not None:
        _say(f"error: {problem}")
        return problem.exit_code
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parse(argv)
    except SystemExit as done:  # argparse exits for --help and for usage errors
        return int(done.code or 0)
    _MADE_FOLDERS.clear()
    code = EXIT_RUNTIME
    try:
        code = _run(args)
    finally:
        if code != EXIT_OK:
            _remove_made_folders()
    return code


def _run(args: argparse.Namespace) -> int:
    """The command, its errors as the exit codes of the README."""
    try:
        return args.run(args)
    except ClrayError as err:
        _say(f"error: {err.with_path() if isinstance(err, SceneError) else err}")
        return err.exit_code
    except cl.Error as err:
        # One that no call naming its device turned into a DeviceError (opencl_errors): still
        # the device's trouble, exit 4, in one line.
        _say(f"error: OpenCL: {opencl_error_text(err)}")
        return EXIT_OPENCL
    except _Signalled as stop:
        _say(f"error: {signal.strsignal(stop.signum).lower()} ({signal.Signals(stop.signum).name})")
        return 128 + stop.signum
    except KeyboardInterrupt:
        _say("error: interrupted")
        return EXIT_INTERRUPTED
    except MemoryError:
        # Past the loaders (which name the file they were reading): the file the command was
        # working on, where it has one, by its path as given (as a SceneError's line names it).
        source = getattr(args, "scene", None) or getattr(args, "model", None)
        _say(f"error: {f'{one_line(str(source))}: ' if source else ''}out of memory")
        return EXIT_RUNTIME
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_RUNTIME


def _remove_made_folders() -> None:
    """The output folders this command made, where they are still empty (an animation's frames
    written before a failure stay, for --resume)."""
    for folder in reversed(_MADE_FOLDERS):  # each after the folders made in it
        try:
            folder.rmdir()
        except OSError:
            pass
    _MADE_FOLDERS.clear()


class _Signalled(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where the command is: a KeyboardInterrupt, so that it takes
    Ctrl-C's way out (temporary files removed by clray.output.write_set, the folders the command
    made by main), where the signal's default would end the process leaving both."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_signalled(signum: int, _frame: object) -> None:
    # Once: a second signal during the cleanup would cut it short (SIGKILL still ends it).
    for other in _ENDING_SIGNALS:
        signal.signal(other, signal.SIG_IGN)
    raise _Signalled(signum)


def run_command() -> NoReturn:
    """The `clray` command (console script and `python -m clray`): main(), then an exit that
    skips Python's finalisation, which spends about 0.05 s tearing down numpy's and pyopencl's
    modules once every file is written and closed. Output is flushed first; where that fails
    (a closed pipe) the ordinary exit reports it as usual. SIGTERM and SIGHUP end the command
    as Ctrl-C does (_Signalled), but where they are ignored (nohup): they stay so. Here, not in
    main(): a program calling main() keeps its own handlers."""
    for signum in _ENDING_SIGNALS:
        if signal.getsignal(signum) == signal.SIG_DFL:
            signal.signal(signum, _raise_signalled)
    code = main()
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:  # None: closed at start (`>&-`)
                stream.flush()
    except BrokenPipeError:
        _quiet_stdout()
        code = code or EXIT_RUNTIME
    except OSError:
        raise SystemExit(code) from None
    os._exit(code)


def _quiet_stdout() -> None:
    """After the reader of stdout went away (`clray devices | head -1`): nothing more to say to
    it, and no later flush may fail again with a traceback."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
