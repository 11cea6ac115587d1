"""Speed against error: render scenes with kernel variants, time them, compare with fp64.

Every variant is one set of KernelConfig switches. The reference is the double build of the same
kernel (same algorithm, more bits). Errors are measured on the linear float images before any
quantisation: RMSE, PSNR, max abs error, and the pixels off by more than 1/255 and 2/255, because
acne and leaks are a few very wrong pixels that RMSE averages away. Non-finite pixels are
counted separately (they make RMSE NaN).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyopencl as cl

from clray import metrics
from clray.errors import EXIT_OK, EXIT_RUNTIME, ClrayError, one_line, plural
from clray.output import cannot_write, figure_png, write_output
from clray.render import RenderSettings, render
from clray.scene.load import load_scene
from clray.scene.model import Scene

if TYPE_CHECKING:
    import matplotlib.axes
    import matplotlib.figure


@dataclass(frozen=True)
class Variant:
    name: str
    precision: str = "float"
    switches: tuple[tuple[str, object], ...] = ()  # KernelConfig fields
    note: str = ""


REFERENCE = Variant("double", "double", note="fp64 everywhere: the reference")
DEFAULT = Variant("float (default)", note="stable sphere, error-bound offsets, watertight "
                                          "triangles, fp64 spheres only where flagged")
VARIANTS: tuple[Variant, ...] = (
    REFERENCE,
    DEFAULT,
    Variant("-cl-mad-enable", switches=(("build_options", ("-cl-mad-enable",)),)),
    Variant("-cl-unsafe-math-optimizations",
            switches=(("build_options", ("-cl-unsafe-math-optimizations",)),)),
    Variant("-cl-fast-relaxed-math", switches=(("build_options", ("-cl-fast-relaxed-math",)),)),
    Variant("textbook sphere", switches=(("sphere_textbook", True),)),
    Variant("fixed-epsilon offsets", switches=(("offset_fixed_eps", True),)),
    Variant("Moller-Trumbore triangles", switches=(("triangle_moller_trumbore", True),)),
    Variant("no fp64 sphere path", switches=(("fp64_spheres", False),),
            note="flagged spheres intersected in float32 too"),
    Variant("Schlick Fresnel", switches=(("fresnel_schlick", True),),
            note="Schlick's approximation in materials with fresnel = true: a model change, "
                 "so it differs from the reference by more than rounding"),
)

def tolerance_text(width: int, height: int) -> str:
    """What FAIL means at this image size, with the figures."""
    n_pixels = width * height
    return (f"FAIL: a NaN or infinite pixel, or over {metrics.fail_allowance(n_pixels)} of the "
            f"{n_pixels} pixels off by more than 2/255")


def failure_reason(record: dict) -> str | None:
    """Why the record's variant FAILs its scene, in figures; None where it passes."""
    allowed = metrics.fail_allowance(record["width"] * record["height"])
    reasons = []
    # .get: results.json written before the study checked its reference has no such field.
    if record.get("reference_nonfinite"):
        reasons.append(f"the reference has {plural(record['reference_nonfinite'], 'pixel')} "
                       "NaN or infinite: no image compares with it")
        if record["variant"] == REFERENCE.name:
            return reasons[0]  # its own figures are those same pixels again
    if record["nonfinite"]:
        reasons.append(f"{plural(record['nonfinite'], 'pixel')} NaN or infinite")
    if record["over_2_255"] > allowed:
        reasons.append(f"{plural(record['over_2_255'], 'pixel')} off by over 2/255, "
                       f"{allowed} allowed")
    return "; ".join(reasons) or None


def scene_line(record: dict) -> str:
    """The progress line before a scene's variants: what each is compared with, and FAIL."""
    line = (f"{record['scene']} at {record['width']}x{record['height']}: each variant's image "
            f"against the double build's (the reference); "
            f"{tolerance_text(record['width'], record['height'])}")
    if record.get("reference_nonfinite"):
        line += (f"; the reference has {plural(record['reference_nonfinite'], 'pixel')} NaN or "
                 "infinite: every variant FAILs")
    return line


