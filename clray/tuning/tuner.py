"""`clray tune`: search the knobs of clray.knobs for the fastest configuration on one
device, with Kernel Tuner (docs/tuning.md: why one Kernel Tuner run per host configuration).

For each scene, the default configuration renders the reference image through clray's own
launches. Then, configuration of the host knobs by configuration (a new BVH, new buffers), the
packed scene's buffers become the arguments of one Kernel Tuner run whose tunable parameters are
the kernel and launch knobs. Kernel Tuner compiles each configuration, launches it over the
whole image, hands the image to ImageCheck (which compares it with the reference within the
scene's tolerance and records the verdict beside the times) and times it by OpenCL profiling
events over several runs, compile time apart. Its cache file, one per scene and host
configuration, makes a second run continue where the first stopped.
"""

from __future__ import annotations

import hashlib
import importlib
import itertools
import json
import math
import random
import re
import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pyopencl as cl

from clray import metrics
from clray.device.launch import render_packed
from clray.device.pack import PackedScene
from clray.device.policy import DevicePlan, device_plan
from clray.device.program import device_build_options, kernel_source
from clray.errors import ClrayError, DeviceError, one_line, plural
from clray.knobs import (
    BUILD_KNOBS,
    DEFAULT_TUNING,
    HOST_KNOBS,
    IMAGE_KNOBS,
    KERNEL_KNOBS,
    KNOB_TABLE,
    KNOBS,
    TRAVERSAL_SCHEMES,
    TRAVERSALS,
    Tuning,
    TuningError,
    other_schemes_knobs,
    restriction_problems,
)
from clray.metrics import fail_allowance
from clray.output import cannot_write
from clray.render import RenderSettings, pack_for
from clray.scene.load import load_scene

INSTALL_HINT = "pip install 'clray[tune]'"
# Kernel Tuner's names for the work-group's sizes: a row segment of work_group_width (y 1), or
# with traversal group_packet a tile of group_side x group_side.
BLOCK_SIZE_X = "block_size_x"
BLOCK_SIZE_Y = "block_size_y"
# Pixels off by more than this from the default's image count against a configuration, unless
# --allow-error gives another bound: the study's float-vs-double threshold (clray.study).
PIXEL_TOLERANCE = 2 / 255
ITERATIONS = 7  # timed launches per configuration, Kernel Tuner's default
# A Kernel Tuner run needs a few seconds of budget to start (a compile, a reference launch).
MIN_RUN_BUDGET_S = 2.0
# A render shorter than this is timed mostly as noise: at 160x90 (about 1 ms on a 2-core CPU)
# Kernel Tuner's table claimed 2.00x that interleaved renders measured at 1.02x. Such a tune is
# said to be so at once, and its winner is stored only where the confirmation (below) confirms
# it, as any winner.
MIN_TIMED_KERNEL_S = 0.02
# The confirmation (confirm, confirmed_gain): the default and the winner rendered in rounds,
# and the winner stored only where a one-sided sign test on the rounds' paired ratios (default
# / tuned) gives p < CONFIRM_P and their median is a gain of at least MIN_GAIN. Without the
# test, storing where three rounds in four were faster stored about 1 winner in 5 that was the
# default itself (its rounds' ratios pure noise) at 5 rounds; a gain under 2 % is not worth
# changing every later render on the device for.
CONFIRM_P = 0.01
MIN_GAIN = 1.02
# Rounds: at least MIN_CONFIRM_ROUNDS, where 12 faster rounds of 14 give p = 0.0065 (a sign
# test reaches 0.01 from 7 rounds, with none slower); more, up to MAX_CONFIRM_ROUNDS, as make
# about CONFIRM_SECONDS of renders a side: 5 rounds of 10 ms renders on a shared 2-core machine
# confirmed gains of 1.47x and 1.64x that 40 rounds measured at 0.99x and 1.01x. Even, so that
# each side is rendered first as often.
MIN_CONFIRM_ROUNDS = 14
CONFIRM_SECONDS = 1.0
MAX_CONFIRM_ROUNDS = 40
# The knobs of one Kernel Tuner run's fixed setup: the packed scene's (host) and the compiler's
# options (build), which Kernel Tuner passes unchanged to every configuration it builds.
OUTER_KNOBS = HOST_KNOBS + BUILD_KNOBS


def kernel_define(name: str) -> str:
    """The kernel's macro of a kernel knob, Kernel Tuner's tunable parameter of that name."""
    return name.upper()


def define_value(name: str, value: Any) -> int:
    """A kernel knob's value as the kernel's macro takes it: the traversal's index (the
    kernel's TRAVERSAL_SINGLE 0, TRAVERSAL_SAMPLE_PACKET 1), a switch's 0 or 1."""
    return TRAVERSALS.index(value) if name == "traversal" else int(value)


def knob_value(name: str, define: int, auto: dict[str, Any]) -> Any:
    """The knob's value of Kernel Tuner's parameter: define_value's inverse, with the
    device's own value of a knob whose None stands for it (auto: the traversal, the packet
    lanes) as None, so the default has one key (the trial's own; Trial.stands_for adds the
    other configurations that build the same kernel on the scene, the walk named among them)."""
    if name == "traversal":
        value = TRAVERSALS[define]
    else:
        value = bool(define) if isinstance(KNOBS[name].default, bool) else int(define)
    return None if name in auto and value == auto[name] else value


