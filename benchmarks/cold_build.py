"""The cold kernel build a new user waits for (issue 42): per example scene (scenes/*.toml at
their own settings, the knob table's defaults), in a new process with an empty PoCL kernel
cache (POCL_CACHE_DIR), the seconds of clBuildProgram plus the one-off compile of the first
launch (PoCL compiles the work-group function there, on the first enqueue of a kernel at a local
size), by CPU time (the process and its threads: less noisy on a shared machine) and wall time.

```
python benchmarks/cold_build.py [--json benchmarks/results/cold_build.json]
                                [--scenes cornell_box,spheres] [--repeat 1] [--device SPEC]
```

The child process builds the render kernel (`build`), then launches it twice over a 16 x 16
crop of the scene's image (same kernel configuration, same local size): the first launch's
time less the second's is the first launch's compile (`first_launch`), and `cold` is their
sum. `clray profile`'s build_cold_s is `build` alone. The JSON holds the device, the load
average before and after, and per scene its configuration's defines and each figure; with
--repeat N the medians of N children.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import RESULTS, check_outputs, names_of, positive_int  # noqa: E402

CROP = 16


def _clock() -> tuple[float, float]:
    return time.process_time(), time.perf_counter()


def _since(start: tuple[float, float]) -> dict:
    cpu, wall = _clock()
    return {"cpu_s": cpu - start[0], "wall_s": wall - start[1]}


def child(scene_path: str, device_spec: str | None) -> dict:
    """Run in the new process: the build and the two launches, timed."""
    from clray.device.context import describe, select_device
    from clray.device.launch import render_packed
    from clray.device.program import build_program
    from clray.render import RenderSettings, pack_for
    from clray.scene.load import load_scene

    device = select_device(device_spec)
    settings = RenderSettings(device=device_spec, stored_tuning=False)
    packed = pack_for(load_scene(Path(scene_path)), settings, device)
    params = packed.params.copy()
    params[0]["width"] = min(int(params[0]["width"]), CROP)
    params[0]["height"] = min(int(params[0]["height"]), CROP)
    packed = dataclasses.replace(packed, params=params)
    start = _clock()
    build_program(device, packed.config)
    build = _since(start)
    start = _clock()
    render_packed(packed, device)
    first = _since(start)
    start = _clock()
    render_packed(packed, device)
    second = _since(start)
    first_launch = {k: first[k] - second[k] for k in first}
    return {"device": describe(device), "options": packed.config.options(),
            "build": build, "first_launch": first_launch, "second_launch": second,
            "cold": {k: build[k] + first_launch[k] for k in build}}


def measure(scene: Path, device_spec: str | None) -> dict:
    with tempfile.TemporaryDirectory(prefix="clray-cold-") as cache:
        env = dict(os.environ, POCL_CACHE_DIR=cache)
        cmd = [sys.executable, __file__, "--child", str(scene)]
        if device_spec:
            cmd += ["--device", device_spec]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env,
                             cwd=ROOT).stdout
    return json.loads(out.splitlines()[-1])


def _median(runs: list[dict], part: str, key: str) -> float:
    return statistics.median(r[part][key] for r in runs)


def main(argv: list[str] | None = None) -> None:
    paths = sorted((ROOT / "scenes").glob("*.toml"))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=RESULTS / "cold_build.json")
    parser.add_argument("--scenes", type=names_of(p.stem for p in paths),
                        help="comma-separated scene names (default: all)")
    parser.add_argument("--repeat", type=positive_int, default=1)
    parser.add_argument("--device")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.device)))
        return
    check_outputs(parser, json=args.json)
    if args.scenes:
        paths = [p for p in paths if p.stem in args.scenes]
    result = {"load_before": os.getloadavg(), "repeat": args.repeat, "scenes": {}}
    print(f"{'scene':16s} {'cold cpu':>9s} {'wall':>7s} {'build cpu':>10s} "
          f"{'1st launch cpu':>15s}  load {os.getloadavg()[0]:.1f}")
    for path in paths:
        runs = [measure(path, args.device) for _ in range(args.repeat)]
        entry = {part: {key: _median(runs, part, key) for key in ("cpu_s", "wall_s")}
                 for part in ("build", "first_launch", "second_launch", "cold")}
        entry["options"] = runs[0]["options"]
        result["device"] = runs[0]["device"]
        result["scenes"][path.stem] = entry
        print(f"{path.stem:16s} {entry['cold']['cpu_s']:9.2f} {entry['cold']['wall_s']:7.2f} "
              f"{entry['build']['cpu_s']:10.2f} {entry['first_launch']['cpu_s']:15.2f}",
              flush=True)
    result["load_after"] = os.getloadavg()
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