def variant_line(record: dict) -> str:
    """A variant's progress line: its time, its error and, where it fails, why."""
    ms = f"{record['scene']}: {record['variant']}: {record['kernel_s_median'] * 1e3:.3g} ms"
    reason = failure_reason(record)
    if record["variant"] == REFERENCE.name:
        return f"{ms}, the reference" + ("" if reason is None else f", FAIL: {reason}")
    rmse = "n/a" if record["rmse"] is None else f"{record['rmse']:.3g}"
    return f"{ms}, RMSE {rmse}, " + ("pass" if reason is None else f"FAIL: {reason}")


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


# What results.json says of the knobs, which each record's `tuning` (the render's
# stats["tuning"]["source"]) shows: the table's defaults, never the device's tuning file.
TUNING_NOTE = "default: the knob table's defaults; a device's tuning file is not used"


def _settings(variant: Variant, base: RenderSettings) -> RenderSettings:
    # The knob table's defaults, as `clray tune` renders its reference: a device's tuning file
    # would make the reference and the default variants other builds than the report names.
    return RenderSettings(width=base.width, height=base.height, device=base.device,
                          precision=variant.precision, variants=variant.switches,
                          stored_tuning=False)


@dataclass
class _Runs:
    """A variant's renders so far: its latest image, its timed kernel seconds, and where its
    knobs came from."""
    image: np.ndarray
    tuning: str
    times: list[float] = field(default_factory=list)


def _warm_up(scene: Scene, variant: Variant, base: RenderSettings) -> _Runs:
    """The variant's first render, untimed: it builds the kernel and pays first-touch costs."""
    result = render(scene, _settings(variant, base))
    return _Runs(result.image, result.stats["tuning"]["source"])


def _time_rounds(scene: Scene, variants: Sequence[Variant], repeat: int, base: RenderSettings,
                 runs: dict[Variant, _Runs]) -> None:
    """`repeat` rounds that render every variant once each, into `runs`: a change in the
    machine's load then falls on every variant alike, as in benchmarks/compare.py and
    clray.profile.time_split. Every other round runs them in reverse order, so that no variant
    always holds the same place in a round."""
    for round_index in range(repeat):
        for variant in variants if round_index % 2 == 0 else reversed(variants):
            result = render(scene, _settings(variant, base))
            runs[variant].times.append(result.stats["kernel_s"])
            runs[variant].image = result.image


def compare(image: np.ndarray, reference: np.ndarray) -> dict:
    """The image's errors against the reference's, and its status: FAIL where either image has
    a non-finite pixel (a NaN in the reference leaves every error undefined, which must not
    read as a pass) or too many pixels are off by over 2/255."""
    n_pixels = image.shape[0] * image.shape[1]
    over_2 = metrics.count_over(image, reference, 2 / 255)
    nonfinite = metrics.nonfinite_count(image)
    reference_nonfinite = metrics.nonfinite_count(reference)
    passes = (nonfinite == 0 and reference_nonfinite == 0
              and over_2 <= metrics.fail_allowance(n_pixels))
    return {
        "rmse": _finite_or_none(metrics.rmse(image, reference)),
        "psnr_db": _finite_or_none(metrics.psnr(image, reference)),
        "max_abs": _finite_or_none(metrics.max_abs(image, reference)),
        "over_1_255": metrics.count_over(image, reference, 1 / 255),
        "over_2_255": over_2,
        "nonfinite": nonfinite,
        "reference_nonfinite": reference_nonfinite,
        "status": "pass" if passes else "FAIL",
    }


def _record(path: Path, scene: Scene, variant: Variant, runs: _Runs,
            reference: np.ndarray) -> dict:
    """A variant's line of results.json: its build, its times and its image against the
    reference's."""
    return {
        "scene": path.stem,
        "scene_file": str(path),
        "variant": variant.name,
        "precision": variant.precision,
        "switches": {k: list(v) if isinstance(v, tuple) else v for k, v in variant.switches},
        "width": int(runs.image.shape[1]),
        "height": int(runs.image.shape[0]),
        "kernel_s_median": statistics.median(runs.times),
        "kernel_s_all": runs.times,
        "tuning": runs.tuning,
        "scene_warnings": list(scene.warnings),
        **compare(runs.image, reference),
    }