def import_kernel_tuner() -> Any:
    """Kernel Tuner's `interface` module, or a one-line ClrayError saying how to install it."""
    try:
        from kernel_tuner import interface
    except ImportError:
        raise ClrayError(f"clray tune needs Kernel Tuner, which is not installed: "
                         f"{INSTALL_HINT}") from None
    return interface


# Modules that Kernel Tuner's strategies import only once they run, after the reference renders:
# imported before any work, so that a missing one is a line and not a traceback minutes in.
STRATEGY_MODULES = {"skopt": ("skopt",), "pyatf_strategies": ("pyatf",),
                    "bayes_opt": ("sklearn",)}
# The pip package of a module, where its name is another.
PIP_NAMES = {"skopt": "scikit-optimize", "sklearn": "scikit-learn"}


def check_strategy(name: str) -> None:
    """A ClrayError naming the missing module where Kernel Tuner's strategy `name` (one of its
    strategy_map) cannot run for want of one: its own module (nsga2's imports pymoo) or those
    it imports as it runs."""
    try:
        # strategy_map's entry imports the strategy's module at the first look inside.
        import_kernel_tuner().strategy_map[name].tune  # noqa: B018
        for module in STRATEGY_MODULES.get(name, ()):
            importlib.import_module(module)
    except ImportError as err:
        # Kernel Tuner raises its own ImportError from the ModuleNotFoundError, which names it.
        missing = next((e.name for e in (err, err.__context__)
                        if isinstance(e, ImportError) and e.name), None)
        if missing is None:
            raise ClrayError(f"--strategy {name}: {one_line(str(err))}") from None
        top = missing.partition(".")[0]
        raise ClrayError(f"--strategy {name} needs the Python module {top}, which is not "
                         f"installed: pip install {PIP_NAMES.get(top, top)}") from None


def _observer_base(name: str) -> type:
    """One of Kernel Tuner's observer classes (imported only when tuning: an optional extra)."""
    from kernel_tuner.observers import observer

    return getattr(observer, name)


def _launch_wait() -> Any:
    """A Kernel Tuner observer that waits for each timed launch to finish, blocking, before
    Kernel Tuner looks: its own wait asks the launch's status in a loop with a microsecond's
    sleep, a host thread that on a CPU device takes a core from the kernel it times. On 2 cores
    Intel's CPU runtime ran spheres' default configuration in 381 ms in Kernel Tuner's launches
    against 195 ms in clray's renders (PoCL up to 20 % more); waiting as clray's renders do, the
    launches take what renders take."""

    class LaunchWait(_observer_base("BenchmarkObserver")):
        def after_start(self) -> None:
            self.dev.synchronize()

        def get_results(self) -> dict:
            return {}

    return LaunchWait()


@dataclass
class Trial:
    """One configuration tried on one scene."""

    scene: str
    tuning: Tuning
    time_ms: float | None  # median kernel time of Kernel Tuner's timed launches
    times_ms: list[float]
    compile_ms: float
    verified: bool
    pixels_off: int  # pixels off the default's image by more than the tolerance
    problem: str | None = None  # why it was rejected or failed
    extra: dict = field(default_factory=dict)  # tunable parameters outside the knob table
    # The keys of every configuration whose render of this scene builds what this trial built
    # (its own among them; Tuner.equivalent_keys): the device's own walk named or left None,
    # a packet knob that a scene of one sample a pixel never builds. Scenes whose own walks
    # differ meet on these (best_configuration). Empty: its own key alone.
    stands_for: tuple[str, ...] = ()

    def key(self) -> str:
        return configuration_key(self.tuning, self.extra)

    def keys(self) -> tuple[str, ...]:
        return self.stands_for or (self.key(),)


def configuration_key(tuning: Tuning, extra: dict) -> str:
    """A configuration's key: its knobs and extra parameters, as JSON."""
    return json.dumps({**tuning.values(), **extra}, sort_keys=True)


def key_tuning(key: str) -> Tuning:
    """The knobs of a configuration's key (configuration_key's), less its extra parameters."""
    return Tuning(**{k: v for k, v in json.loads(key).items() if k in KNOBS})


# Kernel Tuner marks a configuration it did not time with an error object whose text is its
# class name (and its cache file holds that text): the report says what each means instead.
_FAILURES = {
    "InvalidConfig": "not a valid configuration on this device",
    "CompilationFailedConfig": "the kernel build failed",
    "RuntimeFailedConfig": "the launch failed (too many resources asked of the device)",
}


def failure(result: dict) -> str:
    """Why Kernel Tuner has no time for the configuration of `result`, one of its results."""
    error = str(result.get("__error__", result.get("time")))
    return "failed: " + _FAILURES.get(error, "not timed")


@dataclass(frozen=True)
class Tolerance:
    """A configuration passes when it makes no more non-finite pixels than the default and at
    most `allowance` pixels differ from the default's by more than `threshold`."""

    threshold: float
    allowance: int

    def check(self, image: np.ndarray, reference: np.ndarray) -> tuple[bool, int, str | None]:
        off = metrics.count_over(image, reference, self.threshold)
        extra_nonfinite = metrics.nonfinite_count(image) - metrics.nonfinite_count(reference)
        if extra_nonfinite > 0:
            return False, off, (f"{plural(extra_nonfinite, 'more non-finite pixel')} than the "
                                "default")
        if off > self.allowance:
            return False, off, (f"{plural(off, 'pixel')} {'differs' if off == 1 else 'differ'} "
                                "from the default's image by over "
                                f"{self.threshold:.3g} (at most {self.allowance} may)")
        return True, off, None


