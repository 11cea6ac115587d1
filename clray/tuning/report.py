"""`clray tune`'s outputs: DIR/results.json (every configuration tried), DIR/report.md (a table
of every configuration's time per scene, the default's and the best's side by side, the rejected
ones listed) and DIR/tune.png (the same times as a bar chart; needs the `plot` extra)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from clray.image_io import write_bytes_atomically
from clray.tuning.knobs import DEFAULT_TUNING
from clray.tuning.tuner import Trial

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


def _is_default(trial: Trial) -> bool:
    return trial.tuning == DEFAULT_TUNING and not any(trial.extra.values())


def write_results(out: Path, header: dict, trials: Sequence[Trial]) -> Path:
    path = out / "results.json"
    payload = {**header, "trials": [_record(t) for t in trials]}
    write_bytes_atomically(path, (json.dumps(payload, indent=2) + "\n").encode("utf-8"))
    return path


def plot(out: Path, trials: Sequence[Trial], best_key: str | None) -> bool:
    """DIR/tune.png: per scene, every verified configuration's kernel time, fastest first, the
    default and the best coloured; False where matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    scenes = list(dict.fromkeys(t.scene for t in trials))
    fig, axes = plt.subplots(len(scenes), 1, figsize=(9, 1.5 + 0.28 * max(
        sum(t.scene == s and t.verified for t in trials) for s in scenes)), squeeze=False)
    for ax, scene in zip(axes[:, 0], scenes, strict=True):
        rows = sorted((t for t in trials if t.scene == scene and t.verified),
                      key=lambda t: t.time_ms)
        colours = ["tab:orange" if _is_default(t) else "tab:green" if t.key() == best_key
                   else "tab:blue" for t in rows]
        ax.barh(range(len(rows)), [t.time_ms for t in rows], color=colours)
        ax.set_yticks(range(len(rows)), [label(t) for t in rows], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("kernel ms (median of Kernel Tuner's runs; orange: default, green: best)")
        ax.set_title(scene)
    fig.tight_layout()
    fig.savefig(out / PLOT_NAME, dpi=110)
    plt.close(fig)
    return True


def write_report(out: Path, header: dict, trials: Sequence[Trial], best_key: str | None,
                 confirmed: Sequence[dict], plotted: bool) -> Path:
    scenes = list(dict.fromkeys(t.scene for t in trials))
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
    for scene in scenes:
        rows = [t for t in trials if t.scene == scene]
        default = next((t for t in rows if _is_default(t) and t.verified), None)
        lines += [f"## {scene}", "", "| configuration | kernel ms | vs default | build ms | "
                  "image | |", "|---|---|---|---|---|---|"]
        for t in sorted(rows, key=lambda t: (not t.verified, t.time_ms or float("inf"))):
            mark = " ".join(m for m, on in (("**default**", _is_default(t)),
                                            ("**best**", t.key() == best_key)) if on)
            ratio = (f"{default.time_ms / t.time_ms:.2f}x" if default and t.time_ms and t.verified
                     else "")
            time_ms = f"{t.time_ms:.3f}" if t.time_ms is not None else "-"
            image = "ok" if t.verified else f"REJECTED: {t.problem}"
            lines.append(f"| {label(t)} | {time_ms} | {ratio} | {t.compile_ms:.0f} | "
                         f"{image} | {mark} |")
        rejected = [t for t in rows if not t.verified]
        lines += ["", f"{len(rows)} configurations tried, {len(rejected)} rejected "
                      "(never chosen).", ""]
    if confirmed:
        lines += ["## Tuned against default, interleaved", "",
                  "Whole renders through clray's own launches, default and tuned in turns after "
                  "a warm-up of each: median kernel time.", "",
                  "| scene | rounds | default s | tuned s | speed-up |", "|---|---|---|---|---|"]
        lines += [f"| {c['scene']} | {c['rounds']} | {c['default_kernel_s']:.4f} | "
                  f"{c['tuned_kernel_s']:.4f} | {c['speedup']:.3f}x |" for c in confirmed]
        lines.append("")
    lines.append(f"![every configuration's time]({PLOT_NAME})" if plotted else
                 "Plot skipped: matplotlib is not installed (`pip install 'clray[plot]'`).")
    path = out / "report.md"
    write_bytes_atomically(path, ("\n".join(lines) + "\n").encode("utf-8"))
    return path
