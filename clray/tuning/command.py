"""`clray tune SCENE...`: the tuner over the scenes within the budget, the winner confirmed
against the default in interleaved renders and stored as the device's tuning file, and the
results, report and plot written to the output folder."""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pyopencl as cl

from clray.device.context import describe, select_device
from clray.device.tuning_files import save_tuning, tuning_path
from clray.errors import ClrayError, plural
from clray.knobs import DEFAULT_TUNING, IMAGE_KNOBS, Tuning
from clray.output import cannot_write, refuse_a_folder
from clray.scene.load import load_scene
from clray.tuning import report
from clray.tuning.tuner import (
    MIN_RUN_BUDGET_S,
    PIXEL_TOLERANCE,
    SceneRun,
    Trial,
    Tuner,
    best_configuration,
    confirm,
    confirmed_gain,
    key_tuning,
)


class _Progress:
    """A tqdm bar over the budget's seconds, with the best verified time so far."""

    def __init__(self, budget_s: float, show: bool) -> None:
        self.start = time.monotonic()
        self.budget_s = budget_s
        self.best: dict[str, float] = {}
        self.bar: Any = None
        if show:
            from tqdm import tqdm

            self.bar = tqdm(total=round(budget_s), desc="clray: tuning", unit="s",
                            file=sys.stderr, leave=False, dynamic_ncols=True)

    def __call__(self, scene: str, trial: Trial) -> None:
        if trial.verified and trial.time_ms < self.best.get(scene, float("inf")):
            self.best[scene] = trial.time_ms
        if self.bar is not None:
            elapsed = min(round(time.monotonic() - self.start), self.bar.total)
            self.bar.update(elapsed - self.bar.n)
            self.bar.set_postfix_str(", ".join(f"{s} best {ms:.3g} ms"
                                               for s, ms in self.best.items()))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def through(self, say: Callable[[str], None]) -> Callable[[str], None]:
        """`say`, with the bar cleared for the line and drawn again after it."""
        if self.bar is None:
            return say

        def said(text: str) -> None:
            with self.bar.external_write_mode(file=sys.stderr):
                say(text)

        return said


def least_budget_s(reference_s: Sequence[float]) -> float:
    """The budget under which some scene can start no Kernel Tuner run, from the seconds each
    scene's reference render took: scene k's share ends at budget * (k + 1) / n, by when the
    references of scenes 0 to k have taken their time, and a run starts only while
    MIN_RUN_BUDGET_S of it is left. A lower bound: earlier scenes' runs, where they start, take
    time too."""
    n = len(reference_s)
    return max(n * (sum(reference_s[: k + 1]) + MIN_RUN_BUDGET_S) / (k + 1) for k in range(n))


def untried(runs: Sequence[SceneRun], trials: Sequence[Trial], budget_s: float) -> str | None:
    """The scenes on which nothing was tried within the budget and why, in words: those whose
    Kernel Tuner runs started, and those on which none did; None where every scene had a
    configuration tried."""
    least = least_budget_s([run.reference_s for run in runs])
    if least > budget_s:
        spent = sum(run.reference_s for run in runs)
        not_started = (f"the {'reference render' if len(runs) == 1 else 'reference renders'} "
                       f"took {spent:.2g} s of it, and a Kernel Tuner run starts only while "
                       f"{MIN_RUN_BUDGET_S:g} s of a scene's share is left: a budget under "
                       f"{least:.3g} s leaves a scene untried")
    else:  # the reference renders left the scene a run's start: earlier scenes' runs took it
        not_started = (f"no Kernel Tuner run started there: earlier scenes' runs left under "
                       f"{MIN_RUN_BUDGET_S:g} s of the scene's share, the least a run starts "
                       "with")
    why = {True: "Kernel Tuner's runs started, but the budget ended before their first "
                 "configuration was timed",
           False: not_started}
    left = [run for run in runs if not any(t.scene == run.name for t in trials)]
    said = [f"nothing tried on {', '.join(names)} within the budget of {budget_s:g} s: {text}"
            for started, text in why.items()
            if (names := [run.name for run in left if run.run_started == started])]
    return "; ".join(said) or None


def check_outputs(out: Path) -> None:
    """Before tuning, where it costs a look: an output of `out` whose name is taken by the wrong
    kind (a folder where a file goes, or the other way round) would fail after all the work."""
    for name in ("results.json", "report.md", report.PLOT_NAME):
        refuse_a_folder(out / name)
    cache = out / "cache"
    if os.path.lexists(cache) and not cache.is_dir():
        raise cannot_write(cache, "it is a file, not a directory")


def run_tune(paths: Sequence[Path], out: Path, *, device: str | None = None,
             strategy: str = "brute_force", budget_s: float = 120.0,
             allow_error: float | None = None, size: tuple[int | None, int | None] = (None, None),
             save: bool = True, show_progress: bool = False,
             say: Callable[[str], None] = lambda _: None, **tuner_options: Any) -> dict:
    """Tune, confirm, store and report; returns the results' header with the winner."""
    if out.exists() and not out.is_dir():
        raise ClrayError(f"--out {out} exists and is not a directory")
    check_outputs(out)
    cl_device = select_device(device)
    for path in paths:  # a bad scene is one line before anything is written
        load_scene(path)
    _make_folders(out, cl_device, save)
    progress = _Progress(budget_s, show_progress)
    tuner = Tuner(cl_device, out, strategy=strategy, budget_s=budget_s,
                  allow_error=allow_error, size=size, progress=progress,
                  say=progress.through(say), **tuner_options)
    try:
        trials = tuner.tune(paths)
    finally:
        progress.close()
    scenes = [p.stem for p in paths]
    best = best_configuration(trials, scenes)
    header = _results_header(cl_device, paths, strategy, budget_s, allow_error, tuner, trials)
    confirmed: list[dict] = []
    to_store: Tuning | None = None
    if best is not None:
        confirmed, to_store = _judge_winner(header, best, tuner, scenes, cl_device, save)
    header["confirmed"] = confirmed
    report.write_results(out, header, trials)
    plot_skipped = report.plot(out, trials, best[0] if best else None)
    report.write_report(out, header, trials, best[0] if best else None, confirmed, plot_skipped)
    if to_store is not None:
        # Stored after the results are written: a tuning folder that fails now loses the
        # stored winner, not the tuning's results.
        _store_winner(out, header, trials, cl_device, to_store, strategy, budget_s)
    _say_outcome(say, header, trials, confirmed, to_store, cl_device)
    return header


