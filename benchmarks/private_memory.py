"""Private memory per work-item of the render kernel for a GPU, by configuration.

    python benchmarks/private_memory.py [--json benchmarks/results/private_memory.json]

For each traversal scheme (the single-ray walk, sample packets of 8 and 16 lanes, sample
packets of 8 and 16 lanes in a scene without refraction, which trace chains and keep only each
lane's radiance, group packets), float and
double and several ray-tree depths, the model's stacks (the ray stack and the
BVH traversal stack, clray.device.program.private_stack_bytes, which the render-time warning
uses) beside what clang 15's AMDGPU back end (gfx90a, -O2) gives the render kernel: its
scratch (private segment) bytes and vector registers. Without ROCm's device library the math
builtins stay external calls, for each of which the back end would add 16 KiB of assumed callee
stack; `-amdgpu-assume-external-call-stack-size=0` leaves the kernel's own scratch. The scene's
features are all on (but refraction for the chains). Needs clang; each configuration takes 10
to 30 s to compile. Measures only.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import RESULTS, check_outputs
from clray.device.program import (
    FEATURE_SWITCHES,
    GPU_REGISTER_BYTES,
    KernelConfig,
    kernel_source,
    private_stack_bytes,
)

DEPTHS = (1, 4, 8)
# (traversal, packet lanes, refraction): the packet's lanes set its per-lane state (rays, hits,
# shading); without refraction sample packets trace chains (kernels/packet_trace.h,
# PACKET_CHAINS).
SCHEMES = (("single", 1, True), ("sample_packet", 8, True), ("sample_packet", 16, True),
           ("sample_packet", 8, False), ("sample_packet", 16, False), ("group_packet", 1, True))


def amdgpu_render_usage(config: KernelConfig, clang: str) -> dict[str, int]:
    """The render kernel's ScratchSize and NumVgprs from clang's AMDGPU assembly."""
    run = subprocess.run([clang, "-x", "cl", "-cl-std=CL1.2", "-target", "amdgcn-amd-amdhsa",
                          "-mcpu=gfx90a", "-nogpulib", "-mllvm",
                          "-amdgpu-assume-external-call-stack-size=0", "-Xclang",
                          "-finclude-default-header",
                          "-O2", "-S", "-o", "-", *config.options(), "-"],
                         input=kernel_source(), capture_output=True, text=True, check=True)
    asm = run.stdout
    body = asm[asm.index("render:"):]
    return {"scratch_bytes": int(re.search(r"; ScratchSize: (\d+)", body).group(1)),
            "vgprs": int(re.search(r"; NumVgprs: (\d+)", body).group(1))}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=RESULTS / "private_memory.json",
                        help="write the rows here (default: "
                        "benchmarks/results/private_memory.json)")
    args = parser.parse_args(argv)
    check_outputs(parser, json=args.json)
    clang = next((c for c in ("clang", "clang-15") if shutil.which(c)), None)
    if clang is None:
        sys.exit("private_memory: clang not found (Debian: apt-get install clang)")
    rows = []
    for traversal, lanes, refraction in SCHEMES:
        for precision in ("float", "double"):
            for depth in DEPTHS:
                config = KernelConfig(precision=precision, max_depth=depth, bvh_stack_size=32,
                                      traversal=traversal, packet_lanes=lanes,
                                      **{**dict.fromkeys(FEATURE_SWITCHES, True),
                                         "has_refraction": refraction})
                row = {"traversal": traversal, "packet_lanes": lanes if lanes > 1 else None,
                       "refraction": refraction,
                       "precision": precision, "max_depth": depth, "bvh_stack_size": 32,
                       **private_stack_bytes(config), **amdgpu_render_usage(config, clang)}
                print(json.dumps(row), flush=True)
                rows.append(row)
    args.json.write_text(json.dumps({"compiler": "clang 15, amdgcn-amd-amdhsa gfx90a -O2, "
                                                 "no device library",
                                     "register_budget_bytes": GPU_REGISTER_BYTES,
                                     "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
