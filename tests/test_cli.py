"""The `clray` command end to end: files written, flags, exit codes, one-line errors."""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import io
import json
import os
import pty
import re
import signal
import struct
import subprocess
import sys
import termios
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clray import cli, sequence
from clray.device.context import has_fp64
from clray.errors import EXIT_USAGE, ClrayError
from clray.image_io import read_pfm
from clray.output import write_bytes_atomically
from clray.scene import limits
from clray.tuning import Tuning

SCENE = """\
[render]
width = 40
height = 30
max_depth = 2

[camera]
position = [0, 1, 5]
look_at = [0, 0.5, 0]
vfov = 40

[materials.red]
color = [1, 0.2, 0.2]
specular = 0.3
{material_extra}

[[lights]]
type = "point"
position = [-4, 6, 4]

[[objects]]
type = "sphere"
center = [0, 0.5, 0]
radius = {radius}
material = "red"

[[objects]]
type = "plane"
point = [0, -0.5, 0]
normal = [0, 1, 0]
material = "red"
"""

TINY = ["-W", "32", "-H", "24"]
ROOT = Path(__file__).resolve().parent.parent


def scene_text(radius: str = "1", material_extra: str = "") -> str:
    return SCENE.format(radius=radius, material_extra=material_extra)


@pytest.fixture
def scene(tmp_scene, tmp_path, monkeypatch) -> Path:
    monkeypatch.chdir(tmp_path)  # default outputs land in the current directory
    return tmp_scene(scene_text())


def run(capsys, *argv: str | Path) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_error_line(err: str) -> None:
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("clray: error: ")