def _make_folders(out: Path, cl_device: cl.Device, save: bool) -> None:
    """The results' folder, and with `save` the device's tuning folder."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise cannot_write(out, err) from err
    if save:  # the winner's folder, made before the work that finds it
        folder = tuning_path(cl_device).parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise cannot_write(folder, err, "the device's tuning file goes there; --no-save "
                                            "stores none") from err


def _results_header(cl_device: cl.Device, paths: Sequence[Path], strategy: str, budget_s: float,
                    allow_error: float | None, tuner: Tuner, trials: Sequence[Trial]) -> dict:
    """The results' header before a winner is judged: what was tuned, how, and nothing
    stored."""
    return {"device": describe(cl_device), "strategy": strategy, "budget_s": budget_s,
            "iterations": tuner.iterations, "scenes": [str(p) for p in paths],
            "tolerance": (f"at most max(2, 0.2 % of the pixels) may differ by over "
                          f"{PIXEL_TOLERANCE if allow_error is None else allow_error:.3g}, "
                          "and no pixel may turn non-finite"),
            "variants": (f"tried under --allow-error {allow_error:g}: "
                         if allow_error is not None else
                         "not tried (they change the image; --allow-error E tries them): ")
            + ", ".join(IMAGE_KNOBS),
            "untried": untried(tuner.runs, trials, budget_s), "notes": tuner.notes,
            "best": None, "verdict": None, "stored": None,
            "decision": "nothing stored: no configuration was verified on every scene",
            "tuning_file": None}


def _judge_winner(header: dict, best: tuple[str, dict[str, Trial]], tuner: Tuner,
                  scenes: list[str], cl_device: cl.Device,
                  save: bool) -> tuple[list[dict], Tuning | None]:
    """The best configuration's confirmation renders and the tuning to store (None for
    none), with the header's best, verdict, decision and stored filled in."""
    per_scene = best[1]
    # The best key's knobs, which each scene's trial built (its own walk left None, or
    # named where the scenes' own walks differ): what is confirmed and stored.
    winner = dataclasses.replace(next(iter(per_scene.values())),
                                 tuning=key_tuning(best[0]))
    header["best"] = {"label": report.label(winner), "tuning": winner.tuning.values(),
                      "extra": winner.extra,
                      "time_ms": {s: t.time_ms for s, t in per_scene.items()}}
    confirmed: list[dict] = []
    stored = DEFAULT_TUNING
    if winner.tuning != DEFAULT_TUNING or any(winner.extra.values()):
        # Kernel Tuner times one launch over the whole image; renders launch in bands, on
        # a machine whose load comes and goes: the winner is stored only where
        # interleaved renders confirm its gain (confirmed_gain). Outside the budget.
        runs = {run.name: run for run in tuner.runs}
        confirmed = confirm([runs[s] for s in scenes], winner.tuning, cl_device)
        header["verdict"] = confirmed_gain(confirmed)
        if header["verdict"]["confirmed"]:
            stored = winner.tuning
    # A winner that needs a switch outside the knob table (a test's) is not stored.
    to_store = stored if save and not any(winner.extra.values()) else None
    header["decision"] = report.decision(to_store, save)
    header["stored"] = None if to_store is None else to_store.values()
    return confirmed, to_store


def _store_winner(out: Path, header: dict, trials: Sequence[Trial], cl_device: cl.Device,
                  to_store: Tuning, strategy: str, budget_s: float) -> None:
    """The device's tuning file for the winner, named in the header and the results."""
    try:
        header["tuning_file"] = str(save_tuning(cl_device, to_store, {
            "scenes": header["scenes"], "strategy": strategy, "budget_s": budget_s,
            "best": header["best"], "confirmed": header["confirmed"],
            "verdict": header["verdict"]}))
    except OSError as err:
        raise cannot_write(tuning_path(cl_device), err,
                           f"the results are in {out}; nothing stored") from err
    report.write_results(out, header, trials)  # again, naming the tuning file


def _say_outcome(say: Callable[[str], None], header: dict, trials: Sequence[Trial],
                 confirmed: list[dict], to_store: Tuning | None, cl_device: cl.Device) -> None:
    """The tuning's outcome in a few lines: what was tried, each scene's confirmation, and
    what was stored."""
    rejected = sum(not t.verified for t in trials)
    say(f"tried {plural(len(trials), 'configuration')} on {describe(cl_device)}, "
        f"{rejected} rejected")
    if header["untried"]:
        say(header["untried"])
    say(f"study variants {header['variants']}")
    for c in confirmed:
        say(report.scene_confirmation(c))
    if header["best"] is not None:
        say(f"verdict: {report.verdict_text(header)}")
        said = (f"stored {report.stored_knobs(to_store)} in {header['tuning_file']}"
                if to_store is not None and header["tuning_file"] else header["decision"])
        say(f"best: {header['best']['label']}; {said}")
    else:
        say(header["decision"])
