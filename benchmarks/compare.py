"""Kernel time of two or more commits, side by side in one run.

    python benchmarks/compare.py REF[:TRAVERSAL[:LANES]] [REF ...] [--rounds 5] [--per-round 3]
                                 [--scenes spheres,mesh] [--device SPEC] [--spp N] [--size WxH]
                                 [--json benchmarks/results/compare.json]

Each REF (a commit, branch or `WORKTREE` for the files as they are now) is checked out into a
temporary git worktree. Rounds alternate between the refs: in each round every ref renders every
scene in a fresh process (importing clray from its own worktree, kernels included) once as a
warm-up and then `--per-round` times, timed by OpenCL profiling events. Every other round takes
the refs in reverse order (A B C, C B A, A B C, ...), so that no ref always runs first or last;
over an even `--rounds` every ref's average place is the same. Medians over all rounds are
reported per ref and scene, with the ratio to the first ref. Alternating the refs spreads the
machine's load changes over all of them, which separate runs at different times do not.
Each ref packs the scene as its own `clray render --no-tuning` does, where the commit has the
device policy (clray.device.policy.device_plan): the device's BVH width, traversal and switches,
the BVH built on the device where its packer does so. A commit from before it packs with its
KernelConfig's and pack_scene's defaults (a BVH of width 8 built on the host, the single-ray
walk). `REF:TRAVERSAL` (e.g. `WORKTREE:sample_packet`) renders with that traversal, as `clray
render --traversal` does (at 1 spp a sample-packet traversal builds the single-ray walk; before
the device policy, KernelConfig's traversal as named), and `REF:sample_packet:LANES` with
packets of LANES rays (the device's own where not given; before the device policy, 8). The
traversal and BVH width each ref built are recorded. `--spp` and `--size` replace the scenes'
own; every other render setting is the scene's (its `min_weight` too, where the commit has
it). `--scenes` takes spheres, mesh (the generated 327k-triangle mesh) or scene files.

An unknown REF or TRAVERSAL, a REF or scene given twice, or no scene, is a usage error before any
worktree is made; a render that fails stops the run with one line naming the ref, the scene and
its process's last line on stderr. The JSON records the `--device` given, the device and
platform version the processes rendered on (one for all refs, or the run stops), the host's
processor, and each ref's
commit SHA (WORKTREE: HEAD's, and whether tracked files differ from it); an image mean that is
not finite is null, with the image's count of pixels that are not (benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import check_outputs, cpu_model, image_size, positive_int  # noqa: E402
from clray.errors import one_line  # noqa: E402
from clray.knobs import TRAVERSALS  # noqa: E402

if TYPE_CHECKING:
    import numpy as np


def image_summary(image: np.ndarray) -> dict:
    """The image's mean, None where it is not finite (strict JSON has no NaN), and how many
    pixels have a channel that is NaN or infinite, which a NaN mean cannot tell. Its source is
    part of _MEASURE: it runs in each ref's process, on that ref's image."""
    import math

    import numpy as np

    finite = np.isfinite(image)
    pixels = finite.all(axis=-1) if finite.ndim == 3 else finite
    mean = float(image.mean())
    return {"mean": mean if math.isfinite(mean) else None,
            "nonfinite_pixels": int(pixels.size - np.count_nonzero(pixels))}


# Runs inside each worktree's process; API that a compared commit may lack is tried first.
# The annotations stay unevaluated: image_summary's name numpy, which the process imports late.
_MEASURE = """from __future__ import annotations
import importlib.util, json, os, sys
""" + inspect.getsource(image_summary) + """
# The virtual environment's editable install maps clray.kernels to its own checkout's kernels/:
# take this tree's, or every ref would render with the same kernels (against its own layouts).
kernels = os.path.join(os.getcwd(), "kernels", "__init__.py")
if os.path.exists(kernels):
    spec = importlib.util.spec_from_file_location("clray.kernels", kernels)
    sys.modules["clray.kernels"] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sys.modules["clray.kernels"])
from clray.device.context import describe, select_device
from clray.device.pack import pack_scene
try:
    from clray.device.launch import render_packed
