"""Animation: keyframe interpolation against hand-computed values, frame scenes, and
`clray render --frames` rendering and resuming in this process (Dask: test_distributed.py)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_packing_scene

from clray import cli
from clray.errors import ClrayError, SceneError, SettingsError
from clray.image_io import Encoding, read_pfm
from clray.passes import write_with_passes
from clray.render import RenderResult
from clray.scene.animation import Animation, Track, parse_path
from clray.sequence import (
    check_pattern,
    frame_path,
    frames_in,
    frames_to_render,
    load_sequence,
    parse_frames,
)

ROOT = Path(__file__).resolve().parent.parent
ORBIT = ROOT / "scenes" / "orbit.toml"


def refuse_to_render(*_args, **_kwargs):
    raise AssertionError("rendered although the command was to fail before any work")


def track(frames, values, interpolation="linear", path=("camera", "vfov")) -> Track:
    return Track(key=".".join(map(str, path)), path=path, frames=tuple(frames),
                 values=tuple(values), interpolation=interpolation)


def test_linear_between_keys_by_hand():
    t = track([0, 10, 30], [[0.0, 2.0, 4.0], [10.0, 2.0, 0.0], [10.0, 6.0, 0.0]])
    assert t.at(5) == [5.0, 2.0, 2.0]
    assert t.at(20) == [10.0, 4.0, 0.0]
    assert t.at(25) == [10.0, 5.0, 0.0]


def test_catmull_rom_by_hand():
    # Keys of y = x^2 at x = 0, 10, 20, 30 (values 0, 1, 4, 9 for x / 10). At frame 15: s = 1/2,
    # tangents (per frame) (4 - 0) / 20 = 0.2 and (9 - 1) / 20 = 0.4, times the span of 10:
    # 1/2 * 1 + 1/8 * 2 + 1/2 * 4 - 1/8 * 4 = 2.25 = 1.5^2 (Catmull-Rom reproduces quadratics).
    t = track([0, 10, 20, 30], [0.0, 1.0, 4.0, 9.0], "catmull-rom")
    assert t.at(15) == pytest.approx(2.25, abs=1e-12)
    # First span, one-sided tangent (1 - 0) / 10 = 0.1 at frame 0, 0.2 at frame 10; at s = 1/2:
    # 1/8 * 1 + 1/2 * 1 - 1/8 * 2 = 0.375.
    assert t.at(5) == pytest.approx(0.375, abs=1e-12)
    # Uneven spacing: keys 0 at 0, 2 at 10, 4 at 40 (slope 0.1 per frame around key 1). At
    # frame 5 (s = 1/2, span 10): m0 = 0.2, m1 = (4 - 0) / 40 = 0.1:
    # 1/8 * 10 * 0.2 + 1/2 * 2 - 1/8 * 10 * 0.1 = 0.25 + 1 - 0.125 = 1.125.
    uneven = track([0, 10, 40], [0.0, 2.0, 4.0], "catmull-rom")
    assert uneven.at(5) == pytest.approx(1.125, abs=1e-12)


@pytest.mark.parametrize("interpolation", ["linear", "catmull-rom"])
def test_keyframes_are_exact_and_ends_hold(interpolation):
    values = [[0.1, 0.2, 0.3], [1 / 3, 2 / 3, 0.7], [-5.5, 1e-7, 3.0]]
    t = track([2, 17, 40], values, interpolation)
    for frame, value in zip([2, 17, 40], values, strict=True):
        assert t.at(frame) == value  # exactly, not approximately
    assert t.at(0) == values[0]
    assert t.at(41) == values[-1]


def test_frame_data_puts_every_track_and_leaves_the_file_data_alone():
    data = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1}],
            "animation": {"frames": 3}}
    animation = Animation(frames=3, fps=24, tracks=(
        track([0, 2], [[0.0, 0.0, 5.0], [0.0, 2.0, 5.0]], path=("camera", "position")),
        track([0, 2], [1.0, 3.0], path=("objects", 0, "radius")),
        track([0, 2], [30.0, 50.0], path=("camera", "vfov")),
    ))
    out = animation.data_at(data, 1)
    assert out["camera"]["position"] == [0.0, 1.0, 5.0]
    assert out["objects"][0]["radius"] == 2.0
    assert out["camera"]["vfov"] == 40.0  # a default in the file, given a value per frame
    assert "animation" not in out
    assert data["camera"]["position"] == [0, 0, 5] and "vfov" not in data["camera"]


def test_key_paths():
    assert parse_path("objects[2].transform.rotate") == ("objects", 2, "transform", "rotate")
    assert parse_path("materials.red-1.ior") == ("materials", "red-1", "ior")
    assert parse_path("camera..position") is None
    assert parse_path("objects[x].center") is None


def test_example_scene_frames_hit_the_keyframes():
    sequence = load_sequence(ROOT / "scenes" / "orbit.toml")
    assert sequence.animation.frames == 48
    assert sequence.scene(0).camera.position == (0.0, 2.0, 8.0)
    assert sequence.scene(47).camera.position == (0.0, 2.0, 8.0)
    assert sequence.scene(12).camera.position == (8.0, 2.5, 0.0)
    red = next(m for m in sequence.scene(47).materials if m.name == "red")
    assert red.reflect == 0.6
    assert sequence.scene(24).objects[2].center == (1.3, 2.0, 0.5)
    mid = next(m for m in sequence.scene(10).materials if m.name == "red")
    assert mid.reflect == pytest.approx(0.6 * 10 / 47)


def test_overshooting_curve_names_key_and_frame(tmp_scene):
    # Catmull-Rom through 0, 1, 1, 0 at frames 0, 2, 4, 6 rises above 1 between the middle
    # keys: at frame 3, tangents +-1/4 a frame over a span of 2 give 1 + 2 * 1/8 * 2 * 1/4 =
    # 1.125, which reflect does not allow: every key loads, that frame does not.
    path = tmp_scene("""\
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
[materials.m]
reflect = 0.5
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
material = "m"
[animation]
frames = 7
interpolation = "catmull-rom"
[[animation.tracks]]
key = "materials.m.reflect"
frames = [0, 2, 4, 6]
values = [0.0, 1.0, 1.0, 0.0]
""")
    sequence = load_sequence(path)
    assert next(m for m in sequence.scene(2).materials if m.name == "m").reflect == 1.0
    with pytest.raises(SceneError) as info:
        sequence.scene(3)
    assert str(info.value) == ("scene.toml: materials.m.reflect: must be <= 1, got 1.125 "
                               "(animated, frame 3)")


def test_frames_argument_and_output_names():
    assert parse_frames("0:120") == range(0, 120)
    assert parse_frames("7") == range(7, 8)
    animation = Animation(frames=48, fps=24, tracks=())
    assert frames_in(parse_frames("40:"), animation) == range(40, 48)
    for bad in ("a:b", "5:5", "-1:3"):
        with pytest.raises(SettingsError):
            parse_frames(bad)
    with pytest.raises(SettingsError, match="frames 0 to 47"):
        frames_in(parse_frames("0:49"), animation)
    assert frame_path(Path("out/frame_%04d.png"), 12) == Path("out/frame_0012.png")
    with pytest.raises(SettingsError, match="frame number"):
        check_pattern(Path("out.png"), 2)
    check_pattern(Path("out.png"), 1)
    for good in ("f_%d.png", "f_%04d.png", "f_%5i.png", "f_%u.png", "100%%/f_%03d.png"):
        check_pattern(Path(good), 3)


@pytest.mark.parametrize(("name", "got"), [
    ("f_%.1e.png", "%.1e"),  # frames 100 and 101: f_1.0e+02.png both
    ("f_%c.png", "%c"),  # frame 47: f_/.png
    ("f_%g.png", "%g"),  # frames 1000000 and 1000001: f_1e+06.png both
    ("f_%s.png", "%s"),
    ("f_%x.png", "%x"),
    ("f_%d_%02d.png", "%d %02d"),
])
def test_a_frame_number_that_is_not_one_decimal_is_a_usage_error(tmp_path, capsys, monkeypatch,
                                                                 name, got):
    expected = (f"-o {tmp_path / name}: expected one decimal frame number (%d, %04d, %i or %u), "
                f"got {got}")
    with pytest.raises(SettingsError) as info:
        check_pattern(tmp_path / name, 1)
    assert str(info.value) == expected
    monkeypatch.setattr("clray.sequence.render", refuse_to_render)
    assert cli.main(["render", str(ORBIT), "--frames", "0:3", "-o", str(tmp_path / name)]) == 2
    assert capsys.readouterr().err == f"clray: error: {expected}\n"
    assert list(tmp_path.iterdir()) == []


def test_frames_from_past_the_last_are_refused():
    # `A:` with A past the last frame was an empty range, and the command's frames[0] an
    # IndexError traceback.
    animation = Animation(frames=48, fps=24, tracks=())
    assert frames_in(parse_frames("47:"), animation) == range(47, 48)
    for text in ("48:", "60:"):
        with pytest.raises(SettingsError, match=f"frames 0 to 47, asked for {text[:-1]} to the "
                                                "last"):
            frames_in(parse_frames(text), animation)


def test_cli_frames_from_past_the_last_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("clray.sequence.render", refuse_to_render)
    code = cli.main(["render", str(ORBIT), "--frames", "48:", "-o", str(tmp_path / "f/f_%03d.png")])
    err = capsys.readouterr().err
    assert code == 2 and list(tmp_path.iterdir()) == []
    assert err == ("clray: error: --frames: the animation has frames 0 to 47, asked for 48 to "
                   "the last\n")


def test_resume_skips_only_existing_frames(tmp_path):
    pattern = tmp_path / "f_%02d.png"
    (tmp_path / "f_01.png").write_bytes(b"done")
    assert frames_to_render(range(0, 3), pattern, resume=True) == [0, 2]
    assert frames_to_render(range(0, 3), pattern, resume=False) == [0, 1, 2]


def test_resume_takes_no_folder_for_a_frame(tmp_path):
    pattern = tmp_path / "f_%02d.png"
    (tmp_path / "f_01.png").mkdir()
    assert frames_to_render(range(0, 3), pattern, resume=True) == [0, 1, 2]


def test_resume_skips_a_frame_only_with_its_passes(tmp_path):
    pattern = tmp_path / "f_%02d.png"
    for name in ("f_00.png", "f_00.depth.pfm", "f_00.depth.png", "f_01.png", "f_01.depth.pfm",
                 "f_02.png"):
        (tmp_path / name).write_bytes(b"done")
    (tmp_path / "f_02.depth.pfm").mkdir()
    assert frames_to_render(range(0, 3), pattern, True, ("depth",)) == [2]
    assert frames_to_render(range(0, 3), pattern, True, ("depth",), previews=True) == [1, 2]
    assert frames_to_render(range(0, 3), pattern, True, ("depth", "normal")) == [0, 1, 2]


@pytest.mark.parametrize("folder", ["f_01.png", "f_02.depth.pfm"])
@pytest.mark.parametrize("resume", [[], ["--resume"]])
def test_a_folder_in_place_of_a_frames_file_is_named_before_any_work(tmp_path, capsys,
                                                                     monkeypatch, folder,
                                                                     resume):
    # A folder in place of a later frame's file failed the command only after the frames before
    # it were rendered, named as the frame's image even where it was a pass file; with --resume
    # a folder in place of the image counted as a complete frame.
    monkeypatch.setattr("clray.sequence.render", refuse_to_render)
    (tmp_path / folder).mkdir()
    code = cli.main(["render", str(ORBIT), "--frames", "0:3", "--aov", "depth", "-o",
                     str(tmp_path / "f_%02d.png"), *resume])
    assert code == 1
    assert capsys.readouterr().err == (f"clray: error: cannot write {tmp_path / folder}: it is a "
                                       "directory\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == [folder]


@pytest.mark.parametrize("stats", ["o/f_0.png", "o/f_2.depth.pfm", "o/f_1.depth.png"])
@pytest.mark.parametrize("frames", ["0:3", "0:"])
def test_stats_json_naming_a_frames_file_is_a_usage_error(tmp_path, capsys, monkeypatch, stats,
                                                        frames):
    # The stats replaced frame 0's image with JSON, which a later --resume took for complete.
    monkeypatch.setattr("clray.sequence.render", refuse_to_render)
    monkeypatch.chdir(tmp_path)
    code = cli.main(["render", str(ORBIT), "--frames", frames, "-o", "o/f_%d.png", "--aov",
                     "depth", "--aov-preview", "--stats-json", stats])
    frame = stats[4]
    assert code == 2
    assert capsys.readouterr().err == (f"clray: error: --stats-json and frame {frame}'s file "
                                       f"are the same file: {stats}\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("frames", [[], ["--frames", "0:2"]])
@pytest.mark.parametrize("name", ["x_%99999999999d.png", "x_%.99999999999d.png",
                                  "x_%-0256d.png"])
def test_a_frame_number_wider_than_a_file_name_is_a_usage_error(tmp_path, capsys, frames, name):
    # It was a MemoryError traceback: the name was built first, a string of that many digits.
    pattern = tmp_path / name
    code = cli.main(["render", str(ORBIT), "-o", str(pattern), *frames])
    err = capsys.readouterr().err
    assert code == 2 and list(tmp_path.iterdir()) == []
    assert err.startswith(f"clray: error: -o {pattern}: a frame number's width is at most 255")
    assert len(err.splitlines()) == 1


def test_a_frame_number_as_wide_as_a_file_name_is_taken():
    # `%%` is a literal `%`: the `9999d` after it is text, not a width.
    assert frame_path(Path("x_%%9999d_%255d.png"), 1).name == "x_%9999d_" + " " * 254 + "1.png"


def test_a_percent_sign_that_is_no_conversion_is_part_of_a_still_name():
    # `%1000.p` converts nothing (`p` is no conversion type): a still's name, as it always was,
    # not a frame number too wide.
    for name in ("a%1000.png", "runs/%1000/x.png", "a%5.png"):
        assert frame_path(Path(name), 3) == Path(name)


def test_resume_skips_an_exr_frame_only_with_its_passes_as_layers(tmp_path):
    # An OpenEXR frame holds its passes as layers, not files beside it: a frame written
    # without them counted as complete.
    pytest.importorskip("OpenEXR")
    pattern = tmp_path / "f_%02d.exr"
    image = np.zeros((2, 3, 3), np.float32)
    write_with_passes(frame_path(pattern, 0), image, Encoding(), {})
    write_with_passes(frame_path(pattern, 1), image, Encoding(),
                      {"depth": np.ones((2, 3), np.float32)})
    frame_path(pattern, 2).write_bytes(b"not an OpenEXR file")
    assert frames_to_render(range(0, 3), pattern, True) == []
    assert frames_to_render(range(0, 3), pattern, True, ("depth",)) == [0, 2]
    assert frames_to_render(range(0, 3), pattern, True, ("depth", "normal")) == [0, 1, 2]


def test_render_frames_then_resume(cl_device, tmp_path, capsys):
    scene = ROOT / "scenes" / "orbit.toml"
    pattern = tmp_path / "f_%04d.pfm"
    args = [str(scene), "-W", "32", "-H", "18", "--spp", "1", "-o", str(pattern)]
    assert cli.main(["render", *args, "--frames", "0:2", "-q"]) == 0
    first = {f: read_pfm(frame_path(pattern, f)) for f in (0, 1)}
    stamp = frame_path(pattern, 0).stat().st_mtime_ns
    stats = tmp_path / "stats.json"
    assert cli.main(["render", *args, "--frames", "0:3", "--resume",
                     "--stats-json", str(stats)]) == 0
    assert "wrote 1 frame of frames 0-2" in capsys.readouterr().err
    assert frame_path(pattern, 0).stat().st_mtime_ns == stamp  # not written again
    record = json.loads(stats.read_text())
    assert [f["frame"] for f in record["frames"]] == [2] and record["skipped"] == 2
    # The still's figures, each frame's own (PFM: no clipped_pixels).
    frame = record["frames"][0]
    assert frame["nonfinite_pixels"] == 0 and "clipped_pixels" not in frame
    assert frame["total_s"] == pytest.approx(frame["load_s"] + frame["render_s"]
                                             + frame["write_s"])
    assert frame_path(pattern, 2).exists()
    # Frames differ (the camera moves) and each is the still render of its frame's scene.
    assert (first[0] != first[1]).any()
    single = tmp_path / "one.pfm"
    assert cli.main(["render", *args[:-1], str(single), "--frames", "1", "-q"]) == 0
    assert read_pfm(single).tobytes() == first[1].tobytes()


def test_resume_renders_the_frames_without_the_passes_asked_for(cl_device, tmp_path, capsys):
    pattern = tmp_path / "f_%02d.png"
    args = ["render", str(ORBIT), "-W", "8", "-H", "4", "--spp", "1", "-o", str(pattern)]
    assert cli.main([*args, "--frames", "0:2", "-q"]) == 0
    assert cli.main([*args, "--frames", "0:3", "--resume", "--aov", "depth"]) == 0
    assert "wrote 3 frames of frames 0-2" in capsys.readouterr().err
    assert all(frame_path(tmp_path / "f_%02d.depth.pfm", f).is_file() for f in range(3))
    assert cli.main([*args, "--frames", "0:3", "--resume", "--aov", "depth"]) == 0
    assert "wrote 0 frames of frames 0-2 to" in capsys.readouterr().err
    # -v's progress lines, without a terminal, divided by the pixel-samples of no frames.
    assert cli.main([*args, "--frames", "0:3", "--resume", "--aov", "depth", "-v"]) == 0
    assert "wrote 0 frames of frames 0-2 to" in capsys.readouterr().err


def test_frames_usage_errors(tmp_path, capsys):
    scene = str(ROOT / "scenes" / "orbit.toml")
    assert cli.main(["render", scene, "--frames", "0:3", "-o", str(tmp_path / "a.png")]) == 2
    assert "frame number" in capsys.readouterr().err
    assert cli.main(["render", scene, "--resume"]) == 2
    assert cli.main(["render", scene, "--frames", "x"]) == 2
    plain = ROOT / "scenes" / "spheres.toml"
    assert cli.main(["render", str(plain), "--frames", "0:2", "-o",
                     str(tmp_path / "f_%d.png")]) == 3
    assert "animation: missing" in capsys.readouterr().err
    # A mesh file was said to be of an unknown scene file type, which render takes.
    mesh = ROOT / "scenes" / "meshes" / "bumpy_ico2.obj"
    assert cli.main(["render", str(mesh), "--frames", "0", "-o", str(tmp_path / "m.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"clray: error: --frames renders a scene file's [animation] table; "
                          f"{mesh} is a mesh file")
    assert list(tmp_path.iterdir()) == []


def test_object_transform_animates(tmp_scene):
    # Any object's transform can be keyed once the object has a transform table to put it in.
    path = tmp_scene("""\
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
transform = {}
[animation]
frames = 5
[[animation.tracks]]
key = "objects[0].transform.translate"
frames = [0, 4]
values = [[0, 0, 0], [2, -4, 8]]
[[animation.tracks]]
key = "objects[0].transform.scale"
frames = [0, 4]
values = [1, 3]
""")
    sequence = load_sequence(path)
    sphere = sequence.scene(1).objects[0]
    assert sphere.center == (0.5, -1.0, 2.0)
    assert sphere.radius == 1.5
    assert sequence.scene(4).objects[0].center == (2.0, -4.0, 8.0)


def test_a_frame_number_in_the_folder_makes_no_folder_of_the_pattern(cl_device, tmp_path):
    # The check of -o before the frames made a folder literally named shot_%02d.
    pattern = tmp_path / "shot_%02d" / "img.png"
    assert cli.main(["render", str(ORBIT), "-W", "8", "-H", "4", "--frames", "0:2", "--aov",
                     "depth", "-o", str(pattern), "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shot_00", "shot_01"]
    assert sorted(p.name for p in (tmp_path / "shot_01").iterdir()) == ["img.depth.pfm",
                                                                       "img.png"]


@pytest.mark.parametrize(("stem", "frames"), [("50%done", "0:2"), ("orbit", "46:"),
                                               ("50%done", "46:")])
def test_the_default_frame_names_are_the_scenes_name_and_a_number(cl_device, tmp_path,
                                                                  monkeypatch, stem, frames):
    # The scene's stem went into the pattern as it was: `%d` in `50%done` was a frame number.
    # And `A:`, an empty range until the animation's length is known, got a still's name.
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / f"{stem}.toml"
    scene.write_text(ORBIT.read_text())
    assert cli.main(["render", str(scene), "-W", "8", "-H", "4", "--frames", frames, "-q"]) == 0
    first = int(frames.split(":")[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"{stem}.toml", f"{stem}_{first:04d}.png", f"{stem}_{first + 1:04d}.png"]


def test_large_frames_memory_noted_before_rendering(tmp_path, capsys, monkeypatch):
    # The still's note was never said for --frames. Stopped at the render: it takes minutes.
    def stop(*_args, **_kwargs):
        raise ClrayError("stopped")

    monkeypatch.setattr("clray.sequence.render", stop)
    code = cli.main(["render", str(ORBIT), "-W", "16384", "-H", "16384", "--frames", "0:2",
                     "-o", str(tmp_path / "f_%d.png")])
    assert code == 1
    assert capsys.readouterr().err.splitlines() == [
        "clray: note: a 16384 x 16384 image takes about 7.5 GiB of host memory (the float "
        "image and its PNG encoding)", "clray: error: stopped"]


def test_frames_have_the_stills_figures_and_warnings(tmp_path, capsys, monkeypatch):
    # Frames' records lacked load_s, nonfinite_pixels and clipped_pixels; a frame with NaN
    # pixels said nothing, and -v showed no figures.
    def nan_render(scene, settings, geometry_for=None):
        image = np.array([[[0.5, np.nan, 0.5], [2.0, 0.5, 0.5]]], np.float32)
        return RenderResult(image, {"total_s": 0.5, "width": 2, "height": 1, "spp": 1,
                                    "kernel_s": 0.25, "rays": {"total": 4},
                                    "mrays_per_s": None})

    monkeypatch.setattr("clray.sequence.render", nan_render)
    pattern = tmp_path / "f_%d.png"
    stats = tmp_path / "stats.json"
    assert cli.main(["render", str(ORBIT), "--frames", "0:2", "-o", str(pattern), "-v",
                     "--stats-json", str(stats)]) == 0
    err = capsys.readouterr().err.splitlines()
    for frame in (0, 1):
        assert f"clray: warning: frame {frame}: 1 pixel is NaN or infinite (written black)" in err
        assert any(re.fullmatch(rf"  frame {frame}: {re.escape(str(tmp_path))}/f_{frame}\.png "
                                r"\(2x1, 1 spp\), load [\d.]+ s, render 0\.500 s, kernel 0\.250 "
                                r"s, write [\d.]+ s, 4 rays, 1 non-finite, 1 clipped", line)
                   for line in err)
    records = json.loads(stats.read_text())["frames"]
    for record in records:
        assert record["load_s"] >= 0 and record["render_s"] == 0.5 and record["write_s"] >= 0
        assert (record["nonfinite_pixels"], record["clipped_pixels"]) == (1, 1)


def test_one_frame_is_said_in_the_singular(cl_device, tmp_path, capsys):
    pattern = tmp_path / "f_%04d.png"
    assert cli.main(["render", str(ROOT / "scenes" / "orbit.toml"), "-W", "16", "-H", "9",
                     "--frames", "2:3", "-o", str(pattern)]) == 0
    assert f"wrote 1 frame of frame 2 to {pattern}" in capsys.readouterr().err


LIBRARY = """\
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
[[lights]]
type = "point"
position = [0, 5, 5]
[[objects]]
type = "plane"
point = [0, -1, 0]
normal = [0, 1, 0]
"""
INCLUDING = """\
include = ["lib.toml"]
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
[animation]
frames = 3
[[animation.tracks]]
key = "{key}"
frames = [0, 2]
values = {values}
"""


def test_key_paths_name_the_including_files_own_tables(tmp_scene):
    # objects[0] is the file's sphere, though the included plane comes first once merged: the
    # keyframes were checked with the value put into the plane, the frames into the sphere.
    tmp_scene(LIBRARY, "lib.toml")
    path = tmp_scene(INCLUDING.format(key="objects[0].radius", values="[1, 2]"))
    sequence = load_sequence(path)
    plane, sphere = sequence.scene(1).objects
    assert (type(plane).__name__, sphere.radius) == ("Plane", 1.5)


def test_a_key_path_only_an_included_file_has_is_not_in_the_scene(tmp_scene, tmp_path,
                                                                    capsys, monkeypatch):
    """camera is lib.toml's: the frames' data has none to put a value in (a KeyError
    traceback at the first frame), so the keyframes' check refuses it first."""
    monkeypatch.setattr("clray.sequence.render", refuse_to_render)
    tmp_scene(LIBRARY, "lib.toml")
    path = tmp_scene(INCLUDING.format(key="camera.position",
                                      values="[[0, 0, 5], [0, 1, 5]]"))
    assert cli.main(["render", str(path), "--frames", "0:3", "-W", "16", "-H", "12",
                     "-o", str(tmp_path / "f_%04d.png")]) == 3
    assert capsys.readouterr().err.splitlines() == [
        f"clray: error: {path}: animation.tracks[0].key: camera is not in the scene "
        "(give it a value there to animate it)"]
    assert not list(tmp_path.glob("f_*"))


