"""The public entry point: a scene and RenderSettings in, a RenderResult out (load or check the
scene, pack it for the device, launch it with clray.device.launch)."""

from __future__ import annotations

import numbers
import os
import time
import typing
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import pyopencl as cl

from clray.denoise import DENOISE_GUIDES, check_denoiser, denoise
from clray.device.context import describe, queue_for, select_device
from clray.device.launch import render_packed, render_passes_packed
from clray.device.pack import PackedScene, SceneGeometry, pack_scene
from clray.device.policy import DevicePlan, device_plan
from clray.device.program import KernelConfig
from clray.errors import SettingsError
from clray.image_io import Encoding, image_bytes
from clray.knobs import KNOBS, TRAVERSALS, Tuning, python_number
from clray.model_scene import is_mesh_file, load_model_scene
from clray.passes import pass_problem, passes_of, write_with_passes
from clray.scene import limits as L
from clray.scene.check import check_scene
from clray.scene.load import load_scene
from clray.scene.model import Scene

# KernelConfig fields a variant may not set: the packer derives them from the scene (every
# has_* switch, max_depth, bvh_stack_size: a variant's value would clash with pack_scene's
# own), and the render from other settings (precision, passes: RenderSettings.precision,
# aovs and denoise, which the stats and the passes' launch follow).
RENDER_SET_FIELDS = ("max_depth", "bvh_stack_size", "precision", "passes")
_SWITCH_TYPES = typing.get_type_hints(KernelConfig)
# What each type of KernelConfig field takes, and whether a value is one.
_SWITCH_VALUES: dict[object, tuple[str, Callable[[object], bool]]] = {
    bool: ("True or False", lambda v: isinstance(v, bool)),
    int: ("an integer", lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool)),
    str: ("a string", lambda v: isinstance(v, str)),
    tuple[str, ...]: ("a tuple of strings",
                      lambda v: isinstance(v, tuple) and all(isinstance(o, str) for o in v)),
}


def variants_problem(variants: object) -> str | None:
    """What is wrong with RenderSettings.variants (clray.study.Variant.switches), or None: a
    tuple of (KernelConfig field, value) pairs, each field one the render does not set itself,
    each value of the field's type and, for a knob (clray.knobs), one the knob allows."""
    if not isinstance(variants, tuple) or not all(
            isinstance(pair, tuple) and len(pair) == 2 and isinstance(pair[0], str)
            for pair in variants):
        return "expected a tuple of (KernelConfig field name, value) pairs"
    for name, value in variants:
        if name not in _SWITCH_TYPES:
            return f"{name!r} is not a KernelConfig field"
        if name.startswith("has_") or name in RENDER_SET_FIELDS:
            return f"{name!r} is set by the render from the scene and settings, not by a variant"
        takes, fits = _SWITCH_VALUES[_SWITCH_TYPES[name]]
        if not fits(value):
            return f"{name!r} takes {takes}, not {value!r}"
        if name in KNOBS and not KNOBS[name].legal(value):
            # The knob's rule up to its explanation ("4, 8, or None: 8 where ..."), less the
            # None that means "the device's" to a knob: a variant names a value.
            rule = KNOBS[name].legal_text.split(": ")[0]
            if rule.endswith(", or None"):
                rule = f"one of {rule.removesuffix(', or None')}"
            return f"{name!r} takes {rule}, not {value!r}"
    return None