def study_scene(path: Path, variants: Sequence[Variant], repeat: int, base: RenderSettings,
                say: Callable[[str], None] = lambda _: None, scene: Scene | None = None
                ) -> list[dict]:
    """Every variant of the scene at `path` (already loaded: `scene`), timed on one device:
    each variant is built and warmed up, then timed in `repeat` interleaved rounds."""
    scene = scene or load_scene(path)
    # The reference's warm-up gives the reference image, rendered once: where the double build
    # is among the variants too, that render is its warm-up, and its rounds add only its timed
    # renders.
    runs = {REFERENCE: _warm_up(scene, REFERENCE, base)}
    reference = runs[REFERENCE].image
    height, width = reference.shape[:2]
    say(scene_line({"scene": path.stem, "width": width, "height": height,
                    "reference_nonfinite": metrics.nonfinite_count(reference)}))
    for variant in variants:
        if variant not in runs:
            runs[variant] = _warm_up(scene, variant, base)
    _time_rounds(scene, variants, repeat, base, runs)
    records = [_record(path, scene, variant, runs[variant], reference) for variant in variants]
    for record in records:
        say(variant_line(record))
    return records


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats in both time and error, fastest first."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


# One marker per variant, in the order of VARIANTS, so that a variant looks alike in every plot.
_MARKERS = "*osD^vPX<>ph"


def _variant_styles(records: list[dict]) -> list[int]:
    """Each record's place in VARIANTS, which picks its marker and colour: the same in a plot of
    any subset of the variants. Variants not in VARIANTS follow them, in the records' order."""
    places = {variant.name: i for i, variant in enumerate(VARIANTS)}
    others = [name for name in dict.fromkeys(r["variant"] for r in records)
              if name not in places]
    places.update({name: len(VARIANTS) + i for i, name in enumerate(others)})
    return [places[r["variant"]] for r in records]


def _legend_label(record: dict, ms: float) -> str:
    rmse = record["rmse"]
    error = "non-finite pixels" if rmse is None else f"RMSE {rmse:.2g}"
    if record["variant"] == REFERENCE.name:
        error = "the reference (RMSE 0), dotted"
    time = f"{ms:.0f}" if ms >= 100 else f"{ms:.3g}"  # 1230, not 1.23e+03
    fail = ", FAIL" if record["status"] == "FAIL" else ""
    return f"{record['variant']}: {time} ms, {error}{fail}"


