"""Open Image Denoise on clray's renders (docs/denoising.md): the error against a 4,096-spp
reference at a few samples a pixel, denoised and not, the undenoised image at the denoised
one's cost, and the denoiser's time.

    python benchmarks/denoise.py [--json benchmarks/results/denoise.json] [--spp 4,16,64]
                                 [--reference-spp 4096] [--rounds 3] [--cache DIR]
                                 [--picture docs/denoise_depth_of_field.png]
                                 [--picture-scene {soft_lights,depth_of_field}]

Each scene renders at half its own width and height (its framing kept). The reference renders
once with another seed than the noisy images' (their samples must not be its first ones) and is
kept as a PFM in --cache, so a second run skips it. At each spp the scene renders with
`RenderSettings(denoise=True)` (the albedo and normal passes, then the denoiser): rmse of the
noisy image (`RenderResult.noisy`) and of the denoised one against the reference; the
undenoised render's seconds (`render_s`: its own `total_s`, with no passes traced), the
denoised render's `passes_s` and `denoise_s` and its `total_s` (`denoised_total_s`), medians
of --rounds. Its cost (render, passes and denoiser) buys an undenoised render of
`spp x cost / plain render's seconds` samples (the "same cost" render), with its own
measured seconds and rmse. At each spp the plain and the denoised render first run once each
untimed (their kernels' builds and PoCL's first-launch compiles), then once more untimed to
estimate the same-cost spp, whose render then runs once untimed too; then each of --rounds
rounds times the plain, the denoised and the same-cost render in turn, so that no row holds a
compile and the machine's load drifting falls on the three alike. --picture writes the noisy
and denoised images of --picture-scene at the lowest spp side by side as an sRGB PNG. Needs
the denoise extra (pyoidn); without it, says so and exits with status 2. Measures only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

from clray.denoise import check_denoiser
from clray.device.context import describe, select_device
from clray.errors import ClrayError
from clray.image_io import png_bytes, read_pfm, to_png_samples, write_image
from clray.metrics import rmse
from clray.render import RenderResult, RenderSettings, render
from clray.scene.load import load_scene

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import check_outputs, distinct_positive_ints, positive_int  # noqa: E402

SCENES = ("soft_lights", "depth_of_field")
REFERENCE_SEED = 1_000_003  # the noisy renders keep the scene's seed
GAP = 4  # pixels between the picture's halves


def _size(scene_name: str) -> tuple[int, int]:
    r = load_scene(ROOT / "scenes" / f"{scene_name}.toml").render
    return r.width // 2, r.height // 2


def reference(scene_name: str, spp: int, cache: Path) -> np.ndarray:
    width, height = _size(scene_name)
    path = cache / f"{scene_name}_{width}x{height}_{spp}spp_seed{REFERENCE_SEED}.pfm"
    if not path.exists():
        print(f"{scene_name}: reference at {spp} spp ({width}x{height})", flush=True)
        result = render(ROOT / "scenes" / f"{scene_name}.toml",
                        RenderSettings(width=width, height=height, spp=spp,
                                       seed=REFERENCE_SEED))
        write_image(path, result.image)
    return read_pfm(path)


def _render(scene_name: str, **settings: object) -> RenderResult:
    width, height = _size(scene_name)
    return render(ROOT / "scenes" / f"{scene_name}.toml",
                  RenderSettings(width=width, height=height, **settings))


def _median(results: list[RenderResult], key: str) -> float:
    return statistics.median(r.stats[key] for r in results)


def measure(scene_name: str, spp: int, ref: np.ndarray, rounds: int) -> tuple[dict, RenderResult]:
    """One row of the table, and a denoised result for the picture."""
    plain_settings, denoised_settings = {"spp": spp}, {"spp": spp, "denoise": True}
    # Warm-up: the first render of a configuration builds its kernels (the render's, the
    # passes') and PoCL compiles at its first launch; neither belongs in a timed row.
    for settings in (plain_settings, denoised_settings):
        _render(scene_name, **settings)
    # The same-cost spp must be known before the rounds, so that its render can take its
    # turn in them: from one more untimed render of each, now warm.
    estimate_plain_s = _render(scene_name, **plain_settings).stats["total_s"]
    estimate_cost_s = _render(scene_name, **denoised_settings).stats["total_s"]
    same_cost_spp = max(spp, int(spp * estimate_cost_s / estimate_plain_s))
    same_cost_settings = {"spp": same_cost_spp}
    _render(scene_name, **same_cost_settings)  # its own kernel where the spp changes it
    plain: list[RenderResult] = []
    denoised: list[RenderResult] = []
    same_cost: list[RenderResult] = []
    for _ in range(rounds):  # in turns: the load's drift falls on all three alike
        plain.append(_render(scene_name, **plain_settings))
        denoised.append(_render(scene_name, **denoised_settings))
        same_cost.append(_render(scene_name, **same_cost_settings))
    plain_s = _median(plain, "total_s")
    denoise_s = _median(denoised, "denoise_s")
    cost_s = _median(denoised, "total_s")
    row = {
        "scene": scene_name, "spp": spp,
        "rmse_noisy": rmse(denoised[0].noisy, ref),
        "rmse_denoised": rmse(denoised[0].image, ref),
        "render_s": plain_s,
        "passes_s": _median(denoised, "passes_s"),
        "denoise_s": denoise_s,
        "denoised_total_s": cost_s,
        "same_cost_spp": same_cost_spp,
        "same_cost_s": _median(same_cost, "total_s"),
        "rmse_same_cost": rmse(same_cost[0].image, ref),
        # Other work on the machine slows the denoiser's threads most: the load it ran under.
        "load_average_1min": os.getloadavg()[0],
    }
    return row, denoised[0]


def picture(result: RenderResult, path: Path) -> None:
    """Noisy left, denoised right, encoded as the result's PNG."""
    noisy = to_png_samples(result.noisy, result.encoding)
    clean = to_png_samples(result.image, result.encoding)
    gap = np.full((noisy.shape[0], GAP, 3), np.iinfo(noisy.dtype).max, dtype=noisy.dtype)
    path.write_bytes(png_bytes(np.concatenate([noisy, gap, clean], axis=1),
                               linear=result.encoding.linear))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "denoise.json")
    parser.add_argument("--spp", type=distinct_positive_ints, default=[4, 16, 64],
                        help="comma-separated samples per pixel, each once (default: 4,16,64)")
    parser.add_argument("--reference-spp", type=positive_int, default=4096)
    parser.add_argument("--rounds", type=positive_int, default=3)
    parser.add_argument("--cache", type=Path, default=HERE / "results" / "denoise_references")
    parser.add_argument("--picture", type=Path)
    parser.add_argument("--picture-scene", choices=SCENES, default="depth_of_field",
                        help="the scene of --picture (default: depth_of_field)")
    args = parser.parse_args(argv)
    check_outputs(parser, json=args.json, picture=args.picture)
    try:  # the references are written there after minutes of rendering
        args.cache.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        parser.error(f"--cache {args.cache}: cannot make the folder ({err.strerror or err})")
    try:
        check_denoiser()
    except ClrayError as err:
        print(err, file=sys.stderr)
        sys.exit(2)
    spps = args.spp
    rows = []
    for scene_name in SCENES:
        ref = reference(scene_name, args.reference_spp, args.cache)
        for spp in spps:
            row, result = measure(scene_name, spp, ref, args.rounds)
            rows.append(row)
            print(f"{scene_name:15s} {spp:3d} spp  rmse {row['rmse_noisy']:.4f} -> denoised "
                  f"{row['rmse_denoised']:.4f} (render {row['render_s']:.2f} s + passes "
                  f"{row['passes_s']:.2f} s + denoise {row['denoise_s']:.2f} s); same cost: "
                  f"{row['same_cost_spp']} spp {row['same_cost_s']:.2f} s rmse "
                  f"{row['rmse_same_cost']:.4f}", flush=True)
            if args.picture and scene_name == args.picture_scene and spp == min(spps):
                picture(result, args.picture)
    report = {"device": describe(select_device(None)), "machine": platform.processor() or
              platform.machine(), "reference_spp": args.reference_spp,
              "reference_seed": REFERENCE_SEED, "rounds": args.rounds,
              "sizes": {name: list(_size(name)) for name in SCENES}, "rows": rows}
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