@dataclass(frozen=True)
class RenderSettings:
    """Overrides of the scene's [render] values (None keeps the scene's), checked on creation
    by the scene file's rules: a bad value raises SettingsError (a ValueError)."""

    width: int | None = None
    height: int | None = None
    spp: int | None = None
    max_depth: int | None = None
    seed: int | None = None
    min_weight: float | None = None
    device: str | None = None  # clray.device.context.select_device spec
    precision: str = "float"  # "float" | "double"
    # How rays walk the BVH (clray.knobs.TRAVERSALS); None: the tuning's traversal knob.
    traversal: str | None = None
    # progress(done, total) in pixel-samples (pixels x spp): called with done = 0 before the
    # first launch, then after each launch, rising to done = total; several times a second.
    # With passes (aovs, denoise) their kernel traces every pixel-sample again, and the total
    # counts both kernels' (twice the image's): it is reached when the passes' launches end.
    progress: Callable[[int, int], None] | None = field(default=None, compare=False)
    variants: tuple[tuple[str, object], ...] = ()  # extra KernelConfig fields (studies)
    # PNG output (RenderResult.save, docs/rendering.md); None = the scene file's value.
    linear: bool | None = None
    exposure: float | None = None  # stops
    png_bits: int | None = None
    # Performance knobs (clray.tuning): None takes the device's tuning file, written by `clray
    # tune`, where stored_tuning and one exists, else the knob table's defaults.
    tuning: Tuning | None = None
    stored_tuning: bool = True
    # Passes (clray.passes.PASS_NAMES; docs/passes.md) to render beside the image, into
    # RenderResult.aovs: a second kernel after the render's, built in only when asked.
    aovs: tuple[str, ...] = ()
    # Denoise the image with Open Image Denoise (clray.denoise, the `denoise` extra), guided by
    # the albedo and normal passes, traced for it whether or not aovs names them.
    denoise: bool = False
    # on_band(first row, its rows of the image) after each band of rows arrives, linear
    # float32, not yet denoised: a view of the image being filled (copy what you keep).
    on_band: Callable[[int, np.ndarray], None] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        # numpy's numbers are numbers here (numbers.Integral, numbers.Real), but json.dumps
        # refuses them, and these values go into the result's stats: kept as Python's own.
        for name in (*L.RENDER_INTEGERS, *L.RENDER_NUMBERS, *L.RENDER_CHOICES):
            object.__setattr__(self, name, python_number(getattr(self, name)))
        if isinstance(self.variants, tuple):
            object.__setattr__(self, "variants", tuple(
                (pair[0], python_number(pair[1]))
                if isinstance(pair, tuple) and len(pair) == 2 else pair
                for pair in self.variants))
        # The scene file's [render] rules (clray.scene.limits), in the same words.
        checks = [(name, lambda v, r=rule: L.integer_problem(v, *r))
                  for name, rule in L.RENDER_INTEGERS.items()]
        checks += [(name, lambda v, r=rule: L.number_problem(v, *r))
                   for name, rule in L.RENDER_NUMBERS.items()]
        checks += [(name, lambda v, r=rule: L.choice_problem(v, r))
                   for name, rule in L.RENDER_CHOICES.items()]
        checks += [("linear", lambda v: None if isinstance(v, bool) else "expected True or False"),
                   ("precision", lambda v: L.choice_problem(v, L.PRECISIONS)),
                   ("traversal", lambda v: L.choice_problem(v, TRAVERSALS)),
                   ("device", lambda v: None if isinstance(v, str) else "expected a string"),
                   ("tuning", lambda v: None if isinstance(v, Tuning)
                    else "expected a clray.tuning.Tuning"),
                   ("stored_tuning",
                    lambda v: None if isinstance(v, bool) else "expected True or False"),
                   ("aovs", pass_problem),
                   ("variants", variants_problem),
                   ("denoise",
                    lambda v: None if isinstance(v, bool) else "expected True or False")]
        # None keeps the scene's value only where the field's default is None: precision,
        # aovs, variants and the switches take no None (the render reads each as it is).
        optional = {f.name for f in fields(self) if f.default is None}
        for name, problem_of in checks:
            value = getattr(self, name)
            problem = None if value is None and name in optional else problem_of(value)
            if problem:
                raise SettingsError(f"RenderSettings.{name}: {problem}, got {value!r}")
        for name in ("progress", "on_band"):
            if getattr(self, name) is not None and not callable(getattr(self, name)):
                raise SettingsError(f"RenderSettings.{name}: expected a callable, "
                                    f"got {getattr(self, name)!r}")


def settings_or_default(settings: object) -> RenderSettings:
    """`settings`, or RenderSettings() for None; SettingsError for anything else, which would
    fail later with an AttributeError (a dict of overrides, say)."""
    if settings is None:
        return RenderSettings()
    if not isinstance(settings, RenderSettings):
        raise SettingsError(f"settings: expected a clray.RenderSettings or None, got "
                            f"{type(settings).__name__}")
    return settings


@dataclass(frozen=True)
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32, linear, may hold non-finite values
    stats: dict
    encoding: Encoding = field(default_factory=Encoding)  # how save() writes a PNG
    # The passes RenderSettings.aovs asked for, by name (docs/passes.md): depth (H, W) float32,
    # inf where no sample hit; normal, albedo, position (H, W, 3) float32; object, material,
    # instance (H, W) int32, -1 on a miss.
    aovs: dict[str, np.ndarray] = field(default_factory=dict)
    # Where RenderSettings.denoise was set, the image before denoising (image is the denoised
    # one); else None.
    noisy: np.ndarray | None = None

    def save(self, path: str | Path, previews: bool = False) -> None:
        """Write the image, the suffix picking the format (.png, .pfm, .exr), and its passes
        (docs/passes.md): layers of the same file where it is .exr, else one PFM a pass beside
        it (out.depth.pfm), and with `previews` a false-colour PNG of each (out.depth.png)."""
        write_with_passes(path, self.image, self.encoding, self.aovs, previews)

    def _repr_png_(self) -> bytes:
        """The PNG that save() writes, for Jupyter and IPython to show the result inline."""
        return image_bytes(".png", self.image, self.encoding)


