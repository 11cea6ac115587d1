"""Fingerprints of the kernels' images: a sha256 of every float32 image that the example scenes
(scenes/*.toml) and the hard cases (tests/hard_cases/cases.py) render, small, under each
traversal scheme, in float (and double for a few), on one device.

For kernel changes that must not change a single bit (code moved between files, a formula
written once for scalars and lanes): record the hashes before, then after, and compare.

```
python benchmarks/image_hashes.py --json before.json               # record
python benchmarks/image_hashes.py --json after.json --against before.json  # and compare
```

Each scene renders at --size (96x54 by default) with the traversal single at 1 and 16 samples
per pixel, sample_packet at 1 and 16 (at 1 spp render() builds the single-ray kernel for it, at
16 the packets) and, for the example scenes, group_packet at 4. The scenes' own depth, seed and
lights are kept. The knobs are the defaults (stored_tuning off), so a tuning file written by
`clray tune` does not change what is hashed. --against is read before the first render: a
file that cannot be read, of another --size, or with no render in common with this run is a
usage error. It exits 1 where a hash differs or a render is missing. The JSON (by default
benchmarks/results/image_hashes.json) holds the device, the settings, and per render its key,
sha256, mean and seconds.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "hard_cases"))
sys.path.insert(0, str(ROOT))

from cases import CASES  # noqa: E402

from benchmarks.common import RESULTS, check_outputs, image_size, names_of  # noqa: E402
from clray.device.context import describe, select_device  # noqa: E402
from clray.render import RenderSettings, render  # noqa: E402
from clray.scene.load import load_scene, scene_from_dict  # noqa: E402

# (traversal, spp) for every scene; group packets for the example scenes only.
RUNS = (("single", 1), ("single", 16), ("sample_packet", 1), ("sample_packet", 16))
SCENE_RUNS = (*RUNS, ("group_packet", 4))
# Renders in double too: scenes with spheres, triangles, refraction, instances, textures, and
# the hard case whose float image fails (a sphere as big as a ground, flagged for fp64).
DOUBLE = {"spheres", "glass", "instances", "textured", "cornell_box", "huge_ground_sphere",
          "closed_mesh_edges", "thin_ellipsoid_lit"}


def scene_runs() -> dict[str, tuple]:
    """name -> (traversal, spp) runs of every example scene and hard case, in render order."""
    out = {path.stem: SCENE_RUNS for path in sorted((ROOT / "scenes").glob("*.toml"))}
    out.update((case.name, RUNS) for case in CASES)
    return out


def render_keys(names: list[str] | None = None) -> list[str]:
    """NAME/PRECISION/TRAVERSAL/sppN of every render of `names` (default: all), in order."""
    runs = scene_runs()
    return [f"{name}/{precision}/{traversal}/spp{spp}"
            for name in (names or runs)
            for precision in (("float", "double") if name in DOUBLE else ("float",))
            for traversal, spp in runs[name]]


def _scene(name: str) -> object:
    path = ROOT / "scenes" / f"{name}.toml"
    if path.exists():
        return load_scene(path)
    return scene_from_dict(next(case for case in CASES if case.name == name).scene)


def _baseline(parser: argparse.ArgumentParser, path: Path, size: tuple[int, int],
              keys: list[str]) -> dict:
    """--against's renders, read and checked before any render: a missing or unreadable file,
    another image size (every hash would differ) or no render in common (nothing would be
    checked) is a usage error, not a verdict after minutes of renders."""
    try:
        before = json.loads(path.read_text(encoding="utf-8"))
        renders, their_size = before["renders"], tuple(before["size"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        parser.error(f"--against {path}: not a file of this script's hashes ({err})")
    if their_size != size:
        parser.error(f"--against {path} holds {their_size[0]}x{their_size[1]} renders; "
                     f"render at that size (--size {their_size[0]}x{their_size[1]}) to compare")
    if not set(keys) & set(renders):
        parser.error(f"--against {path}: none of its {len(renders)} renders is among this "
                     "run's: nothing would be compared")
    return before


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=RESULTS / "image_hashes.json",
                        help="where to write the hashes (default: "
                        "benchmarks/results/image_hashes.json)")
    parser.add_argument("--against", type=Path, help="hashes to compare with (exit 1 on a "
                        "difference)")
    parser.add_argument("--size", type=image_size, default=(96, 54),
                        help="WxH (default 96x54)")
    parser.add_argument("--device", help="device spec, as clray render --device")
    parser.add_argument("--only", type=names_of(scene_runs()),
                        help="comma-separated scene names (default: all)")
    args = parser.parse_args(argv)
    width, height = args.size
    only = set(args.only) if args.only else None
    keys = render_keys(args.only)
    before = _baseline(parser, args.against, args.size, keys) if args.against else None
    check_outputs(parser, json=args.json)
    device = select_device(args.device)
    if before is not None and before.get("device") not in (None, describe(device)):
        print(f"note: --against was rendered on {before['device']}, this run on "
              f"{describe(device)}: hashes of two devices may differ")
    renders: dict[str, dict] = {}
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene_name, scene = None, None
        for key in keys:
            name, precision, traversal, spp_text = key.split("/")
            if name != scene_name:
                scene_name, scene = name, _scene(name)
            spp = int(spp_text.removeprefix("spp"))
            settings = RenderSettings(width=width, height=height, spp=spp,
                                      precision=precision, traversal=traversal,
                                      device=args.device, stored_tuning=False)
            t0 = time.perf_counter()
            image = np.ascontiguousarray(render(scene, settings).image, dtype=np.float32)
            renders[key] = {
                "sha256": hashlib.sha256(image.tobytes()).hexdigest(),
                "mean": float(image.mean()),
                "seconds": round(time.perf_counter() - t0, 3),
            }
            print(f"{key:60s} {renders[key]['sha256'][:16]} "
                  f"{renders[key]['seconds']:.2f} s", flush=True)
    result = {"device": describe(device), "size": [width, height],
              "seconds": round(time.perf_counter() - start, 1), "renders": renders}
    args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(f"{len(renders)} renders in {result['seconds']} s -> {args.json}")
    if before is None:
        return 0
    before = before["renders"]
    differ = [k for k in renders if k in before and before[k]["sha256"] != renders[k]["sha256"]]
    missing = [k for k in before if k not in renders and (not only or k.split("/")[0] in only)]
    new = [k for k in renders if k not in before]
    for key in differ:
        print(f"DIFFERS {key}: mean {before[key]['mean']!r} -> {renders[key]['mean']!r}")
    for key in missing:
        print(f"MISSING {key}")
    same = sum(1 for k in renders if k in before and k not in differ)
    print(f"{same} identical, {len(differ)} differ, {len(missing)} missing, {len(new)} not in "
          f"the baseline (against {args.against})")
    if same + len(differ) == 0:
        print("nothing was compared")
        return 1
    return 1 if differ or missing else 0


if __name__ == "__main__":
    sys.exit(main())
