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
`clray tune` does not change what is hashed. --against exits 1 where a hash differs or a
render is missing. The JSON holds the device, the settings, and per render its key, sha256,
mean and seconds.
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

from cases import CASES  # noqa: E402

from clray.device.context import describe, select_device  # noqa: E402
from clray.render import RenderSettings, render  # noqa: E402
from clray.scene.load import load_scene, scene_from_dict  # noqa: E402

# (traversal, spp) for every scene; group packets for the example scenes only.
RUNS = (("single", 1), ("single", 16), ("sample_packet", 1), ("sample_packet", 16))
SCENE_RUNS = (*RUNS, ("group_packet", 4))
# Renders in double too: scenes with spheres, triangles, refraction, instances, textures.
DOUBLE = {"spheres", "glass", "instances", "textured", "cornell_box", "huge_ground",
          "closed_mesh_edges", "thin_ellipsoid_lit"}


def _scenes() -> list[tuple[str, object, tuple]]:
    """(name, scene, runs) of every example scene and hard case."""
    out = []
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        out.append((path.stem, load_scene(path), SCENE_RUNS))
    for case in CASES:
        out.append((case.name, scene_from_dict(case.scene), RUNS))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, required=True, help="where to write the hashes")
    parser.add_argument("--against", type=Path, help="hashes to compare with (exit 1 on a "
                        "difference)")
    parser.add_argument("--size", default="96x54", help="WxH (default 96x54)")
    parser.add_argument("--device", help="device spec, as clray render --device")
    parser.add_argument("--only", help="comma-separated scene names (default: all)")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    only = set(args.only.split(",")) if args.only else None
    device = select_device(args.device)
    renders: dict[str, dict] = {}
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, scene, runs in _scenes():
            if only and name not in only:
                continue
            precisions = ("float", "double") if name in DOUBLE else ("float",)
            for precision in precisions:
                for traversal, spp in runs:
                    key = f"{name}/{precision}/{traversal}/spp{spp}"
                    settings = RenderSettings(width=width, height=height, spp=spp,
                                              precision=precision, traversal=traversal,
                                              device=args.device, stored_tuning=False)
                    t0 = time.perf_counter()
                    image = np.ascontiguousarray(render(scene, settings).image,
                                                 dtype=np.float32)
                    renders[key] = {
                        "sha256": hashlib.sha256(image.tobytes()).hexdigest(),
                        "mean": float(image.mean()),
                        "seconds": round(time.perf_counter() - t0, 3),
                    }
                    print(f"{key:60s} {renders[key]['sha256'][:16]} "
                          f"{renders[key]['seconds']:.2f} s", flush=True)
    result = {"device": describe(device), "size": [width, height],
              "seconds": round(time.perf_counter() - start, 1), "renders": renders}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(f"{len(renders)} renders in {result['seconds']} s -> {args.json}")
    if args.against is None:
        return 0
    before = json.loads(args.against.read_text(encoding="utf-8"))["renders"]
    differ = [k for k in renders if k in before and before[k]["sha256"] != renders[k]["sha256"]]
    missing = [k for k in before if k not in renders and (not only or k.split("/")[0] in only)]
    for key in differ:
        print(f"DIFFERS {key}: mean {before[key]['mean']!r} -> {renders[key]['mean']!r}")
    for key in missing:
        print(f"MISSING {key}")
    same = sum(1 for k in renders if k in before and k not in differ)
    print(f"{same} identical, {len(differ)} differ, {len(missing)} missing "
          f"(against {args.against})")
    return 1 if differ or missing else 0


if __name__ == "__main__":
    sys.exit(main())