def traced_passes(settings: RenderSettings) -> tuple[str, ...]:
    """The passes a render traces: the settings' aovs, and the denoiser's guides."""
    guides = DENOISE_GUIDES if settings.denoise else ()
    return settings.aovs + tuple(name for name in guides if name not in settings.aovs)


def _overrides(scene: Scene, settings: RenderSettings, names: tuple[str, ...]) -> dict:
    """Each of `names` from the settings where given, else from the scene's [render]."""
    return {name: getattr(settings, name) if getattr(settings, name) is not None
            else getattr(scene.render, name) for name in names}


def resolved_settings(scene: Scene, settings: RenderSettings) -> dict[str, int | float]:
    """The render's integers and min_weight: the settings' where given, else the scene's."""
    return _overrides(scene, settings, (*L.RENDER_INTEGERS, "min_weight"))


def png_encoding(scene: Scene, settings: RenderSettings) -> Encoding:
    """How the result's PNG is written: the settings' values where given, else the scene's."""
    return Encoding(**_overrides(scene, settings, ("linear", "exposure", "png_bits")))


# Above this depth a transmissive scene without min_weight gets a warning: glass.toml takes
# 0.03 s at depth 16 and did not finish in 5 minutes at depth 32 (80x60 pixels, PoCL).
DEEP_TREE_DEPTH = 20

def warn_deep_tree(scene: Scene, resolved: dict[str, int | float]) -> None:
    """A warning (before any device work) for a transmissive scene traced deep without
    min_weight, whose ray tree can double at every bounce."""
    if (resolved["max_depth"] > DEEP_TREE_DEPTH and resolved["min_weight"] == 0
            and any(m.transmit > 0 for m in scene.materials)):
        warnings.warn(f"max_depth {resolved['max_depth']} with transmissive materials and "
                      "min_weight 0: inside glass the ray tree can double at every bounce and "
                      "the render take very long; set min_weight (e.g. 0.004) to stop faint rays",
                      stacklevel=3)


def plan_for(scene: Scene, settings: RenderSettings, device: cl.Device) -> DevicePlan:
    """The device policy's plan (clray.device.policy.device_plan) of rendering `scene` with
    `settings` on `device`: its knobs, traversal, packet lanes, BVH width and switches."""
    return device_plan(device, spp=resolved_settings(scene, settings)["spp"],
                       precision=settings.precision, traversal=settings.traversal,
                       tuning=settings.tuning, stored_tuning=settings.stored_tuning,
                       passes=bool(traced_passes(settings)), variants=settings.variants)


def pack_for(scene: Scene, settings: RenderSettings, device: cl.Device,
             plan: DevicePlan | None = None, geometry: SceneGeometry | None = None
             ) -> PackedScene:
    """The checked `scene` packed for `device` with `settings` as `plan` (plan_for's where not
    given) decides: what render() launches, and what each worker of a distributed render packs
    once for all its tiles. `geometry`: the scene's objects packed at another frame, moved
    to this scene's eye (pack_scene)."""
    plan = plan or plan_for(scene, settings, device)
    return pack_scene(scene, queue=queue_for(device), geometry=geometry,
                      **resolved_settings(scene, settings), **plan.pack_arguments())


def tuning_stats(plan: DevicePlan, packed: PackedScene) -> dict:
    """Which configuration rendered, for the stats: its source, the knobs it changed from the
    defaults (label), every knob's value as built, and the BVH width that "auto" (None)
    picked. implicit_vectorization is what the kernel was built with: a walk with vector lanes
    of its own is never packed on top, whatever the tuning says (device_plan)."""
    return {"source": plan.tuning_source, "label": packed.tuning.label(),
            **packed.tuning.values(), "bvh_width": packed.config.bvh_width,
            "implicit_vectorization": packed.config.implicit_vectorization}