class BruteForceWithinBudget:
    """Kernel Tuner's brute force, with the time limit that Kernel Tuner's own refuses: every
    configuration of the run, the run's first (the default, or the best so far) first and then
    those that change fewest parameters from it, until Kernel Tuner's budget stops its runner
    (which checks it before each configuration). A Kernel Tuner strategy: an object with
    `tune`."""

    def __init__(self, first: dict[str, Any]) -> None:
        self.first = first

    def tune(self, searchspace: Any, runner: Any, tuning_options: Any) -> list[dict]:
        names = list(searchspace.tune_params)

        def changed(config: tuple) -> int:
            return sum(value != self.first.get(name, value)
                       for name, value in zip(names, config, strict=True))

        # sorted() is stable: Kernel Tuner's own order among equally distant configurations.
        ordered = sorted(searchspace.sorted_list(), key=changed)
        # The runner answers None for each configuration left when the budget ran out.
        return [r for r in runner.run(ordered, tuning_options) if r is not None]


# A run of fewer kernel configurations than this, or than POPULATIONS_IN_SPACE times the
# strategy's population (its first sample), is tried whole by brute force whatever --strategy
# says: on spheres' 12, bayes_opt failed to draw its sample of 20, and diff_evo, pso and
# firefly_algorithm failed with an IndexError (pso on the one configuration of a later host
# configuration), while a search saves little over trying a handful of configurations.
SMALL_SPACE = 16
POPULATIONS_IN_SPACE = 3


def strategy_population(name: str, dimensions: int) -> int:
    """The configurations Kernel Tuner's strategy `name` draws before it searches: its popsize
    option's default (times the space's `dimensions` where its options say so), 0 if it has
    none."""
    options = getattr(import_kernel_tuner().strategy_map[name], "_options", {})
    size = int(options.get("popsize", ("", 0))[1])
    if options.get("popsize_times_dimensions", ("", False))[1]:
        size *= dimensions
    return size


class _RecordingRunner:
    """Kernel Tuner's runner, keeping every result it returns (the configurations timed when a
    strategy lets the budget's end out) and what it raised (not the strategy's failure)."""

    def __init__(self, runner: Any) -> None:
        self.runner = runner
        self.results: list[dict] = []
        self.raised: BaseException | None = None

    def run(self, parameter_space: Any, tuning_options: Any) -> list:
        try:
            results = self.runner.run(parameter_space, tuning_options)
        except BaseException as err:
            self.raised = err
            raise
        self.results += [r for r in results if r is not None]
        return results

    def __getattr__(self, name: str) -> Any:
        return getattr(self.runner, name)


class StrategyWithinBudget:
    """Kernel Tuner's strategy `name` on one run, kept to what its results can say: a space too
    small for it (SMALL_SPACE) tried by `brute_force` instead, told through `note`; the budget's
    end, which some strategies let out as StopCriterionReached (greedy_ils and
    simulated_annealing after their first configuration), the run's end, with what was timed;
    any other failure of the strategy one line naming it. A Kernel Tuner strategy."""

    def __init__(self, name: str, scene: str, brute_force: BruteForceWithinBudget,
                 note: Callable[[str], None]) -> None:
        self.name = name
        self.scene = scene
        self.brute_force = brute_force
        self.note = note

    def tune(self, searchspace: Any, runner: Any, tuning_options: Any) -> list[dict]:
        from kernel_tuner.util import StopCriterionReached

        population = strategy_population(self.name,
                                         len(searchspace.get_true_tunable_params()))
        least = max(SMALL_SPACE, POPULATIONS_IN_SPACE * population)
        if searchspace.size < least:
            why = (f"{POPULATIONS_IN_SPACE} times its population of {population}"
                   if least > SMALL_SPACE else "too few to search")
            self.note(f"--strategy {self.name} on {self.scene}: "
                      f"{plural(searchspace.size, 'kernel configuration')}, under {least} "
                      f"({why}): tried whole by brute force, within the budget")
            return self.brute_force.tune(searchspace, runner, tuning_options)
        recording = _RecordingRunner(runner)
        try:
            return import_kernel_tuner().strategy_map[self.name].tune(
                searchspace, recording, tuning_options)
        except StopCriterionReached:
            return recording.results
        except Exception as err:
            if err is recording.raised:  # the runner's (the cache file's OSError)
                raise
            raise ClrayError(f"--strategy {self.name} failed on {self.scene}: "
                             f"{type(err).__name__}: {one_line(str(err))}") from err


def host_configurations(space: dict[str, Sequence], seed: int = 0) -> list[dict[str, Any]]:
    """Every combination of the host and build knobs' values in `space`, in the order they are
    tried: the default first, then each single-knob change from it, then the rest in a seeded
    random order, so a short budget still covers each knob once. Illegal combinations are left
    out."""
    names = list(OUTER_KNOBS)
    default = {n: KNOBS[n].default for n in names}
    combos = [dict(zip(names, values, strict=True))
              for values in itertools.product(*(space[n] for n in names))]
    legal = []
    for combo in combos:
        try:
            Tuning(**combo)
        except TuningError:
            continue
        legal.append(combo)

    def changed(c: dict) -> int:
        return sum(c[n] != default[n] for n in names)

    first = [c for c in legal if changed(c) <= 1]
    rest = [c for c in legal if changed(c) > 1]
    random.Random(seed).shuffle(rest)
    return sorted(first, key=changed) + rest


