"""`clray profile`: its figures add up, and agree with a render of the same scene."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pty
import re
import struct
import subprocess
import sys
import tempfile
import termios
from pathlib import Path

import pyopencl as cl
import pytest
from pyopencl.characterize import has_src_build_cache

from clray import cli, profile
from clray.device import program as program_module
from clray.device.program import KernelConfig, build_program
from clray.errors import DeviceError
from clray.render import RenderSettings, render

SPHERES = Path(__file__).resolve().parent.parent / "scenes" / "spheres.toml"


def test_profile_figures_add_up_and_match_the_render(cl_device, capsys) -> None:
    code = cli.main(["profile", str(SPHERES), "-W", "40", "-H", "24", "--repeat", "1",
                     "--json"])
    out = capsys.readouterr().out
    assert code == 0
    prof = json.loads(out)
    rendered = render(SPHERES, RenderSettings(width=40, height=24))
    assert prof["rays"] == rendered.stats["rays"]
    rays = prof["rays"]
    assert rays["primary"] == 40 * 24 * prof["spp"]
    assert rays["total"] == rays["primary"] + rays["secondary"] + rays["shadow"]
    parts = prof["time_split"]["parts"]
    assert sum(p["rays"] for p in parts.values()) == rays["total"]
    assert parts["primary"]["rays"] == rays["primary"]
    split = prof["time_split"]["variant_kernel_s"]
    assert prof["kernel_s"] == split["full"]
    assert sum(p["kernel_s"] for p in parts.values()) == pytest.approx(split["full"])
    tests = prof["tests_per_ray"]
    closest = rays["primary"] + rays["secondary"]
    assert tests["totals"]["closest_boxes"] == pytest.approx(
        tests["closest_boxes_per_ray"] * closest)
    assert tests["totals"]["shadow_prims"] == pytest.approx(
        tests["shadow_prims_per_ray"] * rays["shadow"])
    assert prof["device_bytes"] == rendered.stats["device_bytes"]
    assert prof["device_bytes_total"] == sum(prof["device_bytes"].values())
    assert prof["build_cold_s"] > 0 and prof["build_warm_s"] > 0
    assert prof["tuning"] == "default"


def test_profile_renders_no_image_it_does_not_use(cl_device, monkeypatch) -> None:
    # The rays it reports are the last timed run's of the scene as given: a render more for
    # them cost a whole render's time on a large scene.
    calls = []
    real = profile.render_packed

    def counted(packed, device):
        calls.append(packed.config.count_tests)
        return real(packed, device)

    monkeypatch.setattr(profile, "render_packed", counted)
    monkeypatch.setattr(profile, "cold_and_warm_build", lambda config, spec: (1.0, 1.0))
    prof = profile.profile_scene(SPHERES, RenderSettings(width=8, height=6), repeat=2)
    # Each variant's warm-up and timed runs, and the COUNT_TESTS build's render.
    assert calls == [False] * len(profile.VARIANTS) * (1 + 2) + [True]
    assert len(calls) == profile.profile_steps(2) - 2
    assert prof["rays"] == render(SPHERES, RenderSettings(width=8, height=6)).stats["rays"]


def test_profile_spp_replaces_the_scenes_samples(cl_device, capsys) -> None:
    # spheres.toml renders 1 spp: --spp 3 must reach the kernel, not only the printed figures.
    code = cli.main(["profile", str(SPHERES), "-W", "16", "-H", "10", "--spp", "3",
                     "--repeat", "1", "--json"])
    prof = json.loads(capsys.readouterr().out)
    assert code == 0
    assert prof["spp"] == 3
    assert prof["rays"]["primary"] == 16 * 10 * 3
    assert prof["time_split"]["parts"]["primary"]["rays"] == 16 * 10 * 3
    rendered = render(SPHERES, RenderSettings(width=16, height=10, spp=3))
    assert prof["rays"] == rendered.stats["rays"]


@pytest.mark.parametrize("spp", [1, 2])
def test_profile_traversal_reaches_the_kernel(cl_device, capsys, spp) -> None:
    # Sample packets trace the same rays; with one sample a pixel the single-ray build renders.
    code = cli.main(["profile", str(SPHERES), "-W", "12", "-H", "8", "--spp", str(spp),
                     "--traversal", "sample_packet", "--repeat", "1", "--json"])
    prof = json.loads(capsys.readouterr().out)
    assert code == 0
    assert prof["traversal"] == ("sample_packet" if spp > 1 else "single")
    rendered = render(SPHERES, RenderSettings(width=12, height=8, spp=spp, traversal="single"))
    assert prof["rays"] == rendered.stats["rays"]


def test_profile_takes_a_mesh_file_as_render_does(cl_device, capsys, tmp_path) -> None:
    # A mesh file profiles with the automatic scene that `clray render` makes of it.
    cube = Path(__file__).resolve().parent / "data" / "cube.obj"
    code = cli.main(["profile", str(cube), "-W", "12", "-H", "8", "--repeat", "1", "--json"])
    prof = json.loads(capsys.readouterr().out)
    assert code == 0
    stats_path = tmp_path / "stats.json"
    assert cli.main(["render", str(cube), "-W", "12", "-H", "8", "-q", "-o",
                     str(tmp_path / "cube.png"), "--stats-json", str(stats_path)]) == 0
    assert prof["rays"] == json.loads(stats_path.read_text())["rays"]
    assert prof["rays"]["shadow"] > 0  # the automatic lights


def test_profile_prints_a_summary(cl_device, capsys) -> None:
    assert cli.main(["profile", str(SPHERES), "-W", "32", "-H", "18", "--repeat", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{SPHERES}: 32x18, 1 spp on ")
    assert lines[1].startswith("rays: ") and "Mrays/s" in lines[1]
    assert [line.split(":")[0].strip() for line in lines[2:5]] == [
        "primary", "shadow_of_primary", "secondary_and_their_shadow"]
    assert lines[5].startswith("tests per closest-hit ray: ")
    assert lines[6].startswith("kernel build: ") and "cold" in lines[6]
    assert lines[7].startswith("scene on device: ")


# A sphere that reflects nothing, and no lights: only primary rays are ever traced.
NO_LIGHTS = """
[render]
width = 16
height = 10
max_depth = 4
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
[materials.matte]
color = [0.8, 0.2, 0.2]
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
material = "matte"
"""


def test_profile_gives_no_time_to_kinds_of_ray_never_traced(cl_device, capsys,
                                                            tmp_scene) -> None:
    # Their times were differences of renders tracing the same rays, noise alone: -9.47 ms.
    scene = tmp_scene(NO_LIGHTS)
    assert cli.main(["profile", str(scene), "--repeat", "3", "--json"]) == 0
    parts = json.loads(capsys.readouterr().out)["time_split"]["parts"]
    for name in ("shadow_of_primary", "secondary_and_their_shadow"):
        assert parts[name]["rays"] == 0
        assert parts[name]["kernel_s"] == 0.0
        assert parts[name]["mrays_per_s"] is None
    assert cli.main(["profile", str(scene), "--repeat", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[3:5] == ["  shadow_of_primary: no rays", "  secondary_and_their_shadow: no rays"]


def _scripted_split(monkeypatch: pytest.MonkeyPatch, kernel_s: dict[str, list[float]],
                    repeat: int) -> dict:
    """time_split of variants whose timed runs take `kernel_s` seconds by variant, in turn,
    each tracing rays of every kind."""
    def variant(packed: str, *, depth0: bool, lights: bool) -> str:
        return "primary" if not lights else "primary_shadow" if depth0 else "full"

    rays = {"primary": {"primary": 100, "secondary": 0, "shadow": 0, "total": 100},
            "primary_shadow": {"primary": 100, "secondary": 0, "shadow": 200, "total": 300},
            "full": {"primary": 100, "secondary": 50, "shadow": 250, "total": 400}}
    left = {name: [0.0, *times] for name, times in kernel_s.items()}  # a warm-up first

    def render_packed(name: str, device: object) -> tuple[None, dict]:
        return None, {"kernel_s": left[name].pop(0), "rays": rays[name]}

    monkeypatch.setattr(profile, "_variant", variant)
    monkeypatch.setattr(profile, "render_packed", render_packed)
    return profile.time_split("full", None, repeat)["parts"]


def test_a_difference_within_the_runs_spread_is_no_duration(monkeypatch) -> None:
    # With the lights, runs of 1.0 to 1.4 ms against 1.1 to 1.3 ms without: the medians differ
    # by -0.1 ms, which is no time the shadow rays took.
    parts = _scripted_split(monkeypatch, {"primary": [1.1e-3, 1.2e-3, 1.3e-3],
                                          "primary_shadow": [1.0e-3, 1.1e-3, 1.4e-3],
                                          "full": [3.0e-3, 3.1e-3, 3.2e-3]}, 3)
    shadow = parts["shadow_of_primary"]
    assert shadow["within_noise"] is True
    assert shadow["mrays_per_s"] is None
    assert shadow["difference_range_s"] == pytest.approx([1.0e-3 - 1.3e-3, 1.4e-3 - 1.1e-3])
    assert profile.part_text("shadow_of_primary", shadow) == (
        "shadow_of_primary: within noise (runs differ by -0.3 to 0.3 ms), 200 rays, -")
    # Every run with the secondary rays slower than every run without: a duration.
    later = parts["secondary_and_their_shadow"]
    assert later["within_noise"] is False
    assert later["kernel_s"] == pytest.approx(3.1e-3 - 1.1e-3)
    assert later["mrays_per_s"] == pytest.approx(100 / 2.0e-3 * 1e-6)
    assert profile.part_text("secondary_and_their_shadow", later) == (
        "secondary_and_their_shadow: 2 ms, 100 rays, 0.05 Mrays/s")


def test_a_single_run_resolves_any_difference_but_a_negative_one(monkeypatch) -> None:
    # One run a variant has no spread: only a difference of 0 or less is no duration.
    parts = _scripted_split(monkeypatch, {"primary": [2.0e-3], "primary_shadow": [1.5e-3],
                                          "full": [1.6e-3]}, 1)
    assert parts["shadow_of_primary"]["within_noise"] is True
    assert profile.part_text("shadow_of_primary", parts["shadow_of_primary"]) == (
        "shadow_of_primary: within noise (runs differ by -0.5 ms), 200 rays, -")
    assert parts["secondary_and_their_shadow"]["within_noise"] is False
    assert parts["secondary_and_their_shadow"]["kernel_s"] == pytest.approx(0.1e-3)


def test_profile_shows_its_steps_on_a_terminal(cl_device, tmp_path) -> None:
    # Its builds and renders take minutes on a large scene, and nothing showed until the end.
    leader, follower = pty.openpty()
    # A new pseudo-terminal is 0 columns wide, where tqdm draws nothing.
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    done = subprocess.run([sys.executable, "-m", "clray", "profile", str(SPHERES), "-W", "8",
                           "-H", "6", "--repeat", "2"], stderr=follower, stdout=subprocess.PIPE,
                          cwd=tmp_path, check=False, timeout=300)
    os.close(follower)
    chunks = []
    with contextlib.suppress(OSError):  # Linux ends a drained pty with EIO
        while chunk := os.read(leader, 4096):
            chunks.append(chunk)
    os.close(leader)
    shown = b"".join(chunks).decode()
    assert done.returncode == 0, shown
    steps = profile.profile_steps(2)
    assert steps == 2 + 3 * 3 + 1
    assert re.match(r"\rclray: profiling: +0%\|", shown), repr(shown)
    named = re.findall(rf"\| (\d+)/{steps} \[[^],]*, [^],]*, ([^]]*)\]", shown)
    # Each step named as it starts, with the count of those done before it.
    assert (("0", "kernel build in new processes, cold and warm") in named
            and ("10", "full run 2 of 2") in named
            and ("11", "box and primitive tests (the COUNT_TESTS build)") in named
            and named[-1] == (str(steps), "done")), named
    # The bar is erased before the command ends; the profile itself is on stdout.
    assert shown.rstrip("\r").split("\r")[-1].strip() == ""
    assert done.stdout.decode().startswith(f"{SPHERES}: 8x6, 1 spp on ")


def test_a_failed_build_process_is_its_own_device_error(cl_device) -> None:
    # The new process refuses the option before it builds: its DeviceError, not a
    # CalledProcessError with the config dumped in it.
    config = KernelConfig(build_options=("-bogus",))
    with pytest.raises(DeviceError, match=r"^kernel build in a new process failed: "
                                          r"unsupported build option\(s\): -bogus$"):
        profile.new_process_build(config, None)


def test_profile_reports_a_crashed_build_process_in_one_line(cl_device, capsys, monkeypatch,
                                                              tmp_path) -> None:
    # As a build process that a full TMPDIR kills: a traceback, whose last line is the reason.
    child = tmp_path / "python"
    child.write_text("#!/bin/sh\necho 'Traceback (most recent call last):' >&2\n"
                     "echo 'OSError: [Errno 28] No space left on device' >&2\nexit 1\n")
    child.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(child))
    code = cli.main(["profile", str(SPHERES), "-W", "8", "-H", "6", "--repeat", "1"])
    assert code == 1
    assert capsys.readouterr().err.splitlines() == [
        "clray: error: kernel build in a new process failed: OSError: [Errno 28] No space left "
        "on device"]


def test_profile_without_a_temporary_folder_is_an_error(cl_device, capsys, monkeypatch,
                                                       tmp_path) -> None:
    missing = tmp_path / "missing"
    monkeypatch.setattr(tempfile, "tempdir", str(missing))
    code = cli.main(["profile", str(SPHERES), "-W", "8", "-H", "6", "--repeat", "1"])
    assert code == 1
    assert capsys.readouterr().err.splitlines() == [
        f"clray: error: cannot make a temporary folder in {missing} for the cold build's "
        "kernel caches: No such file or directory"]


# The variables that place the kernel caches a build process may be answered from: PoCL's,
# pyopencl's binary cache (under $XDG_CACHE_HOME/pyopencl), NVIDIA's compute cache.
CACHE_VARIABLES = ("POCL_CACHE_DIR", "XDG_CACHE_HOME", "CUDA_CACHE_PATH")


def test_the_cold_build_finds_every_kernel_cache_empty_and_the_warm_one_its_caches(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # Caches of earlier runs where the user keeps them; the cold build must not see them.
    for name in CACHE_VARIABLES:
        (tmp_path / name).mkdir()
        (tmp_path / name / "built-before").write_text("")
        monkeypatch.setenv(name, str(tmp_path / name))
    envs: list[dict[str, str]] = []

    def build_process(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess:
        env = kwargs["env"]
        assert isinstance(env, dict)
        envs.append(env)
        for name in CACHE_VARIABLES:  # what the build leaves in its caches
            Path(env[name]).mkdir(parents=True, exist_ok=True)
            Path(env[name], f"built-{len(envs)}").write_text("")
        return subprocess.CompletedProcess(cmd, 0, '{"build_s": 1.0, "context_s": 0.5}\n', "")

    monkeypatch.setattr(subprocess, "run", build_process)
    assert profile.cold_and_warm_build(KernelConfig(), None) == (1.0, 1.0)
    cold, warm = envs
    folders = [Path(cold[name]) for name in CACHE_VARIABLES]
    assert len(set(folders)) == len(folders)  # one cache's files in no other's folder
    assert all(folder.parent == folders[0].parent for folder in folders)
    assert all(str(tmp_path) not in str(folder) for folder in folders)
    assert not folders[0].parent.exists()  # the temporary folder, removed after
    assert all(warm[name] == cold[name] for name in CACHE_VARIABLES)
    assert all(cold[name] == os.environ[name] for name in cold if name not in CACHE_VARIABLES)


def test_the_cold_build_process_is_not_answered_from_pyopencls_cache(
        cl_device: cl.Device, monkeypatch: pytest.MonkeyPatch) -> None:
    # Where the driver keeps no cache of its own (Intel's CPU runtime), pyopencl keeps the
    # built binary: one in the user's cache, from a render before, answered the "cold" build.
    if has_src_build_cache(cl_device):
        pytest.skip("pyopencl keeps no binary cache for this device: its driver caches builds")
    config = KernelConfig(has_spheres=True, max_depth=1)
    monkeypatch.setattr(program_module, "_programs", {})
    build_program(cl_device, config)  # into this test's $XDG_CACHE_HOME, as a render would
    seen: list[tuple[int, int]] = []  # binaries in the process's pyopencl cache, before, after
    run = subprocess.run

    def binaries(env: dict[str, str]) -> int:
        return len(list((Path(env["XDG_CACHE_HOME"]) / "pyopencl").rglob("binary")))

    def watched(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess:
        env = kwargs["env"]
        assert isinstance(env, dict)
        before = binaries(env)
        done = run(cmd, **kwargs)
        seen.append((before, binaries(env)))
        return done

    monkeypatch.setattr(subprocess, "run", watched)
    profile.cold_and_warm_build(config, None)
    assert seen == [(0, 1), (1, 1)]  # cold: built and kept; warm: found it
