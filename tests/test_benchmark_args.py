"""The benchmarks' argument checks: a bad argument is one usage line (exit status 2) before any
work, not a traceback, a half-written result, or a run that measured or checked nothing.
Each script's work is replaced by a function that fails, so a check that came too late fails
here at once instead of rendering."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pyopencl as cl
import pytest
from conftest import module_from_file

ROOT = Path(__file__).resolve().parent.parent
image_hashes = module_from_file(ROOT / "benchmarks" / "image_hashes.py", "image_hashes")
_loaded: dict[str, ModuleType] = {}


def script(name: str) -> ModuleType:
    """benchmarks/NAME.py as a module, loaded once."""
    if name not in _loaded:
        _loaded[name] = module_from_file(ROOT / "benchmarks" / f"{name}.py", f"bench_{name}")
    return _loaded[name]


def _no_work(*args: object, **kwargs: object) -> None:
    raise AssertionError("the benchmark started work on bad arguments")


def _usage_error(main, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """main(argv)'s usage message; fails unless it exits with status 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    return capsys.readouterr().err


@pytest.fixture
def hashes(monkeypatch: pytest.MonkeyPatch):
    for name in ("render", "select_device"):
        monkeypatch.setattr(image_hashes, name, _no_work)
    return image_hashes


def _baseline(path: Path, size: list[int], keys: list[str]) -> Path:
    renders = {key: {"sha256": "0" * 64, "mean": 0.0, "seconds": 0.0} for key in keys}
    path.write_text(json.dumps({"device": "x", "size": size, "renders": renders}),
                    encoding="utf-8")
    return path