def default_space() -> dict[str, tuple]:
    return {knob.name: knob.tried for knob in KNOB_TABLE}


def allowed_space(space: dict[str, Sequence], allow_error: float | None) -> dict[str, tuple]:
    """`space` with the study variants held at their defaults (off) unless --allow-error
    allows images that differ from the default's."""
    if allow_error is not None:
        return {name: tuple(values) for name, values in space.items()}
    return {name: (KNOBS[name].default,) if name in IMAGE_KNOBS else tuple(values)
            for name, values in space.items()}


def _arguments(packed: PackedScene) -> tuple[list, int]:
    """The render kernel's arguments over the whole image in one launch (the scene's buffers in
    layout.SCENE_BUFFERS' order, as clray.device.launch passes them), and the index of the image
    buffer."""
    width, height = int(packed.params[0]["width"]), int(packed.params[0]["height"])
    # OpenCL has no zero-sized buffers: an empty array becomes one zeroed element.
    args: list = [np.ascontiguousarray(a) if a.size else np.zeros(1, dtype=a.dtype)
                  for a in packed.buffers().values()]
    image_index = len(args)
    # The kernel's outputs: a pixel's radiance (three floats), its secondary and shadow rays
    # (int2), and the test counts, off in a tuned build.
    args += [np.zeros((height, width, 3), np.float32), np.zeros((height * width, 2), np.int32),
             np.zeros(4, np.int32), np.int32(0)]
    return args, image_index


def _platform_indices(device: cl.Device) -> tuple[int, int]:
    for p, platform in enumerate(cl.get_platforms()):
        for d, candidate in enumerate(platform.get_devices()):
            if candidate.int_ptr == device.int_ptr:
                return p, d
    raise DeviceError(f"device {device.name.strip()!r} not found among the platforms")


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.=]+", "_", text).strip("_")[:120] or "default"


def cache_name(tuning: Tuning) -> str:
    """The cache file name of a host and build configuration: its changed knobs, readable but
    cut short, and a digest of every knob's value. By the cut label alone, 48 pairs of the 2,592
    configurations under --allow-error (differing only in cl_fast_relaxed_math, past the 120th
    character) shared a file, and Kernel Tuner gave the second the first's times and image
    verdicts."""
    digest = hashlib.sha256(configuration_key(tuning, {}).encode("utf-8")).hexdigest()[:12]
    return f"{_slug(tuning.label())}-{digest}.json"


def _cache_error(cache: Path, why: str) -> ClrayError:
    return ClrayError(f"Kernel Tuner's cache file {cache}: {why}: delete it, or tune into "
                      "another --out")


def check_cache(cache: Path) -> None:
    """A cache file that Kernel Tuner would fail to read with a traceback (empty, cut short
    mid-entry, not its format) refused in one line. Kernel Tuner itself mends one whose run
    stopped between entries, and an empty one it would 'mend' into a lone comma: it is read
    here without mending."""
    if not cache.exists():
        return
    from kernel_tuner.util import read_cache

    try:
        # The header entries Kernel Tuner looks up before it checks them.
        readable = {"device_name", "kernel_name", "tune_params_keys"} <= read_cache(
            str(cache), open_cache=False).keys()
    except OSError as err:
        raise _cache_error(cache, err.strerror or str(err)) from None
    except (ValueError, LookupError, TypeError, AttributeError):  # JSON's, and its shape's
        readable = False
    if not readable:
        raise _cache_error(cache, "not a Kernel Tuner cache file (cut short, or changed)")


@dataclass
class SceneRun:
    name: str
    path: Path
    settings: RenderSettings
    reference: np.ndarray
    default_packed: PackedScene
    spp: int
    # Seconds the scene's load, packing and reference render took, out of the budget.
    reference_s: float
    # Whether a Kernel Tuner run was started on the scene: one that was not had its share taken
    # before it, which is what `clray tune` says of a scene left untried.
    run_started: bool = False