def _log_time_axis(axis: matplotlib.axes.Axes, times: list[float]) -> None:
    """Kernel times on a log axis (shared by the axes above), where a ratio of times is one
    distance at any speed. Where the times span under a decade, which one scene's variants do
    on one device, the log axis's own ticks (at 1, 10, 100, with unlabelled ones between) would
    leave one label or none: round numbers of milliseconds instead."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator, NullLocator

    axis.set_xscale("log")
    if max(times) < 10 * min(times):
        axis.xaxis.set_major_locator(MaxNLocator(nbins=6, steps=[1, 2, 2.5, 5, 10]))
        axis.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        axis.xaxis.set_minor_locator(NullLocator())


def plot_figure(records: list[dict]) -> matplotlib.figure.Figure:
    """Kernel time against RMSE for one scene's records, both on log axes, with a strip below
    for the variants that match the reference exactly (RMSE 0, the reference itself among them,
    drawn as a vertical line too) and non-finite errors drawn on the top edge. Each
    variant has its own marker, named with its figures in the legend beside the plot instead of
    labels that would collide; FAILs are hollow and the Pareto front is ringed and dashed."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import NullFormatter

    times = [r["kernel_s_median"] * 1e3 for r in records]
    errors = [math.inf if r["rmse"] is None else r["rmse"] for r in records]
    front = pareto_front(list(zip(times, errors, strict=True)))
    fig = plt.figure(figsize=(10, 4.8), dpi=100)
    grid = fig.add_gridspec(2, 1, height_ratios=(5, 1), hspace=0.08, left=0.08, right=0.55,
                            top=0.91, bottom=0.11)
    ax = fig.add_subplot(grid[0])
    exact = fig.add_subplot(grid[1], sharex=ax)
    handles = []
    places = _variant_styles(records)
    for i, record, x, y in zip(places, records, times, errors, strict=True):
        style = {"marker": _MARKERS[i % len(_MARKERS)], "color": f"C{i % 10}",
                 "markersize": 11 if record["variant"] == REFERENCE.name else 8,
                 "linestyle": "none",
                 "markerfacecolor": "none" if record["status"] == "FAIL" else f"C{i % 10}"}
        if record["variant"] == REFERENCE.name:
            style["color"] = style["markerfacecolor"] = "black"
            for axis in (ax, exact):
                axis.axvline(x, color="black", linestyle=":", linewidth=1)
        if y == 0:
            exact.plot([x], [0], **style)
        elif math.isinf(y):
            ax.plot([x], [1], transform=ax.get_xaxis_transform(), clip_on=False, **style)
        else:
            ax.plot([x], [y], **style)
        handles.append(Line2D([], [], label=_legend_label(record, x), **{
            **style, "linestyle": ":" if record["variant"] == REFERENCE.name else "none"}))
    ring = {"marker": "o", "markersize": 17, "markerfacecolor": "none",
            "markeredgecolor": "0.4", "linestyle": "none"}
    for i in front:
        (exact if errors[i] == 0 else ax).plot([times[i]], [errors[i]], **ring)
    drawn = [i for i in front if 0 < errors[i] < math.inf]
    if len(drawn) > 1:
        ax.plot([times[i] for i in drawn], [errors[i] for i in drawn], "--", color="0.4",
                linewidth=1, drawstyle="steps-post")
    handles.append(Line2D([], [], color="0.4", linestyle="--", label="Pareto front (ringed)",
                          **{k: v for k, v in ring.items() if k != "linestyle"}))
    finite = [e for e in errors if 0 < e < math.inf]
    if finite:
        # Whole decades: a narrow range would get tick labels such as 4x10^-3 that tell less.
        ax.set_yscale("log")
        ax.set_ylim(10 ** math.floor(math.log10(min(finite))),
                    10 ** math.ceil(math.log10(max(finite)) + 1e-9))
        ax.yaxis.set_minor_formatter(NullFormatter())
    else:
        ax.set_yticks([])
        ax.text(0.5, 0.5, "no variant differs from the reference", transform=ax.transAxes,
                ha="center", va="center", color="0.4")
    ax.set_ylabel("RMSE vs double")
    ax.tick_params(labelbottom=False)
    ax.grid(True, which="major", alpha=0.3)
    exact.set_ylim(-1, 1)
    exact.set_yticks([0], ["0 (exact)"])
    _log_time_axis(exact, times)
    exact.set_xlabel("kernel time, ms (median; log scale)")
    exact.grid(True, axis="x", alpha=0.3)
    ax.set_title(f"{records[0]['scene']} ({records[0]['width']}x{records[0]['height']}): "
                 "kernel time against error", fontsize=10)
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(0.565, 0.5), fontsize=8,
               frameon=False, title="variant: median kernel time, error\n(hollow: FAIL)",
               title_fontsize=8, alignment="left", borderaxespad=0)
    return fig


def plot_scene(records: list[dict], path: Path) -> bool:
    """Write plot_figure's PNG; False when matplotlib is not installed."""
    try:
        import matplotlib
    except ImportError:
        return False
    matplotlib.use("Agg")
    write_output(path, figure_png(plot_figure(records), bbox_inches="tight", pad_inches=0.15))
    return True


