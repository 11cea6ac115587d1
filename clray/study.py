"""Speed against error: render scenes with kernel variants, time them, compare with fp64.

Every variant is one set of KernelConfig switches. The reference is the double build of the same
kernel (same algorithm, more bits). Errors are measured on the linear float images before any
quantisation: RMSE, PSNR, max abs error, and the pixels off by more than 1/255 and 2/255, because
acne and leaks are a few very wrong pixels that RMSE averages away. Non-finite pixels are
counted separately (they make RMSE NaN).
"""

from __future__ import annotations

import json
import math
import statistics
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyopencl as cl

from clray import metrics
from clray.render import RenderSettings, render
from clray.scene.load import load_scene
from clray.scene.model import Scene


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
)

# A variant fails a scene when any pixel is non-finite or more pixels than this differ from the
# reference by over 2/255: a handful of silhouette pixels may legitimately flip between builds.
FAIL_FRACTION = 0.002
FAIL_MIN_PIXELS = 2


def fail_allowance(n_pixels: int) -> int:
    return max(FAIL_MIN_PIXELS, math.floor(FAIL_FRACTION * n_pixels))


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _render_timed(scene: Scene, variant: Variant, repeat: int, base: RenderSettings
                  ) -> tuple[np.ndarray, list[float]]:
    settings = RenderSettings(width=base.width, height=base.height, device=base.device,
                              precision=variant.precision, variants=variant.switches)
    first = render(scene, settings)  # warm-up: builds the kernel, first-touch costs
    times = []
    image = first.image
    for _ in range(repeat):
        result = render(scene, settings)
        times.append(result.stats["kernel_s"])
        image = result.image
    return image, times


def compare(image: np.ndarray, reference: np.ndarray) -> dict:
    n_pixels = image.shape[0] * image.shape[1]
    over_2 = metrics.count_over(image, reference, 2 / 255)
    nonfinite = metrics.nonfinite_count(image)
    return {
        "rmse": _finite_or_none(metrics.rmse(image, reference)),
        "psnr_db": _finite_or_none(metrics.psnr(image, reference)),
        "max_abs": _finite_or_none(metrics.max_abs(image, reference)),
        "over_1_255": metrics.count_over(image, reference, 1 / 255),
        "over_2_255": over_2,
        "nonfinite": nonfinite,
        "status": "pass" if nonfinite == 0 and over_2 <= fail_allowance(n_pixels) else "FAIL",
    }


def study_scene(path: Path, variants: Sequence[Variant], repeat: int, base: RenderSettings,
                say: Callable[[str], None] = lambda _: None) -> list[dict]:
    scene = load_scene(path)
    reference, _ = _render_timed(scene, REFERENCE, 0, base)
    records = []
    for variant in variants:
        image, times = _render_timed(scene, variant, repeat, base)
        record = {
            "scene": path.stem,
            "scene_file": str(path),
            "variant": variant.name,
            "precision": variant.precision,
            "switches": {k: list(v) if isinstance(v, tuple) else v
                         for k, v in variant.switches},
            "width": int(image.shape[1]),
            "height": int(image.shape[0]),
            "kernel_s_median": statistics.median(times),
            "kernel_s_all": times,
            "scene_warnings": list(scene.warnings),
            **compare(image, reference),
        }
        records.append(record)
        say(f"{path.stem}: {variant.name}: {record['kernel_s_median'] * 1e3:.3g} ms, "
            f"rmse {record['rmse']}, {record['status']}")
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


# Where an error is zero (the reference itself) or NaN, a log plot still needs a value.
_PLOT_FLOOR = 1e-9


def _plot_error(record: dict) -> float:
    rmse = record["rmse"]
    if rmse is None:  # non-finite pixels: plot at the top, it is the worst outcome
        return 1.0
    return max(rmse, _PLOT_FLOOR)


