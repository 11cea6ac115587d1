"""The benchmarks' scene arguments (compare.py, stages.py): the named benchmark scenes and scene
files; and compare.py's other arguments, its failures and its report, with the measuring
processes faked where no render is needed."""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from conftest import module_from_file

from clray.device.context import describe

ROOT = Path(__file__).resolve().parent.parent
compare = module_from_file(ROOT / "benchmarks" / "compare.py", "compare")
stages = module_from_file(ROOT / "benchmarks" / "stages.py", "stages")


def test_scene_names_and_files(tmp_path: Path) -> None:
    scene = tmp_path / "lights.toml"
    scene.write_text("", encoding="utf-8")
    paths = compare.scene_paths(["spheres", str(scene)], tmp_path)
    assert paths == {"spheres": ROOT / "scenes" / "spheres.toml", str(scene): scene.resolve()}


@pytest.mark.parametrize("script", ["compare", "stages"])
def test_unknown_scene_is_a_usage_error(script: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "missing.toml"
    args = {"compare": ["HEAD"], "stages": []}[script]
    with pytest.raises(SystemExit) as exit_info:
        {"compare": compare, "stages": stages}[script].main([*args, "--scenes",
                                                             f"spheres,{missing}"])
    assert exit_info.value.code == 2
    assert str(missing) in capsys.readouterr().err


def _refuse_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """compare.main raises if it gets as far as a worktree, a scene or a render: a bad argument
    must stop it before any of them."""
    def work(*args: object, **kwargs: object) -> None:
        raise AssertionError("compare.py started work on bad arguments")
    for name in ("_worktree", "scene_paths", "_measure"):
        monkeypatch.setattr(compare, name, work)


@pytest.mark.parametrize(("args", "says"), [
    (["HEAD", "--spp", "-4"], "--spp"),  # was a render of no samples, negative Mrays/s
    (["HEAD", "--spp", "0"], "--spp"),
    (["HEAD", "--size", "abc"], "--size"),  # was a ValueError traceback
    (["HEAD", "--size", "64"], "--size"),
    (["HEAD", "--rounds", "0"], "--rounds"),
    (["HEAD", "--per-round", "-1"], "--per-round"),
    # was a CalledProcessError after HEAD's worktree was registered, which stayed so
    (["HEAD", "no-such-ref-xyz"], "no-such-ref-xyz"),
    (["HEAD:sample_packet:many"], "LANES"),
    # was a CalledProcessError traceback, holding the child's whole source, from the first render
    (["WORKTREE:bogus"], "WORKTREE:bogus"),
    # were printed twice, each with both one's runs pooled
    (["HEAD", "WORKTREE", "HEAD"], "repeated: HEAD"),
    (["HEAD", "--scenes", "spheres,mesh,spheres"], "repeated: spheres"),
    (["HEAD", "--scenes", ","], "--scenes"),  # measured nothing and exited 0
])
def test_bad_arguments_are_usage_errors_before_any_work(
        args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    _refuse_work(monkeypatch)
    out = tmp_path / "compare.json"
    with pytest.raises(SystemExit) as exit_info:
        compare.main(["--scenes", "spheres", *args, "--json", str(out)])  # the last --scenes wins
    assert exit_info.value.code == 2
    assert says in capsys.readouterr().err
    assert not out.exists()


def test_unwritable_json_is_refused_before_any_work(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    _refuse_work(monkeypatch)
    blocker = tmp_path / "a_file"
    blocker.write_text("", encoding="utf-8")
    with pytest.raises(SystemExit) as exit_info:
        compare.main(["HEAD", "--scenes", "spheres", "--json", str(blocker / "compare.json")])
    assert exit_info.value.code == 2
    assert "--json" in capsys.readouterr().err


def test_a_failed_render_is_one_line_with_the_ref_scene_and_reason(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The child's exception, not a CalledProcessError traceback that threw its stderr away.
    The scene fails to load, so the child stops before any device work."""
    scene = tmp_path / "broken.toml"
    scene.write_text("[render\n", encoding="utf-8")
    out = tmp_path / "compare.json"
    with pytest.raises(SystemExit) as exit_info:
        compare.main(["WORKTREE", "--rounds", "1", "--per-round", "1", "--scenes", str(scene),
                      "--json", str(out)])
    message = str(exit_info.value.code)
    assert "\n" not in message
    assert message.startswith(f"compare.py: WORKTREE, scene {scene}: ")
    assert message.endswith("(at line 1, column 8)")  # the child's SceneError, its last line
    assert not out.exists()


@pytest.mark.parametrize(("returncode", "stderr", "reason"), [
    (1, "Traceback (most recent call last):\n  ...\nValueError: no\n\n", "ValueError: no"),
    (-9, "", "killed by signal 9"),
    (3, " \n", "exit status 3, and no message"),
])
def test_child_reason(returncode: int, stderr: str, reason: str) -> None:
    assert compare.child_reason(returncode, stderr) == reason


def _strict_json(path: Path) -> dict:
    def refuse(constant: str) -> None:
        raise AssertionError(f"{path} holds {constant}, which strict JSON has not")
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


def _fake_children(monkeypatch: pytest.MonkeyPatch,
                   child: Callable[[str, str, str], dict]) -> list[tuple[str, str, str]]:
    """compare.main without git worktrees or processes: each measurement is child(commit,
    variant, scene name). Returns the measurements made, in order."""
    made: list[tuple[str, str, str]] = []

    def measure(tree: Path, scene: Path, repeat: int, device: str | None, variant: str,
                shape: tuple[int, int, int]) -> dict:
        made.append((tree.name, variant, scene.name))
        return child(tree.name, variant, scene.name)
    monkeypatch.setattr(compare, "_worktree", lambda commit, tmp: tmp / commit)
    monkeypatch.setattr(compare, "scene_paths",
                        lambda names, tmp: {name: tmp / name for name in names})
    monkeypatch.setattr(compare, "_measure", measure)
    return made


def _child(mean: float | None = 0.25, nonfinite: int = 0, device: str = "CPU (PoCL, 6.0)") -> dict:
    return {"kernel_s": [0.5], "rays": 1000, "mean": mean, "nonfinite_pixels": nonfinite,
            "device": device, "platform_version": "OpenCL 3.0 PoCL 6.0"}


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True,
                          text=True).stdout.strip()


def test_image_summary_counts_pixels_not_finite() -> None:
    image = np.full((2, 3, 3), 0.5, dtype=np.float32)
    assert compare.image_summary(image) == {"mean": 0.5, "nonfinite_pixels": 0}
    image[0, 0, 1] = np.nan
    image[1, 2, 0] = np.inf
    image[1, 2, 2] = np.nan  # the same pixel again
    assert compare.image_summary(image) == {"mean": None, "nonfinite_pixels": 2}


def test_a_nan_image_is_null_in_strict_json(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Was `"image_mean": NaN`, which strict JSON readers refuse, and no count of the pixels."""
    _fake_children(monkeypatch, lambda commit, variant, scene:
                   _child(None, 3) if commit == "HEAD" else _child())
    out = tmp_path / "compare.json"
    compare.main(["WORKTREE", "HEAD", "--rounds", "1", "--scenes", "spheres", "--json", str(out)])
    refs = _strict_json(out)["refs"]
    assert refs["HEAD"]["scenes"]["spheres"]["image_mean"] is None
    assert refs["HEAD"]["scenes"]["spheres"]["nonfinite_pixels"] == 3
    assert refs["WORKTREE"]["scenes"]["spheres"]["image_mean"] == 0.25
    assert refs["WORKTREE"]["scenes"]["spheres"]["nonfinite_pixels"] == 0
    printed = capsys.readouterr().out
    assert "3 pixels not finite" in printed
    assert printed.count("not finite") == 1


def test_the_report_names_the_device_and_the_commits(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Was rounds, sizes and the refs as typed ("HEAD~1"): no device, driver or commit."""
    _fake_children(monkeypatch, lambda commit, variant, scene: _child())
    out = tmp_path / "compare.json"
    compare.main(["HEAD~1", "WORKTREE:single", "--rounds", "1", "--scenes", "spheres",
                  "--device", "pocl", "--json", str(out)])
    report = _strict_json(out)
    assert report["device_spec"] == "pocl"
    assert report["device"] == "CPU (PoCL, 6.0)"
    # The host processor too, which the device's name does not give on every platform.
    cpu_model = module_from_file(ROOT / "benchmarks" / "common.py", "common").cpu_model()
    assert {key: report[key] for key in cpu_model} == cpu_model
    assert report["platform_version"] == "OpenCL 3.0 PoCL 6.0"
    old, now = report["refs"]["HEAD~1"], report["refs"]["WORKTREE:single"]
    assert old["commit"] == _git("rev-parse", "HEAD~1") and old["dirty"] is False
    assert now["commit"] == _git("rev-parse", "HEAD")
    assert now["dirty"] is bool(_git("status", "--porcelain", "--untracked-files=no"))
    for ref in (old, now):
        assert ref["device"] == "CPU (PoCL, 6.0)"
        assert ref["platform_version"] == "OpenCL 3.0 PoCL 6.0"
        assert set(ref["scenes"]) == {"spheres"}


def test_refs_on_different_devices_stop_the_run(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_children(monkeypatch, lambda commit, variant, scene:
                   _child(device="GPU (CUDA, 550)" if commit == "HEAD" else "CPU (PoCL, 6.0)"))
    out = tmp_path / "compare.json"
    with pytest.raises(SystemExit) as exit_info:
        compare.main(["WORKTREE", "HEAD", "--rounds", "1", "--scenes", "spheres",
                      "--json", str(out)])
    assert exit_info.value.code == (
        "compare.py: HEAD rendered on GPU (CUDA, 550) (OpenCL 3.0 PoCL 6.0), "
        "WORKTREE on CPU (PoCL, 6.0) (OpenCL 3.0 PoCL 6.0): not one device")
    assert not out.exists()


def test_a_real_run_records_its_device(cl_device: cl.Device, tmp_path: Path) -> None:
    """The measuring process itself, on the test's device, 4x4 pixels: what it reports."""
    spec = os.environ["CLRAY_DEVICE"]  # the test's device (conftest)
    out = tmp_path / "compare.json"
    compare.main(["WORKTREE", "--rounds", "1", "--per-round", "1", "--size", "4x4",
                  "--scenes", "spheres", "--device", spec, "--json", str(out)])
    report = _strict_json(out)
    assert report["device_spec"] == spec
    assert report["device"] == describe(cl_device)
    assert report["platform_version"] == cl_device.platform.version.strip()
    spheres = report["refs"]["WORKTREE"]["scenes"]["spheres"]
    assert spheres["nonfinite_pixels"] == 0
    assert 0 < spheres["image_mean"] < 1
    # Packed as `clray render --no-tuning` packs it, not with KernelConfig's defaults (BVH
    # width 8 on every device, which a GPU's render never builds).
    from clray.device.policy import device_plan
    from clray.knobs import Tuning

    plan = device_plan(cl_device, spp=1, tuning=Tuning())
    assert (spheres["traversal"], spheres["bvh_width"]) == (plan.traversal, plan.bvh_width)


def test_rounds_alternate_the_order_of_the_refs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Was A B C in every round, so A always ran first and C last."""
    made = _fake_children(monkeypatch, lambda commit, variant, scene: _child())
    compare.main(["WORKTREE", "HEAD", "HEAD~1", "--rounds", "3", "--scenes", "spheres",
                  "--json", str(tmp_path / "compare.json")])
    forward = ["WORKTREE", "HEAD", "HEAD~1"]
    assert [commit for commit, _, _ in made] == forward + forward[::-1] + forward


@pytest.mark.parametrize(("value", "text"), [
    (2.0009e-05, "0.0000200"), (0.15437, "0.154"), (4.4979, "4.50"), (1234.4, "1234"), (0.0, "0"),
])
def test_three_figures(value: float, text: str) -> None:
    assert compare.three_figures(value) == text


def test_a_small_render_prints_its_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A 4x4 render's kernel time was printed as 0.0000 s."""
    _fake_children(monkeypatch, lambda commit, variant, scene:
                   {**_child(), "kernel_s": [2.0009e-05], "rays": 90})
    compare.main(["WORKTREE", "--rounds", "1", "--scenes", "spheres",
                  "--json", str(tmp_path / "compare.json")])
    assert "kernel 0.0000200 s (median of 1), 4.50 Mrays/s" in capsys.readouterr().out


def test_a_real_run_renders_with_the_scenes_min_weight(cl_device: cl.Device,
                                                       tmp_path: Path) -> None:
    """The measuring process packed every scene with min_weight 0, so a scene that cuts faint
    rays was timed tracing rays its `clray render` never traces."""
    from clray.render import RenderSettings, render

    text = (ROOT / "scenes" / "fresnel.toml").read_text(encoding="utf-8")
    assert "min_weight = 0.004\n" in text
    scene = tmp_path / "fresnel.toml"
    # Above fresnel's 4 % reflections head on: the cut-off drops rays at this size.
    scene.write_text(text.replace("min_weight = 0.004\n", "min_weight = 0.3\n"),
                     encoding="utf-8")
    spec = os.environ["CLRAY_DEVICE"]  # the test's device (conftest)
    out = tmp_path / "compare.json"
    compare.main(["WORKTREE", "--rounds", "1", "--per-round", "1", "--size", "32x20",
                  "--scenes", str(scene), "--device", spec, "--json", str(out)])
    got = _strict_json(out)["refs"]["WORKTREE"]["scenes"][str(scene)]
    # As `clray render --no-tuning -W 32 -H 20` renders it, and not as at min_weight 0.
    settings = dict(width=32, height=20, device=spec, stored_tuning=False)
    rendered = render(scene, RenderSettings(**settings))
    uncut = render(scene, RenderSettings(**settings, min_weight=0.0))
    assert uncut.stats["rays"]["total"] > rendered.stats["rays"]["total"]
    assert got["rays"] == rendered.stats["rays"]["total"]
    assert got["image_mean"] == float(rendered.image.mean())
