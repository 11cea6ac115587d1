"""Instructions per stage of the render kernel: where a sample's work goes, counted by valgrind.

    python benchmarks/stages.py [--scenes spheres,mesh,SCENE.toml] [--spp 1,16] [--size 32x18]
                                [--rows START:STOP] [--traversals single,sample_packet]
                                [--json benchmarks/results/stages.json] [--mesh-dir DIR]

The kernels mark their stages STAGE (kernels/real.h): the camera ray (`sample_ray`), the ray
set-up (`make_ray`, and `make_walk_ray` for the single-ray closest-hit walks' rays, whose
triangle set-up the walk makes at its first leaf, inside `closest_hit`), the closest hit
(`closest_hit`, and for sample packets `packet_closest`), the shading point (`shade_point`), a
light's shadow ray (`light_ray`) and term (`light_term`), and the shadow ray's walk
(`transmission`, `packet_transmission`). The stage-profiling build (KernelConfig.stage_profile,
-DSTAGE_PROFILE=1) keeps each a function of its own; one render of each scene runs under
`valgrind --tool=callgrind` with one PoCL thread, counting inside the render kernel only. A
stage's count is inclusive (it and everything it calls), with its number of calls. Stages nest
(light_ray sets up its shadow ray with make_ray), so the shares do not add up to 100 %; what no
stage holds is the ray tree's own bookkeeping and the sample packets' gathering of lanes. Calls
that are not inlined cost instructions of their own: the profiling build's total is reported
beside the normal build's, so the overhead is in view.

Sample packets have the lanes a render gives them on PoCL's device at that many samples a
pixel (`clray.device.policy.packet_lanes_for`: 16 on AVX2 at 16 spp).

A pixel's samples are as coherent as the image is large: at 32 x 18 a pixel covers what 1,600
pixels of a 1280 x 720 image do, so a change that pays off where a pixel's rays stay together
(packets) is best counted on a band of a full-size image: `--size 1280x720 --rows 360:361`
renders that row only (the rows a distributed render's tile would), the same values as in the
whole image.

Needs valgrind and PoCL's CPU device. Measures only; each count takes about a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks import compare  # noqa: E402  (its scene names and files)
from benchmarks.common import check_outputs, image_size, names_of, positive_ints  # noqa: E402

# The traversal schemes of clray.knobs.TRAVERSALS, here without importing clray (and OpenCL)
# into the parent, which only starts children; tests/test_benchmark_args.py checks them.
TRAVERSALS = ("single", "sample_packet", "group_packet")
KERNEL_FUNCTION = "_pocl_kernel_render_workgroup"
STAGES = ("sample_ray", "make_ray", "make_walk_ray", "closest_hit", "packet_closest",
          "shade_point", "light_ray", "transmission", "packet_transmission", "light_term")

# Runs in the child: one render; prints the rays it traced.
_RENDER = """
import dataclasses, json, sys
from clray.device.context import select_device
from clray.device.launch import render_packed
from clray.device.pack import pack_scene
from clray.device.policy import packet_lanes_for
from clray.scene.load import load_scene
path, traversal, spp, width, height, profile, first, end = sys.argv[1:9]
scene = load_scene(path)
r = scene.render
device = select_device("pocl")
# Sample packets as a render packs them: the device's own lanes for this many samples.
lanes = {}
if traversal == "sample_packet":
    lanes["packet_lanes"] = packet_lanes_for(device, spp=int(spp))
packed = pack_scene(scene, width=int(width), height=int(height), spp=int(spp),
                    max_depth=r.max_depth, min_weight=r.min_weight, seed=r.seed,
                    traversal=traversal, **lanes)
config = dataclasses.replace(packed.config, stage_profile=profile == "1")
_, stats = render_packed(dataclasses.replace(packed, config=config), device,
                         rows=(int(first), int(end)))