@pytest.mark.parametrize(("argv", "says"), [
    (["--only", "spherse"], "spherse"),  # was 0 renders, and --against passed on nothing
    (["--size", "8"], "--size"),  # was a ValueError traceback
    (["--size", "0x54"], "--size"),
])
def test_image_hashes_refuses_bad_arguments(hashes, argv: list[str], says: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "after.json"
    assert says in _usage_error(hashes.main, [*argv, "--json", str(out)], capsys)
    assert not out.exists()


def test_image_hashes_reads_against_before_rendering(hashes, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = ["--json", str(tmp_path / "after.json"), "--only", "spheres"]
    # A missing baseline was noticed after every render.
    missing = tmp_path / "missing.json"
    assert "missing.json" in _usage_error(hashes.main, [*out, "--against", str(missing)], capsys)
    # A baseline of another size reported every render as differing.
    other = _baseline(tmp_path / "big.json", [192, 108], hashes.render_keys(["spheres"]))
    assert "192x108" in _usage_error(hashes.main, [*out, "--against", str(other)], capsys)
    # A baseline with no render of this run's: nothing would be compared, yet it passed.
    unrelated = _baseline(tmp_path / "glass.json", [96, 54], hashes.render_keys(["glass"]))
    assert "nothing would be compared" in _usage_error(
        hashes.main, [*out, "--against", str(unrelated)], capsys)


def test_image_hashes_counts_in_the_readme() -> None:
    """Every DOUBLE name is a scene or a hard case (a stale name renders nothing in double), and
    benchmarks/README.md gives the number of renders and of scenes in double that the script
    makes."""
    names = image_hashes.scene_runs()
    assert image_hashes.DOUBLE <= set(names), image_hashes.DOUBLE - set(names)
    text = (ROOT / "benchmarks" / "README.md").read_text(encoding="utf-8")
    section = text.split("## `image_hashes.py`")[1].split("\n## ")[0]
    words = {"six": 6, "seven": 7, "eight": 8, "nine": 9, "ten": 10}
    doubles = re.search(r"for (\w+)\s+scenes \(`DOUBLE`\)", section)
    assert doubles and words.get(doubles.group(1)) == len(image_hashes.DOUBLE)
    renders = re.search(r"(\d+) renders", section)
    assert renders and int(renders.group(1)) == len(image_hashes.render_keys())


# (script, its functions that do the work, arguments, what the message names). Each row was a
# traceback, an empty or wrong result, or a check after the work before it was an argparse check.
BAD_ARGUMENTS = [
    ("bench_bvh", ["mesh_bounds", "sphere_bounds"], ["--runs", "0"], "--runs"),
    ("cold_build", ["measure"], ["--repeat", "0"], "--repeat"),
    ("cold_build", ["measure"], ["--scenes", "spherse"], "spherse"),  # wrote {} and exit 0
    ("load_sizes", ["write", "load"], ["--repeat", "0"], "--repeat"),
    ("load_sizes", ["write", "load"], ["--formats", "stl"], "stl"),  # wrote a glTF as .ply
    ("load_sizes", ["write", "load"], ["--sides", "64,x"], "--sides"),
    ("denoise", ["reference", "measure"], ["--rounds", "0"], "--rounds"),
    ("denoise", ["reference", "measure"], ["--spp", "4,0"], "--spp"),
    ("denoise", ["reference", "measure"], ["--spp", "4,16,4"], "repeated: 4"),  # measured twice
    ("bench_obj_materials", ["write_grid"], ["--repeat", "0"], "--repeat"),
    ("bench_instances", ["select_device", "scenes"], ["--repeat", "0"], "--repeat"),
    ("scale", ["write_ply", "measure", "against"], ["--against", "HEAD", "--rounds", "0"],
     "--rounds"),  # wrote empty medians
    ("scale", ["write_ply", "measure", "against"], ["--against", "no-such-ref-xyz"],
     "no-such-ref-xyz"),  # CalledProcessError after the meshes were written
    ("instructions", ["count_scene"], ["--scenes", "foo"], "foo"),  # KeyError
    ("stages", ["count_stages"], ["--size", "4"], "--size"),
    ("stages", ["count_stages"], ["--spp", "x"], "--spp"),
    ("stages", ["count_stages"], ["--traversals", "bogus"], "bogus"),
    ("stages", ["count_stages"], ["--rows", "5:2"], "--rows"),
    ("ply_readers", ["sphere_ply"], ["--repeat", "0"], "--repeat"),
    ("gltf_readers", ["grid_glb"], ["--side", "1"], "--side"),
    ("bench", ["select_device", "bench_scene"], ["--scenes", ","], "--scenes"),  # measured nothing
    ("bench", ["select_device", "bench_scene"], ["--scenes", "spheres,spheres"],
     "repeated: spheres"),  # measured spheres twice
    ("bench", ["select_device", "bench_scene"], ["--scenes", "spherse"], "spherse"),
    # was ignored: no POV-Ray trace, and nothing said so
    ("bench", ["select_device", "bench_scene"], ["--povray", "off", "--povray-spp", "16"],
     "--povray-spp"),
]


@pytest.mark.parametrize(("name", "work", "argv", "says"), BAD_ARGUMENTS,
                         ids=[f"{row[0]} {' '.join(row[2])}" for row in BAD_ARGUMENTS])
def test_bad_arguments_are_usage_errors(name: str, work: list[str], argv: list[str], says: str,
                                        tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    module = script(name)
    for function in work:
        monkeypatch.setattr(module, function, _no_work)
    if name.endswith("_readers"):
        monkeypatch.setattr(sys.modules["benchmarks.readers"], "run", _no_work)
    flag = "--out" if name in ("bench_obj_materials", "bench_instances") or \
        name.endswith("_readers") else "--json"
    out = tmp_path / "result.json"
    assert says in _usage_error(module.main, [*argv, flag, str(out)], capsys)
    assert not out.exists()


# (script, its work, its output flag): a result that cannot be written is refused before the
# work; bench.py, compare.py (test_compare_args.py), bench_bvh.py, image_hashes.py,
# cold_build.py and bench_obj_materials.py noticed it only after.
OUTPUTS = [
    ("bench", ["select_device", "bench_scene"], "--json"),
    ("bench_bvh", ["mesh_bounds", "sphere_bounds"], "--json"),
    ("cold_build", ["measure"], "--json"),
    ("bench_obj_materials", ["write_grid"], "--out"),
    ("bench_instances", ["select_device", "scenes"], "--out"),
    ("denoise", ["reference", "measure"], "--json"),
    ("load_sizes", ["write", "load"], "--json"),
    ("scale", ["write_ply", "measure"], "--json"),
    ("stages", ["count_stages"], "--json"),
    ("instructions", ["count_scene"], "--json"),
    ("gpu_registers", ["assemble"], "--json"),
    ("private_memory", ["amdgpu_render_usage"], "--json"),
    ("embree", ["import_embreex", "write_scene"], "--json"),
    ("ply_readers", ["sphere_ply"], "--out"),
]


@pytest.mark.parametrize(("name", "work", "flag"), OUTPUTS, ids=[row[0] for row in OUTPUTS])
def test_unwritable_output_is_refused_before_the_work(name: str, work: list[str], flag: str,
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    module = script(name)
    for function in work:
        monkeypatch.setattr(module, function, _no_work)
    blocker = tmp_path / "a_file"
    blocker.write_text("", encoding="utf-8")
    argv = {"denoise": ["--cache", str(tmp_path / "cache")]}.get(name, [])
    assert flag in _usage_error(module.main, [*argv, flag, str(blocker / "result.json")], capsys)


def test_image_hashes_refuses_an_unwritable_json(hashes, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("", encoding="utf-8")
    assert "--json" in _usage_error(hashes.main, ["--only", "spheres", "--json",
                                                  str(blocker / "h.json")], capsys)


def test_check_outputs_makes_the_folder_and_leaves_no_file(tmp_path: Path) -> None:
    """The output's folder is made before the work (cold_build.py and bench_obj_materials.py
    failed at the end where it did not exist yet); no empty result is left, and an existing
    one keeps its contents until replaced."""
    import argparse

    from benchmarks.common import check_outputs

    parser = argparse.ArgumentParser()
    new = tmp_path / "new" / "folder" / "result.json"
    old = tmp_path / "old.json"
    old.write_text("{}", encoding="utf-8")
    check_outputs(parser, json=new, out=old, plot=None)
    assert new.parent.is_dir() and not new.exists()
    assert old.read_text(encoding="utf-8") == "{}"


def test_cold_build_writes_into_a_new_folder(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    module = script("cold_build")
    figures = {"cpu_s": 1.0, "wall_s": 1.0}
    monkeypatch.setattr(module, "measure", lambda scene, device: {
        "device": "x", "options": [], **dict.fromkeys(
            ("build", "first_launch", "second_launch", "cold"), figures)})
    out = tmp_path / "new" / "cold.json"
    module.main(["--scenes", "spheres", "--json", str(out)])
    assert list(json.loads(out.read_text(encoding="utf-8"))["scenes"]) == ["spheres"]


def test_load_sizes_ratio_does_not_follow_the_order_of_sides(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """largest_over_smallest_a_triangle is the largest side's over the smallest's: given
    `--sides 128,64` it was the smaller's over the larger's."""
    module = script("load_sizes")

    def write(fmt: str, path: Path, side: int) -> int:
        path.write_bytes(b"x")
        return 2 * (side - 1) ** 2

    def load(path: Path, triangles: int) -> dict:
        per = 2e-6 if "128" in path.name else 1e-6  # the larger costs twice a triangle
        return {"wall_s": triangles * per, "cpu_s": triangles * per, "triangles": triangles}

    monkeypatch.setattr(module, "write", write)
    monkeypatch.setattr(module, "load", load)
    out = tmp_path / "sizes.json"
    module.main(["--sides", "128,64", "--formats", "obj", "--repeat", "1", "--json", str(out)])
    entry = json.loads(out.read_text(encoding="utf-8"))["formats"]["obj"]
    assert [s["side"] for s in entry["sizes"]] == [64, 128]
    assert entry["largest_over_smallest_a_triangle"] == pytest.approx(2.0)


def test_denoise_picture_is_at_the_lowest_spp(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """--picture shows the lowest of --spp, as its help says, in whatever order they come."""
    module = script("denoise")
    row = dict.fromkeys(("rmse_noisy", "rmse_denoised", "render_s", "passes_s", "denoise_s",
                         "same_cost_s", "rmse_same_cost"), 0.0)
    pictured: list[int] = []
    monkeypatch.setattr(module, "check_denoiser", lambda: None)
    monkeypatch.setattr(module, "reference", lambda *args: None)
    monkeypatch.setattr(module, "measure", lambda scene_name, spp, ref, rounds: (
        {**row, "scene": scene_name, "spp": spp, "same_cost_spp": spp}, spp))
    monkeypatch.setattr(module, "picture", lambda result, path: pictured.append(result))
    monkeypatch.setattr(module, "select_device", lambda spec: None)
    monkeypatch.setattr(module, "describe", lambda device: "none")
    module.main(["--spp", "16,4,64", "--json", str(tmp_path / "out.json"), "--cache",
                 str(tmp_path / "cache"), "--picture", str(tmp_path / "picture.png")])
    assert pictured == [4]


def test_cpu_model_names_the_host_processor() -> None:
    from benchmarks.common import cpu_model

    got = cpu_model()
    assert set(got) == {"cpu_model", "avx2", "avx512f"}
    if Path("/proc/cpuinfo").exists():
        assert isinstance(got["cpu_model"], str) and got["cpu_model"]


def test_bench_environment_names_the_processor(cl_device: cl.Device) -> None:
    """bench.py's JSON named the device and driver but not the host processor."""
    from benchmarks.common import cpu_model

    env = script("bench").environment(cl_device)
    assert {key: env[key] for key in ("cpu_model", "avx2", "avx512f")} == cpu_model()
    assert env["driver_version"] == cl_device.driver_version.strip()


def _fake_render(packed: object, device: object) -> tuple[np.ndarray, dict]:
    return np.zeros((1, 1, 3), dtype=np.float32), {"kernel_s": 0.1, "rays": {"total": 4}}


def test_bench_warms_povray_up_at_each_count(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """POV-Ray's first trace at each count was timed, though clray's first render was not."""
    bench = script("bench")
    traced: list[int] = []

    def trace_time(pov_file: Path, width: int, height: int, threads: int = 2,
                   samples: int = 1) -> dict:
        traced.append(samples)
        return {"trace_s": 1.0}

    monkeypatch.setattr(bench.povray, "trace_time", trace_time)
    rendered: list[object] = []
    monkeypatch.setattr(bench, "render_packed",
                        lambda packed, device: (rendered.append(packed), _fake_render(
                            packed, device))[1])
    pov = bench.povray.Interleaved("spheres", ROOT / "scenes" / "spheres.toml", tmp_path, 4, 4, 1)
    got = bench.timed_renders("own", None, 2, pov, {16: "sixteen"}, (1, 16))
    assert traced == [1, 16] + [1, 16] * 2  # a warm-up at each count, then the rounds
    assert {n: len(runs) for n, runs in pov.runs.items()} == {1: 2, 16: 2}
    assert rendered == ["sixteen"] + ["own", "sixteen"] * 2
    assert got["runs"] == [0.1, 0.1] and got["spp_runs"] == {1: [0.1, 0.1], 16: [0.1, 0.1]}


@pytest.mark.parametrize(("argv", "available", "state"), [
    (["--povray", "off"], True, "off"),
    (["--povray-spp", "16"], False, "not installed"),
])
def test_bench_records_why_povray_was_not_compared(
        argv: list[str], available: bool, state: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """--povray-spp was silently ignored without POV-Ray: the JSON gave no reason."""
    bench = script("bench")
    monkeypatch.setattr(bench.povray, "available", lambda: available)
    monkeypatch.setattr(bench.profile, "cache_env", lambda path, env: {})
    monkeypatch.setattr(bench, "select_device", lambda spec: None)
    monkeypatch.setattr(bench, "environment", lambda device: {})
    monkeypatch.setattr(bench, "print_scene", lambda r, repeat: None)

    def bench_scene(name: str, path: Path, device: object, spec: object, repeat: int,
                    povray_dir: Path | None, split: bool, povray_spp: tuple[int, ...]) -> dict:
        assert povray_dir is None
        return {"scene": name}

    monkeypatch.setattr(bench, "bench_scene", bench_scene)
    out = tmp_path / "bench.json"
    bench.main(["--scenes", "spheres", "--json", str(out), *argv])
    scenes = json.loads(out.read_text(encoding="utf-8"))["scenes"]
    assert scenes == [{"scene": "spheres", "povray": state}]
    err = capsys.readouterr().err
    assert ("povray is not on PATH" in err) is (state == "not installed")
    assert "16 not traced" in err or state == "off"


def test_bench_povray_entry_compares_rays_per_second() -> None:
    """Beside the ratio of times, the ratio of rates: POV-Ray traces about n + 1 camera rays a
    pixel at n samples."""
    class Pov:
        def summary(self, samples: int, kernel_s: float, image: np.ndarray) -> dict:
            return {"trace_s": 2.0, "ratio_trace_over_kernel": 2.0 / kernel_s,
                    "rays": {"traced": 3_000_000, "reflected": 0, "shadow_tests": 1_000_000}}

    entry = script("bench").povray_entry(Pov(), 1, [0.5], {"total": 2_000_000},
                                         np.zeros((1, 1, 3)))
    assert entry["clray_mrays_per_s"] == pytest.approx(4.0)
    assert entry["povray_mrays_per_s"] == pytest.approx(2.0)
    assert entry["ratio_rays_per_s"] == pytest.approx(2.0)
    assert entry["ratio_trace_over_kernel"] == pytest.approx(4.0)


def test_bench_packs_every_count_with_the_device_plan(cl_device: cl.Device) -> None:
    """The scene's own count was packed without the plan's switches, the other counts with
    them: both as `clray render --no-tuning` packs."""
    from clray.device.policy import device_plan
    from clray.knobs import Tuning
    from clray.scene.load import load_scene

    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    for spp in (scene.render.spp, 16):
        config = script("bench").pack_at(scene, cl_device, spp).config
        plan = device_plan(cl_device, spp=spp, tuning=Tuning())
        assert config.bvh_width == plan.bvh_width
        for name, value in plan.switches.items():
            assert getattr(config, name) == value, (spp, name)


def test_stages_traversals_are_clrays() -> None:
    from clray.knobs import TRAVERSALS

    assert script("stages").TRAVERSALS == TRAVERSALS


# benchmarks/README.md describes each script in a section `## \`NAME.py\``; every long option
# its --help lists is named there (in the usage block or the text).
SCRIPTS = sorted(path.stem for path in (ROOT / "benchmarks").glob("*.py")
                 if "\ndef main(" in path.read_text(encoding="utf-8"))


def readme_section(name: str) -> str | None:
    text = (ROOT / "benchmarks" / "README.md").read_text(encoding="utf-8")
    match = re.search(rf"^## `{re.escape(name)}\.py`.*?(?=^## |\Z)", text, re.M | re.S)
    return match.group(0) if match else None


def unnamed(flags: set[str], section: str) -> list[str]:
    """The flags that the section does not name."""
    return sorted(flag for flag in flags
                  if not re.search(rf"{re.escape(flag)}(?![\w-])", section))


def help_flags(name: str, capsys: pytest.CaptureFixture[str]) -> set[str]:
    if name == "bench_dask":
        pytest.importorskip("distributed")
    with pytest.raises(SystemExit) as exit_info:
        script(name).main(["--help"])
    assert exit_info.value.code == 0
    return set(re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", capsys.readouterr().out)) - {"--help"}


@pytest.mark.parametrize("name", SCRIPTS)
def test_readme_describes_every_flag(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    section = readme_section(name)
    assert section is not None, f"benchmarks/README.md has no section for {name}.py"
    flags = help_flags(name, capsys)
    assert flags, "no flag read from --help: the check is blind"
    assert unnamed(flags, section) == [], f"benchmarks/README.md's {name}.py section"


def test_the_readme_check_sees_a_missing_flag(capsys: pytest.CaptureFixture[str]) -> None:
    section = readme_section("denoise")
    flags = help_flags("denoise", capsys)
    assert unnamed(flags, section.replace("--picture-scene", "")) == ["--picture-scene"]
    assert "--picture-scene" in flags and "--picture" not in unnamed(flags, section)


@pytest.mark.parametrize("name", ["stages", "instructions"])
def test_counting_children_render_with_the_scenes_min_weight(name: str, cl_device: cl.Device,
                                                             tmp_path: Path) -> None:
    """The counting benchmarks' children packed every scene with min_weight 0, so a scene
    that cuts faint rays was counted tracing rays its `clray render` never traces."""
    import subprocess

    from clray.render import RenderSettings, render
    from clray.scene.load import load_scene

    if not cl_device.platform.name.startswith("Portable Computing Language"):
        pytest.skip("the counting benchmarks render on PoCL")
    text = (ROOT / "scenes" / "fresnel.toml").read_text(encoding="utf-8")
    assert "min_weight = 0.004\n" in text
    scene = tmp_path / "fresnel.toml"
    scene.write_text(text.replace("min_weight = 0.004\n", "min_weight = 0.3\n"),
                     encoding="utf-8")
    spp = load_scene(scene).render.spp
    settings = dict(width=32, height=20, device="pocl", stored_tuning=False, traversal="single")
    rendered = render(scene, RenderSettings(**settings))
    uncut = render(scene, RenderSettings(**settings, min_weight=0.0))
    assert uncut.stats["rays"]["total"] > rendered.stats["rays"]["total"]
    if name == "stages":  # path, traversal, spp, width, height, profile, first row, end row
        args = [str(scene), "single", str(spp), "32", "20", "0", "0", "20"]
    else:  # path, variant, width, height
        args = [str(scene), "full", "32", "20"]
    run = subprocess.run([sys.executable, "-c", script(name)._RENDER, *args],
                         capture_output=True, text=True, check=True)
    rays = json.loads(run.stdout.strip().splitlines()[-1])
    rays = rays.get("rays", rays)
    assert rays["total"] == rendered.stats["rays"]["total"]