def test_a_frame_is_made_without_the_files_and_from_another_folder(tmp_path, monkeypatch):
    """A Dask worker makes a frame's scene from the pickled sequence, in a working directory
    of its own, maybe on a machine without the scene's files: the sequence carries them. (A
    texture was read relative to the worker's directory: `file not found`, frame 0.)"""
    import pickle
    import shutil

    from PIL import Image

    project = tmp_path / "project"
    (project / "tex").mkdir(parents=True)
    (project / "parts").mkdir()
    Image.fromarray(np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)).save(
        project / "tex" / "b.png")
    (project / "parts" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (project / "parts" / "more.toml").write_text(
        '[[objects]]\ntype = "mesh"\nfile = "tri.obj"\nmaterial = "b"\n')
    (project / "anim.toml").write_text(
        'include = ["parts/more.toml"]\n'
        "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n"
        '[materials.b]\ntexture = { type = "image", file = "tex/b.png" }\n'
        '[[lights]]\ntype = "point"\nposition = [4, 6, 5]\n'
        '[[objects]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "b"\n'
        "[animation]\nframes = 3\n[[animation.tracks]]\n"
        'key = "objects[0].center"\nframes = [0, 2]\nvalues = [[0, 0, 0], [0, 1, 0]]\n')
    monkeypatch.chdir(project)
    sequence = load_sequence("anim.toml")
    here = sequence.scene(1)
    sent = pickle.dumps(sequence)
    shutil.rmtree(project)
    (tmp_path / "worker").mkdir()
    monkeypatch.chdir(tmp_path / "worker")
    there = pickle.loads(sent).scene(1)
    assert tuple(there.objects[1].center) == (0, 0.5, 0)
    [texel_here, texel_there] = [[m.texture.image for m in scene.materials if m.texture]
                                 for scene in (here, there)]
    assert np.array_equal(texel_here[0], texel_there[0])
    assert np.array_equal(there.objects[0].vertices, here.objects[0].vertices)


def _four_mesh_files(project: Path) -> Path:
    """An animation naming a mesh file of each kind clray parses (OBJ, PLY, .npz, glTF with a
    .bin beside it, an extension it warns of), the OBJ's transform and the camera animated."""
    from tests.gltf_files import CUBE_FACES, CUBE_VERTICES, Builder

    project.mkdir()
    (project / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n")
    (project / "quad.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    np.savez(project / "tri.npz", vertices=np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1]]),
             faces=np.array([[0, 1, 2]]))
    builder = Builder()
    builder.node(mesh=builder.mesh(CUBE_VERTICES, CUBE_FACES))
    builder.doc["extensionsUsed"] = ["EXT_not_modelled"]
    builder.save(project / "cube.gltf")
    objects = "".join(f'[[objects]]\ntype = "mesh"\nfile = "{name}"\nmaterial = "m"\n'
                      f"transform = {{ translate = [{i}, 0, 0] }}\n"
                      for i, name in enumerate(["tri.obj", "quad.ply", "tri.npz", "cube.gltf"]))
    path = project / "anim.toml"
    path.write_text(
        "[camera]\nposition = [0, 0, 9]\nlook_at = [0, 0, 0]\n[materials.m]\n"
        '[[lights]]\ntype = "point"\nposition = [4, 6, 5]\n' + objects +
        "[animation]\nframes = 4\n"
        '[[animation.tracks]]\nkey = "objects[0].transform.rotate"\nframes = [0, 3]\n'
        "values = [[0, 0, 0], [0, 90, 0]]\n"
        '[[animation.tracks]]\nkey = "camera.position"\nframes = [0, 3]\n'
        "values = [[0, 0, 9], [9, 0, 0]]\n")
    return path


def _count_parses(monkeypatch) -> dict[str, int]:
    """Calls of each mesh file parser that clray.scene.assets calls, by name, from now."""
    from clray.scene import assets

    calls: dict[str, int] = {}

    def counting(name: str):
        parse = getattr(assets, name)

        def counted(*args, **kwargs):
            calls[name] = calls.get(name, 0) + 1
            return parse(*args, **kwargs)
        return counted

    for name in ("parse_obj", "read_ply", "npz_arrays", "read_gltf"):
        monkeypatch.setattr(assets, name, counting(name))
    return calls


def _mesh_arrays(scene) -> list:
    return [(m.vertices, m.faces, m.normals, m.uvs, m.colors, m.face_materials)
            for m in scene.objects]


def test_a_sequence_parses_each_mesh_file_once_for_all_its_frames(tmp_path, monkeypatch):
    """The bytes were kept across frames but parsed again for each (0.50 s a frame of a
    327,680-triangle OBJ); the keyframes' check and every frame now share one parse."""
    path = _four_mesh_files(tmp_path / "project")
    calls = _count_parses(monkeypatch)
    sequence = load_sequence(path)
    scenes = [sequence.scene(frame) for frame in range(4)]
    assert calls == {"parse_obj": 1, "read_ply": 1, "npz_arrays": 1, "read_gltf": 1}
    # The glTF file's warning is each frame's, as a still's.
    for scene in scenes:
        assert [w for w in scene.warnings if "EXT_not_modelled" in w] == [
            "objects[3].file: cube.gltf: extension \"EXT_not_modelled\" is not modelled "
            "(ignored)"]


def _frames_reused_and_fresh(sequence, frames):
    """(the sequence's scene at each frame, that frame's scene loaded from the files alone)."""
    from clray.scene.load import scene_from_dict

    for frame in frames:
        reused = sequence.scene(frame)
        yield reused, scene_from_dict(sequence.animation.data_at(sequence.data, frame),
                                      sequence.path)


def test_frames_from_parsed_meshes_are_the_frames_parsed_afresh(tmp_path):
    """Each frame's scene, its meshes reused, is the scene loaded from the files alone (the
    animated transform applied to the mesh as parsed, not to the frame before's); none of
    the arrays shared between frames can be written."""
    path = _four_mesh_files(tmp_path / "project")
    sequence = load_sequence(path)
    for reused, fresh in _frames_reused_and_fresh(sequence, (0, 1, 3, 1)):
        assert reused.warnings == fresh.warnings
        assert len(reused.objects) == len(fresh.objects) == 4
        for these, those in zip(_mesh_arrays(reused), _mesh_arrays(fresh), strict=True):
            for this, that in zip(these, those, strict=True):
                assert (this is None) == (that is None)
                if this is not None:
                    assert this.dtype == that.dtype
                    np.testing.assert_array_equal(this, that)
    for kind, mesh in sequence.files.parsed.items():
        arrays = mesh.meshes if kind[0] == "glTF" else [mesh]
        for obj in arrays:
            assert not obj.vertices.flags.writeable and not obj.faces.flags.writeable


def test_a_pickled_sequence_parses_again_once_where_it_is_sent(tmp_path, monkeypatch):
    """A Dask worker gets the kept bytes without what they parsed to (which would double what
    it is sent), parses each mesh file once for its frames, from the bytes alone."""
    import pickle
    import shutil

    path = _four_mesh_files(tmp_path / "project")
    sequence = load_sequence(path)
    here = sequence.scene(2)
    assert len(sequence.files.parsed) == 4
    sent = pickle.dumps(sequence)
    shutil.rmtree(tmp_path / "project")
    calls = _count_parses(monkeypatch)
    there = pickle.loads(sent)
    assert there.files.parsed == {}
    scenes = [there.scene(frame) for frame in (2, 3)]
    assert calls == {"parse_obj": 1, "read_ply": 1, "npz_arrays": 1, "read_gltf": 1}
    assert scenes[0].warnings == here.warnings
    for these, those in zip(_mesh_arrays(scenes[0]), _mesh_arrays(here), strict=True):
        for this, that in zip(these, those, strict=True):
            assert (this is None) == (that is None)
            if this is not None:
                np.testing.assert_array_equal(this, that)


def _textured_files(project: Path) -> Path:
    """An animation naming image files every way a scene does: one file as an sRGB material
    texture and as a linear one, a background image, an OBJ's MTL library with a map_Kd
    (and a key it warns of), and a glTF file's own image; the camera animated."""
    from PIL import Image

    from tests.gltf_files import Builder

    (project / "tex").mkdir(parents=True)
    for name, (height, width) in {"a": (4, 6), "bg": (8, 16), "c": (2, 3)}.items():
        texels = np.arange(height * width * 3, dtype=np.uint8).reshape(height, width, 3)
        Image.fromarray(texels * np.uint8(7)).save(project / "tex" / f"{name}.png")
    (project / "m.mtl").write_text("newmtl red\nKd 1 0 0\nPr 0.5\nmap_Kd tex/c.png\n")
    (project / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n"
                                   "vt 1 0\nvt 0 1\nusemtl red\nf 1/1 2/2 3/3\n")
    builder = Builder()
    material = builder.material(pbrMetallicRoughness={"baseColorTexture": {"index": builder.image(
        np.arange(2 * 2 * 3, dtype=np.uint8).reshape(2, 2, 3) * np.uint8(20))}})
    builder.node(mesh=builder.mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], material,
                                   uvs=[[0, 0], [1, 0], [0, 1]]))
    builder.save(project / "t.gltf")
    path = project / "anim.toml"
    path.write_text(
        "[camera]\nposition = [0, 0, 9]\nlook_at = [0, 0, 0]\n"
        '[render]\nbackground = { type = "image", file = "tex/bg.png" }\n'
        '[materials.s]\ntexture = { type = "image", file = "tex/a.png" }\n'
        '[materials.l]\ntexture = { type = "image", file = "tex/a.png", colorspace = "linear" }\n'
        '[[lights]]\ntype = "point"\nposition = [4, 6, 5]\n'
        '[[objects]]\ntype = "sphere"\ncenter = [-2, 0, 0]\nradius = 1\nmaterial = "s"\n'
        '[[objects]]\ntype = "sphere"\ncenter = [2, 0, 0]\nradius = 1\nmaterial = "l"\n'
        '[[objects]]\ntype = "mesh"\nfile = "m.obj"\n'
        '[[objects]]\ntype = "mesh"\nfile = "t.gltf"\ntransform = { translate = [0, 2, 0] }\n'
        "[animation]\nframes = 4\n"
        '[[animation.tracks]]\nkey = "camera.position"\nframes = [0, 3]\n'
        "values = [[0, 0, 9], [9, 0, 0]]\n")
    return path


