"""`clray profile SCENE`: where a render's time goes. Rays by kind, Mrays/s by kind, box and
primitive tests per ray, kernel build time cold and warm, and the scene's device bytes; the
benchmark (benchmarks/bench.py) reports the same split from here.

The render kernel does everything in one launch, so its time is split by rendering the same
packed scene three ways and differencing the medians:

- `primary`: max depth 0 and no lights: eye rays, closest hits and ambient shading only;
- `primary_shadow`: max depth 0 with the lights: adds the shadow rays from primary hits;
- `full`: the scene as given: adds reflected and refracted rays and their shadow rays.

A part's figure carries the noise of two medians: where the variants' timed runs overlap (some
run with the part's rays took no longer than some run without them) the difference is within
that noise, and is reported as such (`within_noise`, with the range of the runs' differences),
with no Mrays/s; a kind of ray the scene never traces (no lights, nothing that reflects) has no
time. Box and primitive tests come from the instrumented build (KernelConfig.count_tests),
rendered once and untimed: its counters cost time of their own.

Build times are measured in new processes, so this process's program cache does not answer them:
cold with every kernel cache a new process could be answered from empty (PoCL's, pyopencl's
binary cache, which it keeps for drivers without one of their own such as Intel's CPU runtime,
and NVIDIA's compute cache: `cache_env`), warm with those caches as the cold build left them, as
a user's second run finds them. A cache the environment turns off (PYOPENCL_NO_CACHE,
CUDA_CACHE_DISABLE) stays off in both. Both time `clBuildProgram` only: PoCL compiles the
work-group function at a kernel's first launch, about as long again on the CPU, which
`benchmarks/cold_build.py` adds (docs/acceleration.md, The cold build a new user waits for).
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
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pyopencl as cl

from clray.device.context import context_for, describe, select_device
from clray.device.launch import render_packed
from clray.device.pack import PackedScene
from clray.device.program import KernelConfig, build_program
from clray.errors import EXIT_OPENCL, ClrayError, DeviceError, one_line
from clray.render import RenderSettings, pack_for
from clray.scene.load import load_scene
from clray.scene.model import Scene


def _variant(packed: PackedScene, *, depth0: bool, lights: bool) -> PackedScene:
    config = packed.config
    params = packed.params.copy()
    if depth0:
        config = dataclasses.replace(config, max_depth=0)
        params[0]["max_depth"] = 0
    if not lights:
        params[0]["n_lights"] = 0
    return dataclasses.replace(packed, config=config, params=params)


# The variants time_split renders, each a warm-up and then `repeat` timed runs.
VARIANTS = ("primary", "primary_shadow", "full")


def time_split(packed: PackedScene, device: cl.Device, repeat: int,
               step: Callable[[str], None] = lambda _: None) -> dict:
    """Kernel seconds and Mrays/s per kind of ray, from the three variants above. `step` hears
    what each render is as it starts."""
    return _timed_split(packed, device, repeat, step)[0]


def _timed_split(packed: PackedScene, device: cl.Device, repeat: int,
                 step: Callable[[str], None]) -> tuple[dict, dict]:
    """time_split's figures, and the rays of the scene as given (its `full` variant's last
    timed run: every render of a scene traces the same rays)."""
    variants = {"primary": _variant(packed, depth0=True, lights=False),
                "primary_shadow": _variant(packed, depth0=True, lights=True),
                "full": packed}
    # Interleave the variants' runs so load changes spread over all three.
    runs: dict[str, list[float]] = {name: [] for name in variants}
    rays: dict[str, dict] = {}
    for name, variant in variants.items():
        step(f"{name} warm-up")
        render_packed(variant, device)  # build and warm-up
    for run in range(repeat):
        for name, variant in variants.items():
            step(f"{name} run {run + 1} of {repeat}")
            _, stats = render_packed(variant, device)
            runs[name].append(stats["kernel_s"])
            rays[name] = stats["rays"]
    t = {name: statistics.median(r) for name, r in runs.items()}
    primary_shadow_rays = rays["primary_shadow"]["shadow"]
    later_rays = rays["full"]["total"] - rays["primary_shadow"]["total"]
    return {
        "variant_kernel_s": t,
        "parts": {
            "primary": _part(runs["primary"], None, rays["full"]["primary"]),
            "shadow_of_primary": _part(runs["primary_shadow"], runs["primary"],
                                       primary_shadow_rays),
            "secondary_and_their_shadow": _part(runs["full"], runs["primary_shadow"],
                                                later_rays),
        },
    }, rays["full"]


def _part(runs: list[float], without: list[float] | None, rays: int) -> dict:
    """One kind of ray's figures: its `rays` and kernel seconds, the median of `runs`, less the
    median of the runs `without` those rays where given. A kind with no rays has no time: the
    difference of two variants that trace the same rays is noise alone, and may be negative.
    A difference is `within_noise` where the two variants' runs overlap, so that not every run
    with the rays took longer than every run without them: a negative difference always is,
    and its rate would be noise."""
    if rays == 0:
        return {"kernel_s": 0.0, "rays": 0, "mrays_per_s": None, "within_noise": False,
                "difference_range_s": None}
    seconds = statistics.median(runs)
    spread = None
    if without is not None:
        seconds -= statistics.median(without)
        # Every run with the rays against every run without: the least and the most it took.
        spread = [min(runs) - max(without), max(runs) - min(without)]
    within = spread is not None and spread[0] <= 0
    return {"kernel_s": seconds, "rays": rays,
            "mrays_per_s": None if within or seconds <= 0 else rays / seconds * 1e-6,
            "within_noise": within, "difference_range_s": spread}


def part_text(name: str, part: Mapping[str, Any]) -> str:
    """One kind of ray's line of the profile, as `clray profile` and benchmarks/bench.py print
    it: its time and rate, "no rays" where the scene traces none, and where its time is within
    the noise of the timed runs, that and the range of the runs' differences, not a duration
    (which could be negative)."""
    rays = part["rays"]
    if rays == 0:
        return f"{name}: no rays"
    if part["within_noise"]:
        low, high = (f"{s * 1e3:.3g}" for s in part["difference_range_s"])
        # One run a variant (--repeat 1) gives one difference, not a range.
        by = low if low == high else f"{low} to {high}"
        return f"{name}: within noise (runs differ by {by} ms), {rays:,} rays, -"
    rate = "-" if part["mrays_per_s"] is None else f"{part['mrays_per_s']:.3g} Mrays/s"
    return f"{name}: {part['kernel_s'] * 1e3:.3g} ms, {rays:,} rays, {rate}"


def tests_per_ray(packed: PackedScene, device: cl.Device) -> dict:
    """Box and primitive tests per closest-hit ray (primary and secondary) and per shadow ray."""
    counted = dataclasses.replace(packed, config=dataclasses.replace(packed.config,
                                                                     count_tests=True))
    _, stats = render_packed(counted, device)
    tests, rays = stats["tests"], stats["rays"]
    closest = rays["primary"] + rays["secondary"]
    shadow = rays["shadow"]

    def per(n: int, d: int) -> float | None:
        return n / d if d else None

    return {
        "closest_boxes_per_ray": per(tests["closest_boxes"], closest),
        "closest_prims_per_ray": per(tests["closest_prims"], closest),
        "shadow_boxes_per_ray": per(tests["shadow_boxes"], shadow),
        "shadow_prims_per_ray": per(tests["shadow_prims"], shadow),
        "totals": tests,
    }


# Where a new process looks for kernels built before it, by the variable that moves each there:
# PoCL's kernel cache; pyopencl's binary cache, which pyopencl keeps for the drivers that keep
# none (all but PoCL and NVIDIA's: Intel's CPU runtime), and any driver's cache kept under
# $XDG_CACHE_HOME; NVIDIA's compute cache, which answers its builds (~/.nv/ComputeCache).
CACHE_FOLDERS = {"POCL_CACHE_DIR": "pocl", "XDG_CACHE_HOME": "xdg", "CUDA_CACHE_PATH": "nv"}


def cache_env(caches: Path, base: Mapping[str, str]) -> dict[str, str]:
    """`base` with every kernel cache that could answer a new process's build in a folder of
    its own under `caches` (CACHE_FOLDERS): empty for the first process, so its build is cold,
    and as that process left it for the next, so theirs is warm."""
    return {**base, **{name: str(caches / folder) for name, folder in CACHE_FOLDERS.items()}}


def new_process_build(config: KernelConfig, device_spec: str | None,
                      caches: Path | None = None) -> dict[str, float]:
    """A new process's seconds to make its context (`context_s`) and then to build the render
    kernel of `config` (`build_s`), with its kernel caches under `caches` (`cache_env`) where
    given, else where this process's environment puts them."""
    env = dict(os.environ) if caches is None else cache_env(caches, os.environ)
    cmd = [sys.executable, "-m", "clray.profile", "--build-only",
           json.dumps(dataclasses.asdict(config))]
    if device_spec:
        cmd += ["--device", device_spec]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    except OSError as err:
        raise ClrayError(f"cannot start a new process to time the kernel build: "
                         f"{err.strerror or err}") from None
    if done.returncode != 0:
        raise _child_error(done.returncode, done.stderr)
    return {key: float(value) for key, value in json.loads(done.stdout.splitlines()[-1]).items()}