print(json.dumps(stats["rays"]))
"""


def _callgrind_stages(out_file: Path) -> dict[str, dict[str, int]]:
    """Inclusive instructions and calls of each stage, and the kernel's total, from a
    callgrind output file (its call records: `cfn=` names the callee, the `calls=` line after
    it counts calls, the line after that holds the inclusive cost)."""
    names: dict[str, str] = {}
    totals: dict[str, dict[str, int]] = defaultdict(lambda: {"instructions": 0, "calls": 0})
    callee = None
    lines = out_file.read_text().splitlines()
    for i, line in enumerate(lines):
        named = re.match(r"c?fn=\((\d+)\)(?: (.*))?", line)
        if named:
            ident, name = named.groups()
            if name:
                names[ident] = name
            callee = names.get(ident) if line.startswith("cfn=") else None
            continue
        if line.startswith("calls=") and callee is not None:
            calls = int(line.split()[0].split("=")[1])
            cost = int(lines[i + 1].split()[1])
            for stage in STAGES:
                if callee == stage or callee.startswith(stage + "."):
                    totals[stage]["calls"] += calls
                    totals[stage]["instructions"] += cost
            callee = None
    return dict(totals)


def _run(scene: Path, traversal: str, spp: int, size: tuple[int, int], rows: tuple[int, int],
         profile: bool, out_file: Path | None) -> dict:
    env = {**os.environ, "POCL_MAX_PTHREAD_COUNT": "1"}
    command = [sys.executable, "-c", _RENDER, str(scene), traversal, str(spp), str(size[0]),
               str(size[1]), "1" if profile else "0", str(rows[0]), str(rows[1])]
    if out_file is not None:
        command = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out_file}",
                   f"--toggle-collect={KERNEL_FUNCTION}*", *command]
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env,
                          check=True)
    result = {"rays": json.loads(done.stdout.strip().splitlines()[-1])}
    if out_file is not None:
        collected = re.findall(r"Collected\s*:\s*(\d+)", done.stderr)
        if not collected:
            raise RuntimeError(f"no instruction count in valgrind's output:\n{done.stderr}")
        result["instructions"] = int(collected[-1])
    return result


def count_stages(scene: Path, traversal: str, spp: int, size: tuple[int, int],
                 rows: tuple[int, int], tmp: Path) -> dict:
    """The normal build's instructions and the profiling build's, by stage, for the image's
    rows [rows[0], rows[1])."""
    out_file = tmp / "callgrind.out"
    # Plain renders first fill PoCL's kernel cache, so no compiler runs under valgrind.
    _run(scene, traversal, spp, size, rows, False, None)
    normal = _run(scene, traversal, spp, size, rows, False, out_file)
    _run(scene, traversal, spp, size, rows, True, None)
    profiled = _run(scene, traversal, spp, size, rows, True, out_file)
    stages = _callgrind_stages(out_file)
    total = profiled["instructions"]
    samples = size[0] * (rows[1] - rows[0]) * spp
    report = {}
    for stage, s in stages.items():
        report[stage] = {**s, "share": s["instructions"] / total,
                         "per_call": s["instructions"] / s["calls"] if s["calls"] else None,
                         "per_sample": s["instructions"] / samples}
    return {"rays": normal["rays"], "samples": samples,
            "instructions": normal["instructions"],
            "instructions_profiling_build": total, "stages": report}


def _summary(name: str, traversal: str, spp: int, result: dict) -> str:
    samples = result["samples"]
    lines = [f"{name}, {traversal}, {spp} spp: {result['instructions'] / samples:.0f} "
             f"instructions a sample ({result['instructions_profiling_build'] / samples:.0f} "
             "in the profiling build)"]
    for stage in STAGES:
        s = result["stages"].get(stage)
        if s:
            lines.append(f"  {stage:20s} {100 * s['share']:5.1f} %  {s['per_sample']:6.0f} a "
                         f"sample  {s['per_call']:6.0f} a call  ({s['calls']} calls)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="spheres,mesh", help="comma-separated: spheres, "
                        "mesh (generated) or paths to scene files")
    parser.add_argument("--spp", type=positive_ints, default=[1, 16],
                        help="comma-separated samples per pixel")
    parser.add_argument("--size", type=image_size, default=(32, 18), metavar="WxH")
    parser.add_argument("--rows", metavar="START:STOP",
                        help="count only these rows of the image (default: all of them)")
    parser.add_argument("--traversals", type=names_of(TRAVERSALS),
                        default=["single", "sample_packet"],
                        help=f"comma-separated, of {','.join(TRAVERSALS)}")
    parser.add_argument("--json", type=Path, default=HERE / "results" / "stages.json")
    parser.add_argument("--mesh-dir", help="where to write the mesh scene (its folder mesh/ "
                        "there; default: a temporary folder)")
    args = parser.parse_args(argv)
    width, height = args.size
    rows = (0, height)
    if args.rows:
        start, _, stop = args.rows.partition(":")
        if not (start.isdigit() and stop.isdigit() and 0 <= int(start) < int(stop) <= height):
            parser.error(f"--rows {args.rows}: expected START:STOP within the image's "
                         f"{height} rows")
        rows = (int(start), int(stop))
    names = [n for n in args.scenes.split(",") if n]
    unknown = compare.unknown_scenes(names)
    if unknown:
        parser.error(f"scenes are spheres, mesh or scene files (not found: {unknown})")
    check_outputs(parser, json=args.json)
    if shutil.which("valgrind") is None:
        sys.exit("stages.py needs valgrind (Debian: apt-get install valgrind)")
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        scenes = compare.scene_paths(names, Path(args.mesh_dir) if args.mesh_dir else tmp)
        for name in names:
            for spp in args.spp:
                for traversal in args.traversals:
                    result = count_stages(scenes[name], traversal, spp, (width, height), rows,
                                          tmp)
                    results.setdefault(name, {}).setdefault(str(spp), {})[traversal] = result
                    print(_summary(name, traversal, spp, result), flush=True)
    args.json.write_text(json.dumps({"size": [width, height], "rows": list(rows),
                                           "scenes": results},
                                          indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