class Tuner:
    """One `clray tune` run on one device: trials accumulate over scenes and host
    configurations until the budget is spent."""

    def __init__(self, device: cl.Device, out: Path, *, strategy: str = "brute_force",
                 budget_s: float = 120.0, allow_error: float | None = None,
                 space: dict[str, Sequence] | None = None, iterations: int = ITERATIONS,
                 size: tuple[int | None, int | None] = (None, None),
                 search_every_host: bool = False,
                 source: str | None = None, extra_params: dict[str, list] | None = None,
                 progress: Callable[[str, Trial | None], None] | None = None,
                 say: Callable[[str], None] | None = None) -> None:
        self.kt = import_kernel_tuner()
        self.device = device
        self.out = out
        self.strategy = strategy
        self.budget_s = budget_s
        self.allow_error = allow_error
        self.space = allowed_space({**default_space(), **(space or {})}, allow_error)
        # The samples a pixel of the scene being tuned, on which the traversal a render builds
        # depends (rendered_traversal), and the device's own values of the kernel knobs whose
        # None stands for them, at those samples (set_scene_spp).
        self.spp = 16
        self.auto: dict[str, Any] = {}
        self.set_scene_spp(self.spp)
        self.iterations = iterations
        self.size = size
        # False: the kernel and launch knobs are searched with the first (default) host
        # configuration; later ones keep the best values found so far, so that each costs one
        # build rather than one per kernel configuration and the budget reaches more of them.
        self.search_every_host = search_every_host
        # The kernel's source, unless a test hands in a changed one (with its extra_params).
        self.source = source if source is not None else kernel_source()
        self.extra_params = extra_params or {}
        self.progress = progress or (lambda _msg, _trial: None)
        self.say = say or (lambda _text: None)
        # What was said while tuning (through `say`, at once), for the results and the report.
        self.notes: list[str] = []
        self._noted: set[str] = set()
        self.trials: list[Trial] = []
        self.runs: list[SceneRun] = []

    def note(self, text: str, once: str | None = None) -> None:
        """Say `text` now and keep it for the report; only the first of those `once` names."""
        if once is not None:
            if once in self._noted:
                return
            self._noted.add(once)
        self.notes.append(text)
        self.say(text)

    def prepare(self, path: Path) -> SceneRun:
        start = time.monotonic()
        scene = load_scene(path)
        settings = RenderSettings(width=self.size[0], height=self.size[1],
                                  tuning=DEFAULT_TUNING)
        packed = pack_for(scene, settings, self.device)
        reference, stats = render_packed(packed, self.device)
        if stats["kernel_s"] < MIN_TIMED_KERNEL_S:
            height, width = reference.shape[:2]
            self.note(f"{path.stem}: the default renders {width}x{height} in "
                      f"{stats['kernel_s'] * 1e3:.2g} ms, too short to time against the "
                      f"machine's noise (under {MIN_TIMED_KERNEL_S * 1e3:.0f} ms): Kernel "
                      "Tuner's times are mostly noise, and a winner is stored only where the "
                      "interleaved renders confirm it; tune at the size you render, or larger "
                      "(-W, -H)")
        return SceneRun(path.stem, path, settings, reference, packed, scene.render.spp,
                        time.monotonic() - start)

    def tolerance(self, reference: np.ndarray) -> Tolerance:
        n = reference.shape[0] * reference.shape[1]
        threshold = PIXEL_TOLERANCE if self.allow_error is None else self.allow_error
        return Tolerance(threshold, fail_allowance(n))

    def cache_folder(self, run: SceneRun) -> str:
        """The folder of a scene's cache files, one for each image size (Kernel Tuner refuses
        a cache file of another size) and each set of what the cached verdicts and times
        depend on: the reference image (the scene as it is now: an edited scene with the
        same name had its old verdicts taken), the image tolerance (--allow-error), and the
        kernel's source and the scene's default build (another clray) with the device's build
        options."""
        height, width = run.reference.shape[:2]
        key = hashlib.sha256(np.ascontiguousarray(run.reference).tobytes())
        for part in (repr(self.tolerance(run.reference)), self.source,
                     *run.default_packed.config.options(), *device_build_options(self.device)):
            key.update(b"\0" + part.encode("utf-8"))
        return f"{width}x{height}-{key.hexdigest()[:12]}"

    def run_host(self, run: SceneRun, host: dict, time_limit: float,
                 kernel_space: dict[str, list]) -> list[Trial]:
        """One Kernel Tuner run: the scene packed with `host`'s knobs, the kernel and launch
        knobs' values in `kernel_space` as tunable parameters."""
        base = Tuning(**host)
        packed = pack_for(load_scene(run.path), RenderSettings(
            width=self.size[0], height=self.size[1], tuning=base), self.device)
        args, image_index = _arguments(packed)
        height, width = run.reference.shape[:2]
        check = _image_check(image_index, run.reference, self.tolerance(run.reference))
        tune_params = kernel_space
        # The kernel knobs' -D switches come from Kernel Tuner's #defines instead.
        tuned = tuple(f"-D{kernel_define(name)}=" for name in KERNEL_KNOBS)
        # With the options every render's build on this device takes (a GPU's one pixel a
        # work-item, correctly rounded division): what is timed is what renders build.
        options = [*(o for o in packed.config.options() if not o.startswith(tuned)),
                   *device_build_options(self.device)]
        answer = [None] * len(args)
        answer[image_index] = args[image_index]
        cache = (self.out / "cache" / _slug(self.device.name) / run.name
                 / self.cache_folder(run) / cache_name(base))
        try:
            cache.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise cannot_write(cache.parent, err) from err
        check_cache(cache)
        platform, device = _platform_indices(self.device)

        # A def, not a lambda: Kernel Tuner rewrites a lambda restriction from its source text.
        def legal(params: dict) -> bool:
            return self._legal(base, params, kernel_space)

        first = {**self.block_params(base), **self.kernel_params(base)}
        brute_force = BruteForceWithinBudget({k: v[0] for k, v in first.items()})
        strategy: Any = brute_force
        if self.strategy != "brute_force":
            strategy = StrategyWithinBudget(self.strategy, run.name, brute_force,
                                            partial(self.note, once=f"strategy {run.name}"))
        with warnings.catch_warnings():
            # Kernel Tuner warns where a structured buffer meets a struct pointer: expected.
            warnings.simplefilter("ignore")
            try:
                results, _env = self.kt.tune_kernel(
                    "render", self.source, (width, height), args, tune_params,
                    answer=answer, observers=[_launch_wait(), check], compiler_options=options,
                    restrictions=legal,
                    lang="OpenCL", platform=platform, device=device,
                    iterations=self.iterations, strategy=strategy,
                    strategy_options={"time_limit": time_limit},
                    cache=str(cache), quiet=True, verbose=False)
            except RuntimeError as exc:
                # Kernel Tuner refuses a run whose start-up (its context, the arguments'
                # copies) took longer than the time left: the budget is spent.
                if "startup time" not in str(exc):
                    raise
                return []
            except ValueError as exc:
                # Kernel Tuner refuses a cache file of another device, kernel or set of
                # parameters (an older clray's knobs).
                if "cache" not in str(exc):
                    raise
                raise _cache_error(cache, " ".join(str(exc).split())) from None
            except OSError as err:  # reading or appending to the cache file: its only files
                raise _cache_error(cache, err.strerror or str(err)) from err
        trials = [self._trial(run.name, base, r) for r in results if r]
        self.trials += trials
        return trials

    def _tuning(self, base: Tuning, params: dict) -> Tuning:
        """The configuration of Kernel Tuner's parameters on the run's host and build knobs."""
        kernel = {name: knob_value(name, params[kernel_define(name)], self.auto)
                  for name in KERNEL_KNOBS if kernel_define(name) in params}
        traversal = kernel.get("traversal", base.traversal) or self.auto["traversal"]
        # A scheme's build ignores other schemes' #defines (the single-ray walk the packet's):
        # their knobs keep their defaults.
        others = other_schemes_knobs(traversal)
        kernel = {k: v for k, v in kernel.items() if k not in others}
        if TRAVERSAL_SCHEMES[traversal].tiles:
            launch = {"group_side": int(params[BLOCK_SIZE_Y])}
        else:
            launch = {"work_group_width": int(params[BLOCK_SIZE_X])}
        return Tuning(**{**base.values(), **kernel, **launch})

    def _legal(self, base: Tuning, params: dict, space: dict[str, list]) -> bool:
        """Kernel Tuner's restriction: the knob table's, with the walk and the packet's lanes
        resolved (packet_min_lanes below the device's own where packet_lanes is left to it), and the
        single-ray walk built once, with the packet knobs' first values, which it ignores (as
        every scheme other schemes' kernel knobs)."""
        traversal = TRAVERSALS[params["TRAVERSAL"]]
        if any(params[kernel_define(n)] != space[kernel_define(n)][0]
               for n in other_schemes_knobs(traversal) if n in KERNEL_KNOBS):
            return False
        # A group packet's work-group is a square tile; every other a row segment.
        x, y = params[BLOCK_SIZE_X], params[BLOCK_SIZE_Y]
        if TRAVERSAL_SCHEMES[traversal].tiles:
            if x != y or y not in self.space["group_side"]:
                return False
        elif y != 1 or x not in self.space["work_group_width"]:
            return False
        try:
            tuning = self._tuning(base, params)
        except TuningError:
            return False
        # The knob table's rules again with the walk Kernel Tuner builds named: _tuning's
        # traversal None (the device's own) may be sample packets, which implicit
        # vectorization must not build with.
        if restriction_problems({**tuning.values(), "traversal": traversal}):
            return False
        return tuning.packet_min_lanes < (tuning.packet_lanes or self.auto["packet_lanes"])

    def _trial(self, scene: str, base: Tuning, result: dict) -> Trial:
        extra = {k: result[k] for k in self.extra_params}
        tuning = self._tuning(base, result)
        time_ms = result.get("time")
        if not isinstance(time_ms, int | float) or "__error__" in result:
            return Trial(scene, tuning, None, [], float(result.get("compile_time", 0)), False,
                         0, failure(result), extra)
        verified = bool(result.get("verified", 0))
        problem = None if verified else result.get("problem") or "image differs"
        times = [float(t) for t in result.get("times", [])]
        # Kernel Tuner's strategies follow the mean ("time"); clray ranks by the median of the
        # same runs, which one launch slowed by the shared machine does not move.
        return Trial(scene, tuning, statistics.median(times) if times else float(time_ms), times,
                     float(result.get("compile_time", 0)), verified,
                     int(result.get("pixels_off", 0)), problem, extra,
                     self.equivalent_keys(tuning, extra))

    def equivalent_keys(self, tuning: Tuning, extra: dict) -> tuple[str, ...]:
        """The keys of the configurations whose render of the scene being tuned builds what
        `tuning` builds: its walk knobs (traversal, packet_lanes, packet_min_lanes,
        implicit_vectorization) at every value of the space or None, wherever the device
        policy's plan is the same. A trial's knobs name the device's own walk and lanes as None
        (knob_value), and those differ between scenes of other samples a pixel: a walk that is
        one scene's own and another's named has a key of each kind."""
        built = self._built(tuning)
        names = ("traversal", "packet_lanes", "packet_min_lanes", "implicit_vectorization")
        values = [dict.fromkeys((getattr(tuning, n), KNOBS[n].default, *self.space[n]))
                  for n in names]
        keys = [configuration_key(tuning, extra)]
        for combination in itertools.product(*values):
            try:
                other = Tuning(**{**tuning.values(), **dict(zip(names, combination,
                                                                strict=True))})
            except TuningError:
                continue
            if other != tuning and self._built(other) == built:
                keys.append(configuration_key(other, extra))
        return tuple(keys)

    def _built(self, tuning: Tuning) -> tuple[dict, int] | None:
        """What a render of the scene being tuned with `tuning` builds (the plan's switches and
        BVH width), or None where it cannot build."""
        try:
            plan = self.plan(tuning)
        except ClrayError:
            return None
        return plan.switches, plan.bvh_width

    def block_params(self, only: Tuning | None = None) -> dict[str, list[int]]:
        """Kernel Tuner's work-group sizes: the work_group_width values as row segments and,
        where group packets are searched, the group_side values as tiles (_legal pairs them
        with their traversals); or `only`'s."""
        if only is not None:
            if TRAVERSAL_SCHEMES[only.traversal or self.auto["traversal"]].tiles:
                return {BLOCK_SIZE_X: [only.group_side], BLOCK_SIZE_Y: [only.group_side]}
            return {BLOCK_SIZE_X: [only.work_group_width], BLOCK_SIZE_Y: [1]}
        widths, heights = list(self.space["work_group_width"]), [1]
        if any(TRAVERSAL_SCHEMES[v or self.auto["traversal"]].tiles
               for v in self.space["traversal"]):
            sides = list(self.space["group_side"])
            widths, heights = widths + sides, heights + sides
        return {BLOCK_SIZE_X: list(dict.fromkeys(widths)),
                BLOCK_SIZE_Y: list(dict.fromkeys(heights))}

    def kernel_params(self, only: Tuning | None = None) -> dict[str, list[int]]:
        """Kernel Tuner's tunable parameters of the kernel knobs: the values of the space, or
        `only`'s; the device's own traversal and packet lanes where None (the default) stands
        for them."""
        params = {}
        for name in KERNEL_KNOBS:
            values = [getattr(only, name)] if only is not None else self.space[name]
            if name == "traversal":
                values = [self.rendered_traversal(v) for v in values]
            if name in self.auto:
                values = [self.auto[name] if v is None else v for v in values]
            defines = [define_value(name, v) for v in values]
            params[kernel_define(name)] = list(dict.fromkeys(defines))
        return params

    def plan(self, tuning: Tuning) -> DevicePlan:
        """The device policy's plan of a render of the scene being tuned with `tuning`."""
        return device_plan(self.device, spp=self.spp, tuning=tuning)

    def set_scene_spp(self, spp: int) -> None:
        """Tune for a scene of `spp` samples a pixel: a render's own traversal and packet lanes
        depend on them, and so the values that None stands for."""
        self.spp = spp
        own = self.plan(DEFAULT_TUNING)
        self.auto = {"traversal": own.traversal, "packet_lanes": own.packet_lanes}

    def rendered_traversal(self, traversal: str | None) -> str:
        """The walk a render of the scene being tuned builds with the knob's `traversal` (as
        the device policy decides: one sample a pixel is no packet): the kernel that Kernel
        Tuner builds and times for it, so a scene at 1 spp times no packet builds, which its
        renders never use."""
        return self.plan(Tuning(traversal=traversal)).traversal

    def tune(self, paths: Sequence[Path]) -> list[Trial]:
        """Every scene, host configuration by host configuration, until the budget is spent
        (each scene gets an equal share)."""
        # bvh_width None means the device's own width: the same tree as that width given,
        # tried once (as None, the default, where both are in the space).
        auto = self.plan(DEFAULT_TUNING).bvh_width
        hosts, seen = [], set()
        for host in host_configurations(self.space):
            resolved = json.dumps({**host, "bvh_width": host["bvh_width"] or auto})
            if resolved not in seen:
                seen.add(resolved)
                hosts.append(host)
        start = time.monotonic()
        for i, path in enumerate(paths):
            run = self.prepare(path)
            self.runs.append(run)
            self.set_scene_spp(run.spp)
            deadline = start + self.budget_s * (i + 1) / len(paths)
            kernel_space = {**self.block_params(), **self.kernel_params(),
                            **self.extra_params}
            for host in hosts:
                left = deadline - time.monotonic()
                if left < MIN_RUN_BUDGET_S:
                    break
                run.run_started = True
                trials = self.run_host(run, host, left, kernel_space)
                for trial in trials:
                    self.progress(run.name, trial)
                best = min((t for t in trials if t.verified), key=lambda t: t.time_ms,
                           default=None)
                if best is not None and not self.search_every_host:
                    kernel_space = {**self.block_params(best.tuning),
                                    **self.kernel_params(best.tuning),
                                    **{k: [v] for k, v in best.extra.items()}}
        return self.trials