def files_in(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# --- usage errors (exit 2): no device needed ---------------------------------------------------

@pytest.mark.parametrize("argv", [
    [],
    ["render"],
    ["render", "{scene}", "-o", "out.jpg"],
    ["render", "{scene}", "-o", "out"],
    ["render", "{scene}", "-W", "0"],
    ["render", "{scene}", "-H", "-3"],
    ["render", "{scene}", "--spp", "two"],
    ["render", "{scene}", "--max-depth", "-1"],
    ["render", "{scene}", "--seed", str(2**32)],
    # Past the documented maxima: these used to be OverflowError tracebacks.
    ["render", "{scene}", "-W", str(2**31)],
    ["render", "{scene}", "-H", "16385"],
    ["render", "{scene}", "--spp", str(2**31)],
    ["render", "{scene}", "--max-depth", str(2**31)],
    ["render", "{scene}", "--spp", "9" * 5000],
    # Output paths that name no file: --stats-json used to fail after the image was written.
    ["render", "{scene}", "--stats-json", ""],
    ["render", "{scene}", "--stats-json", "."],
    ["render", "{scene}", "--stats-json", "sub/"],
    ["render", "{scene}", "-o", "out.png", "--stats-json", "out.png"],
    ["study", "{scene}", "--out", "d", "--repeat", str(2**31)],
    ["profile", "{scene}", "--spp", "0"],
    ["profile", "{scene}", "--spp", "sixteen"],
    ["profile", "{scene}", "--spp", "4097"],
    ["render", "{scene}", "--precision", "half"],
    ["render", "{scene}", "-q", "-v"],
    ["render", "{scene}", "--no-such-flag"],
    ["paint", "{scene}"],
])
def test_usage_errors_exit_2(capsys, scene, tmp_path, argv) -> None:
    code, out, err = run(capsys, *[a.format(scene=scene) for a in argv])
    assert code == 2
    assert out == ""
    assert_one_error_line(err)
    assert files_in(tmp_path) == ["scene.toml"]


@pytest.mark.parametrize("frames", [[], ["--frames", "0:2", "-o", "f_%d.png"]])
def test_stats_json_naming_the_scene_file_is_refused(capsys, scene, tmp_path, frames) -> None:
    # `--stats-json sc.toml` replaced the scene with the stats (compared with the images only).
    text = scene.read_text()
    (tmp_path / "link.json").symlink_to(scene.name)
    for stats in ("scene.toml", "link.json"):
        code, out, err = run(capsys, "render", scene, *frames, "--stats-json", stats)
        assert (code, out) == (2, "")
        assert_one_error_line(err)
        assert f"--stats-json {stats} is the scene file" in err
    assert scene.read_text() == text
    assert files_in(tmp_path) == ["link.json", "scene.toml"]


@pytest.mark.parametrize(("command", "flags"), [
    ("render", ["--dask-workers", "3"]),
    ("render", ["--dask-timeout", "5"]),
    ("study", ["--out", "d", "--dask-workers", "3", "--dask-timeout", "5"]),
])
def test_dask_flags_without_dask_are_refused(capsys, scene, tmp_path, command, flags) -> None:
    # They were ignored: the command ran without Dask as if they had not been given.
    code, _, err = run(capsys, command, scene, *flags)
    assert code == 2 and files_in(tmp_path) == ["scene.toml"]
    assert_one_error_line(err)
    given = " and ".join(flag for flag in flags if flag.startswith("--dask"))
    assert f"{given} {'apply' if ' and ' in given else 'applies'} to --dask" in err


def test_usage_errors_after_parsing_point_to_the_commands_help(capsys, scene) -> None:
    # They pointed to 'clray --help', which lists the commands, not the flag at fault.
    _, _, err = run(capsys, "render", scene, "--resume")
    assert err == "clray: error: --resume applies to --frames (see 'clray render --help')\n"
    _, _, err = run(capsys, "study", scene, "--out", "d", "--dask", "tcp://h:1",
                    "--dask-workers", "2")
    assert err.endswith("(see 'clray study --help')\n")


@pytest.mark.parametrize("command", [["render", "s.toml"], ["profile", "s.toml"], ["devices"],
                                     ["tune", "s.toml"], ["study", "s.toml", "--out", "d"],
                                     ["scene", "m.obj"]])
def test_an_unknown_flag_points_to_the_commands_help(capsys, command) -> None:
    # It pointed to 'clray --help', which lists the commands, not the flags of the one given.
    code, _, err = run(capsys, *command, "--bogus")
    assert code == 2
    assert err == ("clray: error: unrecognized arguments: --bogus "
                   f"(see 'clray {command[0]} --help')\n")


def test_an_image_is_not_written_to_a_terminal(capsys, scene, monkeypatch) -> None:
    # `-o -` at a prompt wrote the PNG's bytes to the terminal.
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    code, out, err = run(capsys, "render", scene, *TINY, "-o", "-")
    assert (code, out) == (2, "")
    assert err == ("clray: error: -o - writes the PNG to standard output, which is a terminal: "
                   "redirect it (> out.png) or pipe it, or give -o a file name "
                   "(see 'clray render --help')\n")


def test_a_write_error_names_the_file_that_failed(tmp_path) -> None:
    # An image's write writes its pass files too; one of theirs was said as the image's.
    blocker = tmp_path / "out.depth.pfm"
    blocker.mkdir()
    with pytest.raises(ClrayError) as info:
        cli._write(tmp_path / "out.png", lambda: write_bytes_atomically(blocker, b"PF"))
    assert str(info.value) == f"cannot write {blocker}: Is a directory"
    assert files_in(tmp_path) == ["out.depth.pfm"]


def test_bad_suffix_message_names_supported_ones(capsys, scene) -> None:
    _, _, err = run(capsys, "render", scene, "-o", "out.jpg")
    assert ".png" in err and ".pfm" in err


def test_help_exits_0(capsys) -> None:
    code, out, _ = run(capsys, "render", "--help")
    assert code == 0
    for flag in ("--output", "--width", "--height", "--spp", "--max-depth", "--seed",
                 "--device", "--precision", "--linear", "--srgb", "--exposure", "--png-bits",
                 "--stats-json", "--quiet", "--verbose"):
        assert flag in out


def test_profile_help_names_its_flags(capsys) -> None:
    code, out, _ = run(capsys, "profile", "--help")
    assert code == 0
    for flag in ("--device", "--width", "--height", "--spp", "--repeat", "--no-tuning", "--json"):
        assert flag in out


# --- scene errors (exit 3): the scene is loaded before any device is touched ---------------------

@pytest.mark.parametrize(("text", "needle"), [
    ("[render\nwidth = ", "scene.toml"),
    (scene_text().replace("max_depth = 2", "max_depht = 2"), "max_depht"),
    (scene_text(radius="-1"), "radius"),
    (scene_text(material_extra='texture = { type = "image", file = "missing.png" }'),
     "missing.png"),
])
def test_scene_errors_exit_3(capsys, tmp_scene, tmp_path, monkeypatch, text, needle) -> None:
    monkeypatch.chdir(tmp_path)
    path = tmp_scene(text)
    code, _, err = run(capsys, "render", path, *TINY)
    assert code == 3
    assert_one_error_line(err)
    assert needle in err
    assert files_in(tmp_path) == ["scene.toml"]


def test_missing_scene_file_exits_3(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "render", tmp_path / "nowhere.toml")
    assert code == 3
    assert_one_error_line(err)
    assert "nowhere.toml" in err
    assert files_in(tmp_path) == []


# --- OpenCL errors (exit 4) and runtime errors (exit 1) ------------------------------------------

def test_unknown_device_exits_4(capsys, scene, tmp_path) -> None:
    # With no OpenCL platform at all this is still exit 4, with the install hint.
    code, _, err = run(capsys, "render", scene, *TINY, "--device", "no-such-device-xyz")
    assert code == 4
    assert_one_error_line(err)
    assert files_in(tmp_path) == ["scene.toml"]


def test_an_opencl_error_making_the_context_exits_4(capsys, cl_device, scene,
                                                    monkeypatch) -> None:
    # A device that a driver lists but cannot open (another process holds it exclusively):
    # one line naming the device and OpenCL's error, not a traceback.
    import pyopencl as cl

    from clray.device import context

    def unavailable(device: cl.Device) -> cl.Context:
        raise cl.RuntimeError("clCreateContext failed: DEVICE_NOT_AVAILABLE")

    monkeypatch.setattr(context, "context_for", unavailable)
    context.queue_for.cache_clear()
    code, _, err = run(capsys, "render", scene, *TINY, "--no-tuning")
    context.queue_for.cache_clear()
    assert code == 4
    assert_one_error_line(err)
    assert "DEVICE_NOT_AVAILABLE" in err and cl_device.name.strip() in err


def test_any_other_opencl_error_exits_4(capsys, monkeypatch) -> None:
    import pyopencl as cl

    def fails() -> list:
        raise cl.LogicError("clGetDeviceInfo failed: INVALID_VALUE\nmore")

    monkeypatch.setattr(cli, "list_devices", fails)
    code, _, err = run(capsys, "devices")
    assert code == 4
    assert_one_error_line(err)
    assert err == "clray: error: OpenCL: clGetDeviceInfo failed: INVALID_VALUE\n"


def test_unwritable_output_exits_1_and_leaves_no_temp_file(capsys, cl_device, scene,
                                                           tmp_path) -> None:
    (tmp_path / "taken.png").mkdir()  # a directory where the image should go
    code, _, err = run(capsys, "render", scene, *TINY, "-o", "taken.png")
    assert code == 1
    assert_one_error_line(err)
    assert "taken.png" in err
    assert files_in(tmp_path) == ["scene.toml", "taken.png"]
    assert files_in(tmp_path / "taken.png") == []


# --- successful renders (exit 0) -----------------------------------------------------------------

def test_default_output_is_scene_stem_png_with_scene_size(capsys, cl_device, scene,
                                                          tmp_path) -> None:
    code, out, err = run(capsys, "render", scene)
    assert code == 0
    assert out == ""
    assert err.splitlines() == [err.strip()]
    summary = re.fullmatch(r"clray: wrote scene\.png \(40x30, 1 spp, wall (\S+) s, "
                           r"kernel (\S+) s\)\n", err)
    assert summary, err
    assert float(summary[1]) >= float(summary[2]) > 0
    with Image.open(tmp_path / "scene.png") as png:
        assert png.mode == "RGB" and png.size == (40, 30)
        assert np.asarray(png).max() > 0  # the lit sphere is not black
    assert files_in(tmp_path) == ["scene.png", "scene.toml"]


def test_pfm_with_overrides_and_stats_json(capsys, cl_device, scene, tmp_path) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "--spp", "2", "--max-depth", "1",
                       "--seed", "7", "-o", "out.pfm", "--stats-json", "stats.json", "-q")
    assert code == 0
    assert err == ""
    image = read_pfm(tmp_path / "out.pfm")
    assert image.shape == (24, 32, 3)
    assert np.isfinite(image).all()
    stats = json.loads((tmp_path / "stats.json").read_text())
    for key in ("width", "height", "spp", "device", "precision", "load_s", "bvh_s", "build_s",
                "kernel_s", "total_s"):
        assert key in stats, key
    assert (stats["width"], stats["height"], stats["spp"]) == (32, 24, 2)
    assert stats["max_depth"] == 1
    assert stats["precision"] == "float"
    assert stats["total_s"] >= stats["kernel_s"] >= 0
    assert files_in(tmp_path) == ["out.pfm", "scene.toml", "stats.json"]


def test_default_srgb_png_is_brighter_than_linear(capsys, cl_device, scene, tmp_path) -> None:
    assert run(capsys, "render", scene, *TINY, "-o", "linear.png", "-q", "--linear")[0] == 0
    assert run(capsys, "render", scene, *TINY, "-o", "srgb.png", "-q")[0] == 0
    with Image.open(tmp_path / "linear.png") as a, Image.open(tmp_path / "srgb.png") as b:
        linear, srgb = np.asarray(a, dtype=int), np.asarray(b, dtype=int)
    assert (srgb >= linear).all() and (srgb > linear).any()


