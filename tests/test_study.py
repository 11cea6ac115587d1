"""clray study: metrics and pass/fail per variant, Pareto front, report files, optional plots."""

from __future__ import annotations

import builtins
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from clray import metrics, study
from clray.cli import main
from clray.device.tuning_files import save_tuning
from clray.knobs import Tuning
from clray.scene.load import load_scene

SCENE = """
[render]
width = 24
height = 18
max_depth = 0
[camera]
position = [0, 0, 4]
look_at = [0, 0, 0]
[[lights]]
type = "directional"
direction = [0, -1, -1]
[[objects]]
type = "sphere"
center = [0, 0, 0]
radius = 1
"""


def test_pareto_front_keeps_points_nothing_beats() -> None:
    points = [(1.0, 5.0), (2.0, 1.0), (3.0, 2.0), (0.5, 9.0), (4.0, 0.5)]
    assert study.pareto_front(points) == [3, 0, 1, 4]


def test_compare_fails_on_non_finite_and_on_many_wrong_pixels() -> None:
    ref = np.zeros((10, 10, 3), dtype=np.float32)
    assert study.compare(ref, ref)["status"] == "pass"
    nan = ref.copy()
    nan[3, 4, 1] = np.nan
    record = study.compare(nan, ref)
    assert (record["status"], record["nonfinite"], record["rmse"]) == ("FAIL", 1, None)
    off = ref.copy()
    off[0, :3] = 0.5  # three pixels, over the allowance of max(2, 0.2 %) for 100 pixels
    assert study.compare(off, ref)["status"] == "FAIL"


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
def test_run_study_writes_results_report_and_plot(tmp_path: Path, tmp_scene,
                                                  cl_device: cl.Device) -> None:
    scene = tmp_scene(SCENE)
    variants = (study.DEFAULT, study.VARIANTS[4])  # default and -cl-fast-relaxed-math
    records = study.run_study([scene], tmp_path / "out", repeat=2, variants=variants)
    assert [r["variant"] for r in records] == ["float (default)", "-cl-fast-relaxed-math"]
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(data["records"]) == 2 and data["repeat"] == 2
    assert all(len(r["kernel_s_all"]) == 2 for r in data["records"])
    assert records[0]["status"] == "pass"
    report = (tmp_path / "out" / "report.md").read_text()
    assert "| float (default) |" in report and "-cl-fast-relaxed-math" in report
    pytest.importorskip("matplotlib")
    png = (tmp_path / "out" / "scene.png").read_bytes()
    assert png[:4] == b"\x89PNG"
    # Redrawn from results.json alone: the same report, a plot again.
    (tmp_path / "out" / "scene.png").unlink()
    assert study.main([str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "report.md").read_text() == report
    assert (tmp_path / "out" / "scene.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
def test_study_renders_with_the_default_knobs_not_the_tuning_file(tmp_path: Path, tmp_scene,
                                                                  cl_device: cl.Device) -> None:
    # Its reference and default variant are the knob table's builds, as the report names them.
    save_tuning(cl_device, Tuning(work_group_width=16), {"note": "test"})
    study.run_study([tmp_scene(SCENE)], tmp_path / "out", repeat=1, variants=(study.DEFAULT,))
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert data["tuning"].startswith("default: ")
    assert [r["tuning"] for r in data["records"]] == ["default"]


def _record(variant: str, ms: float, rmse: float | None, status: str = "pass") -> dict:
    return {"scene": "s", "width": 8, "height": 6, "variant": variant,
            "kernel_s_median": ms / 1e3, "rmse": rmse, "status": status}


def test_plot_names_every_variant_once_and_keeps_zero_off_the_log_axis() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    records = [_record("double", 12.0, 0.0), _record("a", 10.0, 3e-4),
               _record("b", 10.5, 3e-4, "FAIL"), _record("c", 9.0, 2e-3),
               _record("d", 11.0, None, "FAIL"), _record("e", 8.0, 0.0)]
    fig = study.plot_figure(records)
    try:
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert texts == ["double: 12 ms, the reference (RMSE 0), dotted",
                         "a: 10 ms, RMSE 0.0003", "b: 10.5 ms, RMSE 0.0003, FAIL",
                         "c: 9 ms, RMSE 0.002", "d: 11 ms, non-finite pixels, FAIL",
                         "e: 8 ms, RMSE 0", "Pareto front (ringed)"]
        errors, exact = fig.axes
        # No point labels in the plot: names are in the legend only.
        assert not errors.texts and not exact.texts
        assert errors.get_yscale() == "log"
        assert errors.get_ylim() == pytest.approx((1e-4, 1e-2))  # whole decades, no 1e-9
        # The exact results (the reference and e) sit in the strip below, at 0.
        strip = sorted(float(line.get_xdata()[0]) for line in exact.lines
                       if line.get_marker() not in ("o", "None", None) and
                       line.get_linestyle() == "None")
        assert strip == [8.0, 12.0]
    finally:
        plt.close(fig)


def test_plot_of_only_exact_variants_says_so() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    fig = study.plot_figure([_record("double", 2.0, 0.0), _record("a", 1.0, 0.0)])
    try:
        assert [t.get_text() for t in fig.axes[0].texts] == [
            "no variant differs from the reference"]
        assert fig.axes[0].get_yscale() == "linear"
    finally:
        plt.close(fig)


def test_replot_of_a_folder_without_results_is_one_error_line(tmp_path: Path, capsys) -> None:
    assert study.main([str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("clray: error: cannot replot ") and err.count("\n") == 1


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
def test_study_without_matplotlib_skips_plots_with_a_note(tmp_path: Path, tmp_scene,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         cl_device: cl.Device) -> None:
    real_import = builtins.__import__

    def no_matplotlib(name: str, *args: object, **kwargs: object) -> object:
        if name.startswith("matplotlib"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    study.run_study([tmp_scene(SCENE)], tmp_path, repeat=1, variants=(study.DEFAULT,))
    assert not list(tmp_path.glob("*.png"))
    assert "Plots skipped" in (tmp_path / "report.md").read_text()


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
def test_cli_study(tmp_path: Path, tmp_scene, cl_device: cl.Device,
                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(study, "VARIANTS", (study.REFERENCE, study.DEFAULT))
    monkeypatch.setattr(study.run_study, "__kwdefaults__",
                        {**study.run_study.__kwdefaults__, "variants": study.VARIANTS})
    assert main(["study", str(tmp_scene(SCENE)), "--out", str(tmp_path / "o"), "--repeat",
                 "1", "-q"]) == 0
    assert (tmp_path / "o" / "report.md").exists()


def test_a_failed_study_takes_back_its_out_folder(tmp_path: Path, capsys) -> None:
    # The folder is made (and shown writable) before the scenes render; a scene that does not
    # load ends the study with no folder left behind.
    out = tmp_path / "o" / "deep"
    assert main(["study", str(tmp_path / "nothere.toml"), "--out", str(out)]) == 3
    assert "cannot read scene file" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_bad_scene_stops_the_study_before_any_render(tmp_path: Path, tmp_scene, capsys,
                                                       cl_device: cl.Device,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    # Every scene loads before the first renders: minutes of variants are not thrown away
    # for a typo in the last scene.
    rendered = []
    monkeypatch.setattr(study, "study_scene", lambda path, *a, **k: rendered.append(path))
    bad = tmp_path / "bad.toml"
    bad.write_text("[render]\nwidth = -3\n")
    assert main(["study", str(tmp_scene(SCENE)), str(bad), "--out", str(tmp_path / "o")]) == 3
    assert capsys.readouterr().err == f"clray: error: {bad}: camera: missing required key\n"
    assert rendered == [] and not (tmp_path / "o").exists()


def test_a_folder_where_a_study_file_goes_is_refused_before_rendering(
        tmp_path: Path, tmp_scene, capsys, cl_device: cl.Device) -> None:
    scene = tmp_scene(SCENE)
    for name in ("report.md", f"{scene.stem}.png"):
        out = tmp_path / name.replace(".", "_")
        (out / name).mkdir(parents=True)
        assert main(["study", str(scene), "--out", str(out), "-q"]) == 1
        assert capsys.readouterr().err == (f"clray: error: cannot write {out / name}: "
                                           "it is a directory\n")


def test_a_study_file_that_cannot_be_written_is_one_line_and_never_half_written(
        tmp_path: Path, tmp_scene, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    # A full disk after the renders: results.json is there whole or not at all.
    def full_disk(source: object, target: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(study, "study_scene", lambda path, *a, **k: [])
    monkeypatch.setattr(study, "plot_scenes", lambda records, out: {})
    monkeypatch.setattr("os.replace", full_disk)
    out = tmp_path / "o"
    assert main(["study", str(tmp_scene(SCENE)), "--out", str(out), "-q"]) == 1
    assert capsys.readouterr().err == (f"clray: error: cannot write {out / 'results.json'}: "
                                       "No space left on device\n")
    assert not out.exists() or list(out.iterdir()) == []


def test_study_refuses_two_scenes_of_one_name(tmp_path: Path, tmp_scene, capsys) -> None:
    # Its records, plots and report sections are keyed by the name: one would hide the other.
    first = tmp_scene(SCENE)
    other = tmp_path / "other" / first.name
    other.parent.mkdir()
    other.write_text(SCENE)
    assert main(["study", str(first), str(other), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == (
        f"clray: error: SCENE: {first} and {other} have the same name {first.stem!r}, under "
        "which their results are kept: rename one\n")
    assert not (tmp_path / "o").exists()


def test_cli_study_needs_out(tmp_scene) -> None:
    assert main(["study", str(tmp_scene(SCENE))]) == 2


def _full(variant: str, rmse: float, over: int, nonfinite: int = 0, **fields: object) -> dict:
    """A record as study_scene makes it, of a 64x48 image: the allowance is 6 pixels."""
    n_pixels = 64 * 48
    status = "pass" if nonfinite == 0 and over <= metrics.fail_allowance(n_pixels) else "FAIL"
    return {"scene": "glass", "scene_file": "scenes/glass.toml", "variant": variant,
            "width": 64, "height": 48, "kernel_s_median": 0.0131, "rmse": rmse,
            "psnr_db": 47.4, "max_abs": 0.123, "over_1_255": over, "over_2_255": over,
            "nonfinite": nonfinite, "status": status, "scene_warnings": [], **fields}


GLASS = [_full("double", 0.0, 0), _full("float (default)", 0.004273047055896146, 13),
         _full("-cl-mad-enable", 0.0021, 6), _full("-cl-fast-relaxed-math", 0.0044, 1, 1)]


def test_progress_lines_say_what_is_compared_and_why_a_variant_fails() -> None:
    assert study.scene_line(GLASS[0]) == (
        "glass at 64x48: each variant's image against the double build's (the reference); "
        "FAIL: a NaN or infinite pixel, or over 6 of the 3072 pixels off by more than 2/255")
    assert [study.variant_line(r) for r in GLASS] == [
        "glass: double: 13.1 ms, the reference",
        # Three significant digits, not the 17 of the float's repr.
        "glass: float (default): 13.1 ms, RMSE 0.00427, FAIL: 13 pixels off by over 2/255, "
        "6 allowed",
        "glass: -cl-mad-enable: 13.1 ms, RMSE 0.0021, pass",
        "glass: -cl-fast-relaxed-math: 13.1 ms, RMSE 0.0044, FAIL: 1 pixel NaN or infinite"]


def test_report_says_what_is_compared_the_tolerance_and_why_a_variant_fails(
        tmp_path: Path) -> None:
    study.write_report(GLASS, tmp_path, 1, "a device", {})
    report = (tmp_path / "report.md").read_text()
    assert "median of 1 timed run after a warm-up" in report
    assert "compared pixel by pixel with the image of the **double** variant" in report
    assert ("`scenes/glass.toml` at 64x48. FAIL: a NaN or infinite pixel, or over 6 of the "
            "3072 pixels off by more than 2/255.") in report
    assert "The float default fails here too" in report
    assert ("| glass | reference | **FAIL**: 13 pixels off by over 2/255, 6 allowed | pass | "
            "**FAIL**: 1 pixel NaN or infinite |") in report
    assert report.count("| **FAIL**: 13 pixels off by over 2/255, 6 allowed |") == 2
    study.write_report(GLASS, tmp_path, 3, "a device", {})
    assert "median of 3 timed runs" in (tmp_path / "report.md").read_text()


def test_one_dask_worker_is_named_in_the_singular(tmp_path: Path) -> None:
    def one_worker(paths, variants, repeat, base, say) -> list[dict]:
        return [{**r, "worker": "w:1", "device": "a device"} for r in GLASS]

    study.run_study([Path("scenes/glass.toml")], tmp_path, run_scenes=one_worker)
    device = json.loads((tmp_path / "results.json").read_text())["device"]
    assert device.startswith("1 Dask worker (a device), each scene's variants")


def _fake_render(calls: list[str], nan_in: str | None = None) -> object:
    """A stand-in for clray.render.render that records which variant each call renders, and
    returns a black 24x18 image (with a NaN pixel for the precision `nan_in`)."""
    names = {(v.precision, v.switches): v.name for v in study.VARIANTS}

    def fake(scene: object, settings: object) -> object:
        calls.append(names[settings.precision, settings.variants])
        image = np.zeros((18, 24, 3), dtype=np.float32)
        if settings.precision == nan_in:
            image[2, 3] = np.nan
        return SimpleNamespace(image=image,
                               stats={"kernel_s": 0.01, "tuning": {"source": "default"}})
    return fake


@pytest.mark.parametrize("variants", [
    (study.REFERENCE, study.DEFAULT, study.VARIANTS[2]),
    (study.DEFAULT, study.VARIANTS[2], study.REFERENCE),
    (study.DEFAULT, study.VARIANTS[2]),
], ids=["reference-first", "reference-last", "no-reference"])
def test_study_warms_every_variant_up_then_times_them_in_interleaved_rounds(
        tmp_scene, monkeypatch: pytest.MonkeyPatch, variants: tuple) -> None:
    calls: list[str] = []
    monkeypatch.setattr(study, "render", _fake_render(calls))
    path = tmp_scene(SCENE)
    records = study.study_scene(path, variants, 3, study.RenderSettings(),
                                scene=load_scene(path))
    names = [v.name for v in variants]
    # The reference renders once before any variant, as the reference image and, where it is
    # a variant, as its warm-up; then one warm-up a variant, then three rounds, every other
    # one reversed.
    warm_ups = ["double", *(name for name in names if name != "double")]
    assert calls == warm_ups + names + names[::-1] + names
    assert [len(r["kernel_s_all"]) for r in records] == [3] * len(variants)


def test_a_non_finite_reference_fails_every_variant_and_says_so(
        tmp_scene, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # A NaN in the double build's image made every error n/a and no variant's pixel
    # non-finite: each variant passed, the fault nowhere.
    monkeypatch.setattr(study, "render", _fake_render([], nan_in="double"))
    path = tmp_scene(SCENE)
    said: list[str] = []
    records = study.study_scene(path, (study.REFERENCE, study.DEFAULT), 1,
                                study.RenderSettings(), said.append, load_scene(path))
    default = records[1]
    assert (default["reference_nonfinite"], default["nonfinite"], default["rmse"],
            default["status"]) == (1, 0, None, "FAIL")
    fault = "the reference has 1 pixel NaN or infinite: no image compares with it"
    assert said[0].endswith("; the reference has 1 pixel NaN or infinite: every variant FAILs")
    assert said[1].endswith(f", the reference, FAIL: {fault}")
    assert said[2].endswith(f", RMSE n/a, FAIL: {fault}")
    study.write_report(records, tmp_path, 1, "a device", {})
    assert (f"| scene | reference, **FAIL**: {fault} | **FAIL**: {fault} |"
            in (tmp_path / "report.md").read_text())


def test_a_variant_has_its_marker_and_colour_in_a_plot_of_any_subset() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    def styles(names: list[str]) -> dict[str, tuple[str, str]]:
        fig = study.plot_figure([_record(name, 10.0 + i, 1e-3) for i, name in enumerate(names)])
        try:
            return {t.get_text().split(":")[0]: (h.get_marker(), h.get_color())
                    for t, h in zip(fig.legends[0].get_texts(), fig.legends[0].legend_handles,
                                    strict=True)}
        finally:
            plt.close(fig)

    every = styles([v.name for v in study.VARIANTS])
    some = styles(["Schlick Fresnel", "float (default)", "not a variant"])
    assert some["Schlick Fresnel"] == every["Schlick Fresnel"]
    assert some["float (default)"] == every["float (default)"]
    assert some["not a variant"] not in every.values()


def test_summary_averages_the_shipped_scenes_times_and_lists_each_variants_failures(
        tmp_path: Path) -> None:
    def at(scene: str, file: str, variant: str, ms: float, over: int = 0) -> dict:
        return _full(variant, 0.001, over, scene=scene, scene_file=file,
                     kernel_s_median=ms / 1e3)

    shipped = [at(s, f"scenes/{s}.toml", v, ms, over) for s, v, ms, over in (
        ("a", "float (default)", 10, 0), ("a", "x", 20, 13),
        ("b", "float (default)", 10, 0), ("b", "x", 5, 0))]
    hard = [at("h", "docs/study/scenes/h.json", "float (default)", 1, 0),
            at("h", "docs/study/scenes/h.json", "x", 100, 0)]
    # x takes twice the default's time on a, half on b: 1.00 over the shipped scenes; the hard
    # case h (x100) is not averaged while there are shipped scenes.
    rows = study.summary(shipped + hard)
    assert [(row["variant"], row["time"], row["fails"]) for row in rows] == [
        ("float (default)", 1.0, {}), ("x", pytest.approx(1.0), {"a": (13, 0)})]
    assert study.summary(hard)[1]["time"] == pytest.approx(100)
    study.write_report(shipped + hard, tmp_path, 1, "a device", {})
    report = (tmp_path / "report.md").read_text()
    assert "the geometric mean over the 2 shipped scenes (`scenes/`)" in report
    assert "| float (default) | 1.00 | - |\n| x | 1.00 | a (13) |\n" in report


@pytest.mark.parametrize(("ms", "labels"), [
    ((9.0, 10.0, 12.0), ["9", "10", "11", "12"]),  # one scene's variants: round milliseconds
    ((3.0, 10.0, 300.0), ["$\\mathdefault{10^{1}}$", "$\\mathdefault{10^{2}}$"]),  # decades
], ids=["under-a-decade", "decades"])
def test_plot_times_are_on_a_log_axis(ms: tuple[float, ...], labels: list[str]) -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    fig = study.plot_figure([_record(name, t, 1e-3) for name, t in zip("abc", ms, strict=True)])
    try:
        errors, exact = fig.axes
        fig.canvas.draw()
        low, high = exact.get_xlim()
        shown = [t.get_text() for t in exact.get_xticklabels()
                 if low <= t.get_position()[0] <= high]
        assert (errors.get_xscale(), exact.get_xscale()) == ("log", "log")
        assert [label for label in shown if label] == labels
    finally:
        plt.close(fig)


def test_study_times_a_median_of_five_runs_by_default(tmp_scene) -> None:
    # docs/cli.md gives the default; five, as a median of fewer moves too much between runs
    # on a loaded machine.
    from clray.cli import _build_parser

    args = _build_parser().parse_args(["study", str(tmp_scene(SCENE)), "--out", "o"])
    assert args.repeat == study.run_study.__kwdefaults__["repeat"] == 5
    row = next(line for line in (Path(__file__).parent.parent / "docs/cli.md").read_text()
               .splitlines() if line.startswith("| `--repeat N` | Timed runs per variant"))
    assert row.endswith(" Default 5. |")