except ImportError:  # a commit from before clray.device.launch
    from clray.render import render_packed
from clray.scene.load import load_scene
try:
    from clray.device.context import queue_for
    from clray.device.policy import device_plan
    from clray.knobs import Tuning
except ImportError:  # a commit from before the device policy
    device_plan = None
path, repeat, spec, variant = sys.argv[1], int(sys.argv[2]), sys.argv[3] or None, sys.argv[4]
spp, width, height = (int(v) for v in sys.argv[5:8])
scene = load_scene(path)
r = scene.render
spp = spp or r.spp
traversal, _, lanes = variant.partition(":")
device = select_device(spec)
if device_plan is None:
    # KernelConfig's and pack_scene's defaults: what the commit's own render packed.
    switches = {"traversal": traversal} if traversal else {}
else:
    # As the commit's `clray render --no-tuning [--traversal T]` packs it: the device plan's
    # BVH width, traversal and switches, the BVH built on the device where the packer does.
    plan = device_plan(device, spp=spp, traversal=traversal or None, tuning=Tuning())
    switches = {"queue": queue_for(device), **plan.pack_arguments()}
if lanes:
    switches["packet_lanes"] = int(lanes)
# The scene's own min_weight, as its `clray render` packs it; a commit from before min_weight
# has neither the setting nor the argument.
if hasattr(r, "min_weight"):
    switches["min_weight"] = r.min_weight
packed = pack_scene(scene, width=width or r.width, height=height or r.height, spp=spp,
                    max_depth=r.max_depth, seed=r.seed, **switches)
render_packed(packed, device)
times = []
for _ in range(repeat):
    image, stats = render_packed(packed, device)
    times.append(stats["kernel_s"])
config = packed.config
print(json.dumps({"kernel_s": times, "rays": stats["rays"]["total"], **image_summary(image),
                  "traversal": getattr(config, "traversal", None),
                  "bvh_width": getattr(config, "bvh_width", None),
                  "device": describe(device),
                  "platform_version": device.platform.version.strip()}))
"""


def _split_ref(ref: str) -> tuple[str, str]:
    """(commit, "TRAVERSAL[:LANES]" or "") of a REF[:TRAVERSAL[:LANES]] argument."""
    commit, _, variant = ref.partition(":")
    return commit, variant


def _worktree(ref: str, tmp: Path) -> Path:
    ref = _split_ref(ref)[0]
    if ref == "WORKTREE":
        return ROOT
    path = tmp / ref.replace("/", "_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(path), ref],
                   check=True, capture_output=True)
    return path


def unknown_refs(refs: list[str]) -> list[str]:
    """The commits of `refs` (REF[:TRAVERSAL[:LANES]]) that git does not resolve to a commit
    here: checked before any worktree is made, so that a typo is a usage error, not a
    traceback after the other refs' worktrees were registered."""
    commits = dict.fromkeys(_split_ref(ref)[0] for ref in refs)
    return [commit for commit in commits if commit != "WORKTREE" and subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}"],
        capture_output=True).returncode != 0]


def revision(commit: str) -> dict:
    """What a ref renders, as git names it: `commit`'s SHA, or for WORKTREE the SHA of HEAD here
    and whether tracked files differ from it (`dirty`; untracked files are not counted, or a
    worktree whose .venv is a link would always be dirty). A name such as HEAD~3 moves."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True,
                              text=True).stdout.strip()
    if commit != "WORKTREE":
        return {"commit": git("rev-parse", "--verify", f"{commit}^{{commit}}"), "dirty": False}
    return {"commit": git("rev-parse", "--verify", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}


def unknown_scenes(names: list[str]) -> list[str]:
    """The names that are neither spheres, mesh nor a scene file."""
    return [n for n in names if n not in ("spheres", "mesh") and not Path(n).is_file()]


def scene_paths(names: list[str], tmp: Path) -> dict[str, Path]:
    """Scene file of each name: spheres, mesh (generated) or a path to a scene file."""
    paths = {"spheres": ROOT / "scenes" / "spheres.toml"}
    if "mesh" in names:
        subprocess.run([sys.executable, str(ROOT / "scripts" / "make_mesh_scene.py"), "--out",
                        str(tmp / "mesh")], check=True, capture_output=True)
        paths["mesh"] = tmp / "mesh" / "bumpy.toml"
    return {name: paths.get(name) or Path(name).resolve() for name in names}


def three_figures(value: float) -> str:
    """`value` to three significant figures, without an exponent: a 4x4 render's kernel time
    at four decimals was 0.0000 s, and 1234 Mrays/s in `.3g` is 1.23e+03."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    return f"{value:.{max(0, 2 - math.floor(math.log10(abs(value))))}f}"