def test_verbose_prints_progress_and_stats(capsys, cl_device, scene) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "-v")
    assert code == 0
    lines = err.splitlines()
    assert "clray: rendering: 100% (768 of 768 pixel-samples, " in err
    table = lines[lines.index("clray: stats:") + 1:-1]
    labels = [line.split("  ")[1] for line in table]
    assert labels[:20] == ["scene", "output", "device", "image", "tuning", "traversal", "load",
                           "select device", "bvh", "pack", "build", "kernel", "render", "write",
                           "total (wall)", "rays primary", "rays secondary", "rays shadow",
                           "rays total", "Mrays/s"]
    assert labels[20:] == ["scene on device", "non-finite pixels", "clipped pixels"]
    # Labels padded to one width: the values start in one column.
    column = 2 + len("non-finite pixels") + 2
    assert all(line[2:column].rstrip() == label for line, label in zip(table, labels,
                                                                         strict=True))
    assert "image              32x24, 1 spp, max depth 2, min weight 0, seed 0, float" in err
    assert "tuning             default (default; BVH width " in err
    assert lines[-1].startswith("clray: wrote scene.png (32x24")


def test_verbose_progress_lines_follow_pixel_samples(capsys, cl_device, scene,
                                                     monkeypatch) -> None:
    # Bands of four rows: the knob table's defaults, as every render without a tuning file
    # takes them, changed.
    monkeypatch.setattr("clray.device.tuning_files.DEFAULT_TUNING", Tuning(
        first_launch_pixel_samples=32 * 4, max_launch_pixel_samples=32 * 4))
    code, _, err = run(capsys, "render", scene, *TINY, "-v")
    assert code == 0
    steps = re.findall(r"^clray: rendering: (\d+)% \((\d+) of 768 pixel-samples, "
                       r"[\d.]+ s, [\d.]+ s left\)$", err, re.MULTILINE)
    # Six bands of four rows: a line at each tenth of the work that a band crosses.
    assert steps == [("10", "128"), ("30", "256"), ("50", "384"), ("60", "512"),
                     ("80", "640"), ("100", "768")]


def test_terminal_gets_a_progress_bar_unless_quiet(cl_device, scene, tmp_path) -> None:
    def stderr_on_a_terminal(*flags: str) -> str:
        leader, follower = pty.openpty()
        # A new pseudo-terminal is 0 columns wide, where tqdm draws nothing.
        fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
        done = subprocess.run([sys.executable, "-m", "clray", "render", str(scene), *TINY,
                               *flags], stderr=follower, stdout=subprocess.DEVNULL,
                              cwd=tmp_path, check=False, timeout=300)
        os.close(follower)
        chunks = []
        with contextlib.suppress(OSError):  # Linux ends a drained pty with EIO
            while chunk := os.read(leader, 4096):
                chunks.append(chunk)
        os.close(leader)
        assert done.returncode == 0
        return b"".join(chunks).decode()

    shown = stderr_on_a_terminal()
    assert re.match(r"\rclray: rendering: +0%\|.*\| \S+/768 \[00:00<\?, \?samples/s\]\r",
                    shown), repr(shown)
    # The bar is erased (overwritten with blanks) before the summary line is printed.
    *_, erased, summary = shown.rstrip("\r\n").split("\r")
    assert erased.strip() == ""
    assert summary.startswith("clray: wrote scene.png (32x24, 1 spp, wall ")
    assert stderr_on_a_terminal("-q") == ""


def test_scene_warnings_shown_unless_quiet(capsys, cl_device, scene, monkeypatch) -> None:
    load = cli.load_scene
    monkeypatch.setattr(cli, "load_scene",
                        lambda path: dataclasses.replace(load(path), warnings=("look out",)))
    code, _, err = run(capsys, "render", scene, *TINY)
    assert code == 0
    assert err.splitlines()[0] == "clray: warning: look out"
    code, _, err = run(capsys, "render", scene, *TINY, "-q")
    assert (code, err) == (0, "")


def test_double_precision_renders_or_reports_missing_fp64(capsys, cl_device, scene,
                                                          tmp_path) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "--precision", "double",
                       "-o", "d.pfm", "--stats-json", "s.json")
    if has_fp64(cl_device):
        assert code == 0, err
        assert json.loads((tmp_path / "s.json").read_text())["precision"] == "double"
        assert read_pfm(tmp_path / "d.pfm").shape == (24, 32, 3)
    else:
        assert code == 4
        assert_one_error_line(err)


def test_devices_lists_one_line_per_device(capsys, cl_device) -> None:
    code, out, err = run(capsys, "devices")
    assert code == 0
    assert err == ""
    lines = out.splitlines()
    assert lines
    for line in lines:
        assert " CU " in line and ("fp64 yes" in line or "fp64 no" in line)
    assert any(cl_device.name.strip() in line for line in lines)


def test_devices_help_says_what_its_columns_are(capsys) -> None:
    # It left out the last: which device renders by default, and why.
    code, out, _ = run(capsys, "devices", "--help")
    assert code == 0
    text = " ".join(out.split())
    for column in ("spec", "type", "name", "platform", "compute units", "fp64",
                   "driver version", "tuning file", "renders by default"):
        assert column in text


def test_devices_still_lists_where_clray_device_names_none(capsys, cl_device,
                                                           monkeypatch) -> None:
    """A bad CLRAY_DEVICE is what `clray devices` is run to mend: the list, then the error."""
    monkeypatch.setenv("CLRAY_DEVICE", "no-such-device")
    code, out, err = run(capsys, "devices")
    assert code == 4
    assert_one_error_line(err)
    assert "no-such-device" in err
    assert any(cl_device.name.strip() in line for line in out.splitlines())
    assert "renders by default" not in out


def test_a_render_names_the_clray_device_that_matches_none(capsys, scene, cl_device,
                                                          monkeypatch) -> None:
    # The error named the spec alone, which no flag given held: the variable is what to mend.
    monkeypatch.setenv("CLRAY_DEVICE", "no-such-device")
    code, _, err = run(capsys, "render", scene, *TINY, "-o", "out.png")
    assert code == 4
    assert_one_error_line(err)
    assert err.startswith("clray: error: CLRAY_DEVICE='no-such-device': no OpenCL device "
                          "matches 'no-such-device' (devices: ")


