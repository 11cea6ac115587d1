"""`clray tune` on a tiny scene: Kernel Tuner's brute force over two configurations, every image
verified against the default's (a configuration that drops shadows is rejected, never chosen),
the cache file resumed by a second run, and the stored winner used by `clray render` unless
--no-tuning."""

from __future__ import annotations

import itertools
import json
import re
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clray import cli
from clray.device import program
from clray.device.policy import device_plan
from clray.device.program import GPU_BUILD_OPTIONS, kernel_source
from clray.errors import ClrayError
from clray.knobs import TRAVERSALS
from clray.tuning import KNOB_TABLE, Tuning
from clray.tuning import tuner as tuner_module
from clray.tuning.command import least_budget_s, run_tune, untried

ROOT = Path(__file__).resolve().parent.parent
SPHERES = ROOT / "scenes" / "spheres.toml"
FRESNEL = ROOT / "scenes" / "fresnel.toml"
SIZE = (48, 27)
# Host knobs at their defaults, two work-group widths: two configurations, the default one of them.
TWO = {**{k.name: (k.default,) for k in KNOB_TABLE}, "work_group_width": (16, 64)}
SHADOW_LINE = "        REAL3 filter = transmission(s, &shadow, tmax);\n"


@pytest.fixture
def kernel_tuner():
    return pytest.importorskip("kernel_tuner", reason="Kernel Tuner is the 'tune' extra: "
                                                      "pip install 'clray[tune]'")


def tune(cl_device, out: Path, scene: Path = SPHERES, **options) -> list[tuner_module.Trial]:
    options = {"space": TWO, "size": SIZE, "iterations": 3, "budget_s": 300, **options}
    return tuner_module.Tuner(cl_device, out, **options).tune([scene])


def own_traversal(device, spp: int) -> str:
    """The walk a default render builds on `device` at `spp` samples a pixel."""
    return device_plan(device, spp=spp, tuning=Tuning()).traversal


def record_tune_kernel(kernel_tuner, monkeypatch) -> list[tuple[tuple, dict]]:
    """The arguments of every Kernel Tuner run the tuner starts, which still runs."""
    calls = []
    tune_kernel = kernel_tuner.interface.tune_kernel

    def recording(*args, **kwargs):
        calls.append((args, kwargs))
        return tune_kernel(*args, **kwargs)

    monkeypatch.setattr(kernel_tuner.interface, "tune_kernel", recording)
    return calls


def spheres_at(folder: Path, spp: int) -> Path:
    """The spheres scene with `spp` samples a pixel (spheres.toml has 1, where no sample
    packet is built), under its own name."""
    text = SPHERES.read_text(encoding="utf-8")
    assert text.count("spp = 1\n") == 1
    path = folder / "spheres.toml"
    path.write_text(text.replace("spp = 1\n", f"spp = {spp}\n"), encoding="utf-8")
    return path


def test_brute_force_tries_verifies_and_times_each_configuration_then_resumes(
        kernel_tuner, cl_device, tmp_path) -> None:
    trials = tune(cl_device, tmp_path)
    assert sorted(t.tuning.work_group_width for t in trials) == [16, 64]
    assert all(t.verified and t.pixels_off == 0 and t.problem is None for t in trials)
    assert all(len(t.times_ms) == 3 and t.time_ms > 0 for t in trials)
    assert any(t.tuning == Tuning() for t in trials)
    best = tuner_module.best_configuration(trials, ["spheres"])
    assert best is not None
    fastest = min(trials, key=lambda t: t.time_ms)
    assert best[1]["spheres"].tuning == fastest.tuning
    cache = list((tmp_path / "cache").rglob("*.json"))
    assert len(cache) == 1 and len(json.loads(cache[0].read_text())["cache"]) == 2
    # A second run over the same folder takes both configurations from the cache: the same
    # times, and no build (Kernel Tuner zeroes a cached entry's build time).
    again = tune(cl_device, tmp_path)
    assert sorted((t.tuning.work_group_width, t.time_ms) for t in again) == sorted(
        (t.tuning.work_group_width, t.time_ms) for t in trials)
    assert all(t.compile_ms == 0 for t in again)
    assert all(t.compile_ms > 0 for t in trials)


def test_brute_force_stops_where_the_budget_ends_the_default_first(
        kernel_tuner, cl_device, tmp_path, monkeypatch) -> None:
    calls = record_tune_kernel(kernel_tuner, monkeypatch)
    # The budget ends after two configurations, as a time limit would (Kernel Tuner's runner
    # asks its budget before each one).
    monkeypatch.setattr(kernel_tuner.util.TuningBudget, "is_done",
                        lambda budget: budget.num_fevals >= 2)
    trials = tune(cl_device, tmp_path, space={**TWO, "work_group_width": (16, 32, 64, 128)})
    limits = [kwargs["strategy_options"]["time_limit"] for _args, kwargs in calls]
    assert len(limits) == 1 and 0 < limits[0] <= 300
    # The default first, then one that changes one parameter from it; the rest not tried.
    assert [t.tuning for t in trials] == [Tuning(), Tuning(work_group_width=16)]
    assert all(t.verified for t in trials)


def test_timed_launches_are_waited_for_not_polled(kernel_tuner, cl_device, tmp_path,
                                                   monkeypatch) -> None:
    """Kernel Tuner polls a launch's status in a loop that, on a CPU device, takes a core from
    the kernel it times: the tuner's launches are finished before it polls."""
    from kernel_tuner.backends.opencl import OpenCLFunctions

    polls: list[bool] = []
    kernel_finished = OpenCLFunctions.kernel_finished

    def recording(self) -> bool:
        polls.append(kernel_finished(self))
        return polls[-1]

    monkeypatch.setattr(OpenCLFunctions, "kernel_finished", recording)
    # 160 x 90 takes milliseconds a launch: a poll straight after it would find it running.
    trials = tune(cl_device, tmp_path, size=(160, 90))
    assert len(trials) == 2 and all(t.verified for t in trials)
    assert len(polls) >= 2 * 3 and all(polls)


def test_short_renders_are_confirmed_over_more_rounds(kernel_tuner, cl_device,
                                                      tmp_path) -> None:
    """A 48 x 27 render takes about a millisecond: 14 rounds of it measure the machine's noise,
    so the confirmation takes as many rounds as make a second of renders, at most 40."""
    tuner = tuner_module.Tuner(cl_device, tmp_path, space=TWO, size=SIZE)
    run = tuner.prepare(SPHERES)
    [confirmed] = tuner_module.confirm([run], Tuning(work_group_width=16), cl_device)
    assert confirmed["rounds"] == tuner_module.MAX_CONFIRM_ROUNDS
    assert len(confirmed["default_runs_s"]) == len(confirmed["tuned_runs_s"]) == 40
    assert sum(confirmed["tuned_runs_s"]) < tuner_module.CONFIRM_SECONDS