def _image_check(index: int, reference: np.ndarray, tolerance: Tolerance) -> Any:
    """A Kernel Tuner OutputObserver: the configuration's image against the default's, the
    verdict recorded with its times (and so in the cache file)."""

    class ImageCheck(_observer_base("OutputObserver")):
        def __init__(self) -> None:
            self.result: dict = {}

        def process_output(self, answer: list, output: list) -> None:
            image = output[index].reshape(reference.shape[0], reference.shape[1], 3)
            ok, off, problem = tolerance.check(image, reference)
            self.result = {"verified": int(ok), "pixels_off": off, "problem": problem or ""}

        def get_results(self) -> dict:
            return self.result

    return ImageCheck()


def best_configuration(trials: Sequence[Trial], scenes: Sequence[str]
                       ) -> tuple[str, dict[str, Trial]] | None:
    """The configuration verified on every scene with the least total time, as (key, its trial
    per scene: the trial that built what the key's knobs build there); None when none was."""
    by_key: dict[str, dict[str, Trial]] = {}
    for trial in trials:
        for key in trial.keys():
            by_key.setdefault(key, {})[trial.scene] = trial
    whole = {k: v for k, v in by_key.items()
             if set(v) == set(scenes) and all(t.verified for t in v.values())}
    if not whole:
        return None

    def changed(key: str) -> int:
        return len(key_tuning(key).changed())

    # Of the keys that stand for the same trials, the fewest knobs named: the device's own
    # walk as None, which stays its own on another driver.
    key = min(whole, key=lambda k: (sum(t.time_ms for t in whole[k].values()), changed(k)))
    return key, whole[key]