def _fmt(value: float | None, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def _status(record: dict) -> str:
    reason = failure_reason(record)
    verdict = "pass" if reason is None else f"**FAIL**: {reason}"
    if record["variant"] == REFERENCE.name:
        return "reference" if reason is None else f"reference, {verdict}"
    return verdict


def _shipped(record: dict) -> bool:
    """A scene file under scenes/, as `clray study scenes/*.toml docs/study/scenes/*.json`
    names the shipped scenes."""
    return Path(record["scene_file"]).parts[:1] == ("scenes",)


def timed_scenes(records: list[dict]) -> list[str]:
    """The scenes whose times summary() averages: the shipped ones, as README.md and
    docs/accuracy.md give the times; every scene where none is shipped."""
    shipped = [r["scene"] for r in records if _shipped(r)]
    return list(dict.fromkeys(shipped or [r["scene"] for r in records]))


def summary(records: list[dict]) -> list[dict]:
    """One row a variant, as the summary tables of README.md and docs/accuracy.md give them:
    `time`, its kernel time relative to the float default's (geometric mean over
    timed_scenes; None without the default), and `fails`, {scene: (pixels off by over 2/255,
    non-finite pixels)} of the scenes it FAILs."""
    by_key = {(r["scene"], r["variant"]): r for r in records}
    timed = timed_scenes(records)
    rows = []
    for variant in dict.fromkeys(r["variant"] for r in records):
        pairs = [(by_key[scene, variant], by_key[scene, DEFAULT.name]) for scene in timed
                 if (scene, variant) in by_key and (scene, DEFAULT.name) in by_key]
        logs = [math.log(r["kernel_s_median"] / default["kernel_s_median"])
                for r, default in pairs]
        fails = {r["scene"]: (r["over_2_255"], r["nonfinite"]) for r in records
                 if r["variant"] == variant and r["status"] == "FAIL"}
        rows.append({"variant": variant,
                     "time": math.exp(statistics.fmean(logs)) if logs else None,
                     "fails": fails})
    return rows


def _summary_lines(records: list[dict]) -> list[str]:
    """report.md's summary: summary()'s table, the figures README.md and docs/accuracy.md
    give."""
    timed = len(timed_scenes(records))
    over = (f"the {plural(timed, 'shipped scene')} (`scenes/`)" if any(map(_shipped, records))
            else f"the {plural(timed, 'scene')}")
    lines = ["## Summary", "",
             f"Kernel time relative to the float default, the geometric mean over {over}, and "
             "the scenes each variant FAILs, with its pixels off by more than 2/255 in brackets "
             "(README.md and docs/accuracy.md give this table):", "",
             "| variant | time | fails |", "|---|---|---|"]
    for row in summary(records):
        name = row["variant"] + (" (the reference)" if row["variant"] == REFERENCE.name else "")
        fails = ", ".join(f"{scene} ({over_2}" + (f", {nonfinite} non-finite)" if nonfinite
                                                   else ")")
                          for scene, (over_2, nonfinite) in row["fails"].items())
        lines.append(f"| {name} | {_fmt(row['time'], '.2f')} | {fails or '-'} |")
    return lines


def _scene_lines(rows: list[dict], plotted: bool) -> list[str]:
    """report.md's section of one scene: its file, size and tolerance, and a row a variant."""
    first = rows[0]
    scene = first["scene"]
    lines = ["", f"## {scene}", "",
             f"`{first['scene_file']}` at {first['width']}x{first['height']}"
             + (f", on worker {first['worker']} ({first['device']})."
                if "worker" in first else ".")
             + f" {tolerance_text(first['width'], first['height'])}."]
    default = next((r for r in rows if r["variant"] == DEFAULT.name), None)
    if default is not None and default["status"] == "FAIL":
        lines.append("The float default fails here too: float rounding alone moves more "
                     "pixels than that in this scene, so read the other variants against "
                     "the default's row.")
    for warning in first["scene_warnings"]:
        lines.append(f"Loader warning: {warning}")
    lines += ["", "| variant | kernel ms | RMSE | PSNR dB | max abs | px > 1/255 | "
                  "px > 2/255 | non-finite | status |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['variant']} | {r['kernel_s_median'] * 1e3:.3g} | {_fmt(r['rmse'], '.2e')} "
            f"| {_fmt(r['psnr_db'], '.1f') if r['rmse'] != 0 else 'inf'} "
            f"| {_fmt(r['max_abs'], '.3g')} | {r['over_1_255']} | {r['over_2_255']} "
            f"| {r['nonfinite']} | {_status(r)} |")
    if plotted:
        lines += ["", f"![time vs error, {scene}]({scene}.png)"]
    return lines


def write_report(records: list[dict], out: Path, repeat: int, device: str,
                 plots: dict[str, bool]) -> None:
    """report.md in `out`: what is compared, the summary, pass/fail side by side, and a
    section a scene."""
    scenes = list(dict.fromkeys(r["scene"] for r in records))
    variants = list(dict.fromkeys(r["variant"] for r in records))
    by_key = {(r["scene"], r["variant"]): r for r in records}
    lines = [
        "# Speed against error",
        "",
        f"Generated by `clray study` on {device}. Kernel time: median of "
        f"{plural(repeat, 'timed run')} after a warm-up (OpenCL profiling events).",
        "",
        "What is compared: each variant renders each scene at the same size, and its image is "
        "compared pixel by pixel with the image of the **double** variant of the same scene, "
        "the reference (the same kernel built with fp64 everywhere), on the linear float "
        "values before quantisation to 8 bits. RMSE, PSNR and max abs are over every channel; "
        "px > 1/255 and px > 2/255 count the pixels with any channel off by more than that.",
        "",
        "Tolerance: a variant FAILs a scene when any pixel is NaN or infinite, or when over "
        f"max({metrics.FAIL_MIN_PIXELS}, {metrics.FAIL_FRACTION:.1%} of the pixels) are off by "
        "more than 2/255 "
        "(each scene's section gives the figure): a few pixels on silhouettes may flip between "
        "builds, and no more. FAIL says that the image is not the reference's, not that it is "
        "worse than the float default's: where the default fails too, float rounding alone "
        "moves that many pixels.",
        "",
    ]
    if records:
        lines += [*_summary_lines(records), ""]
    lines += [
        "## Pass/fail, all scenes side by side",
        "",
        "| scene | " + " | ".join(variants) + " |",
        "|---|" + "---|" * len(variants),
    ]
    for scene in scenes:
        cells = [_status(by_key[scene, v]) if (scene, v) in by_key else "" for v in variants]
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    for scene in scenes:
        lines += _scene_lines([r for r in records if r["scene"] == scene],
                              bool(plots.get(scene)))
    if not any(plots.values()):
        lines += ["", "Plots skipped: matplotlib is not installed (`pip install 'clray[plot]'`)."]
    write_output(out / "report.md", ("\n".join(lines) + "\n").encode("utf-8"))


def run_study(paths: Sequence[Path], out: Path, *, repeat: int = 5,
              width: int | None = None, height: int | None = None, device: str | None = None,
              variants: Sequence[Variant] = VARIANTS,
              say: Callable[[str], None] = lambda _: None,
              run_scenes: Callable[..., list[dict]] | None = None) -> list[dict]:
    """Render every scene with every variant; write results.json, report.md and plots.
    `run_scenes(paths, variants, repeat, base, say)` renders elsewhere (a Dask cluster, one
    task a scene: clray.distributed.study_scenes); its records name their device."""
    from clray.device.context import describe, select_device

    for path in paths:  # a bad scene is one line before minutes of rendering the others
        load_scene(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise cannot_write(out, err) from err
    base = RenderSettings(width=width, height=height, device=device)
    records: list[dict] = []
    if run_scenes is not None:
        records = run_scenes(paths, variants, repeat, base, say)
    else:
        with warnings.catch_warnings():
            # PoCL repeats its build warnings on every cached build; they are noise here.
            warnings.simplefilter("ignore", cl.CompilerWarning)
            for path in paths:
                records += study_scene(path, variants, repeat, base, say)
    plots = plot_scenes(records, out)
    if not all(plots.values()):
        say("plots skipped: matplotlib is not installed (pip install 'clray[plot]')")
    workers = {r["worker"]: r["device"] for r in records if "worker" in r}
    device_name = (describe(select_device(device)) if not workers else
                   f"{plural(len(workers), 'Dask worker')} ("
                   + "; ".join(sorted(set(workers.values())))
                   + "), each scene's variants all on one worker, whose name each scene's "
                   "section gives: times compare within a scene, not across scenes")
    write_output(out / "results.json", (json.dumps(
        {"device": device_name, "repeat": repeat, "tuning": TUNING_NOTE, "records": records},
        indent=1)
        + "\n").encode("utf-8"))
    write_report(records, out, repeat, device_name, plots)
    return records


def plot_scenes(records: list[dict], out: Path) -> dict[str, bool]:
    """One PNG per scene in `out`: {scene: written}."""
    return {scene: plot_scene([r for r in records if r["scene"] == scene], out / f"{scene}.png")
            for scene in dict.fromkeys(r["scene"] for r in records)}


def replot(out: Path) -> dict[str, bool]:
    """Redraw a study folder's plots and report.md from its results.json, without rendering:
    `python -m clray.study DIR`."""
    data = json.loads((out / "results.json").read_text(encoding="utf-8"))
    plots = plot_scenes(data["records"], out)
    write_report(data["records"], out, data["repeat"], data["device"], plots)
    return plots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m clray.study",
        description="Redraw the plots and report.md of a `clray study` folder from its "
                    "results.json, without rendering.")
    parser.add_argument("folder", type=Path, metavar="DIR")
    args = parser.parse_args(argv)
    try:
        plots = replot(args.folder)
    except (ClrayError, OSError, ValueError, KeyError, TypeError) as err:
        print(f"clray: error: cannot replot {args.folder}: {one_line(str(err))}", file=sys.stderr)
        return EXIT_RUNTIME
    if not all(plots.values()):
        print("clray: error: plots need matplotlib (pip install 'clray[plot]')", file=sys.stderr)
        return EXIT_RUNTIME
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