def progress_parts(progress: Callable[[int, int], None] | None, parts: int
                   ) -> list[Callable[[int, int], None] | None]:
    """One progress callback for each of `parts` of equal work run one after the other (the
    kernels of a render over the same pixel-samples, the frames of an animation), each reporting
    its own (done, total): together they report one rise from 0 to parts x total, so that the
    end is heard when the last part's work ends."""
    if progress is None:
        return [None] * parts

    def part(k: int) -> Callable[[int, int], None]:
        return lambda done, total: progress(k * total + done, parts * total)
    return [part(k) for k in range(parts)]


SceneSource = Scene | str | os.PathLike | Callable[[], Scene]


def scene_from(source: SceneSource, settings: RenderSettings | None = None) -> Scene:
    """The checked scene of what render() takes: a scene (checked by the scene file's rules,
    clray.scene.check), a scene file, a mesh file (its automatic scene, as `clray render
    model.obj` frames it, for the settings' image size where they give one), or the scene a
    callable returns."""
    if isinstance(source, str | os.PathLike):
        path = Path(os.fsdecode(source))
        if is_mesh_file(path):
            size = settings or RenderSettings()
            return load_model_scene(path, width=size.width, height=size.height)
        return load_scene(path)
    return check_scene(source() if callable(source) else source)


# What gives a frame's render its objects packed for the device and plan
# (clray.sequence.Sequence.packed_objects).
GeometrySource = Callable[[cl.Device, DevicePlan], SceneGeometry]


def render(scene: SceneSource, settings: RenderSettings | None = None, *,
           geometry_for: GeometrySource | None = None) -> RenderResult:
    """Render a scene, the scene or mesh file at a path, or the scene a callable returns
    (scene_from). A scene built in Python is first checked by the scene file's rules
    (clray.scene.check): SceneError names the bad value. `geometry_for`: where the scene is
    a frame of an animation whose frames share a packing, what gives its objects as packed
    at another frame (clray.sequence.Sequence.frame_geometry), moved to this frame's eye,
    instances' places and shapes' values.

    Given a path or a callable, render holds the scene alone and lets it go once it is packed
    (unless passes need it after the render): a big model's mesh (18 B a triangle from a PLY
    file) is not held beside the packed scene while it renders. `clray render` hands its
    scene over so (a list's `pop`)."""
    settings = settings_or_default(settings)
    scene = scene_from(scene, settings)
    start = time.perf_counter()
    encoding = png_encoding(scene, settings)
    resolved = resolved_settings(scene, settings)
    warn_deep_tree(scene, resolved)
    if settings.denoise:
        check_denoiser()  # before any device work
    device_start = time.perf_counter()
    device = select_device(settings.device)
    plan = plan_for(scene, settings, device)
    pack_start = time.perf_counter()
    packed = pack_for(scene, settings, device, plan,
                      None if geometry_for is None else geometry_for(device, plan))
    # device_s: finding the device and its plan (platforms, context, tuning file); pack_s:
    # the packing beside its BVH build (bvh_s).
    device_s = pack_start - device_start
    pack_s = time.perf_counter() - pack_start - packed.bvh_s
    passes = traced_passes(settings)
    if not passes:
        del scene  # where render holds it alone, the scene's arrays go before the render's
    reports = progress_parts(settings.progress, 2 if passes else 1)
    image, stats = render_packed(packed, device, reports[0], on_band=settings.on_band)
    aovs: dict[str, np.ndarray] = {}
    if passes:
        passes_start = time.perf_counter()
        raw, pass_stats = render_passes_packed(packed, device, progress=reports[1])
        aovs = passes_of(raw, scene, passes)
        del raw  # 64 bytes a pixel, not held through the denoiser and the write
        # passes_s: the wall time, with the host's work and PoCL's first-launch compile of the
        # passes kernel; passes_kernel_s: the launches' device time.
        stats.update(pass_stats, passes_s=time.perf_counter() - passes_start)
    noisy = None
    if settings.denoise:
        denoise_start = time.perf_counter()
        noisy, image = image, denoise(image, aovs["albedo"], aovs["normal"])
        stats["denoise_s"] = time.perf_counter() - denoise_start
        aovs = {name: aovs[name] for name in settings.aovs}
    stats = {
        **resolved,
        "device": describe(device),
        "precision": settings.precision,
        "tuning": tuning_stats(plan, packed),
        "traversal": packed.config.traversal,
        "device_s": device_s,
        "bvh_s": packed.bvh_s,
        "pack_s": pack_s,
        **stats,
        "total_s": time.perf_counter() - start,
    }
    return RenderResult(image, stats, encoding, aovs, noisy)
