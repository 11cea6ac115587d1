"""Registers, stack and spills a work-item of the render kernel needs on an NVIDIA GPU, per
scene and traversal scheme, estimated without a GPU: clang compiles the kernels to PTX with
libclc's OpenCL builtins for nvptx64, and NVIDIA's PTX assembler (ptxas, from the CUDA toolkit)
assembles them for the target architecture with --verbose, whose figures
scripts/gpu_check_steps.py's parser reads (the same lines as NVIDIA's OpenCL driver gives
under -cl-nv-verbose).

These are compile-time figures of clang's code, not of NVIDIA's own OpenCL front end, and not
measured on a GPU; scripts/gpu_check.sh reads the driver's figures on a GPU machine.

    python benchmarks/gpu_registers.py [--arch sm_90] [--json benchmarks/results/gpu_registers.json]

Needs clang-15 and libclc-15 (Debian: apt-get install clang-15 libclc-15) and ptxas on PATH.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import RESULTS, check_outputs
from clray.device.pack import pack_scene
from clray.device.program import KernelConfig, kernel_source
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent
LIBCLC = Path("/usr/lib/clc/nvptx64--nvidiacl.bc")
CLANG = "clang-15"
# Every example scene on the single-ray walk (a GPU's default); the other schemes on two.
SCHEMES = {"single": {"traversal": "single"},
           "sample_packet4": {"traversal": "sample_packet", "packet_lanes": 4},
           "sample_packet8": {"traversal": "sample_packet", "packet_lanes": 8},
           "sample_packet16": {"traversal": "sample_packet", "packet_lanes": 16},
           "group_packet": {"traversal": "group_packet"}}
ALL_SCHEMES_ON = ("spheres", "cornell_box")


def _ptxas_parser():
    path = ROOT / "scripts" / "gpu_check_steps.py"
    spec = importlib.util.spec_from_file_location("gpu_check_steps", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.parse_ptxas_log


def config_for(scene_path: Path, scheme: dict) -> KernelConfig:
    scene = load_scene(scene_path)
    return pack_scene(scene, width=8, height=4, spp=16, max_depth=scene.render.max_depth,
                      seed=0, **scheme).config


def assemble(config: KernelConfig, arch: str, source: str, parse) -> dict:
    """The render kernel's figures for `config` on `arch`."""
    ptx = subprocess.run([CLANG, "-x", "cl", "-cl-std=CL1.2", "-target", "nvptx64-nvidia-nvcl",
                          "-Xclang", "-finclude-default-header", "-Xclang",
                          "-mlink-builtin-bitcode", "-Xclang", str(LIBCLC), "-O2", "-S",
                          "-Wno-linker-warnings", "-o", "-", *config.options(), "-"],
                         input=source, capture_output=True, text=True, timeout=600)
    if ptx.returncode:
        return {"error": ptx.stderr.strip()[-500:]}
    with tempfile.TemporaryDirectory() as tmp:
        ptx_path = Path(tmp) / "kernel.ptx"
        ptx_path.write_text(ptx.stdout)
        run = subprocess.run(["ptxas", f"-arch={arch}", "--verbose", str(ptx_path), "-o",
                              str(Path(tmp) / "kernel.cubin")], capture_output=True, text=True,
                             timeout=600)
    if run.returncode:
        return {"error": run.stderr.strip()[-500:]}
    return parse(run.stderr + run.stdout).get("render", {})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arch", default="sm_90", help="ptxas target (default: sm_90, the "
                                                        "H100 and H200)")
    parser.add_argument("--json", type=Path, default=RESULTS / "gpu_registers.json",
                        help="write the figures here (default: "
                        "benchmarks/results/gpu_registers.json)")
    args = parser.parse_args(argv)
    check_outputs(parser, json=args.json)
    missing = [name for name, found in ((CLANG, shutil.which(CLANG)),
                                        ("ptxas", shutil.which("ptxas")),
                                        (str(LIBCLC), LIBCLC.exists())) if not found]
    if missing:
        print(f"gpu_registers: missing {', '.join(missing)} (Debian: apt-get install clang-15 "
              "libclc-15; ptxas comes with NVIDIA's CUDA toolkit)", file=sys.stderr)
        return 2
    parse = _ptxas_parser()
    source = kernel_source()
    version = subprocess.run(["ptxas", "--version"], capture_output=True, text=True).stdout
    rows = []
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        for name, scheme in SCHEMES.items():
            if name != "single" and path.stem not in ALL_SCHEMES_ON:
                continue
            figures = assemble(config_for(path, scheme), args.arch, source, parse)
            rows.append({"scene": path.stem, "scheme": name, **figures})
            print(f"{path.stem:12} {name:16} " + ", ".join(
                f"{k} {v}" for k, v in figures.items() if k != "entry"), flush=True)
    result = {"arch": args.arch, "ptxas": version.strip().splitlines()[-1] if version else None,
              "clang": CLANG, "libclc": str(LIBCLC), "host": platform.processor() or None,
              "spp": 16, "rows": rows}
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
