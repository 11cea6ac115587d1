"""`clray tune`'s outputs: DIR/results.json (every configuration tried), DIR/report.md (a table
of every configuration's time per scene, the default's and the best's side by side, the rejected
ones listed) and DIR/tune.png (the same times as a bar chart; needs the `plot` extra)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from clray.errors import plural
from clray.knobs import DEFAULT_TUNING, Tuning
from clray.output import figure_png, write_output
from clray.tuning.tuner import CONFIRM_P, MIN_GAIN, Trial

if TYPE_CHECKING:
    import matplotlib.figure

PLOT_NAME = "tune.png"


def _record(trial: Trial) -> dict:
    return {"scene": trial.scene, "label": label(trial), "tuning": trial.tuning.values(),
            "extra": trial.extra, "time_ms": trial.time_ms, "times_ms": trial.times_ms,
            "compile_ms": trial.compile_ms, "verified": trial.verified,
            "pixels_off": trial.pixels_off, "problem": trial.problem}


def label(trial: Trial) -> str:
    """The configuration in one line: the changed knobs and any extra parameters."""
    extra = ", ".join(f"{k}={v}" for k, v in trial.extra.items())
    label = trial.tuning.label()
    return f"{label}, {extra}" if extra and label != "default" else extra or label


def decision(stored: Tuning | None, save: bool) -> str:
    """What a tune whose best was found stores (`stored`; None: nothing), in words."""
    if not save:
        return "nothing stored (--no-save)"
    if stored is None:
        return "nothing stored (the best needs a switch outside the knob table)"
    return f"storing {stored_knobs(stored)} as the device's tuning file"


def stored_knobs(stored: Tuning) -> str:
    """A stored configuration in words: its changed knobs, or the defaults."""
    return "the defaults" if stored == DEFAULT_TUNING else stored.label()


def verdict_text(header: dict) -> str:
    """The confirmation's verdict on the best configuration, in one line (stderr, report.md):
    the figures it decides by, and what it decided."""
    verdict = header["verdict"]
    if verdict is None:
        return "the best is the default configuration, nothing to confirm"
    lower, upper = verdict["quartiles"]
    rounds = verdict["rounds"]
    outcome = ("confirmed" if verdict["confirmed"] else
               f"not confirmed (storing needs p < {CONFIRM_P:g} and at least {MIN_GAIN:g}x)")
    return (f"{header['best']['label']} at {verdict['gain']:.3f}x (median of {rounds} "
            f"rounds' ratios of default to tuned kernel time, middle half {lower:.3f}x to "
            f"{upper:.3f}x), faster in {verdict['faster_rounds']} of {rounds} rounds (sign "
            f"test p = {verdict['p']:.2g}): {outcome}")


def scene_confirmation(record: dict) -> str:
    """A scene's confirming renders in one line: the speed-up (the rounds' median ratio, as the
    verdict's) with its middle half, and how long the default's renders take."""
    lower, upper = record["quartiles"]
    return (f"{record['scene']}: {record['speedup']:.3f}x (median of {record['rounds']} rounds' "
            f"ratios, middle half {lower:.3f}x to {upper:.3f}x), faster in "
            f"{record['faster_rounds']} of {record['rounds']} rounds; the default renders in "
            f"{record['default_kernel_s'] * 1e3:.3g} ms")


def _is_default(trial: Trial) -> bool:
    return trial.tuning == DEFAULT_TUNING and not any(trial.extra.values())


def write_results(out: Path, header: dict, trials: Sequence[Trial]) -> Path:
    path = out / "results.json"
    payload = {**header, "trials": [_record(t) for t in trials]}
    write_output(path, (json.dumps(payload, indent=2) + "\n").encode("utf-8"))
    return path


# Characters a line of a bar's label holds; longer labels wrap between knobs. An unwrapped label
# of many knobs is wider than the figure, and matplotlib then cuts it at the left edge.
LABEL_WIDTH = 48
_LINE_IN = 0.13  # inches a line of the labels' 7-point text takes, with its leading


def wrapped(text: str, width: int = LABEL_WIDTH) -> str:
    """`text`, a label's comma-separated knobs, on lines of at most `width` characters where
    the knobs allow (a knob longer than a line keeps a line of its own)."""
    lines: list[str] = []
    for part in text.split(", "):
        if lines and len(lines[-1]) + 2 + len(part) <= width:
            lines[-1] += ", " + part
        else:
            lines.append(part)
    return ",\n".join(lines)


def plot_figure(trials: Sequence[Trial], best_key: str | None) -> matplotlib.figure.Figure:
    """Per scene, every verified configuration's kernel time, fastest first, the default and
    the best coloured, each bar as tall as its label's lines need."""
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(t.scene for t in trials))
    rows = {s: sorted((t for t in trials if t.scene == s and t.verified), key=lambda t: t.time_ms)
            for s in scenes}
    labels = {s: [wrapped(label(t)) for t in rows[s]] for s in scenes}
    row_in = _LINE_IN * max((lab.count("\n") + 1 for ls in labels.values() for lab in ls),
                            default=1) + 0.15
    # Inches per scene: its title and time axis, and its bars.
    heights = [1.2 + row_in * max(len(rows[s]), 1) for s in scenes]
    fig, axes = plt.subplots(len(scenes), 1, squeeze=False, figsize=(9, sum(heights)),
                             height_ratios=heights)
    for ax, scene in zip(axes[:, 0], scenes, strict=True):
        colours = ["tab:orange" if _is_default(t) else "tab:green" if best_key in t.keys()
                   else "tab:blue" for t in rows[scene]]
        ax.barh(range(len(rows[scene])), [t.time_ms for t in rows[scene]], color=colours)
        ax.set_yticks(range(len(rows[scene])), labels[scene], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("kernel ms (median of Kernel Tuner's runs; orange: default, green: best)")
        ax.set_title(scene)
    fig.tight_layout()
    return fig


def plot(out: Path, trials: Sequence[Trial], best_key: str | None) -> str | None:
    """DIR/tune.png, plot_figure's; where it is skipped, why (for the report)."""
    if not trials:  # a figure needs a row of axes per scene tried
        return "nothing was tried"
    try:
        import matplotlib
    except ImportError:
        return "matplotlib is not installed (`pip install 'clray[plot]'`)"
    matplotlib.use("Agg")
    write_output(out / PLOT_NAME, figure_png(plot_figure(trials, best_key), dpi=110))
    return None


def write_report(out: Path, header: dict, trials: Sequence[Trial], best_key: str | None,
                 confirmed: Sequence[dict], plot_skipped: str | None) -> Path:
    # Every scene, each under its name as trials know it: one the budget left untried says so.
    scenes = [Path(s).stem for s in header["scenes"]]
    lines = [
        "# clray tune",
        "",
        f"Device: {header['device']}. Strategy: {header['strategy']}, budget "
        f"{header['budget_s']:g} s, {header['iterations']} timed launches per configuration "
        "(OpenCL profiling events; the median is shown), kernel build time apart. Every "
        "configuration's image is checked against the default configuration's: "
        f"{header['tolerance']}.",
        "",
        f"Study variants: {header['variants']}.",
        "",
    ]
    if header["untried"]:
        lines += [f"**Budget:** {header['untried']}.", ""]
    lines += [line for note in header["notes"] for line in (f"**Note:** {note}.", "")]
    for scene in scenes:
        rows = [t for t in trials if t.scene == scene]
        if not rows:
            lines += [f"## {scene}", "", "Nothing tried within the budget.", ""]
            continue
        default = next((t for t in rows if _is_default(t) and t.verified), None)
        lines += [f"## {scene}", "", "| configuration | kernel ms | vs default | build ms | "
                  "image | |", "|---|---|---|---|---|---|"]
        for t in sorted(rows, key=lambda t: (not t.verified, t.time_ms or float("inf"))):
            mark = " ".join(m for m, on in (("**default**", _is_default(t)),
                                            ("**best**", best_key in t.keys())) if on)
            ratio = (f"{default.time_ms / t.time_ms:.2f}x" if default and t.time_ms and t.verified
                     else "")
            time_ms = f"{t.time_ms:.3f}" if t.time_ms is not None else "-"
            image = "ok" if t.verified else f"REJECTED: {t.problem}"
            lines.append(f"| {label(t)} | {time_ms} | {ratio} | {t.compile_ms:.0f} | "
                         f"{image} | {mark} |")
        rejected = [t for t in rows if not t.verified]
        lines += ["", f"{plural(len(rows), 'configuration')} tried, {len(rejected)} rejected "
                      "(never chosen).", ""]
    if header["best"] is not None:
        lines += ["## Confirmation: the best against the default, interleaved", ""]
        if confirmed:
            lines += ["Whole renders through clray's own launches after a warm-up of each, "
                      "default and tuned in rounds, the default first in every other round "
                      "(not counted in the budget). Speed-up: the median of the rounds' ratios "
                      "of default to tuned kernel time, with their middle half; the default's "
                      "median kernel time.", "",
                      "| scene | rounds | speed-up | middle half | faster rounds | default ms |",
                      "|---|---|---|---|---|---|"]
            lines += [f"| {c['scene']} | {c['rounds']} | {c['speedup']:.3f}x | "
                      f"{c['quartiles'][0]:.3f}x to {c['quartiles'][1]:.3f}x | "
                      f"{c['faster_rounds']} | {c['default_kernel_s'] * 1e3:.3f} |"
                      for c in confirmed]
            lines.append("")
        lines += [f"**Verdict:** {verdict_text(header)}.", "",
                  f"**Decision:** {header['decision']}.", ""]
    lines.append(f"![every configuration's time]({PLOT_NAME})" if plot_skipped is None else
                 f"Plot skipped: {plot_skipped}.")
    path = out / "report.md"
    write_output(path, ("\n".join(lines) + "\n").encode("utf-8"))
    return path