def test_python_dash_m_clray(cl_device, scene, tmp_path) -> None:
    done = subprocess.run([sys.executable, "-m", "clray", "render", str(scene), *TINY,
                           "-o", "sub.png"], capture_output=True, text=True, cwd=tmp_path,
                          check=False, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stderr.startswith("clray: wrote sub.png (32x24")
    with Image.open(tmp_path / "sub.png") as png:
        assert png.size == (32, 24)

    failed = subprocess.run([sys.executable, "-m", "clray", "render", "missing.toml"],
                            capture_output=True, text=True, cwd=tmp_path, check=False,
                            timeout=300)
    assert failed.returncode == 3
    assert_one_error_line(failed.stderr)


# --- hostile input (issue 10) --------------------------------------------------------------------

def test_flag_maxima_are_in_the_message(capsys, scene) -> None:
    _, _, err = run(capsys, "render", scene, "-W", str(2**31))
    assert "must be an integer in [1, 16384], got '2147483648'" in err
    _, _, err = run(capsys, "render", scene, "--spp", "9" * 5000)
    assert_one_error_line(err)
    assert len(err) < 200


def refuse_to_render(*_args, **_kwargs):
    raise AssertionError("rendered although an output could not be written")


TEXTURED_OBJ = "mtllib tri.mtl\nv -1 -1 0\nv 1 -1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0.5 1\n" \
               "usemtl m\nf 1/1 2/2 3/3\n"


def sky_scene(tmp_path: Path, texture: str, animated: bool = False) -> Path:
    """A scene whose background is the image `texture` (written), in `tmp_path`."""
    texture_path = tmp_path / texture
    texture_path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 2), (90, 140, 200)).save(texture_path)
    animation = ('[animation]\nframes = 3\n[[animation.tracks]]\nkey = "camera.vfov"\n'
                 'frames = [0, 2]\nvalues = [40, 50]\n') if animated else ""
    scene = tmp_path / "sky.toml"
    scene.write_text(SCENE.format(radius="1", material_extra="").replace(
        "max_depth = 2", f'max_depth = 2\nbackground = {{ type = "image", file = "{texture}" }}')
        + animation)
    return scene


@pytest.mark.parametrize(("texture", "flags", "named"), [
    ("textures/sky.png", ["-o", "textures/sky.png"], "-o textures/sky.png"),
    ("sky.png", [], "the output sky.png (the scene's name"),
    ("out.depth.pfm", ["-o", "out.png", "--aov", "depth"], "the depth pass file out.depth.pfm"),
    ("out.normal.png", ["-o", "out.png", "--aov", "normal", "--aov-preview"],
     "the normal preview file out.normal.png"),
    ("s.png", ["-o", "out.png", "--stats-json", "s.png"], "--stats-json s.png"),
    ("f_0002.png", ["--frames", "0:3", "-o", "f_%04d.png"], "frame 2's file f_0002.png"),
    ("f_0001.png", ["--frames", "0:3", "-o", "x_%d.png", "--stats-json", "f_0001.png"],
     "--stats-json f_0001.png"),
])
def test_an_output_that_the_scene_reads_is_refused(capsys, tmp_path, monkeypatch, texture,
                                                   flags, named) -> None:
    # `clray render tri.obj` wrote tri.png over the texture its tri.mtl names, and
    # `-o textures/sky.png` replaced the scene's background image.
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli, "render", refuse_to_render)
    monkeypatch.setattr(sequence, "render_frames", refuse_to_render)
    scene = sky_scene(tmp_path, texture, animated="--frames" in flags)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    code, out, err = run(capsys, "render", scene.name, *flags)
    assert (code, out) == (2, ""), err
    assert_one_error_line(err)
    assert named in err and "the scene reads this file" in err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_mesh_files_texture_named_as_the_default_output_is_kept(capsys, tmp_path,
                                                                  monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli, "render", refuse_to_render)
    (tmp_path / "tri.obj").write_text(TEXTURED_OBJ)
    (tmp_path / "tri.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tri.png\n")
    Image.new("RGB", (2, 2), (200, 10, 10)).save(tmp_path / "tri.png")
    texture = (tmp_path / "tri.png").read_bytes()
    code, _, err = run(capsys, "render", "tri.obj")
    assert code == 2
    assert_one_error_line(err)
    assert "the output tri.png (the scene's name" in err and "the scene reads this file" in err
    assert (tmp_path / "tri.png").read_bytes() == texture
    assert files_in(tmp_path) == ["tri.mtl", "tri.obj", "tri.png"]


def test_unwritable_stats_folder_is_found_before_rendering(capsys, scene, tmp_path,
                                                           monkeypatch) -> None:
    monkeypatch.setattr(cli, "render", refuse_to_render)
    (tmp_path / "file").write_text("")
    code, _, err = run(capsys, "render", scene, "--stats-json", tmp_path / "file" / "s.json")
    assert code == 1
    assert_one_error_line(err)
    assert files_in(tmp_path) == ["file", "scene.toml"]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
@pytest.mark.parametrize("full", ["a.png", "s.json"])
def test_a_full_disk_leaves_no_file_of_the_render(capsys, cl_device, scene, tmp_path,
                                                  full) -> None:
    # The pass files were written before the image and stayed when it failed, and the image
    # and its passes when the stats failed after them (exit 1 both).
    out = tmp_path / "fs"
    out.mkdir()
    (out / full).symlink_to("/dev/full")
    code, _, err = run(capsys, "render", scene, *TINY, "-o", out / "a.png", "--aov",
                       "depth,normal", "--aov-preview", "--stats-json", out / "s.json", "-q")
    assert code == 1
    assert err == f"clray: error: cannot write {out / full}: No space left on device\n"
    assert files_in(out) == [full]