def test_one_sample_a_pixel_times_no_packet_build(kernel_tuner, cl_device, tmp_path,
                                                  monkeypatch) -> None:
    calls = record_tune_kernel(kernel_tuner, monkeypatch)
    # spheres.toml has 1 sample a pixel: its renders build the single-ray walk whatever the
    # traversal knob says, so sample packets are not a configuration of their own.
    trials = tune(cl_device, tmp_path, space={**TWO, "work_group_width": (64,),
                                              "traversal": ("single", "sample_packet")})
    [params] = [args[4] for args, _kwargs in calls]
    assert params["TRAVERSAL"] == [TRAVERSALS.index("single")]
    assert [t.tuning for t in trials] == [Tuning()]


def test_a_configuration_that_drops_shadows_is_rejected_and_never_chosen(
        kernel_tuner, cl_device, tmp_path) -> None:
    source = kernel_source()
    assert source.count(SHADOW_LINE) == 1
    wrong = source.replace(SHADOW_LINE, "#if drop_shadows\n        REAL3 filter = (REAL3)(1);\n"
                                         "#else\n" + SHADOW_LINE + "#endif\n")
    trials = tune(cl_device, tmp_path, source=wrong, extra_params={"drop_shadows": [0, 1]},
                  space={**TWO, "work_group_width": (64,)})
    by_switch = {t.extra["drop_shadows"]: t for t in trials}
    assert by_switch[0].verified
    assert not by_switch[1].verified
    assert by_switch[1].pixels_off > 2 and "differ from the default's image" in by_switch[1].problem
    best = tuner_module.best_configuration(trials, ["spheres"])
    assert best[1]["spheres"].extra == {"drop_shadows": 0}


def test_tune_command_stores_the_winner_that_render_then_uses(
        kernel_tuner, cl_device, tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(tuner_module, "default_space", lambda: TWO)
    out = tmp_path / "tuned"
    code = cli.main(["tune", str(SPHERES), "-W", "48", "-H", "27", "--budget", "300",
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "clray: tried 2 configurations" in err and "0 rejected" in err
    assert "clray: verdict: " in err
    assert "study variants not tried (they change the image; --allow-error E tries them)" in err
    report = (out / "report.md").read_text()
    assert "Study variants: not tried" in report and "cl_fast_relaxed_math" in report
    assert "**default**" in report and "**best**" in report
    results = json.loads((out / "results.json").read_text())
    assert len(results["trials"]) == 2
    # The best of Kernel Tuner's runs, or the defaults where interleaved renders did not
    # confirm its gain.
    stored = Tuning(**results["stored"])
    assert stored in (Tuning(**results["best"]["tuning"]), Tuning())
    assert results["tuning_file"]

    def render_stats(*flags: str) -> dict:
        stats = tmp_path / "stats.json"
        assert cli.main(["render", str(SPHERES), "-W", "48", "-H", "27", "-q", "-o",
                         str(tmp_path / "out.png"), "--stats-json", str(stats), *flags]) == 0
        return json.loads(stats.read_text())["tuning"]

    used = render_stats()
    assert used["source"] == f"tuning file {results['tuning_file']}"
    assert used["work_group_width"] == stored.work_group_width
    assert render_stats("--no-tuning")["source"] == "default"
    capsys.readouterr()
    assert cli.main(["devices"]) == 0
    assert f"tuned ({stored.label()})" in capsys.readouterr().out


class FakeSpace:
    """Kernel Tuner's Searchspace, of `size` values of one parameter."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.tune_params = {"block_size_x": list(range(size))}

    def get_true_tunable_params(self) -> dict:
        return self.tune_params

    def sorted_list(self) -> list[tuple]:
        return [(v,) for v in range(self.size)]


class FakeRunner:
    """Kernel Tuner's runner: every configuration it is given timed at 1 ms."""

    def run(self, configurations: list, options: object) -> list[dict]:
        return [{"block_size_x": c[0], "time": 1.0} for c in configurations]


def within_budget(name: str, notes: list[str]) -> tuner_module.StrategyWithinBudget:
    return tuner_module.StrategyWithinBudget(
        name, "spheres", tuner_module.BruteForceWithinBudget({"block_size_x": 3}), notes.append)


@pytest.mark.parametrize(("strategy", "size", "why"), [
    ("pso", 44, "under 150 (3 times its population of 50)"),
    ("greedy_ils", 1, "under 16 (too few to search)"),
])
def test_a_space_too_small_for_the_strategy_is_tried_by_brute_force(kernel_tuner, strategy,
                                                                    size, why) -> None:
    # bayes_opt failed to draw 20 of spheres' 12 configurations; pso, diff_evo and
    # firefly_algorithm failed with IndexError, pso on the one of a later host configuration.
    notes: list[str] = []
    results = within_budget(strategy, notes).tune(FakeSpace(size), FakeRunner(), None)
    assert sorted(r["block_size_x"] for r in results) == list(range(size))
    assert results[0]["block_size_x"] == min(3, size - 1)  # brute force's first, the default
    assert notes == [f"--strategy {strategy} on spheres: {size} kernel configuration"
                     f"{'s' if size > 1 else ''}, {why}: tried whole by brute force, within the "
                     "budget"]


def test_a_strategy_that_lets_the_budgets_end_out_keeps_what_it_timed(kernel_tuner,
                                                                      monkeypatch) -> None:
    # greedy_ils and simulated_annealing let StopCriterionReached out after their first
    # configuration: a traceback, the configurations timed lost.
    def stopped(searchspace, runner, options):
        runner.run([(0,)], options)
        runner.run([(5,)], options)
        raise kernel_tuner.util.StopCriterionReached("max_fevals (2) reached")

    monkeypatch.setitem(kernel_tuner.interface.strategy_map, "stops",
                        SimpleNamespace(tune=stopped))
    notes: list[str] = []
    results = within_budget("stops", notes).tune(FakeSpace(20), FakeRunner(), None)
    assert [r["block_size_x"] for r in results] == [0, 5] and notes == []


def test_a_strategy_that_fails_is_one_line_naming_it(kernel_tuner, monkeypatch) -> None:
    def failing(searchspace, runner, options):
        runner.run([(0,)], options)
        return [][1]

    monkeypatch.setitem(kernel_tuner.interface.strategy_map, "fails",
                        SimpleNamespace(tune=failing))
    with pytest.raises(ClrayError, match=r"^--strategy fails failed on spheres: IndexError: "
                                         r"list index out of range$"):
        within_budget("fails", []).tune(FakeSpace(20), FakeRunner(), None)

    # The runner's own failure (a cache file that cannot be written) is not the strategy's.
    class Full(FakeRunner):
        def run(self, configurations: list, options: object) -> list[dict]:
            raise OSError(28, "No space left on device")

    monkeypatch.setitem(kernel_tuner.interface.strategy_map, "fails",
                        SimpleNamespace(tune=lambda space, runner, options: runner.run([], {})))
    with pytest.raises(OSError, match="No space left"):
        within_budget("fails", []).tune(FakeSpace(20), Full(), None)


def test_a_population_strategy_on_a_tiny_space_tunes(kernel_tuner, cl_device, tmp_path) -> None:
    notes: list[str] = []
    tuner = tuner_module.Tuner(cl_device, tmp_path, strategy="pso", space=TWO, size=SIZE,
                               iterations=2, budget_s=300, say=notes.append)
    trials = tuner.tune([SPHERES])
    assert sorted(t.tuning.work_group_width for t in trials) == [16, 64]
    assert all(t.verified for t in trials)
    assert notes == tuner.notes and notes[-1] == (
        "--strategy pso on spheres: 2 kernel configurations, under 150 (3 times its population "
        "of 50): tried whole by brute force, within the budget")


def test_what_is_said_while_the_bar_shows_is_a_line_of_its_own(capsys) -> None:
    pytest.importorskip("tqdm")
    from clray.tuning import command

    progress = command._Progress(10, show=True)
    progress.through(lambda text: print(f"clray: {text}", file=sys.stderr))("spheres: said")
    progress.close()
    assert "\rclray: spheres: said\n" in capsys.readouterr().err


def test_tune_without_kernel_tuner_says_how_to_install(monkeypatch, capsys, tmp_path) -> None:
    monkeypatch.setitem(sys.modules, "kernel_tuner", None)
    code = cli.main(["tune", str(SPHERES), "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert code == 1
    assert err == ("clray: error: clray tune needs Kernel Tuner, which is not installed: "
                   "pip install 'clray[tune]'\n")
    assert not (tmp_path / "t").exists()


def test_tune_refuses_an_unknown_strategy(kernel_tuner, capsys, tmp_path) -> None:
    code = cli.main(["tune", str(SPHERES), "--strategy", "guesswork", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("clray: error: --strategy: expected one of ") and "brute_force" in err
    assert err.endswith("got 'guesswork'\n")


@pytest.mark.parametrize("name", ["spheres.toml", "Spheres.toml"])
def test_tune_refuses_two_scenes_of_one_name_before_any_work(capsys, tmp_path, name) -> None:
    # Results and caches are kept under the name: the second scene's times were the first's.
    other = tmp_path / "x" / name
    other.parent.mkdir()
    other.write_text((ROOT / "scenes" / "glass.toml").read_text())
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), str(other), "--out", str(out)])
    assert code == 2
    assert capsys.readouterr().err == (
        f"clray: error: SCENE: {SPHERES} and {other} have the same name {other.stem!r}, under "
        "which their results are kept: rename one\n")
    assert not out.exists()
    assert cli.main(["tune", str(SPHERES), str(SPHERES), "--out", str(out)]) == 2
    assert capsys.readouterr().err == f"clray: error: SCENE: {SPHERES} is given twice\n"


def test_an_unwritable_tuning_folder_is_refused_before_tuning(kernel_tuner, cl_device, capsys,
                                                              tmp_path, monkeypatch) -> None:
    # It was a NotADirectoryError traceback from save_tuning after all the work, with nothing
    # written.
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    (tmp_path / "xdg").mkdir()
    (tmp_path / "xdg" / "clray").write_text("")
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), "-W", "32", "-H", "18", "--budget", "1", "--out",
                     str(out)])
    assert code == 1
    assert capsys.readouterr().err == (
        f"clray: error: cannot write {tmp_path / 'xdg' / 'clray' / 'tuning'}: Not a directory "
        "(the device's tuning file goes there; --no-save stores none)\n")
    assert not out.exists()


def test_a_tuning_file_that_fails_to_save_keeps_the_results(kernel_tuner, cl_device, capsys,
                                                            tmp_path, monkeypatch) -> None:
    # The winner was stored before results.json and report.md were written: a failed save lost
    # the whole tuning's results.
    from clray.device.tuning_files import tuning_path

    monkeypatch.setattr(tuner_module, "default_space",
                        lambda: {**TWO, "work_group_width": (64,)})
    tuning_path(cl_device).mkdir(parents=True)  # a folder where the file goes
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), "-W", "48", "-H", "27", "--budget", "300",
                     "--out", str(out)])
    assert code == 1
    assert capsys.readouterr().err.endswith(
        f"clray: error: cannot write {tuning_path(cl_device)}: Is a directory (the results are "
        f"in {out}; nothing stored)\n")
    assert json.loads((out / "results.json").read_text())["tuning_file"] is None
    assert "**default**" in (out / "report.md").read_text()