def confirm_rounds(round_s: float) -> int:
    """The confirmation's rounds where a round renders each side for `round_s`: as many as make
    CONFIRM_SECONDS of renders a side, within MIN_CONFIRM_ROUNDS and MAX_CONFIRM_ROUNDS, and
    even (each side first as often)."""
    wanted = math.ceil(CONFIRM_SECONDS / round_s) if round_s > 0 else MAX_CONFIRM_ROUNDS
    rounds = min(MAX_CONFIRM_ROUNDS, max(MIN_CONFIRM_ROUNDS, wanted))
    return rounds + rounds % 2


def confirm(runs: Sequence[SceneRun], tuning: Tuning, device: cl.Device) -> list[dict]:
    """The default and `tuning` rendered through clray's own launches (bands and all) after a
    warm-up of each, in rounds (confirm_rounds) that render both on every scene: the default
    first in even rounds and `tuning` first in odd ones (ABBA), so that whatever favours a
    render for following the other (a warm cache, a clock) favours each side alike. Per scene,
    kernel times as renders see them (confirmation)."""
    sides = [(run.default_packed,
              pack_for(load_scene(run.path), RenderSettings(width=run.settings.width,
                                                            height=run.settings.height,
                                                            tuning=tuning), device))
             for run in runs]
    round_s = sum(max(render_packed(packed, device)[1]["kernel_s"] for packed in pair)
                  for pair in sides)
    rounds = confirm_rounds(round_s)
    times: list[tuple[list[float], list[float]]] = [([], []) for _ in runs]
    for i in range(rounds):
        for pair, scene_times in zip(sides, times, strict=True):
            for side in ((0, 1) if i % 2 == 0 else (1, 0)):
                scene_times[side].append(render_packed(pair[side], device)[1]["kernel_s"])
    return [confirmation(run.name, default_s, tuned_s)
            for run, (default_s, tuned_s) in zip(runs, times, strict=True)]