def test_an_exr_that_cannot_be_written_is_one_line_and_leaves_no_file(
        capsys, cl_device, scene, tmp_path, monkeypatch) -> None:
    # OpenEXR raises RuntimeError, not OSError, for a write that fails: it was a traceback.
    openexr = pytest.importorskip("OpenEXR")

    class FullDisk:
        def __init__(self, *_: object) -> None:
            pass

        def write(self, name: str) -> None:
            Path(name).write_bytes(b"v/1\x01")  # some of the file, as a full disk leaves it
            raise RuntimeError(f'Failed to write pixel data to image file "{name}". No space '
                               "left on device.")

    monkeypatch.setattr(openexr, "File", FullDisk)
    code, _, err = run(capsys, "render", scene, *TINY, "-o", "out.exr", "--aov", "depth",
                       "--stats-json", "s.json")
    assert code == 1
    assert err == ("clray: error: cannot write out.exr: OpenEXR: Failed to write pixel data to "
                   "image file. No space left on device\n")
    assert files_in(tmp_path) == ["scene.toml"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder_is_found_before_rendering(capsys, scene, tmp_path,
                                                           monkeypatch) -> None:
    monkeypatch.setattr(cli, "render", refuse_to_render)
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    code, _, err = run(capsys, "render", scene, "-o", locked / "out.png")
    assert code == 1
    assert_one_error_line(err)
    assert "Permission denied" in err


def test_output_folder_probe_leaves_nothing(capsys, scene, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(cli, "render", refuse_to_render)
    (tmp_path / "out").mkdir()
    with pytest.raises(AssertionError, match="rendered although"):
        cli.main(["render", str(scene), "-o", str(tmp_path / "out" / "x.png")])
    assert files_in(tmp_path / "out") == []


def test_newline_in_scene_name_gives_one_error_line(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "render", "a\nclray: error: b.toml")
    assert code == 3
    assert_one_error_line(err)
    assert "a\\nclray: error: b.toml" in err


def test_scene_errors_name_the_file_by_its_path(capsys, tmp_path, monkeypatch) -> None:
    # Two files named scene.toml, one including the other from its folder: each error names
    # its file by the path as given, or joined to the including scene's folder, as the
    # warnings do; a base name alone would not say which it was. Exit 3, one line.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "shots" / "parts").mkdir(parents=True)
    camera = '[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n'
    (tmp_path / "shots" / "scene.toml").write_text('include = ["parts/scene.toml"]\n' + camera)
    (tmp_path / "shots" / "parts" / "scene.toml").write_text("[materials.bad]\nior = 0\n")
    code, _, err = run(capsys, "render", "shots/scene.toml", "-o", "x.png")
    assert code == 3
    assert err == ("clray: error: shots/parts/scene.toml: materials.bad.ior: must be >= 0.01, "
                   "got 0\n")
    (tmp_path / "shots" / "scene.toml").write_text("[camera]\n")
    # An absolute path outside the working directory stays as it was given.
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    code, _, err = run(capsys, "render", tmp_path / "shots" / "scene.toml", "-o", "x.png")
    assert code == 3
    assert err == (f"clray: error: {tmp_path / 'shots' / 'scene.toml'}: camera.position: "
                   "missing required key\n")
    assert files_in(tmp_path) == ["elsewhere", "shots"]
    assert files_in(tmp_path / "elsewhere") == []


@pytest.mark.parametrize("command", ["render", "scene"])
def test_a_mesh_files_errors_name_it_as_given(capsys, tmp_path, monkeypatch, command) -> None:
    # The automatic scene of a mesh file loads it by an absolute path; its errors name it by
    # the relative one given.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    output = ["-o", "x.png"] if command == "render" else []
    code, _, err = run(capsys, command, "models/bad.obj", *output)
    assert code == 3
    assert err.startswith("clray: error: models/bad.obj: line 4: ")
    assert len(err.splitlines()) == 1


def test_an_animations_errors_name_the_scene_as_given(capsys, tmp_path, monkeypatch) -> None:
    # --frames loads the scene by its absolute path (for Dask's workers); its errors name it
    # by the relative one given.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "shots").mkdir()
    (tmp_path / "shots" / "plain.toml").write_text(
        '[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n')
    code, _, err = run(capsys, "render", "shots/plain.toml", "--frames", "0:2", "-o",
                       "f_%04d.png")
    assert code == 3
    assert err.startswith("clray: error: shots/plain.toml: animation: missing")
    assert files_in(tmp_path) == ["shots"]


def test_fifo_scene_exits_3_without_blocking(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "pipe.toml")
    code, _, err = run(capsys, "render", "pipe.toml")
    assert code == 3
    assert err == "clray: error: pipe.toml: cannot read scene file: not a regular file\n"


@pytest.mark.parametrize("command", ["render", "scene"])
def test_an_unreadable_mesh_file_is_said_as_a_scene_file_is(capsys, tmp_path, monkeypatch,
                                                            command) -> None:
    # A mesh file given for its automatic scene: "cannot read mesh file", and why, as for a
    # scene file (the fuzzer's FIFO and symbolic-link loop).
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "pipe.obj")
    os.symlink("loop.ply", tmp_path / "loop.ply")
    big = limits.MAX_MESH_BYTES + 1  # an OBJ's limit, below a binary mesh's (sparse)
    with open(tmp_path / "big.obj", "wb") as stream:
        stream.truncate(big)
    for name, why in [("pipe.obj", "not a regular file"),
                      ("loop.ply", "Too many levels of symbolic links"),
                      ("gone.glb", "file not found"),
                      ("big.obj", f"{big} bytes is over the limit of {limits.MAX_MESH_BYTES} "
                                  "bytes")]:
        code, out, err = run(capsys, command, name)
        assert code == 3 and out == ""
        assert_one_error_line(err)
        assert err == f"clray: error: {name}: cannot read mesh file: {why}\n"


def test_python_warnings_become_clray_warning_lines(capsys, scene, monkeypatch) -> None:
    def warn_and_fail(*_args, **_kwargs):
        warnings.warn("overflow encountered in cast", RuntimeWarning, stacklevel=1)
        raise ClrayError("stopped")

    monkeypatch.setattr(cli, "render", warn_and_fail)
    code, _, err = run(capsys, "render", scene)
    assert code == 1
    assert err.splitlines() == ["clray: warning: overflow encountered in cast",
                                "clray: error: stopped"]
    code, _, err = run(capsys, "render", scene, "-q")
    assert err.splitlines() == ["clray: error: stopped"]


INTERRUPT_AT_IMPORT = """\
import sys


class _Interrupt:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            raise KeyboardInterrupt
        return None


sys.meta_path.insert(0, _Interrupt())
"""


@pytest.mark.parametrize(("argv", "code", "err"), [
    (["-m", "clray", "render", "x.toml"], 130, "clray: error: interrupted\n"),
    (["-c", "import clray"], None, "KeyboardInterrupt"),
])
def test_ctrl_c_while_importing(tmp_path, argv, code, err) -> None:
    # A sitecustomize that presses Ctrl-C when numpy is first imported: deterministic, unlike
    # a signal sent after a guessed delay.
    (tmp_path / "sitecustomize.py").write_text(INTERRUPT_AT_IMPORT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    done = subprocess.run([sys.executable, *argv], capture_output=True, text=True, cwd=tmp_path,
                          env=env, check=False, timeout=60)
    if code is None:  # a program importing the library keeps its KeyboardInterrupt
        assert done.returncode != 0 and err in done.stderr
    else:
        assert (done.returncode, done.stderr) == (code, err)


@pytest.mark.parametrize(("signum", "words"), [(signal.SIGTERM, "terminated (SIGTERM)"),
                                              (signal.SIGHUP, "hangup (SIGHUP)")])
def test_sigterm_or_sighup_mid_render_leaves_nothing(cl_device, scene, tmp_path, signum,
                                                     words) -> None:
    # SIGTERM and SIGHUP ended the process at once, leaving the output folders it made (and
    # mid-write, its temporary files); they end it as Ctrl-C does, with 128 + the signal.
    image = tmp_path / "out" / "deep" / "img.png"
    with subprocess.Popen([sys.executable, "-m", "clray", "render", str(scene), "-W", "2000",
                           "-H", "1500", "--spp", "1024", "-o", str(image), "--aov", "depth",
                           "--stats-json", str(image.with_suffix(".json"))],
                          stderr=subprocess.PIPE, text=True, cwd=tmp_path) as proc:
        try:
            deadline = time.monotonic() + 10
            while not image.parent.is_dir():  # made before the scene is loaded and rendered
                assert proc.poll() is None and time.monotonic() < deadline, "no render started"
                time.sleep(0.02)
            time.sleep(1.0)  # into the render
            assert proc.poll() is None, "the render ended before the signal"
            proc.send_signal(signum)
            _, err = proc.communicate(timeout=10)
        finally:
            proc.kill()
    assert (proc.returncode, err.splitlines()[-1:]) == (128 + signum, [f"clray: error: {words}"])
    assert "Traceback" not in err
    assert files_in(tmp_path) == ["scene.toml"]


def test_over_long_output_name_exits_1_before_rendering(capsys, scene, tmp_path,
                                                        monkeypatch) -> None:
    # Found by tests/fuzz.py: Path.is_dir() raised ENAMETOOLONG as a traceback.
    monkeypatch.setattr(cli, "render", refuse_to_render)
    code, _, err = run(capsys, "render", scene, "-o", "a" * 300 + ".png")
    assert code == 1
    assert_one_error_line(err)
    assert err.endswith(".png: File name too long\n")


def test_a_long_output_name_with_pass_files_is_written(cl_device, scene, tmp_path,
                                                       capsys) -> None:
    # A valid 244-byte name (its pass files' 250) failed after the render: the temporary files'
    # names were longer than the names, though the probe before the render had passed.
    image = tmp_path / ("x" * 240 + ".png")
    code, _, err = run(capsys, "render", scene, *TINY, "-o", image, "--aov", "depth")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [image.name, "x" * 240 + ".depth.pfm", "scene.toml"])


def test_verbose_figures_escape_a_newline_in_the_output_name(capsys, cl_device, scene) -> None:
    # Found by tests/fuzz.py: "  output: x" and "y.png" came out as two lines.
    code, _, err = run(capsys, "render", scene, *TINY, "-v", "-o", "x\ny.png")
    assert code == 0
    assert "  output             x\\ny.png" in err.splitlines()
    assert all(line.startswith(("clray: ", "  ")) for line in err.splitlines())


def test_out_of_memory_is_one_line(capsys, scene, monkeypatch) -> None:
    def exhausted(_path):
        raise MemoryError

    monkeypatch.setattr(cli, "load_scene", exhausted)
    code, _, err = run(capsys, "render", scene)
    # Named: the file the command was working on.
    assert (code, err) == (1, f"clray: error: {scene}: out of memory\n")


# --- standard output ---------------------------------------------------------------------------

def _clray(*argv: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "clray", *map(str, argv)], capture_output=True,
                          timeout=300)