def plot_scene(records: list[dict], path: Path) -> bool:
    """Time-vs-error PNG with the Pareto front; False when matplotlib is not installed."""
    try:
        import matplotlib
    except ImportError:
        return False
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [(r["kernel_s_median"] * 1e3, _plot_error(r)) for r in records]
    front = pareto_front(points)
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    for record, (x, y) in zip(records, points, strict=True):
        failed = record["status"] == "FAIL"
        ax.scatter([x], [y], marker="x" if failed else "o", color="red" if failed else "C0")
        ax.annotate(record["variant"], (x, y), fontsize=7, xytext=(4, 3),
                    textcoords="offset points")
    ax.plot([points[i][0] for i in front], [points[i][1] for i in front], "--", color="C2",
            label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("kernel time, ms (median)")
    ax.set_ylabel(f"RMSE vs double (zero plotted at {_PLOT_FLOOR:g})")
    ax.set_title(f"{records[0]['scene']} ({records[0]['width']}x{records[0]['height']}); "
                 "x = FAIL", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def _fmt(value: float | None, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def write_report(records: list[dict], out: Path, repeat: int, device: str,
                 plots: dict[str, bool]) -> None:
    scenes = list(dict.fromkeys(r["scene"] for r in records))
    variants = list(dict.fromkeys(r["variant"] for r in records))
    by_key = {(r["scene"], r["variant"]): r for r in records}
    lines = [
        "# Speed against error",
        "",
        f"Generated by `clray study` on {device}. Kernel time: median of {repeat} runs after a "
        "warm-up (OpenCL profiling events). Errors against the double build of the same kernel, "
        "on linear float images before quantisation. A variant FAILs a scene when any pixel is "
        f"non-finite or more than max({FAIL_MIN_PIXELS}, {FAIL_FRACTION:.1%} of the pixels) "
        "differ by over 2/255.",
        "",
        "## Pass/fail, all scenes side by side",
        "",
        "| scene | " + " | ".join(variants) + " |",
        "|---|" + "---|" * len(variants),
    ]
    for scene in scenes:
        cells = []
        for v in variants:
            r = by_key.get((scene, v))
            cells.append("" if r is None else
                         ("pass" if r["status"] == "pass" else f"**FAIL** ({r['over_2_255']}"
                          f"{', ' + str(r['nonfinite']) + ' NaN/inf' if r['nonfinite'] else ''})"))
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    for scene in scenes:
        rows = [r for r in records if r["scene"] == scene]
        lines += ["", f"## {scene}", "",
                  f"`{rows[0]['scene_file']}` at {rows[0]['width']}x{rows[0]['height']}."]
        for warning in rows[0]["scene_warnings"]:
            lines.append(f"Loader warning: {warning}")
        lines += ["", "| variant | kernel ms | RMSE | PSNR dB | max abs | px > 1/255 | "
                      "px > 2/255 | non-finite | status |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(
                f"| {r['variant']} | {r['kernel_s_median'] * 1e3:.3g} | {_fmt(r['rmse'], '.2e')} "
                f"| {_fmt(r['psnr_db'], '.1f') if r['rmse'] != 0 else 'inf'} "
                f"| {_fmt(r['max_abs'], '.3g')} | {r['over_1_255']} | {r['over_2_255']} "
                f"| {r['nonfinite']} | {r['status']} |")
        if plots.get(scene):
            lines += ["", f"![time vs error, {scene}]({scene}.png)"]
    if not any(plots.values()):
        lines += ["", "Plots skipped: matplotlib is not installed (`pip install 'clray[plot]'`)."]
    (out / "report.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


def run_study(paths: Sequence[Path], out: Path, *, repeat: int = 3,
              width: int | None = None, height: int | None = None, device: str | None = None,
              variants: Sequence[Variant] = VARIANTS,
              say: Callable[[str], None] = lambda _: None) -> list[dict]:
    """Render every scene with every variant; write results.json, report.md and plots."""
    from clray.device.context import describe, select_device

    out.mkdir(parents=True, exist_ok=True)
    base = RenderSettings(width=width, height=height, device=device)
    records: list[dict] = []
    with warnings.catch_warnings():
        # PoCL repeats its build warnings on every cached build; they are noise here.
        warnings.simplefilter("ignore", cl.CompilerWarning)
        for path in paths:
            records += study_scene(path, variants, repeat, base, say)
    plots = {}
    for scene in dict.fromkeys(r["scene"] for r in records):
        plots[scene] = plot_scene([r for r in records if r["scene"] == scene],
                                  out / f"{scene}.png")
    if not all(plots.values()):
        say("plots skipped: matplotlib is not installed (pip install 'clray[plot]')")
    device_name = describe(select_device(device))
    (out / "results.json").write_text(
        json.dumps({"device": device_name, "repeat": repeat, "records": records}, indent=1)
        + "\n", encoding="utf-8")
    write_report(records, out, repeat, device_name, plots)
    return records
