"""Every performance knob of the renderer, in one table: where it acts, its default, its legal
values, the values `clray tune` tries, and the restrictions between knobs (docs/tuning.md).

A knob changes how fast an image renders, not which image: every legal configuration renders
the default's image within the scene's float tolerance (clray.tuning.tuner's image check, an
output observer of Kernel Tuner's, checks it for every configuration `clray tune` tries).
implicit_vectorization with sample packets, which renders wrong images on Intel's CPU runtime,
is not legal (restriction_problems), and clray.device.policy.device_plan leaves it off where a
render builds sample packets whatever a tuning says. The study variants are the exception:
they change the image, and `clray tune` tries them only under --allow-error. This module
imports nothing of clray's but clray.errors (which imports nothing of clray's), so the modules
whose constants it replaces (clray.render, clray.accel.bvh, clray.accel.wide) can read it.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Literal

from clray.errors import SettingsError, plural

# Where a knob acts. host: how the packed scene is built (a new BVH, new buffers); kernel: a -D
# switch of the render kernel's build; build: an option of the kernel's compiler (-cl-...);
# launch: how the host launches the built kernel.
Acts = Literal["host", "host+kernel", "kernel", "build", "launch"]


@dataclass(frozen=True)
class Knob:
    name: str
    acts: Acts
    default: object
    legal: Callable[[object], bool]
    legal_text: str  # `legal` in words, for docs and errors
    tried: tuple  # the values `clray tune` tries, the default among them
    why: str  # what it trades
    # A study variant (clray.study): a different formula or a relaxed build, faster perhaps but
    # not the default's image. `clray tune` tries it only under --allow-error E.
    changes_image: bool = False


def python_number(value: object) -> object:
    """A real number (numpy's too) as Python's int or float; anything else as it is. numpy's
    numbers are numbers (numbers.Integral, numbers.Real), but the knobs' checks and json.dumps
    take Python's own."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return value
    return int(value) if isinstance(value, numbers.Integral) else float(value)


def _int_in(low: int, high: int) -> Callable[[object], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and low <= v <= high


def _power_of_two_upto(high: int) -> Callable[[object], bool]:
    return lambda v: _int_in(1, high)(v) and v & (v - 1) == 0


def _one_of(*values: object) -> Callable[[object], bool]:
    return lambda v: any(v == x and type(v) is type(x) for x in values)


def _number_in(low: float, high: float) -> Callable[[object], bool]:
    return lambda v: (isinstance(v, int | float) and not isinstance(v, bool)
                      and low < v <= high)


@dataclass(frozen=True)
class TraversalScheme:
    """A way rays walk the BVH: a value of the traversal knob, and its kernel build."""

    name: str  # the knob's value; the build's -D TRAVERSAL=TRAVERSAL_<NAME> (kernels/lanes.h)
    # The knobs that act only with this scheme: a configuration of another leaves them at
    # their defaults (restriction_problems).
    knobs: tuple[str, ...] = ()
    # The KernelConfig fields this scheme's build takes as -D NAME=value beside TRAVERSAL.
    defines: tuple[str, ...] = ()
    # A pixel's samples traced together, packet_lanes of them: a render with one sample a
    # pixel builds the single-ray walk instead (clray.device.policy.device_plan).
    packs_samples: bool = False
    # Launched in square work-groups of group_side x group_side pixels that walk the BVH
    # together, not in row segments of work_group_width (clray.device.launch).
    tiles: bool = False
    # A work-item's rays are lanes of its own float8/float16 vectors: a driver must not pack
    # work-items into vector lanes on top (implicit_vectorization). On Intel's CPU runtime that
    # combination renders wrong images with transmission (645 of 768 pixels of glass.toml at
    # 16 spp, up to 1.07 off), so the knob table refuses it and device_plan leaves it off.
    vector_lanes: bool = False


# The traversal schemes (docs/acceleration.md), in the order of kernels/lanes.h's
# TRAVERSAL_* codes, which `clray tune` passes as a scheme's index: a new scheme is one entry
# here, its code there and its kernel header.
TRAVERSAL_TABLE: tuple[TraversalScheme, ...] = (
    TraversalScheme("single"),
    TraversalScheme("sample_packet", knobs=("packet_lanes", "packet_min_lanes"),
                    defines=("packet_lanes", "packet_min_lanes"), packs_samples=True,
                    vector_lanes=True),
    TraversalScheme("group_packet", knobs=("group_side",), tiles=True),
)
TRAVERSAL_SCHEMES: dict[str, TraversalScheme] = {t.name: t for t in TRAVERSAL_TABLE}


def other_schemes_knobs(traversal: str) -> tuple[str, ...]:
    """The knobs that act only with traversal schemes other than `traversal`."""
    return tuple(name for scheme in TRAVERSAL_TABLE if scheme.name != traversal
                 for name in scheme.knobs)


TRAVERSALS = tuple(TRAVERSAL_SCHEMES)
GROUP_SIDES = (4, 8)
PACKET_LANES = (4, 8, 16)


def _variant(name: str, acts: Acts, why: str) -> Knob:
    return Knob(name, acts, False, _one_of(False, True), "True or False", (False, True), why,
                changes_image=True)


# Largest count in one of a leaf's sections (clray.accel.wide.LEAF_FIELD_MASK): the bound of
# largest_leaf.
_LEAF_SECTION_MAX = 255

KNOB_TABLE: tuple[Knob, ...] = (
    Knob("work_group_width", "launch", 64, _power_of_two_upto(1024),
         "a power of two, 1 to 1024 (the launch clamps it to the kernel's work-group limit)",
         (16, 32, 64, 128),
         "work-items per work-group, one row segment. PoCL left to itself puts up to 4096 in "
         "a group and gives their private memory one thread's stack, which a deep ray stack "
         "overflows; on PoCL 64 costs nothing against its own choice"),
    # _one_of, not `in (4, 8)`: 4.0 == 4, and a float width failed in the wide BVH's build.
    Knob("bvh_width", "host+kernel", None, lambda v: v is None or _one_of(4, 8)(v),
         "4, 8, or None: 8 where the device's vectors of the arithmetic's type are 8 wide or "
         "more (its preferred or native width: float on AVX CPUs), else 4", (None, 4, 8),
         "children per BVH node (the -D BVH_WIDTH of the node's vector slab test): wider "
         "nodes mean fewer visits, each testing more boxes"),
    Knob("traversal_cost", "host", 1.5, _number_in(0.0, 16.0), "a number over 0, at most 16",
         (1.0, 1.5, 2.0),
         "the SAH's cost of a node visit against one packet test: higher makes shallower "
         "trees with bigger leaves (1.5: 65 B per mesh triangle and both benchmark kernels a "
         "few per cent faster than 1.0; from 1.875 the 64 spheres go into four leaves of 16 "
         "and take 9 % longer)"),
    Knob("max_leaf_size", "host", 4, _int_in(1, 64), "an integer, 1 to 64",
         (2, 4, 8),
         "primitives below which a BVH node is always a leaf, whatever the SAH says"),
    Knob("largest_leaf", "host", 16, _int_in(1, _LEAF_SECTION_MAX),
         f"an integer, 1 to {_LEAF_SECTION_MAX}, at least max_leaf_size", (8, 16, 32),
         "the largest leaf the SAH may choose; bigger nodes are split regardless of cost, so "
         "duplicate or coincident primitives still make bounded leaves"),
    Knob("fold_packets", "host", 4, _int_in(0, 64), "an integer, 0 to 64 (0: no folding)",
         (0, 2, 4, 8),
         "a wide node whose children are all leaves, and which one leaf of at most this many "
         "packet tests would cover, is folded into that leaf: choosing among a few packets is "
         "not worth a node visit"),
    Knob("traversal", "kernel", None, lambda v: v is None or _one_of(*TRAVERSALS)(v),
         "single, sample_packet, group_packet, or None: the device's own (sample_packet on "
         "the CPU devices of PoCL and Intel's CPU runtime, where a pixel's samples fill a "
         "packet; single elsewhere: docs/acceleration.md)",
         (None, *TRAVERSALS),
         "how rays walk the BVH (the -D TRAVERSAL, docs/acceleration.md): every ray alone, "
         "a pixel's samples in packets of packet_lanes vector lanes, or a work-group's tile of "
         "pixels together; RenderSettings.traversal and --traversal override it"),
    Knob("packet_lanes", "kernel", None, lambda v: v is None or _one_of(*PACKET_LANES)(v),
         "4, 8, 16, or None: the device's vector width of the arithmetic's type "
         "(8 floats on AVX2, 16 on AVX-512), within 4 to 16, and 16 on 8-wide devices "
         "where a pixel has 16 samples or more", (None, 4, 8, 16),
         "rays in a sample packet (the -D PACKET_LANES; only with traversal sample_packet): "
         "wider packets share more node visits, and lose more lanes where rays diverge"),
    Knob("packet_min_lanes", "kernel", 2, _int_in(0, 15),
         "an integer, 0 to 15, below packet_lanes", (0, 2, 4),
         "the hybrid walk's switch-over (the -D PACKET_MIN_LANES; only with traversal "
         "sample_packet): where at most this many lanes reach a subtree they go on ray by ray"),
    Knob("group_side", "launch", 4, _one_of(*GROUP_SIDES), "4 or 8", GROUP_SIDES,
         "the work-group's tile of group_side x group_side pixels, which walk the BVH together "
         "(only with traversal group_packet): larger tiles share more node visits and visit "
         "more nodes that few of their rays need"),
    Knob("implicit_vectorization", "kernel", False, _one_of(False, True), "True or False",
         (False, True),
         "whether a driver that packs work-items into a vector's lanes may (the -D "
         "IMPLICIT_VECTORIZATION; Intel's CPU runtime packs 8 or 16 a thread unless the kernel "
         "asks for one): the pixels' walks diverge and their node loads become gathers, 2.1x "
         "to 3.5x slower there at 1 spp. Drivers that do not pack (PoCL, GPUs) ignore it. "
         "Never with sample packets (TraversalScheme.vector_lanes): a render building them "
         "leaves it off"),
    _variant("cl_mad_enable", "build",
             "-cl-mad-enable: a * b + c may be one fused or less exact instruction"),
    _variant("cl_unsafe_math_optimizations", "build",
             "-cl-unsafe-math-optimizations: reassociation and approximations IEEE 754 forbids"),
    _variant("cl_fast_relaxed_math", "build",
             "-cl-fast-relaxed-math: the unsafe optimisations, and no infinities or NaNs"),
    _variant("sphere_textbook", "kernel",
             "the textbook sphere quadratic (the -D SPHERE_TEXTBOOK), which cancels "
             "catastrophically far from the sphere"),
    _variant("triangle_moller_trumbore", "kernel",
             "Moller-Trumbore triangles (the -D TRIANGLE_MOLLER_TRUMBORE), not watertight: "
             "rays may slip between triangles sharing an edge"),
    _variant("fresnel_schlick", "kernel",
             "Schlick's approximation of Fresnel (the -D FRESNEL_SCHLICK): a model change"),
    Knob("first_launch_pixel_samples", "launch", 1 << 16, _int_in(1, 1 << 30),
         "an integer, 1 to 2^30", (1 << 16,),
         "pixel-samples of a render's first launch (band of rows), before its rate is known"),
    Knob("max_launch_pixel_samples", "launch", 1 << 24, _int_in(1, 1 << 30),
         "an integer, 1 to 2^30, at least first_launch_pixel_samples", (1 << 24,),
         "pixel-samples of one launch at most"),
    Knob("launch_seconds", "launch", 0.25, _number_in(0.0, 10.0),
         "a number of seconds over 0, at most 10", (0.25,),
         "device time each later launch aims at: progress advances several times a second "
         "and no launch nears a GPU watchdog"),
    Knob("launch_growth", "launch", 4, _int_in(1, 1024), "an integer, 1 to 1024", (4,),
         "a launch covers at most this many times the previous one's rows (one fast band of "
         "sky says little about the rows below it)"),
)
KNOBS: dict[str, Knob] = {knob.name: knob for knob in KNOB_TABLE}

# The knobs that change the packed scene (a new BVH, new buffers): `clray tune` runs Kernel
# Tuner once for each combination of their values, with the others as Kernel Tuner's
# tunable parameters.
HOST_KNOBS = tuple(k.name for k in KNOB_TABLE if k.acts.startswith("host"))
# The compiler options: Kernel Tuner fixes them for a run, so they join the host knobs' loop.
BUILD_KNOBS = tuple(k.name for k in KNOB_TABLE if k.acts == "build")
# The -D switches Kernel Tuner searches (as #defines of the same names, upper case), with the
# launch's work-group width.
KERNEL_KNOBS = tuple(k.name for k in KNOB_TABLE if k.acts == "kernel")
# The study variants, tried only under --allow-error.
IMAGE_KNOBS = tuple(k.name for k in KNOB_TABLE if k.changes_image)


def build_option(name: str) -> str:
    """The compiler option of a build knob: cl_mad_enable -> -cl-mad-enable."""
    return "-" + name.replace("_", "-")


def restriction_problems(values: dict[str, object]) -> list[str]:
    """What is wrong between knobs of one configuration (each already legal on its own)."""
    problems = []
    if values["largest_leaf"] < values["max_leaf_size"]:
        problems.append(f"largest_leaf {values['largest_leaf']} is below max_leaf_size "
                        f"{values['max_leaf_size']}")
    if values["max_launch_pixel_samples"] < values["first_launch_pixel_samples"]:
        problems.append(f"max_launch_pixel_samples {values['max_launch_pixel_samples']} is "
                        f"below first_launch_pixel_samples "
                        f"{values['first_launch_pixel_samples']}")
    lanes = values["packet_lanes"]
    if lanes is not None and values["packet_min_lanes"] >= lanes:
        problems.append(f"packet_min_lanes {values['packet_min_lanes']} is not below "
                        f"packet_lanes {lanes}")
    # A scheme's own knobs, where another scheme is named (None may be any device's own).
    traversal = values["traversal"]
    if (traversal is not None and TRAVERSAL_SCHEMES[traversal].vector_lanes
            and values["implicit_vectorization"]):
        problems.append(f"implicit_vectorization True does not build with traversal "
                        f"{traversal}, whose work-items' rays are vector lanes already "
                        "(Intel's CPU runtime renders wrong images with both)")
    for scheme in TRAVERSAL_TABLE:
        if traversal is not None and traversal != scheme.name:
            problems += [f"{name} {values[name]} acts only with traversal {scheme.name} (leave "
                         f"it at {KNOBS[name].default!r} with {traversal})"
                         for name in scheme.knobs if values[name] != KNOBS[name].default]
    return problems


class TuningError(SettingsError):
    """A knob value that is not legal, or knobs that break a restriction: a SettingsError (a
    ValueError), as another render setting's would be, so a bad knob is one line."""


@dataclass(frozen=True)
class Tuning:
    """One value per knob of KNOB_TABLE; a field left out takes the table's default."""

    work_group_width: int = KNOBS["work_group_width"].default
    bvh_width: int | None = KNOBS["bvh_width"].default
    traversal_cost: float = KNOBS["traversal_cost"].default
    max_leaf_size: int = KNOBS["max_leaf_size"].default
    largest_leaf: int = KNOBS["largest_leaf"].default
    fold_packets: int = KNOBS["fold_packets"].default
    traversal: str | None = KNOBS["traversal"].default
    packet_lanes: int | None = KNOBS["packet_lanes"].default
    packet_min_lanes: int = KNOBS["packet_min_lanes"].default
    group_side: int = KNOBS["group_side"].default
    implicit_vectorization: bool = KNOBS["implicit_vectorization"].default
    cl_mad_enable: bool = KNOBS["cl_mad_enable"].default
    cl_unsafe_math_optimizations: bool = KNOBS["cl_unsafe_math_optimizations"].default
    cl_fast_relaxed_math: bool = KNOBS["cl_fast_relaxed_math"].default
    sphere_textbook: bool = KNOBS["sphere_textbook"].default
    triangle_moller_trumbore: bool = KNOBS["triangle_moller_trumbore"].default
    fresnel_schlick: bool = KNOBS["fresnel_schlick"].default
    first_launch_pixel_samples: int = KNOBS["first_launch_pixel_samples"].default
    max_launch_pixel_samples: int = KNOBS["max_launch_pixel_samples"].default
    launch_seconds: float = KNOBS["launch_seconds"].default
    launch_growth: int = KNOBS["launch_growth"].default

    def __post_init__(self) -> None:
        for name, value in self.values().items():
            value = python_number(value)
            object.__setattr__(self, name, value)
            knob = KNOBS[name]
            if not knob.legal(value):
                raise TuningError(f"{name}: expected {knob.legal_text}, got {value!r}")
        problems = restriction_problems(self.values())
        if problems:
            raise TuningError("; ".join(problems))

    def values(self) -> dict[str, object]:
        return asdict(self)

    def changed(self) -> dict[str, object]:
        """The knobs that differ from the table's defaults."""
        return {name: value for name, value in self.values().items()
                if value != KNOBS[name].default}

    def host(self) -> dict[str, object]:
        return {name: getattr(self, name) for name in HOST_KNOBS}

    def build_options(self) -> tuple[str, ...]:
        """The compiler options the build knobs switch on."""
        return tuple(build_option(name) for name in BUILD_KNOBS if getattr(self, name))

    def label(self) -> str:
        """The configuration in one line: `default`, or the changed knobs."""
        changed = self.changed()
        return ", ".join(f"{k}={v}" for k, v in changed.items()) if changed else "default"

    @classmethod
    def from_values(cls, values: dict[str, object]) -> Tuning:
        """From a mapping of knob names (a tuning file's), refusing names no knob has."""
        unknown = set(values) - {f.name for f in fields(cls)}
        if unknown:
            raise TuningError(f"{plural(len(unknown), 'unknown knob')}: "
                              f"{', '.join(sorted(unknown))}")
        return cls(**values)


DEFAULT_TUNING = Tuning()
