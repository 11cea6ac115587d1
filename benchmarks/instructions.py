"""Instructions the render kernel executes per pixel and per ray, counted by valgrind.

    python benchmarks/instructions.py [--json benchmarks/results/instructions.json]
                                      [--scenes spheres,mesh,SCENE.toml] [--size WxH]
                                      [--mesh-dir DIR]

Times on a shared machine move by 10 to 30 % from one minute to the next; the number of
instructions a render executes does not. Each scene renders once per variant (as bench.py's time
split: `primary` at depth 0 without lights, `primary_shadow` at depth 0 with them, `full`) in a
child process under `valgrind --tool=callgrind`, counting only inside PoCL's work-group function
of the render kernel, with one PoCL thread. The kernel comes from PoCL's cache, filled by a plain
render first, so no compiler runs under valgrind. Needs valgrind and PoCL's CPU device (the
counted function is PoCL's); each count takes about a minute. Measures only.
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
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from benchmarks import compare  # noqa: E402  (its scene names and files)
from benchmarks.common import check_outputs, image_size  # noqa: E402

VARIANTS = ("primary", "primary_shadow", "full")
KERNEL_FUNCTION = "_pocl_kernel_render_workgroup*"

# Runs in the child: one render of a variant of the scene; prints the rays it traced.
_RENDER = """
import dataclasses, json, sys
from clray.device.context import select_device
from clray.device.pack import pack_scene
from clray.device.launch import render_packed
from clray.scene.load import load_scene
path, variant, width, height = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
scene = load_scene(path)
r = scene.render
width, height = width or r.width, height or r.height
packed = pack_scene(scene, width=width, height=height, spp=r.spp, max_depth=r.max_depth,
                    min_weight=r.min_weight, seed=r.seed)
config, params = packed.config, packed.params.copy()
if variant != "full":
    config = dataclasses.replace(config, max_depth=0)
    params[0]["max_depth"] = 0
if variant == "primary":
    params[0]["n_lights"] = 0
packed = dataclasses.replace(packed, config=config, params=params)
_, stats = render_packed(packed, select_device("pocl"))
print(json.dumps({"rays": stats["rays"], "pixels": int(width) * int(height)}))
"""


def _render(scene: Path, variant: str, size: tuple[int, int], valgrind: bool) -> dict:
    env = {**os.environ, "POCL_MAX_PTHREAD_COUNT": "1"}
    command = [sys.executable, "-c", _RENDER, str(scene), variant, str(size[0]), str(size[1])]
    if valgrind:
        command = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
                   f"--toggle-collect={KERNEL_FUNCTION}", *command]
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env,
                          check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if valgrind:
        collected = re.findall(r"Collected\s*:\s*(\d+)", done.stderr)
        if not collected:
            raise RuntimeError(f"no instruction count in valgrind's output:\n{done.stderr}")
        result["instructions"] = int(collected[-1])
    return result


def count_scene(scene: Path, size: tuple[int, int] = (0, 0)) -> dict:
    """Instructions per variant, per pixel, and per ray of each kind (by differences), at
    `size` (width, height; 0 for the scene's own)."""
    out = {}
    for variant in VARIANTS:
        _render(scene, variant, size, valgrind=False)  # fills PoCL's kernel cache for it
        out[variant] = _render(scene, variant, size, valgrind=True)
    pixels = out["full"]["pixels"]
    primary = out["primary"]
    shadow = out["primary_shadow"]["rays"]["shadow"]
    full = out["full"]["rays"]
    later = full["secondary"] + full["shadow"] - shadow
    per_ray = {
        "primary": primary["instructions"] / primary["rays"]["primary"],
        "shadow_of_primary": ((out["primary_shadow"]["instructions"] - primary["instructions"])
                              / shadow if shadow else None),
        "secondary_and_their_shadow": ((out["full"]["instructions"]
                                        - out["primary_shadow"]["instructions"]) / later
                                       if later else None),
        "all": out["full"]["instructions"] / full["total"],
    }
    return {"variants": out, "pixels": pixels,
            "instructions_per_pixel": out["full"]["instructions"] / pixels,
            "instructions_per_ray": per_ray}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=HERE / "results" / "instructions.json")
    parser.add_argument("--scenes", default="spheres,mesh", help="comma-separated: spheres, "
                        "mesh (generated) or paths to scene files")
    parser.add_argument("--size", type=image_size, metavar="WxH",
                        help="image size (default: each scene's own)")
    parser.add_argument("--mesh-dir", help="where to write the mesh scene (its folder mesh/ "
                        "there; default: a temporary folder)")
    args = parser.parse_args(argv)
    names = list(dict.fromkeys(n.strip() for n in args.scenes.split(",") if n.strip()))
    unknown = compare.unknown_scenes(names)
    if unknown or not names:
        parser.error(f"--scenes: expected spheres, mesh or scene files (not found: {unknown})")
    check_outputs(parser, json=args.json)
    if shutil.which("valgrind") is None:
        sys.exit("instructions.py needs valgrind (Debian: apt-get install valgrind)")
    with tempfile.TemporaryDirectory() as tmp:
        scenes = compare.scene_paths(names, Path(args.mesh_dir) if args.mesh_dir else Path(tmp))
        results = {}
        for name in names:
            results[name] = count_scene(scenes[name], args.size or (0, 0))
            per = results[name]["instructions_per_ray"]
            print(f"{name}: {results[name]['instructions_per_pixel']:.0f} instructions a pixel; "
                  "a ray: " + ", ".join(f"{k} {v:.0f}" for k, v in per.items() if v is not None))
    args.json.write_text(json.dumps({"size": list(args.size) if args.size else None,
                                     "scenes": results}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