def _count_decodes(monkeypatch) -> dict[str, int]:
    """From now: images decoded (Pillow's opens), sRGB decodes and MTL files parsed."""
    from PIL import Image

    from clray.scene import assets

    calls = {"image": 0, "srgb_decode": 0, "parse_mtl": 0}

    def counting(name: str, function):
        def counted(*args, **kwargs):
            calls[name] += 1
            return function(*args, **kwargs)
        return counted

    monkeypatch.setattr(Image, "open", counting("image", Image.open))
    for name in ("srgb_decode", "parse_mtl"):
        monkeypatch.setattr(assets, name, counting(name, getattr(assets, name)))
    return calls


def _texture_arrays(scene) -> list:
    """(colorspace, texels) of each material's image texture, and of the background."""
    textures = [(m.texture.colorspace, m.texture.image) for m in scene.materials
                if m.texture is not None]
    return [*textures, (scene.render.background.colorspace, scene.render.background.image)]


def test_a_sequence_decodes_each_image_file_once_for_all_its_frames(tmp_path, monkeypatch):
    """Each frame decoded every image file again (and parsed the MTL library again), from the
    kept bytes; the keyframes' check and every frame now share one decode of each, and one
    sRGB decode of each image taken as sRGB. Each frame still has the MTL file's warning."""
    path = _textured_files(tmp_path / "project")
    calls = _count_decodes(monkeypatch)
    sequence = load_sequence(path)
    scenes = [sequence.scene(frame) for frame in range(4)]
    # a.png, bg.png, c.png and the glTF file's image; all four sRGB (a.png once so).
    assert calls == {"image": 4, "srgb_decode": 4, "parse_mtl": 1}
    for scene in scenes:
        assert [w for w in scene.warnings if "Pr" in w] == [
            "objects[2].file: m.obj: line 1: m.mtl: line 3: Pr is not modelled by clray "
            "(ignored in the whole file)"]