@pytest.mark.parametrize(("strategy", "module", "package"), [
    ("skopt", "skopt", "scikit-optimize"), ("pyatf_strategies", "pyatf", "pyatf"),
    ("bayes_opt", "sklearn", "scikit-learn")])
def test_tune_refuses_a_strategy_whose_module_is_missing_before_any_work(
        kernel_tuner, capsys, tmp_path, monkeypatch, strategy, module, package) -> None:
    # Kernel Tuner imports them as the strategy starts: a ModuleNotFoundError traceback after
    # the reference render, a cache folder left.
    monkeypatch.setitem(sys.modules, module, None)
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), "-W", "32", "-H", "18", "--budget", "3",
                     "--strategy", strategy, "--out", str(out)])
    assert code == 1
    assert capsys.readouterr().err == (
        f"clray: error: --strategy {strategy} needs the Python module {module}, which is not "
        f"installed: pip install {package}\n")
    assert not out.exists()


def test_tune_refuses_a_bad_scene_before_writing_anything(kernel_tuner, capsys, tmp_path,
                                                          cl_device) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[render]\nwidth = -3\n")
    code = cli.main(["tune", str(bad), "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert code == 3
    assert err == f"clray: error: {bad}: camera: missing required key\n"
    assert not (tmp_path / "t").exists()


def test_tune_refuses_an_unwritable_out_before_tuning(kernel_tuner, capsys, tmp_path,
                                                      cl_device) -> None:
    # Checked before minutes of tuning, as render's -o is, and one line, not a traceback.
    blocker = tmp_path / "file"
    blocker.write_text("")
    code = cli.main(["tune", str(SPHERES), "--budget", "1", "--out", str(blocker / "t")])
    assert code == 1
    assert capsys.readouterr().err == (f"clray: error: cannot write {blocker / 't' / 'report.md'}"
                                       f": {blocker} is a file, not a directory\n")
    with pytest.raises(ClrayError, match=f"^cannot write {blocker / 't'}: "):
        run_tune([SPHERES], blocker / "t", budget_s=1)


@pytest.mark.parametrize(("name", "why"), [("cache", "it is a file, not a directory"),
                                         ("results.json", "it is a directory"),
                                         ("tune.png", "it is a directory")])
def test_tune_refuses_an_output_of_the_wrong_kind_before_tuning(kernel_tuner, capsys, tmp_path,
                                                                name, why) -> None:
    # A file at cache/ was a NotADirectoryError traceback after the reference render; a folder
    # at results.json an IsADirectoryError after the whole tuning, the tuning file saved.
    out = tmp_path / "t"
    out.mkdir()
    (out / name).mkdir() if name.endswith((".json", ".png")) else (out / name).write_text("")
    code = cli.main(["tune", str(SPHERES), "-W", "32", "-H", "18", "--budget", "3", "--out",
                     str(out)])
    assert code == 1
    assert capsys.readouterr().err == f"clray: error: cannot write {out / name}: {why}\n"


def test_tune_writes_that_fail_are_one_line(kernel_tuner, cl_device, tmp_path) -> None:
    from clray.tuning import report

    # After the checks before tuning, as where another process puts a file or folder in the way.
    (tmp_path / "cache").write_text("")
    blocked = f"^cannot write {tmp_path / 'cache'}/.*: Not a directory$"
    with pytest.raises(ClrayError, match=blocked):
        tune(cl_device, tmp_path, size=(32, 18))
    header = {"device": "d", "strategy": "s", "budget_s": 1, "iterations": 1, "tolerance": "t",
              "variants": "v", "untried": None, "notes": [], "best": None,
              "scenes": [str(SPHERES)]}
    trials = [tuner_module.Trial("spheres", Tuning(), 1.0, [1.0], 0.0, True, 0)]
    for name, write in (("results.json", lambda: report.write_results(tmp_path, header, trials)),
                        ("report.md", lambda: report.write_report(tmp_path, header, trials, None,
                                                                  [], None)),
                        ("tune.png", lambda: report.plot(tmp_path, trials, None))):
        (tmp_path / name).mkdir()
        with pytest.raises(ClrayError, match=f"^cannot write {tmp_path / name}: "):
            write()


def test_a_failed_tune_takes_back_the_folders_it_made(kernel_tuner, capsys, tmp_path,
                                                      cl_device) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[render]\nwidth = -3\n")
    code = cli.main(["tune", str(bad), "--out", str(tmp_path / "new" / "t")])
    assert code == 3
    assert capsys.readouterr().err == f"clray: error: {bad}: camera: missing required key\n"
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("budget", ["0", "1"])
def test_a_budget_too_small_to_try_anything_says_so_and_skips_the_plot(
        kernel_tuner, cl_device, tmp_path, capsys, budget) -> None:
    # Only the reference render fits: the plot of no rows was a matplotlib traceback, after
    # results.json and before report.md.
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), "-W", "32", "-H", "18", "--budget", budget,
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    said = f"clray: nothing tried on spheres within the budget of {budget} s: the reference render"
    assert said in err and "leaves a scene untried" in err
    assert "nothing stored" in err
    report = (out / "report.md").read_text()
    assert "**Budget:** nothing tried on spheres" in report
    assert "Nothing tried within the budget." in report
    assert "Plot skipped: nothing was tried." in report
    assert not (out / "tune.png").exists()
    results = json.loads((out / "results.json").read_text())
    assert results["trials"] == [] and results["untried"].startswith("nothing tried on spheres")


def test_the_least_budget_counts_each_scenes_reference_and_a_runs_start() -> None:
    # Scene 0's share (half) must hold its reference and a run's 2 s; scene 1's end (the whole
    # budget) both references and 2 s.
    assert least_budget_s([1.0]) == pytest.approx(3.0)
    assert least_budget_s([1.0, 3.0]) == pytest.approx(6.0)
    assert least_budget_s([3.0, 0.5]) == pytest.approx(10.0)
    runs = [SimpleNamespace(name="a", reference_s=1.0, run_started=True),
            SimpleNamespace(name="b", reference_s=1.0, run_started=True)]
    trial = tuner_module.Trial("a", Tuning(), 1.0, [1.0], 0.0, True, 0)
    assert untried(runs, [trial], 100.0) == (
        "nothing tried on b within the budget of 100 s: Kernel Tuner's runs started, but the "
        "budget ended before their first configuration was timed")
    runs[1].run_started = False
    assert untried(runs, [trial], 5.0) == (
        "nothing tried on b within the budget of 5 s: the reference renders took 2 s of it, and "
        "a Kernel Tuner run starts only while 2 s of a scene's share is left: a budget under "
        "6 s leaves a scene untried")
    assert untried(runs[:1], [trial], 5.0) is None


def test_a_scene_whose_share_earlier_runs_took_is_not_told_its_runs_started(
        kernel_tuner, cl_device, tmp_path, monkeypatch) -> None:
    # A budget over least_budget_s was said as "Kernel Tuner's runs started" for every untried
    # scene, also for one whose share the first scene's run (builds take 5 to 25 s) had taken.
    skew = [0.0]
    monkeypatch.setattr(tuner_module, "time", SimpleNamespace(
        monotonic=lambda: time.monotonic() + skew[0]))

    def slow_run(self, run, host, time_limit, kernel_space):
        skew[0] += time_limit + 100.0  # past the end of the whole budget, timing nothing
        return []

    monkeypatch.setattr(tuner_module.Tuner, "run_host", slow_run)
    tuner = tuner_module.Tuner(cl_device, tmp_path, space=TWO, size=(32, 18), budget_s=100)
    trials = tuner.tune([SPHERES, FRESNEL])
    assert [run.run_started for run in tuner.runs] == [True, False]
    assert untried(tuner.runs, trials, 100) == (
        "nothing tried on spheres within the budget of 100 s: Kernel Tuner's runs started, but "
        "the budget ended before their first configuration was timed; nothing tried on fresnel "
        "within the budget of 100 s: no Kernel Tuner run started there: earlier scenes' runs "
        "left under 2 s of the scene's share, the least a run starts with")


def test_the_plot_is_written_whole_or_not_at_all(tmp_path, monkeypatch) -> None:
    # It was saved straight into tune.png: a full disk left half a PNG, and a traceback.
    pytest.importorskip("matplotlib")
    from clray.tuning import report

    def full_disk(source: object, target: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("os.replace", full_disk)
    trials = [tuner_module.Trial("spheres", Tuning(), 1.0, [1.0], 0.0, True, 0)]
    with pytest.raises(ClrayError) as info:
        report.plot(tmp_path, trials, None)
    assert str(info.value) == f"cannot write {tmp_path / 'tune.png'}: No space left on device"
    assert list(tmp_path.iterdir()) == []


def test_each_image_size_has_its_own_cache_and_a_broken_one_is_one_line(
        kernel_tuner, cl_device, tmp_path) -> None:
    # Kernel Tuner refuses a cache file of another image size: with one per scene, a second
    # tune at another size into the same --out (by default clray-tune) was its traceback.
    one = {**TWO, "work_group_width": (64,)}
    tune(cl_device, tmp_path, size=(32, 18), space=one)
    assert tune(cl_device, tmp_path, size=(40, 18), space=one)
    (device,) = (tmp_path / "cache").iterdir()
    sizes = sorted((device / "spheres").iterdir())
    assert [p.name.split("-")[0] for p in sizes] == ["32x18", "40x18"]
    (cache,) = sizes[0].glob("default-*.json")
    record = cache.read_text()
    refused = f"^Kernel Tuner's cache file {re.escape(str(cache))}: .+: delete it, or tune into " \
              "another --out$"
    # Empty or cut short mid-entry (Kernel Tuner's JSONDecodeError), read as they are, not
    # 'mended'; another kernel's (its ValueError).
    for text in ("", record[:-40]):
        cache.write_text(text)
        with pytest.raises(ClrayError, match=refused):
            tune(cl_device, tmp_path, size=(32, 18), space=one)
        assert cache.read_text() == text
    cache.write_text(record.replace('"render"', '"other"'))
    with pytest.raises(ClrayError, match=refused):
        tune(cl_device, tmp_path, size=(32, 18), space=one)


def test_configurations_that_differ_late_have_their_own_cache_files(
        kernel_tuner, cl_device, tmp_path, monkeypatch) -> None:
    # Named by the label cut at 120 characters, these two shared one file under --allow-error:
    # the second took the first's times and image verdicts from it.
    caches = []

    def no_run(*args, **kwargs):
        caches.append(kwargs["cache"])
        return [], {}

    monkeypatch.setattr(kernel_tuner.interface, "tune_kernel", no_run)
    tuner = tuner_module.Tuner(cl_device, tmp_path, space=TWO, size=(32, 18), allow_error=0.5)
    run = tuner.prepare(SPHERES)
    many = Tuning(bvh_width=4, traversal_cost=2.0, max_leaf_size=8, largest_leaf=32,
                  fold_packets=8, cl_mad_enable=True, cl_unsafe_math_optimizations=True)
    assert len(many.label()) > 120
    for fast in (False, True):
        host = {name: getattr(many, name) for name in tuner_module.OUTER_KNOBS}
        tuner.run_host(run, {**host, "cl_fast_relaxed_math": fast}, 100.0,
                       {**tuner.block_params(), **tuner.kernel_params()})
    assert len(set(caches)) == 2
    assert all(Path(c).name.startswith("bvh_width=4_traversal_cost=2.0") for c in caches)


def test_kernel_tuner_builds_with_the_devices_build_options(kernel_tuner, cl_device,
                                                            tmp_path, monkeypatch) -> None:
    # What renders build on a GPU (a pixel a work-item), here a CPU device built as one: the
    # builds Kernel Tuner times take the same options, and their cached verdicts are apart.
    calls = record_tune_kernel(kernel_tuner, monkeypatch)
    one = {**TWO, "work_group_width": (64,)}
    tune(cl_device, tmp_path, space=one)
    with program.built_as_for_a_gpu():
        trials = tune(cl_device, tmp_path, space=one)
    (cpu, _), (gpu, _) = [(kwargs["compiler_options"], kwargs["cache"]) for _, kwargs in calls]
    assert GPU_BUILD_OPTIONS[0] in gpu and GPU_BUILD_OPTIONS[0] not in cpu
    assert trials and all(t.verified for t in trials)
    (device,) = (tmp_path / "cache").iterdir()
    assert len(list((device / "spheres").iterdir())) == 2


def test_an_edited_scene_or_tolerance_takes_no_cached_verdict(kernel_tuner, cl_device,
                                                              tmp_path) -> None:
    # Kernel Tuner's cache holds each configuration's image verdict beside its times: an
    # edited scene of the same name, or another --allow-error, must not take them.
    one = {**TWO, "work_group_width": (64,)}
    scene = tmp_path / "spheres.toml"
    scene.write_text(SPHERES.read_text())
    out = tmp_path / "out"

    def folders() -> list[str]:
        (device,) = (out / "cache").iterdir()
        return sorted(p.name for p in (device / "spheres").iterdir())

    tune(cl_device, out, scene, space=one)
    first = folders()
    tune(cl_device, out, scene, space=one)
    assert folders() == first  # unchanged: the same cache, taken again
    scene.write_text(SPHERES.read_text().replace("max_depth = 4", "max_depth = 1"))
    tune(cl_device, out, scene, space=one)
    assert len(folders()) == 2
    tune(cl_device, out, scene, space=one, allow_error=0.5)
    assert len(folders()) == 3


def test_later_host_configurations_keep_the_best_kernel_knobs(kernel_tuner, cl_device,
                                                              tmp_path) -> None:
    trials = tune(cl_device, tmp_path, space={**TWO, "traversal_cost": (1.5, 1.0)})
    first = [t for t in trials if t.tuning.traversal_cost == 1.5]
    later = [t for t in trials if t.tuning.traversal_cost == 1.0]
    assert sorted(t.tuning.work_group_width for t in first) == [16, 64]
    best = min(first, key=lambda t: t.time_ms)
    assert [t.tuning.work_group_width for t in later] == [best.tuning.work_group_width]
    assert all(t.verified for t in trials)


def test_tune_tries_both_traversals_as_kernel_defines_and_picks_one(
        kernel_tuner, cl_device, tmp_path, monkeypatch) -> None:
    calls = record_tune_kernel(kernel_tuner, monkeypatch)
    trials = tune(cl_device, tmp_path, spheres_at(tmp_path, 16),
                  space={**TWO, "work_group_width": (64,),
                         "traversal": ("single", "sample_packet")})
    # One Kernel Tuner run, the traversal its #define TRAVERSAL, no longer a compiler option.
    [(params, options)] = [(args[4], kwargs["compiler_options"]) for args, kwargs in calls]
    assert params["TRAVERSAL"] == [0, 1]
    assert not any(o.startswith(("-DTRAVERSAL=", "-DPACKET_")) for o in options)
    # The device's own traversal is the knob's None (the default's key).
    own = own_traversal(cl_device, 16)
    assert sorted(t.tuning.traversal or own for t in trials) == ["sample_packet", "single"]
    assert all(t.verified and t.time_ms > 0 and t.compile_ms > 0 for t in trials)
    other = next(name for name in TRAVERSALS if name != own)
    assert {t.tuning for t in trials} == {Tuning(), Tuning(traversal=other)}
    best = tuner_module.best_configuration(trials, ["spheres"])
    assert best[1]["spheres"].tuning == min(trials, key=lambda t: t.time_ms).tuning


def test_scenes_whose_own_walks_differ_can_share_a_named_walk(kernel_tuner, cl_device,
                                                              tmp_path) -> None:
    # At 1 spp the device's own walk is the single-ray one; at 16 spp sample packets on the
    # CPU drivers. A trial's knobs name the walk only where it is not the scene's own, so
    # traversal single had no key on both scenes, and could never be chosen.
    if own_traversal(cl_device, 16) == own_traversal(cl_device, 1):
        pytest.skip("this device's own walk is the same at 1 and at 16 spp")
    (tmp_path / "many").mkdir()
    many = spheres_at(tmp_path / "many", 16).rename(tmp_path / "many.toml")
    one = tmp_path / "one.toml"
    one.write_text(SPHERES.read_text(encoding="utf-8"), encoding="utf-8")
    tuner = tuner_module.Tuner(cl_device, tmp_path / "out", size=SIZE, iterations=1,
                               budget_s=300, space={**TWO, "work_group_width": (64,),
                                                    "traversal": (None, "single")})
    trials = tuner.tune([many, one])
    assert all(t.verified for t in trials)
    # Make the single-ray walk the fastest on the 16-spp scene: single is the best for both.
    for t in trials:
        t.time_ms = 1.0 if (t.scene, t.tuning.traversal) == ("many", "single") else 10.0
    key, per_scene = tuner_module.best_configuration(trials, ["many", "one"])
    assert tuner_module.key_tuning(key) == Tuning(traversal="single")
    assert {s: t.tuning for s, t in per_scene.items()} == {
        "many": Tuning(traversal="single"), "one": Tuning()}
    # And where sample packets are faster, the device's own walk, left None.
    for t in trials:
        t.time_ms = 10.0 if (t.scene, t.tuning.traversal) == ("many", "single") else 1.0
    assert tuner_module.key_tuning(
        tuner_module.best_configuration(trials, ["many", "one"])[0]) == Tuning()


def test_packet_knobs_act_only_with_sample_packets_and_below_the_lanes(
        kernel_tuner, cl_device, tmp_path) -> None:
    trials = tune(cl_device, tmp_path, spheres_at(tmp_path, 16), space={
        **TWO, "work_group_width": (64,), "traversal": ("single", "sample_packet"),
        "packet_lanes": (4,), "packet_min_lanes": (2, 4)})
    # Single rays once, with the default packet knobs, which they ignore; packets of 4 lanes
    # (no CPU's own width, so not folded into the default) with 2 (4 is not below 4).
    own = own_traversal(cl_device, 16)

    def knob(traversal: str) -> str | None:
        return None if traversal == own else traversal

    assert {t.tuning for t in trials} == {
        Tuning(traversal=knob("single")),
        Tuning(traversal=knob("sample_packet"), packet_lanes=4, packet_min_lanes=2)}


def test_group_packets_are_searched_in_square_tiles(kernel_tuner, cl_device, tmp_path) -> None:
    trials = tune(cl_device, tmp_path, space={
        **TWO, "work_group_width": (64,), "traversal": ("single", "group_packet"),
        "group_side": (4, 8)})
    # Single rays in row segments of 64 (at 1 spp the default's walk); group packets in tiles
    # of 4 x 4 and 8 x 8, each verified against the default's image.
    assert {t.tuning for t in trials} == {
        Tuning(),
        Tuning(traversal="group_packet"),
        Tuning(traversal="group_packet", group_side=8)}
    assert all(t.verified and t.time_ms > 0 for t in trials)


VARIANTS = {**TWO, "work_group_width": (64,), "fresnel_schlick": (False, True),
            "cl_mad_enable": (False, True)}


def test_study_variants_are_not_tried_without_allow_error(kernel_tuner, cl_device,
                                                          tmp_path) -> None:
    trials = tuner_module.Tuner(cl_device, tmp_path, space=VARIANTS, size=SIZE, iterations=2,
                                budget_s=300).tune([FRESNEL])
    assert [t.tuning for t in trials] == [Tuning()]


def test_study_variants_are_tried_under_allow_error_and_rejected_beyond_it(
        kernel_tuner, cl_device, tmp_path) -> None:
    trials = tuner_module.Tuner(cl_device, tmp_path, space=VARIANTS, size=SIZE, iterations=2,
                                budget_s=300, allow_error=1e-4).tune([FRESNEL])
    # The default build's run tries Schlick's Fresnel, rejected; the -cl-mad-enable run keeps
    # the best kernel knobs found (as every later host or build configuration does).
    assert [(t.tuning.cl_mad_enable, t.tuning.fresnel_schlick) for t in trials] == [
        (False, False), (False, True), (True, False)]
    default = next(t for t in trials if t.tuning == Tuning())
    assert default.verified
    # Schlick's approximation moves the glass balls' rims by far more than 1e-4.
    schlick = [t for t in trials if t.tuning.fresnel_schlick]
    assert all(not t.verified and "by over 0.0001" in t.problem for t in schlick)
    best = tuner_module.best_configuration(trials, ["fresnel"])
    assert not best[1]["fresnel"].tuning.fresnel_schlick


def test_plot_keeps_long_configuration_labels_inside_the_figure() -> None:
    pytest.importorskip("matplotlib", reason="plots are the 'plot' extra")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from clray.tuning import report

    many = Tuning(work_group_width=128, bvh_width=8, traversal_cost=2.5, max_leaf_size=8,
                  largest_leaf=32, fold_packets=8, cl_mad_enable=True,
                  cl_unsafe_math_optimizations=True, sphere_textbook=True,
                  triangle_moller_trumbore=True, launch_seconds=0.5)
    trials = [tuner_module.Trial(scene, tuning, ms, [ms], 100.0, True, 0)
              for scene in ("spheres", "fresnel")
              for tuning, ms in ((Tuning(), 3.0), (many, 2.0), (Tuning(work_group_width=16), 2.5))]
    fig = report.plot_figure(trials, trials[1].key())
    renderer = fig.canvas.get_renderer()
    texts = [t for ax in fig.axes for t in (*ax.get_yticklabels(), ax.xaxis.label, ax.title)]
    assert any("launch_seconds=0.5" in t.get_text() for t in texts)
    for text in texts:
        box = text.get_window_extent(renderer)
        assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1, text.get_text()
        assert fig.bbox.y0 <= box.y0 and box.y1 <= fig.bbox.y1, text.get_text()
    plt.close(fig)


def confirmation(ratios: list[float], scene: str = "spheres") -> dict:
    """A confirm() record whose rounds' paired ratios (default / tuned) are `ratios`."""
    return tuner_module.confirmation(scene, list(ratios), [1.0] * len(ratios))


def stored_rate(rng: np.random.Generator, trials: int, rounds: int, gain: float,
                noise: Callable[[np.random.Generator, int], np.ndarray]) -> float:
    """The share of `trials` tunes whose winner the rule stores, where the winner's renders are
    `gain` times as fast as the default's and each render's time carries `noise` (a factor)."""
    stored = 0
    for _ in range(trials):
        load = np.exp(rng.normal(0, 0.3, rounds))  # the machine's load, shared by a round
        default = load * noise(rng, rounds)
        tuned = load * noise(rng, rounds) / gain
        record = tuner_module.confirmation("spheres", list(default), list(tuned))
        stored += tuner_module.confirmed_gain([record])["confirmed"]
    return stored / trials


def lognormal(sigma: float) -> Callable[[np.random.Generator, int], np.ndarray]:
    return lambda rng, n: np.exp(rng.normal(0, sigma, n))


def spiky(rng: np.random.Generator, n: int) -> np.ndarray:
    """Mostly quiet, and one render in 10 slowed by half by another process."""
    return np.exp(rng.normal(0, 0.01, n)) * np.where(rng.random(n) < 0.1, 1.5, 1.0)


@pytest.mark.parametrize("rounds", [tuner_module.MIN_CONFIRM_ROUNDS,
                                    tuner_module.MAX_CONFIRM_ROUNDS])
@pytest.mark.parametrize("noise", [lognormal(0.01), lognormal(0.1), spiky],
                         ids=["quiet", "noisy", "spiky"])
def test_a_winner_no_faster_than_the_default_is_stored_under_1_time_in_100(rounds,
                                                                          noise) -> None:
    # With the rule before (store where three rounds in four were faster) the default
    # confirmed against itself was stored about 1 time in 5 at 5 rounds, and 2 times in 12 on
    # glass at 400x225.
    rate = stored_rate(np.random.default_rng(rounds), 20_000, rounds, 1.0, noise)
    assert rate < tuner_module.CONFIRM_P


@pytest.mark.parametrize(("rounds", "sigma"), [(tuner_module.MIN_CONFIRM_ROUNDS, 0.03),
                                               (tuner_module.MAX_CONFIRM_ROUNDS, 0.06)])
def test_a_real_ten_per_cent_gain_is_stored(rounds, sigma) -> None:
    rate = stored_rate(np.random.default_rng(7), 400, rounds, 1.10, lognormal(sigma))
    assert rate > 0.95


@pytest.mark.parametrize(("ratios", "stored"), [
    ([1.30] * 14, True),  # every round faster: a gain
    ([1.10] * 12 + [0.95] * 2, True),  # 12 of 14 faster: p = 0.0065
    ([1.10] * 11 + [0.95] * 3, False),  # 11 of 14: p = 0.029, could be noise
    ([1.01] * 14, False),  # every round faster, by 1 %: too small to store
    ([2.00] * 4 + [0.99] * 10, False),  # a few lucky rounds claim 2x
    ([0.90] * 14, False),  # slower
])
def test_a_winner_is_stored_only_where_the_sign_test_and_the_gain_say_so(ratios,
                                                                          stored) -> None:
    verdict = tuner_module.confirmed_gain([confirmation(ratios)])
    assert verdict["confirmed"] is stored
    assert verdict["gain"] == pytest.approx(statistics.median(ratios))
    assert verdict["faster_rounds"] == sum(r > 1 for r in ratios) and verdict["rounds"] == 14
    lower, upper = verdict["quartiles"]
    assert lower <= verdict["gain"] <= upper


def test_the_sign_test_and_the_rounds() -> None:
    assert tuner_module.sign_test_p(14, 14) == pytest.approx(1 / 2**14)
    assert tuner_module.sign_test_p(12, 14) == pytest.approx(106 / 2**14)  # 0.0065
    assert tuner_module.sign_test_p(7, 7) < 0.01 < tuner_module.sign_test_p(6, 6)
    assert tuner_module.sign_test_p(0, 14) == 1
    # At least 14 rounds, at most 40, as many as make a second of renders a side; even.
    assert tuner_module.confirm_rounds(1.0) == 14
    assert tuner_module.confirm_rounds(1 / 29) == 30
    assert tuner_module.confirm_rounds(0.001) == tuner_module.confirm_rounds(0.0) == 40


def test_every_scene_counts_in_the_verdict() -> None:
    # A clear gain on one scene and a loss on the other: each round's geometric mean decides.
    gain = confirmation([1.5] * 14)
    loss = confirmation([0.6] * 14, "glass")
    assert not tuner_module.confirmed_gain([gain, loss])["confirmed"]
    assert tuner_module.confirmed_gain([gain, confirmation([1.0] * 14, "glass")])["confirmed"]


def test_the_confirmation_alternates_which_side_renders_first(monkeypatch) -> None:
    # Where a render is faster for following the other (a warm cache), always rendering the
    # default first made the default against itself a 1.11x gain in every round.
    rendered: list[str] = []

    def render(packed: str, device: object) -> tuple[None, dict]:
        rendered.append(packed)
        return None, {"kernel_s": 0.1 if len(rendered) % 2 else 0.09}

    monkeypatch.setattr(tuner_module, "load_scene", lambda path: None)
    monkeypatch.setattr(tuner_module, "pack_for", lambda scene, settings, device: "tuned")
    monkeypatch.setattr(tuner_module, "render_packed", render)
    run = SimpleNamespace(name="spheres", path=SPHERES, default_packed="default",
                          settings=SimpleNamespace(width=4, height=4))
    [record] = tuner_module.confirm([run], Tuning(), None)
    assert rendered[:6] == ["default", "tuned", "default", "tuned", "tuned", "default"]
    assert record["rounds"] == tuner_module.MIN_CONFIRM_ROUNDS
    assert record["faster_rounds"] == 7
    assert not tuner_module.confirmed_gain([record])["confirmed"]


def test_an_image_too_small_to_time_is_said_at_once(kernel_tuner, cl_device, tmp_path) -> None:
    said: list[str] = []
    tuner = tuner_module.Tuner(cl_device, tmp_path, space=TWO, size=SIZE, say=said.append)
    tuner.prepare(SPHERES)  # before any configuration is tried
    assert len(said) == 1 and tuner.notes == said
    assert re.fullmatch(r"spheres: the default renders 48x27 in .* ms, too short to time .*: "
                        r"Kernel Tuner's times are mostly noise, and a winner is stored only "
                        r"where the interleaved renders confirm it; tune at the size you "
                        r"render, or larger \(-W, -H\)", said[0])


def test_configurations_kernel_tuner_did_not_time_say_why_in_words(kernel_tuner) -> None:
    from kernel_tuner import util

    assert tuner_module.failure({"time": util.CompilationFailedConfig(),
                                 "__error__": util.CompilationFailedConfig()}) == (
        "failed: the kernel build failed")
    # Read back from Kernel Tuner's cache file, the error is its class name as text.
    assert tuner_module.failure({"time": "InvalidConfig"}) == (
        "failed: not a valid configuration on this device")
    assert tuner_module.failure({"time": util.RuntimeFailedConfig()}).startswith(
        "failed: the launch failed")
    assert tuner_module.failure({"time": None}) == "failed: not timed"


def test_counts_of_one_take_the_singular(kernel_tuner, tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(tuner_module, "default_space",
                        lambda: {**TWO, "work_group_width": (64,)})
    out = tmp_path / "tuned"
    code = cli.main(["tune", str(SPHERES), "-W", "48", "-H", "27", "--budget", "300",
                     "--out", str(out), "--no-save"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "clray: tried 1 configuration on " in err
    report = (out / "report.md").read_text()
    assert "1 configuration tried, 0 rejected" in report
    # The default won: nothing rendered to confirm it, and --no-save stores nothing (it said
    # "storing the defaults").
    assert "clray: verdict: the best is the default configuration, nothing to confirm\n" in err
    assert "clray: best: default; nothing stored (--no-save)\n" in err and "storing" not in err
    assert "**Verdict:** the best is the default configuration, nothing to confirm." in report
    assert "**Decision:** nothing stored (--no-save)." in report
    results = json.loads((out / "results.json").read_text())
    assert results["confirmed"] == [] and results["verdict"] is None
    assert results["stored"] is None and results["tuning_file"] is None
    # 48 x 27 renders in about a millisecond: said at once, and in the report and results.
    too_short = "spheres: the default renders 48x27 in "
    assert err.startswith(f"clray: {too_short}")
    assert f"**Note:** {too_short}" in report and results["notes"][0].startswith(too_short)


@pytest.mark.parametrize(("ratios", "save", "verdict", "decision", "last"), [
    ([1.1] * 14, False,
     "work_group_width=16 at 1.100x (median of 14 rounds' ratios of default to tuned kernel "
     "time, middle half 1.100x to 1.100x), faster in 14 of 14 rounds (sign test p = 6.1e-05): "
     "confirmed", "nothing stored (--no-save)", "nothing stored (--no-save)"),
    ([1.1] * 7 + [0.95] * 7, True,
     "work_group_width=16 at 1.025x (median of 14 rounds' ratios of default to tuned kernel "
     "time, middle half 0.950x to 1.100x), faster in 7 of 14 rounds (sign test p = 0.6): not "
     "confirmed (storing needs p < 0.01 and at least 1.02x)",
     "storing the defaults as the device's tuning file", "stored the defaults in "),
    ([1.1] * 14, True, None, "storing work_group_width=16 as the device's tuning file",
     "stored work_group_width=16 in "),
])
def test_the_verdict_is_said_with_its_figures_in_one_statistic(
        kernel_tuner, tmp_path, monkeypatch, capsys, ratios, save, verdict, decision,
        last) -> None:
    # The report had no verdict, and stderr said "0.999x in interleaved renders ... storing the
    # defaults" beside "spheres: ... (1.070x, interleaved renders)": a median of ratios beside
    # a ratio of medians.
    from clray.tuning import command

    def tuned(self, paths):
        self.runs = [SimpleNamespace(name="spheres", reference_s=0.1, run_started=True)]
        return [tuner_module.Trial("spheres", Tuning(), 2.0, [2.0], 0.0, True, 0),
                tuner_module.Trial("spheres", Tuning(work_group_width=16), 1.0, [1.0], 0.0,
                                   True, 0)]

    monkeypatch.setattr(command.Tuner, "tune", tuned)
    monkeypatch.setattr(command, "confirm", lambda runs, tuning, device: [
        tuner_module.confirmation("spheres", [r * 0.01 for r in ratios], [0.01] * 14)])
    out = tmp_path / "t"
    code = cli.main(["tune", str(SPHERES), "--out", str(out), *([] if save else ["--no-save"])])
    err = capsys.readouterr().err
    assert code == 0, err
    report = (out / "report.md").read_text()
    header = json.loads((out / "results.json").read_text())
    if verdict is None:  # the same ratios, stored: the verdict as in the first case
        assert header["verdict"]["confirmed"] and header["stored"]["work_group_width"] == 16
        verdict = err.split("clray: verdict: ")[1].split("\n")[0]
    # Each scene's speed-up is the verdict's statistic: with one scene, the same figures.
    lower, speedup, upper = statistics.quantiles(ratios, n=4, method="inclusive")
    figures = f"{speedup:.3f}x (median of 14 rounds' ratios"
    assert (f"clray: spheres: {figures}, middle half {lower:.3f}x to {upper:.3f}x), faster in "
            f"{sum(r > 1 for r in ratios)} of 14 rounds; the default renders in ") in err
    assert f" at {figures} of default to tuned kernel time, middle half {lower:.3f}x" in verdict
    assert f"clray: verdict: {verdict}\n" in err
    assert f"**Verdict:** {verdict}." in report and f"**Decision:** {decision}." in report
    assert f"clray: best: work_group_width=16; {last}" in err
    assert header["decision"] == decision and header["verdict"]["rounds"] == 14


@pytest.mark.parametrize(("image", "reason"), [
    (np.array([[[0.5, 0, 0], [0, 0, 0]]], np.float32),
     "1 pixel differs from the default's image by over 0.01 (at most 0 may)"),
    (np.array([[[0.5, 0, 0], [0.5, 0, 0]]], np.float32),
     "2 pixels differ from the default's image by over 0.01 (at most 0 may)"),
    (np.array([[[np.nan, 0, 0], [0, 0, 0]]], np.float32),
     "1 more non-finite pixel than the default"),
])
def test_rejections_count_pixels_in_the_right_form(image, reason) -> None:
    tolerance = tuner_module.Tolerance(0.01, 0)
    assert tolerance.check(image, np.zeros((1, 2, 3), np.float32))[2] == reason


def test_implicit_vectorization_is_never_tried_with_sample_packets(kernel_tuner, cl_device,
                                                                  tmp_path) -> None:
    # Intel's CPU runtime renders wrong images with both; the device's own walk (TRAVERSAL's
    # None) is sample packets at 16 spp on the CPU drivers, so the walk built is what counts.
    tuner = tuner_module.Tuner(cl_device, tmp_path)
    tuner.set_scene_spp(16)
    space = {**tuner.block_params(), **tuner.kernel_params()}
    legal = [params for values in itertools.product(*space.values())
             if tuner._legal(Tuning(), params := dict(zip(space, values, strict=True)), space)]
    packets = TRAVERSALS.index("sample_packet")
    assert {(p["TRAVERSAL"] == packets, p["IMPLICIT_VECTORIZATION"]) for p in legal} == {
        (True, 0), (False, 0), (False, 1)}


def test_the_docs_count_a_runs_kernel_configurations(kernel_tuner, cl_device, tmp_path) -> None:
    # docs/tuning.md counts the kernel configurations Kernel Tuner's restriction leaves of the
    # table's tried values, on PoCL: at 2 or more samples a pixel, and at 1.
    if cl_device.platform.name.strip() != "Portable Computing Language":
        pytest.skip("docs/tuning.md counts PoCL's configurations")
    text = " ".join((ROOT / "docs" / "tuning.md").read_text(encoding="utf-8").split())
    packed = re.search(r"a run on PoCL has (\d+) kernel configurations for a scene of 2 or more "
                       r"samples a pixel", text)
    single = re.search(r"the packet knobs are not searched \((\d+) kernel configurations", text)
    assert packed and single, "docs/tuning.md no longer counts a run's kernel configurations"
    tuner = tuner_module.Tuner(cl_device, tmp_path)
    for spp, found in ((16, packed), (2, packed), (1, single)):
        tuner.set_scene_spp(spp)
        space = {**tuner.block_params(), **tuner.kernel_params()}
        legal = [values for values in itertools.product(*space.values())
                 if tuner._legal(Tuning(), dict(zip(space, values, strict=True)), space)]
        assert len(legal) == int(found.group(1)), f"{spp} spp"