def confirmation(scene: str, default_s: list[float], tuned_s: list[float]) -> dict:
    """A scene's record of the confirmation: its rounds' kernel times, default and tuned, their
    medians, and its rounds' ratios (default / tuned): their median, the speed-up, and middle
    half, and the rounds in which the tuned render was faster. The speed-up is not the ratio of
    the medians, which pairs renders of different rounds (160x90 on PoCL under load: medians of
    7.95 and 6.25 ms, 1.27x, where the rounds' ratios, 0.15x to 5.6x, had a median of 0.96x)."""
    record = {"scene": scene, "rounds": len(default_s),
              "default_kernel_s": statistics.median(default_s),
              "tuned_kernel_s": statistics.median(tuned_s),
              "default_runs_s": default_s, "tuned_runs_s": tuned_s}
    ratios = round_ratios(record)
    lower, speedup, upper = statistics.quantiles(ratios, n=4, method="inclusive")
    return {**record, "speedup": speedup, "quartiles": [lower, upper],
            "faster_rounds": sum(r > 1 for r in ratios)}


def round_ratios(record: dict) -> list[float]:
    """A confirmation's ratio of each round: the default's kernel time over the tuned one's,
    rendered back to back, so under the same load."""
    return [d / t for d, t in zip(record["default_runs_s"], record["tuned_runs_s"], strict=True)]


def sign_test_p(faster: int, rounds: int) -> float:
    """The one-sided sign test's p: the chance that at least `faster` of `rounds` rounds favour
    the winner where each favours either side with even odds (no difference). Exact, whatever
    the noise's distribution; a round's order effect, alternated (confirm), only lowers it."""
    return sum(math.comb(rounds, k) for k in range(faster, rounds + 1)) / 2**rounds


def confirmed_gain(confirmed: Sequence[dict]) -> dict:
    """The confirmation's verdict on a winner over every scene (their records of one count of
    rounds, confirm's). A round's ratio is the geometric mean of the scenes' ratios of that
    round; the gain is the median of the rounds' ratios, with their middle half; the sign test
    counts the rounds in which the winner was faster (a tie counts against it). Confirmed where
    p < CONFIRM_P and the gain is at least MIN_GAIN: identical configurations pass the test in
    fewer than 1 tune in 100, and less often still with the gain's bound. A gain that fails is
    noise, or too small: storing it would change every later render on the device for it."""
    by_round = zip(*(round_ratios(c) for c in confirmed), strict=True)
    ratios = [math.prod(r) ** (1 / len(r)) for r in by_round]
    lower, gain, upper = statistics.quantiles(ratios, n=4, method="inclusive")
    faster = sum(r > 1 for r in ratios)
    p = sign_test_p(faster, len(ratios))
    return {"rounds": len(ratios), "gain": gain, "quartiles": [lower, upper],
            "faster_rounds": faster, "p": p, "confirmed": p < CONFIRM_P and gain >= MIN_GAIN}