def test_dash_writes_the_png_to_stdout(cl_device, scene, tmp_path) -> None:
    done = _clray("render", scene, *TINY, "-o", "-")
    assert done.returncode == 0, done.stderr
    assert _clray("render", scene, *TINY, "-o", tmp_path / "file.png", "-q").returncode == 0
    assert done.stdout == (tmp_path / "file.png").read_bytes()
    assert b"wrote -" in done.stderr  # clray's own lines stay on stderr
    assert files_in(tmp_path) == ["file.png", "scene.toml"]


def test_stats_json_dash_writes_json_to_stdout(cl_device, scene, tmp_path) -> None:
    done = _clray("render", scene, *TINY, "-o", tmp_path / "out.pfm", "--stats-json", "-", "-q")
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout)
    assert (stats["width"], stats["height"], stats["output"]) == (32, 24, str(tmp_path / "out.pfm"))
    assert done.stderr == b""
    assert files_in(tmp_path) == ["out.pfm", "scene.toml"]


def test_stats_json_dev_stdout_goes_into_a_pipe_or_is_appended(cl_device, scene,
                                                                tmp_path) -> None:
    # A pipe: /dev/stdout's resolved name is no file. A file opened to append: renaming onto its
    # resolved name would have dropped what it held.
    done = _clray("render", scene, *TINY, "-o", tmp_path / "out.pfm", "--stats-json",
                  "/dev/stdout", "-q")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["width"] == 32
    log = tmp_path / "log.txt"
    log.write_text("earlier\n")
    with log.open("a") as stdout:
        appended = subprocess.run([sys.executable, "-m", "clray", "render", scene, *TINY, "-o",
                                   tmp_path / "out.pfm", "--stats-json", "/dev/stdout", "-q"],
                                  stdout=stdout, stderr=subprocess.PIPE, timeout=300)
    assert appended.returncode == 0, appended.stderr
    earlier, stats = log.read_text().split("\n", 1)
    assert earlier == "earlier" and json.loads(stats)["height"] == 24


def test_stats_json_dot_slash_dash_is_a_file(cl_device, scene, tmp_path, capsys) -> None:
    # Path("./-") == Path("-"): the stats went to standard output.
    code, out, err = run(capsys, "render", scene, *TINY, "-o", "out.png", "--stats-json", "./-",
                         "-q")
    assert (code, out, err) == (0, "", "")
    assert json.loads((tmp_path / "-").read_text())["width"] == 32


def test_image_and_stats_both_to_stdout_is_a_usage_error(capsys, scene) -> None:
    code, out, err = run(capsys, "render", scene, "-o", "-", "--stats-json", "-")
    assert code == EXIT_USAGE and out == ""
    assert_one_error_line(err)
    assert "both write to standard output" in err


@pytest.mark.parametrize(("link_to", "words"), [
    ("out.png", "the output image are the same file"),
    ("out.depth.pfm", "the out.depth.pfm pass file are the same file"),
    ("sub/../out.png", "the output image are the same file"),
], ids=["image", "pass", "dotdot"])
def test_stats_json_through_a_link_to_the_image_is_a_usage_error(capsys, scene, tmp_path,
                                                                 link_to, words) -> None:
    # The names differ, so the stats replaced the image (or a pass file) with JSON, exit 0.
    (tmp_path / "sub").mkdir()
    (tmp_path / "out.png").write_bytes(b"image")
    (tmp_path / "stats.json").symlink_to(link_to)
    code, out, err = run(capsys, "render", scene, "-o", "out.png", "--aov", "depth",
                         "--stats-json", "stats.json")
    assert code == EXIT_USAGE and out == ""
    assert_one_error_line(err)
    assert words in err
    assert (tmp_path / "out.png").read_bytes() == b"image"