def test_frames_from_decoded_images_are_the_frames_decoded_afresh(tmp_path):
    """Each frame's textures and background, decoded once for all frames, are those of the
    scene loaded from the files alone: the file named as sRGB and as linear gives each its
    own texels. What is kept is read-only."""
    path = _textured_files(tmp_path / "project")
    sequence = load_sequence(path)
    for reused, fresh in _frames_reused_and_fresh(sequence, (0, 2, 3, 2)):
        assert reused.warnings == fresh.warnings
        assert reused.materials == fresh.materials
        got, want = _texture_arrays(reused), _texture_arrays(fresh)
        assert [c for c, _ in got] == [c for c, _ in want] == ["srgb", "linear", "srgb",
                                                               "srgb", "srgb"]
        for (_, this), (_, that) in zip(got, want, strict=True):
            assert this.dtype == that.dtype == np.float32
            np.testing.assert_array_equal(this, that)
        assert not np.array_equal(got[0][1], got[1][1])  # sRGB-decoded, and as stored
    project = str(tmp_path / "project")
    kept = {(kind, Path(name).relative_to(project).as_posix())
            for kind, name in sequence.files.parsed}
    assert {("image", "tex/a.png"), ("image", "tex/bg.png"), ("image", "tex/c.png")} <= kept
    for value in sequence.files.parsed.values():
        for array in _kept_arrays(value):
            assert not array.flags.writeable