class MeasureError(Exception):
    """A ref's measuring process failed; the message is its reason, one line."""


def child_reason(returncode: int, stderr: str) -> str:
    """Why a measuring process failed: its last line on stderr (a traceback's last line, the
    exception), as clray.profile reads a failed child, else its signal or exit status."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    if lines:
        return one_line(lines[-1])
    if returncode < 0:
        return f"killed by signal {-returncode}"
    return f"exit status {returncode}, and no message"


def _measure(tree: Path, scene: Path, repeat: int, device: str | None, variant: str,
             shape: tuple[int, int, int]) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", _MEASURE, str(scene), str(repeat), device or "",
                           variant, *(str(v) for v in shape)],
                          capture_output=True, text=True, cwd=tree, env=env)
    if done.returncode != 0:
        raise MeasureError(child_reason(done.returncode, done.stderr))
    return json.loads(done.stdout.splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("refs", nargs="+", help="commits to compare, each at most once; "
                        "WORKTREE = files as they are")
    parser.add_argument("--rounds", type=positive_int, default=5)
    parser.add_argument("--per-round", type=positive_int, default=3)
    parser.add_argument("--scenes", default="spheres,mesh", help="comma-separated, each at "
                        "most once: spheres, mesh (generated) or paths to scene files")
    parser.add_argument("--device", default=None)
    parser.add_argument("--json", type=Path, default=HERE / "results" / "compare.json")
    parser.add_argument("--spp", type=positive_int, default=None,
                        help="samples per pixel (default: the scene's)")
    parser.add_argument("--size", type=image_size, default=None, metavar="WxH",
                        help="image size (default: the scene's)")
    args = parser.parse_args(argv)
    # The child reads 0 as "the scene's own".
    shape = (args.spp or 0, *(args.size or (0, 0)))
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    if not names:
        parser.error("--scenes: expected at least one of spheres, mesh or a scene file")
    # A repeat is refused, not merged: results are keyed by name, so a repeated ref or scene
    # was printed twice with its runs pooled, and dropping it would hide what was typed.
    for what, given in (("REF", args.refs), ("scene", names)):
        repeated = sorted({x for x in given if given.count(x) > 1})
        if repeated:
            parser.error(f"each {what} at most once; repeated: {', '.join(repeated)}")
    unknown = unknown_scenes(names)
    if unknown:
        parser.error(f"scenes are spheres, mesh or scene files (not found: {unknown})")
    # A misspelt traversal would fail only in the first child, after the worktrees were made.
    # The names are this tree's: the schemes have only been added to, never renamed, so an
    # older commit's are among them.
    traversals = {ref: _split_ref(ref)[1].partition(":")[0] for ref in args.refs}
    bad_traversals = [ref for ref, t in traversals.items() if t and t not in TRAVERSALS]
    if bad_traversals:
        parser.error(f"REF:TRAVERSAL takes a traversal of {', '.join(TRAVERSALS)}: "
                     f"{', '.join(bad_traversals)}")
    lanes = {ref: _split_ref(ref)[1].partition(":")[2] for ref in args.refs}
    bad_lanes = [ref for ref, n in lanes.items() if n and not (n.isdigit() and int(n) > 0)]
    if bad_lanes:
        parser.error(f"REF:TRAVERSAL:LANES takes a whole number of lanes: {bad_lanes}")
    bad_refs = unknown_refs(args.refs)
    if bad_refs:
        parser.error(f"not a commit in {ROOT}: {', '.join(bad_refs)}")
    check_outputs(parser, json=args.json)

    with tempfile.TemporaryDirectory(prefix="clray-compare-") as tmp_name:
        tmp = Path(tmp_name)
        commits = dict.fromkeys(_split_ref(ref)[0] for ref in args.refs)
        commit_trees: dict[str, Path] = {}
        times: dict[str, dict[str, list[float]]] = {r: {n: [] for n in names} for r in args.refs}
        last: dict[str, dict[str, dict]] = {r: {} for r in args.refs}  # each one's last child
        revisions = {commit: revision(commit) for commit in commits}
        # (description, platform version) each ref's children rendered on; all must be the
        # first's: one --device can pick different devices in commits whose select_device
        # differs, and their times would not compare.
        devices: dict[str, tuple[str, str]] = {}
        # The worktrees are made inside the try: one that fails to check out, or an interrupt
        # between two, still removes those already registered.
        try:
            for commit in commits:
                commit_trees[commit] = _worktree(commit, tmp)
            trees = {ref: commit_trees[_split_ref(ref)[0]] for ref in args.refs}
            scenes = scene_paths(names, tmp)
            for round_index in range(args.rounds):
                # Every other round takes the refs in reverse (A B C, C B A, ...): a ref that
                # always ran first (cold caches, a clock still rising) or last would carry
                # that place's bias; over an even number of rounds every ref's average place
                # is the same.
                order = args.refs if round_index % 2 == 0 else args.refs[::-1]
                for ref in order:
                    for name, path in scenes.items():
                        try:
                            got = _measure(trees[ref], path, args.per_round, args.device,
                                           _split_ref(ref)[1], shape)
                        except MeasureError as err:
                            # One line, and the finally below still removes the worktrees.
                            sys.exit(one_line(f"compare.py: {ref}, scene {name}: the "
                                              f"measuring process failed: {err}"))
                        seen = (got["device"], got["platform_version"])
                        first, device = next(iter(devices.items()), (ref, seen))
                        if seen != device:
                            sys.exit(one_line(
                                f"compare.py: {ref} rendered on {seen[0]} ({seen[1]}), "
                                f"{first} on {device[0]} ({device[1]}): not one device"))
                        devices[ref] = seen
                        times[ref][name] += got["kernel_s"]
                        last[ref][name] = got
                print(f"round {round_index + 1}/{args.rounds} done", file=sys.stderr)
        finally:
            for tree in commit_trees.values():
                if tree != ROOT:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                                    str(tree)], capture_output=True)

    base = args.refs[0]
    device = devices[base]  # every ref's, checked above
    report = {"benchmark": "compare", "device_spec": args.device, "device": device[0],
              "platform_version": device[1], **cpu_model(), "rounds": args.rounds,
              "per_round": args.per_round, "spp": args.spp,
              "size": "x".join(map(str, args.size)) if args.size else None, "refs": {}}
    for ref in args.refs:
        entry = {}
        for name in names:
            median = statistics.median(times[ref][name])
            got = last[ref][name]
            entry[name] = {"kernel_s": median, "kernel_runs_s": times[ref][name],
                           "image_mean": got["mean"], "nonfinite_pixels": got["nonfinite_pixels"],
                           "rays": got["rays"], "mrays_per_s": got["rays"] / median * 1e-6,
                           "traversal": got.get("traversal"), "bvh_width": got.get("bvh_width"),
                           "speedup_vs_first": statistics.median(times[base][name]) / median}
            print(f"{ref:>12} {Path(name).stem:>8}: kernel {three_figures(median)} s (median "
                  f"of {len(times[ref][name])}), {three_figures(entry[name]['mrays_per_s'])} "
                  "Mrays/s, "
                  f"x{entry[name]['speedup_vs_first']:.2f} vs {base}"
                  + (f", {got['nonfinite_pixels']} pixels not finite"
                     if got["nonfinite_pixels"] else ""))
        report["refs"][ref] = {**revisions[_split_ref(ref)[0]], "device": devices[ref][0],
                               "platform_version": devices[ref][1], "scenes": entry}
    # allow_nan=False: a NaN or infinity here is a bug to see, not a file other readers refuse.
    args.json.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