def test_empty_scene_name_is_a_usage_error(capsys) -> None:
    code, out, err = run(capsys, "render", "")
    assert code == EXIT_USAGE and out == ""
    assert_one_error_line(err)
    assert "expected a scene file name, got ''" in err


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
@pytest.mark.parametrize("obstacle", ["device", "folder"])
def test_a_stats_file_that_cannot_be_written_stops_the_image_to_stdout(
        capsysbinary, cl_device, scene, tmp_path, monkeypatch, obstacle) -> None:
    # -o - sent the image before the stats file was written: a stats file that then failed
    # (a full disk; a folder put in its place during the render) left an image sent and
    # exit 1. The stats file is now written (to its temporary name) before the image goes.
    out = tmp_path / "fs"
    out.mkdir()
    stats = out / "s.json"
    rendered = cli.render
    if obstacle == "device":
        stats.symlink_to("/dev/full")
        why = "No space left on device"
    else:
        def render_then_obstruct(*args, **kwargs):
            result = rendered(*args, **kwargs)
            stats.mkdir()  # after the checks before rendering, as another process might
            return result

        monkeypatch.setattr(cli, "render", render_then_obstruct)
        why = "Is a directory"
    code = cli.main(["render", str(scene), *TINY, "-o", "-", "--stats-json", str(stats), "-q"])
    out_bytes, err = capsysbinary.readouterr()
    assert (code, out_bytes) == (1, b"")
    assert err.decode() == f"clray: error: cannot write {stats}: {why}\n"
    assert files_in(out) == ["s.json"]  # the obstacle alone: no temporary file left
    # Where the stats file can be written, both arrive.
    monkeypatch.setattr(cli, "render", rendered)
    good = out / "good.json"
    code = cli.main(["render", str(scene), *TINY, "-o", "-", "--stats-json", str(good), "-q"])
    out_bytes, err = capsysbinary.readouterr()
    assert (code, err) == (0, b"")
    assert out_bytes.startswith(b"\x89PNG\r\n\x1a\n")
    assert Image.open(io.BytesIO(out_bytes)).size == (32, 24)
    assert json.loads(good.read_text())["output"] == "-"


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
def test_an_image_to_stdout_that_fails_leaves_no_stats_file(cl_device, scene, tmp_path) -> None:
    # The stats file is written to its temporary name before the image goes, and put in place
    # only once the image is sent: none where the image could not be.
    stats = tmp_path / "s.json"
    shell = (f"{sys.executable} -m clray render {scene} {' '.join(TINY)} -o - --stats-json "
             f"{stats} -q > /dev/full")
    done = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=300)
    assert (done.returncode, done.stderr) == (1, "clray: error: cannot write standard output: "
                                                 "No space left on device\n")
    assert files_in(tmp_path) == ["scene.toml"]


@pytest.mark.parametrize("redirect", ["> /dev/full", ">&-"], ids=["full", "closed"])
@pytest.mark.parametrize("argv", [
    ["scene", ROOT / "scenes" / "meshes" / "bumpy_ico2.obj"],
    ["devices"],
    ["profile", "{scene}", "-W", "8", "-H", "6", "--repeat", "1", "--json"],
    ["profile", "{scene}", "-W", "8", "-H", "6", "--repeat", "1"],
    ["render", "{scene}", *TINY, "-o", "-", "-q"],
    ["render", "{scene}", *TINY, "-o", "{tmp}/out.png", "--stats-json", "-", "-q"],
], ids=["scene", "devices", "profile-json", "profile", "render-o", "stats-json"])
def test_a_standard_output_that_fails_is_one_line(cl_device, scene, tmp_path, argv,
                                                   redirect) -> None:
    # A full disk's ENOSPC was a traceback, and a closed stdout (Python's is then None) an
    # AttributeError's.
    words = [str(a).format(scene=scene, tmp=tmp_path) for a in argv]
    shell = f"{sys.executable} -m clray {' '.join(words)} {redirect}"
    done = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=300)
    why = "No space left on device" if "full" in redirect else "Bad file descriptor"
    assert (done.returncode, done.stderr) == (1, f"clray: error: cannot write standard output: "
                                                 f"{why}\n")


@pytest.mark.parametrize("unbuffered", ["1", ""])
def test_closed_stdout_is_not_a_traceback(cl_device, unbuffered: str) -> None:
    # A pipe whose reader is gone before clray writes: every write fails with EPIPE.
    read_end, write_end = os.pipe()
    os.close(read_end)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if unbuffered:
        env["PYTHONUNBUFFERED"] = unbuffered
    try:
        done = subprocess.run([sys.executable, "-m", "clray", "devices"], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, env=env, timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == 1
    assert done.stderr == ""


def test_missing_output_folders_are_made(cl_device, scene, tmp_path, capsys) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "-o", tmp_path / "out" / "deep" / "a.png")
    assert code == 0, err
    assert Image.open(tmp_path / "out" / "deep" / "a.png").size == (32, 24)


def test_missing_frame_folders_are_made(cl_device, tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    pattern = tmp_path / "frames" / "orbit_%04d.png"
    code, _, err = run(capsys, "render", ROOT / "scenes" / "orbit.toml", *TINY,
                       "--frames", "0:2", "-o", pattern)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["orbit_0000.png",
                                                                       "orbit_0001.png"]


def test_a_failed_render_takes_back_the_folders_it_made(tmp_path, capsys) -> None:
    # The checks make the outputs' folders before the scene is read; a scene that fails to load
    # must leave none of them, the deepest nested in one another's included.
    keep = tmp_path / "kept"
    (keep / "held").mkdir(parents=True)
    (keep / "held" / "old.png").write_text("")
    missing = tmp_path / "nothere.toml"
    code, _, err = run(capsys, "render", missing, "-o", tmp_path / "out" / "a.png",
                       "--stats-json", tmp_path / "out" / "deep" / "er" / "s.json",
                       "--aov", "depth", "--aov-preview")
    assert code == 3
    assert_one_error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]
    code, _, err = run(capsys, "render", missing, "-o", keep / "held" / "new" / "a.png")
    assert code == 3
    assert sorted(p.name for p in (keep / "held").iterdir()) == ["old.png"]
    # Empty folders the user had stay, however the path reaches them.
    (keep / "empty").mkdir()
    for output in (keep / "empty" / "new" / "a.png", tmp_path / "new" / ".." / "kept" / "empty"
                   / "a.png"):
        assert run(capsys, "render", missing, "-o", output)[0] == 3
        assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]
        assert (keep / "empty").is_dir() and not any((keep / "empty").iterdir())
    # A folder made before a later level's name is refused (too long) is taken back too.
    code, _, err = run(capsys, "render", missing, "-o", tmp_path / "made" / ("a" * 300) / "x.png")
    assert code == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]


def test_the_output_folder_is_made_again_for_the_write(cl_device, scene, tmp_path, capsys,
                                                       monkeypatch) -> None:
    # Renders started side by side into one new folder: one that fails takes the folder back
    # (above) while another renders, whose image and stats must still land.
    real = cli.render

    def render_while_the_folder_goes(*args, **kwargs):
        result = real(*args, **kwargs)
        (tmp_path / "new").rmdir()
        return result

    monkeypatch.setattr(cli, "render", render_while_the_folder_goes)
    code, _, err = run(capsys, "render", scene, *TINY, "-o", tmp_path / "new" / "a.png",
                       "--stats-json", tmp_path / "new" / "s.json")
    assert code == 0, err
    assert Image.open(tmp_path / "new" / "a.png").size == (32, 24)
    assert json.loads((tmp_path / "new" / "s.json").read_text())