def _kept_arrays(value) -> list:
    """The numpy arrays in a kept parse (a tuple holding them, or one)."""
    if isinstance(value, np.ndarray):
        return [value]
    if isinstance(value, tuple):
        return [item for item in value if isinstance(item, np.ndarray)]
    return []


def test_a_pickled_sequence_decodes_its_images_again_once_where_it_is_sent(tmp_path,
                                                                           monkeypatch):
    """A Dask worker gets the image files' bytes, not their texels, and decodes each once."""
    import pickle
    import shutil

    path = _textured_files(tmp_path / "project")
    sequence = load_sequence(path)
    here = sequence.scene(1)
    sent = pickle.dumps(sequence)
    shutil.rmtree(tmp_path / "project")
    calls = _count_decodes(monkeypatch)
    there = pickle.loads(sent)
    scenes = [there.scene(frame) for frame in (1, 2, 3)]
    assert calls == {"image": 4, "srgb_decode": 4, "parse_mtl": 1}
    assert scenes[0].warnings == here.warnings
    for (_, this), (_, that) in zip(_texture_arrays(scenes[0]), _texture_arrays(here),
                                    strict=True):
        np.testing.assert_array_equal(this, that)


def test_an_image_decoded_once_still_counts_against_each_scenes_texels(tmp_path, monkeypatch):
    """A scene given an image decoded for another (kept_parse) checks its size against its
    own texels left, as a decode would, with the same words."""
    from clray.scene import limits as L
    from clray.scene.assets import Assets
    from clray.scene.files import KeptFiles
    from clray.scene.values import Values

    path = _textured_files(tmp_path / "project")
    calls = _count_decodes(monkeypatch)
    base = path.parent
    with KeptFiles().used():
        first = Assets(Values(path), base)
        first.image("tex/bg.png", "render.background.file")
        assert first.texels_left == L.MAX_TEXELS - 8 * 16
        second = Assets(Values(path), base)
        second.texels_left = 100
        with pytest.raises(SceneError) as kept:
            second.image("tex/bg.png", "render.background.file")
    assert calls["image"] == 1
    third = Assets(Values(path), base)
    third.texels_left = 100
    with pytest.raises(SceneError) as fresh:
        third.image("tex/bg.png", "render.background.file")
    assert str(kept.value) == str(fresh.value)
    assert "16x8 = 128 texels, over what is left (100)" in str(kept.value)