def _child_error(returncode: int, stderr: str) -> ClrayError:
    """The failure of a --build-only process, as the error it reported: its last line on stderr
    (its `clray: error:` line, or a traceback's last line), of the class its exit code says."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    if lines:
        reason = lines[-1].removeprefix("clray: error: ")
    elif returncode < 0:
        reason = f"killed by signal {-returncode}"
    else:
        reason = f"exit status {returncode}, and no message"
    error = DeviceError if returncode == EXIT_OPENCL else ClrayError
    return error(one_line(f"kernel build in a new process failed: {reason}"))


def build_seconds(config: KernelConfig, device_spec: str | None,
                  caches: Path | None = None) -> float:
    """Seconds a new process takes to build the render kernel of `config`, its context made,
    with its kernel caches under `caches` where given (`new_process_build`)."""
    return new_process_build(config, device_spec, caches)["build_s"]


def cold_and_warm_build(config: KernelConfig, device_spec: str | None) -> tuple[float, float]:
    """Seconds a new process takes to build the render kernel of `config` with every kernel
    cache empty (cold), then another with those caches as the first left them (warm)."""
    try:
        folder = tempfile.TemporaryDirectory(prefix="clray-profile-")
    except OSError as err:  # TMPDIR full or read-only, or no usable temporary folder at all
        where = f" in {os.path.dirname(err.filename)}" if err.filename else ""
        raise ClrayError(f"cannot make a temporary folder{where} for the cold build's kernel "
                         f"caches: {err.strerror or err}") from None
    with folder as caches:
        cold = build_seconds(config, device_spec, Path(caches))
        warm = build_seconds(config, device_spec, Path(caches))
    return cold, warm


def _build_only(config_json: str, device_spec: str | None) -> None:
    fields = json.loads(config_json)
    fields["build_options"] = tuple(fields["build_options"])
    device = select_device(device_spec)
    start = time.perf_counter()
    context_for(device)
    context_s = time.perf_counter() - start
    _, seconds = build_program(device, KernelConfig(**fields))
    print(json.dumps({"build_s": seconds, "context_s": context_s}))


def profile_steps(repeat: int) -> int:
    """The steps of profile_scene: the builds, cold and warm, each variant's warm-up and timed
    runs (the last of the scene as given reports its rays), and the render of the COUNT_TESTS
    build."""
    return 2 + len(VARIANTS) * (1 + repeat) + 1


def profile_scene(path: Path, settings: RenderSettings, repeat: int = 3,
                  scene: Scene | None = None,
                  progress: Callable[[int, int, str], None] | None = None) -> dict:
    """The whole profile of the scene at `path` (or of `scene`, where given, loaded from it:
    a mesh file's automatic scene) rendered with `settings` on its device. `progress` hears
    (steps done, steps in all, what the next is) before each step (profile_steps), and
    (all, all, "done") at the end: on a large scene the whole takes minutes."""
    total = profile_steps(repeat)
    done = 0

    def step(what: str, count: int = 1) -> None:
        nonlocal done
        if progress is not None:
            progress(done, total, what)
        done += count

    device = select_device(settings.device)
    packed = pack_for(scene if scene is not None else load_scene(path), settings, device)
    step("kernel build in new processes, cold and warm", 2)
    cold, warm = cold_and_warm_build(packed.config, settings.device)
    split, rays = _timed_split(packed, device, repeat, step)
    step("box and primitive tests (the COUNT_TESTS build)")
    tests = tests_per_ray(packed, device)
    if progress is not None:
        progress(total, total, "done")
    width, height = int(packed.params[0]["width"]), int(packed.params[0]["height"])
    return {
        "scene": str(path),
        "device": describe(device),
        "width": width,
        "height": height,
        "spp": int(packed.params[0]["spp"]),
        "tuning": packed.tuning.label(),
        "traversal": packed.config.traversal,
        "repeat": repeat,
        "rays": rays,
        "kernel_s": split["variant_kernel_s"]["full"],
        "mrays_per_s": rays["total"] / split["variant_kernel_s"]["full"] * 1e-6,
        "time_split": split,
        "tests_per_ray": tests,
        "build_cold_s": cold,
        "build_warm_s": warm,
        "device_bytes": packed.device_bytes(),
        "device_bytes_total": sum(packed.device_bytes().values()),
    }


def main(argv: list[str] | None = None) -> None:
    # `python -m clray.profile --build-only CONFIG`: build_seconds' new process.
    parser = argparse.ArgumentParser(prog="python -m clray.profile")
    parser.add_argument("--build-only", required=True)
    parser.add_argument("--device")
    args = parser.parse_args(argv)
    try:
        _build_only(args.build_only, args.device)
    except ClrayError as err:
        # One line, and the exit code of its class, for new_process_build to pass on.
        print(f"clray: error: {one_line(str(err))}", file=sys.stderr)
        sys.exit(err.exit_code)


if __name__ == "__main__":
    main()