def test_a_file_in_the_output_path_is_named(scene, tmp_path, capsys) -> None:
    (tmp_path / "afile").write_text("not a folder")
    code, _, err = run(capsys, "render", scene, *TINY, "-o", tmp_path / "afile" / "x.png")
    assert code == 1
    assert_one_error_line(err)
    assert f"{tmp_path / 'afile'} is a file, not a directory" in err


def test_a_broken_link_in_the_output_path_is_named(scene, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "gone").symlink_to(out / "nowhere")
    code, _, err = run(capsys, "render", scene, *TINY, "-o", out / "gone" / "sub" / "x.png")
    assert code == 1
    assert_one_error_line(err)
    assert f"{out / 'gone'} is a broken symbolic link, not a directory" in err
    assert [p.name for p in out.iterdir()] == ["gone"]


@pytest.mark.parametrize("flags", [["--view", "front"], ["--ground"],
                                   ["--view", "top", "--ground"]])
def test_mesh_flags_with_a_scene_file_are_refused(scene, capsys, flags) -> None:
    code, out, err = run(capsys, "render", scene, *TINY, *flags)
    assert code == EXIT_USAGE and out == ""
    assert_one_error_line(err)
    assert "to a mesh file" in err and "is a scene file" in err
    assert not list(scene.parent.glob("*.png"))


def test_a_frame_pattern_without_frames_is_refused(scene, tmp_path, capsys) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "-o", tmp_path / "x_%04d.png")
    assert code == EXIT_USAGE
    assert_one_error_line(err)
    assert "holds a frame number: give --frames" in err
    assert not list(tmp_path.glob("x_*"))


def test_a_percent_sign_in_a_still_name_is_kept(cl_device, scene, tmp_path, capsys) -> None:
    code, _, err = run(capsys, "render", scene, *TINY, "-o", tmp_path / "100%.png")
    assert code == 0, err
    assert (tmp_path / "100%.png").is_file()


def test_a_percent_sign_in_the_scenes_name_is_kept_in_the_default_output(cl_device, tmp_path,
                                                                          capsys,
                                                                          monkeypatch) -> None:
    # `50%done.toml` was refused: "-o 50%done.png holds a frame number".
    monkeypatch.chdir(tmp_path)
    (tmp_path / "50%done.toml").write_text(scene_text())
    code, _, err = run(capsys, "render", "50%done.toml", *TINY)
    assert code == 0, err
    assert files_in(tmp_path) == ["50%done.png", "50%done.toml"]


@pytest.mark.parametrize("reader", ["head -c 10", "true", "sleep 0.5"])
def test_a_reader_that_leaves_early_is_one_exit_code(cl_device, scene, reader) -> None:
    # Whether the reader closes the pipe before clray writes (true), after taking part of the
    # image (head), or without reading (sleep), the image did not arrive: exit 1, one line.
    shell = (f"{sys.executable} -m clray render {scene} {' '.join(TINY)} -o - | "
             f"{reader} > /dev/null; exit ${{PIPESTATUS[0]}}")
    done = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert done.stderr == "clray: error: cannot write standard output: Broken pipe\n"


def test_a_reader_that_takes_everything_gets_exit_0(cl_device, scene) -> None:
    shell = (f"{sys.executable} -m clray render {scene} {' '.join(TINY)} -o - | "
             "(sleep 0.3; cat) | wc -c; exit ${PIPESTATUS[0]}")
    done = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) > 100 and "wrote -" in done.stderr


def test_the_demo_is_anti_aliased() -> None:
    # The first picture a newcomer sees: several samples a pixel, not jagged 1-spp edges.
    recipe = subprocess.run(["make", "-n", "demo"], cwd=ROOT, capture_output=True, text=True,
                            check=True).stdout
    render_line = next(line for line in recipe.splitlines() if "clray render" in line)
    spp = re.search(r"--spp (\d+)", render_line)
    assert spp and int(spp.group(1)) >= 4, render_line


@pytest.mark.parametrize(("objects", "lights", "material", "warning"), [
    (False, True, "", "the scene has no objects: the image is the background alone"),
    (True, False, "", "no lights and no material with ambient or emission: every object "
                      "renders black"),
    (True, False, "ambient = 0.2", None),  # lit by its ambient term: not black
    (True, True, "", None),
])
def test_a_scene_that_renders_black_says_why(cl_device, tmp_scene, tmp_path, capsys, objects,
                                             lights, material, warning) -> None:
    text = ("[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n"
            f"[materials.red]\ncolor = [1, 0, 0]\n{material}\n")
    if lights:
        text += '[[lights]]\ntype = "point"\nposition = [2, 2, 2]\n'
    if objects:
        text += '[[objects]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "red"\n'
    code, _, err = run(capsys, "render", tmp_scene(text), *TINY, "-o", tmp_path / "x.png")
    assert code == 0, err
    warnings_seen = [line for line in err.splitlines() if "warning" in line]
    if warning is None:
        assert warnings_seen == []
    else:
        assert len(warnings_seen) == 1 and warning in warnings_seen[0]


def test_large_image_memory_noted_before_rendering(capsys, scene, monkeypatch) -> None:
    # The note comes before any render (stopped here: a 16384 x 16384 render takes minutes)
    # and names the size and the memory; small images, and -q, say nothing.
    def stop(*_args, **_kwargs):
        raise ClrayError("stopped")

    monkeypatch.setattr(cli, "render", stop)
    code, _, err = run(capsys, "render", scene, "-W", "16384", "-H", "16384", "-o", "big.png")
    assert code == 1
    assert err.splitlines() == ["clray: note: a 16384 x 16384 image takes about 7.5 GiB of host "
                                "memory (the float image and its PNG encoding)",
                                "clray: error: stopped"]
    code, _, err = run(capsys, "render", scene, "-W", "16384", "-H", "16384", "-o", "big.pfm")
    assert err.splitlines()[0].endswith("about 9.5 GiB of host memory (the float image and its "
                                        "PFM encoding)")
    code, _, err = run(capsys, "render", scene, "-W", "16384", "-H", "16384", "-o", "big.png",
                       "--png-bits", "16")
    assert err.splitlines()[0].endswith("about 8.0 GiB of host memory (the float image and its "
                                        "PNG encoding)")
    code, _, err = run(capsys, "render", scene, "-W", "8192", "-H", "8192", "-o", "big.png")
    assert err.splitlines() == ["clray: error: stopped"]  # 1.9 GiB: no note
    # Passes count too (clray.passes.passes_host_bytes): 122 bytes a pixel, not 30.
    code, _, err = run(capsys, "render", scene, "-W", "8192", "-H", "8192", "-o", "big.png",
                       "--aov", "depth,normal,albedo")
    assert err.splitlines()[0] == ("clray: note: a 8192 x 8192 image takes about 7.6 GiB of host "
                                   "memory (the float image, its passes and its PNG encoding)")
    code, _, err = run(capsys, "render", scene, "-W", "16384", "-H", "16384", "-q")
    assert err.splitlines() == ["clray: error: stopped"]