@pytest.mark.parametrize("aovs", [(), ("depth",)])
def test_render_frames_reports_progress_within_each_frame(cl_device, aovs):
    """One rise over all the frames, each frame's pixel-samples heard as it renders (the command
    showed 0 % until a long frame was done)."""
    from clray.render import RenderSettings
    from clray.sequence import render_frames

    reports: list[tuple[int, int]] = []
    settings = RenderSettings(width=8, height=6, spp=2, aovs=aovs,
                              progress=lambda done, total: reports.append((done, total)))
    rendered: list[int] = []
    render_frames(load_sequence(ORBIT), [4, 0, 7], settings,
                  lambda frame, result: rendered.append(frame))
    assert rendered == [4, 0, 7]
    kernels = 1 + len(aovs)  # the passes' kernel reports after the image's
    total = 3 * kernels * 8 * 6 * 2
    assert {t for _, t in reports} == {total}
    done = [d for d, _ in reports]
    assert done == sorted(done) and done[0] == 0 and done[-1] == total
    # Each frame's start and end is heard, not only the frames' ends.
    assert {total // 3, 2 * total // 3} <= set(done)


def test_a_frame_the_animation_lacks_is_refused_before_any_is_rendered():
    # Tracks hold their first and last values beyond their keys: frame 1000 of 48 rendered
    # frame 47's camera, and -7 frame 0's.
    from clray.render import RenderSettings
    from clray.sequence import render_frames

    sequence = load_sequence(ORBIT)
    for frame in (1000, -7, 48):
        with pytest.raises(SettingsError, match=rf"^frame {frame}: the animation has frames 0 "
                           "to 47$"):
            sequence.scene(frame)
    with pytest.raises(SettingsError, match=r"^frame: expected a frame number, 0 to 47, got "
                       r"float$"):
        sequence.scene(1.5)
    with pytest.raises(SettingsError, match=r"^frame 1000: "):
        render_frames(sequence, [0, 1000], RenderSettings(), refuse_to_render)
    assert sequence.scene(np.int64(47)).camera == sequence.scene(47).camera


def test_resume_with_every_frame_done_starts_no_cluster(tmp_path, capsys, monkeypatch):
    for name in ("f_00.png", "f_01.png"):
        (tmp_path / name).write_bytes(b"done")
    monkeypatch.setattr(cli, "_cluster", refuse_to_render)
    assert cli.main(["render", str(ORBIT), "--frames", "0:2", "-o", str(tmp_path / "f_%02d.png"),
                     "--resume", "--dask"]) == 0
    err = capsys.readouterr().err
    assert "wrote 0 frames of frames 0-1" in err and "2 complete already" in err, err


def test_texels_decoded_once_are_not_given_to_another_array_after_they_are_freed(tmp_path):
    """Assets.decoded keys its results by id() of the texels: a glTF file's texels are freed
    once decoded, and a later array may then have their id. Each array gets its own values."""
    from clray.scene.assets import Assets
    from clray.scene.colour import srgb_decode
    from clray.scene.values import Values

    assets = Assets(Values(tmp_path / "scene.toml"), tmp_path)
    for k in range(32):
        texels = np.full((2, 2, 3), k / 32, dtype=np.float32)
        expected = srgb_decode(np.float64(k / 32))
        np.testing.assert_allclose(assets.decoded(texels), expected, rtol=1e-6)
        del texels


@pytest.mark.parametrize("name", ["orbit", "rising", "instances", "turntable"])
def test_frames_that_share_a_packing_share_one_bvh_and_render_their_stills(
        cl_device, tmp_path, monkeypatch, bvh_builds, name):
    """Frame 0's objects packed once, placed at each frame's eye, instances' places and
    shapes' values (clray.device.pack): one BVH build for all the frames, each frame the image
    its still renders, whichever frames a run renders (frame 0's tree, not the first rendered
    frame's)."""
    from clray import sequence as sequence_module
    from clray.render import RenderSettings, render
    from clray.sequence import render_frames

    settings = RenderSettings(width=48, height=27, spp=2)
    path = shared_packing_scene(tmp_path, name)
    sequence = load_sequence(path)
    assert not sequence.packs_each_frame()
    frames: dict[int, np.ndarray] = {}
    render_frames(sequence, [0, 1, 2, 3], settings,
                  lambda frame, result: frames.update({frame: result.image}))
    assert len(bvh_builds) == 1
    others: dict[int, np.ndarray] = {}
    packed_at = []
    pack_geometry = sequence_module.pack_geometry
    monkeypatch.setattr(sequence_module, "pack_geometry", lambda scene, **k: packed_at.append(
        scene.camera.position) or pack_geometry(scene, **k))
    render_frames(load_sequence(path), [3, 1], settings,
                  lambda frame, result: others.update({frame: result.image}))
    assert len(bvh_builds) == 2 and packed_at == [sequence.scene(0).camera.position]
    for frame in (1, 3):
        np.testing.assert_array_equal(others[frame], frames[frame])
    for frame, image in frames.items():
        still = render(sequence.scene(frame), settings).image
        assert np.count_nonzero(image) > image.size // 4
        np.testing.assert_array_equal(image, still)
    assert not np.array_equal(frames[0], frames[3])  # the camera moved


def _swapping_balls(tmp_path: Path) -> Path:
    """64 instances of a ball on an 8 x 8 grid that change places between frames 0 and 2:
    frame 0's tree refitted to frames 1 and 2 costs over REFIT_COST_LIMIT times its build."""
    places = [[x, 0.4, z] for x in range(8) for z in range(8)]
    order = np.random.default_rng(1).permutation(64)
    text = ('[camera]\nposition = [3.5, 9, 12]\nlook_at = [3.5, 0, 3.5]\n'
            '[[lights]]\ntype = "point"\nposition = [2, 9, 4]\n'
            '[groups.ball]\nobjects = [{ type = "sphere", center = [0, 0, 0], radius = 0.4 }]\n')
    text += "".join(f'[[objects]]\ntype = "instance"\ngroup = "ball"\n'
                    f'transform = {{ translate = {places[i]} }}\n' for i in range(64))
    text += "[animation]\nframes = 3\n"
    text += "".join(f'[[animation.tracks]]\nkey = "objects[{i}].transform.translate"\n'
                    f'frames = [0, 2]\nvalues = [{places[i]}, {places[order[i]]}]\n'
                    for i in range(64))
    path = tmp_path / "balls.toml"
    path.write_text(text)
    return path


def test_frames_past_the_refit_cost_limit_are_built_and_leave_frame_0s_tree(cl_device, tmp_path,
                                                                           bvh_builds):
    from clray.render import RenderSettings, render
    from clray.sequence import render_frames

    settings = RenderSettings(width=48, height=27, spp=1)
    path = _swapping_balls(tmp_path)
    assert not load_sequence(path).packs_each_frame()
    runs: dict[tuple[int, ...], dict[int, np.ndarray]] = {}
    for frames in ((0, 1, 2), (2, 0), (1,)):
        images: dict[int, np.ndarray] = {}
        bvh_builds.clear()
        render_frames(load_sequence(path), frames, settings,
                      lambda frame, result, images=images: images.update({frame: result.image}))
        # Frame 0's packing, then a build for each frame past the limit.
        assert len(bvh_builds) == 1 + sum(frame != 0 for frame in frames)
        runs[frames] = images
    sequence = load_sequence(path)
    for frame in (0, 1, 2):
        still = render(sequence.scene(frame), settings).image
        assert np.count_nonzero(still) > still.size // 10
        for images in runs.values():
            if frame in images:
                np.testing.assert_array_equal(images[frame], still)


def test_frames_that_move_a_mesh_are_each_packed_afresh(cl_device, tmp_path, bvh_builds):
    from clray.render import RenderSettings
    from clray.sequence import render_frames

    path = shared_packing_scene(tmp_path, "orbit")
    path.write_text(path.read_text() + '\n[[animation.tracks]]\nkey = "objects[3].transform.'
                    'scale"\nframes = [0, 47]\nvalues = [0.6, 0.9]\n')
    sequence = load_sequence(path)
    assert sequence.packs_each_frame() and sequence.frame_geometry() is None
    render_frames(sequence, [0, 1, 2], RenderSettings(width=8, height=6, spp=1), lambda *_: None)
    assert len(bvh_builds) == 3


@pytest.mark.parametrize(("key", "afresh"), [
    ("objects[1].transform.rotate", False),  # an instance: its group's primitives stay
    ("objects[0].point", False),  # a plane without a transform
    ("groups.pawn.objects[2].radius", True),
    ("objects[7].transform.rotate", True),  # a sphere, placed by an instance of its own
    ("objects[8].min", True),  # a box with a transform: at some angles an instance
])
def test_a_track_packs_each_frame_unless_it_moves_an_instance_or_a_plain_shape(tmp_path, key,
                                                                               afresh):
    text = (shared_packing_scene(tmp_path, "instances").read_text() +
            f'\n[[animation.tracks]]\nkey = "{key}"\nframes = [0]\nvalues = [[0, 1, 0]]\n')
    if key.endswith("radius"):
        text = text.replace("values = [[0, 1, 0]]\n", "values = [0.25]\n")
    path = tmp_path / "moved.toml"
    path.write_text(text)
    assert load_sequence(path).packs_each_frame() is afresh


@pytest.mark.parametrize(("key", "values", "afresh"), [
    ("objects[0].center", "[[0, 1, 0], [0, 1.5, 0]]", False),  # a sphere without a transform
    ("objects[1].major_radius", "[0.6, 0.5]", False),  # a torus without one
    ("objects[2].radius", "[0.3, 0.4]", True),  # a spheres array: its own arrays
    ("objects[3].center", "[[0, 3, 0], [0, 3.5, 0]]", True),  # a sphere with a transform
    ("camera.vfov", "[40, 45]", False),
])
def test_each_kind_of_shape_moves_with_the_packing_kept_unless_a_transform_places_it(
        tmp_path, key, values, afresh):
    path = tmp_path / "shapes.toml"
    path.write_text(
        '[camera]\nposition = [0, 2, 8]\nlook_at = [0, 0, 0]\n'
        '[[objects]]\ntype = "sphere"\ncenter = [0, 1, 0]\nradius = 1\n'
        '[[objects]]\ntype = "torus"\ncenter = [2, 1, 0]\naxis = [0, 1, 0]\n'
        'major_radius = 0.6\nminor_radius = 0.2\n'
        '[[objects]]\ntype = "spheres"\ncenters = [[-2, 1, 0], [-2, 2, 0]]\nradius = 0.3\n'
        '[[objects]]\ntype = "sphere"\ncenter = [0, 3, 0]\nradius = 0.5\n'
        'transform = { rotate = [0, 30, 0] }\n'
        f'[animation]\nframes = 2\n[[animation.tracks]]\nkey = "{key}"\nframes = [0, 1]\n'
        f'values = {values}\n')
    assert load_sequence(path).packs_each_frame() is afresh


def test_a_pickled_sequence_leaves_its_packed_objects_behind(cl_device, tmp_path):
    """A Dask worker packs its own: the client's packed geometry is not sent with the
    sequence. render_frames lets go of it at the end of the run: a caller that keeps the
    sequence does not keep the packing."""
    import pickle

    from clray.render import RenderSettings, plan_for
    from clray.sequence import render_frames

    sequence = load_sequence(shared_packing_scene(tmp_path, "orbit"))
    sent = len(pickle.dumps(sequence))
    settings = RenderSettings(width=8, height=6, spp=1)
    geometry = sequence.frame_geometry()(cl_device, plan_for(sequence.scene(0), settings,
                                                             cl_device))
    assert sequence._packed[1] is geometry
    assert len(pickle.dumps(sequence)) == sent
    assert pickle.loads(pickle.dumps(sequence))._packed is None
    render_frames(sequence, [0], settings, lambda *_: None)
    assert sequence._packed is None
