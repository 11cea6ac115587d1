"""What a scene may ask for: the limits docs/scene_format.md (section Limits) documents.

They are checked while loading, before anything large is allocated, so that an untrusted scene
file ends in a one-line error rather than a traceback, non-finite pixels or an exhausted memory.
The kernels compute in float32 (largest finite value about 3.4e38): numbers are kept well inside
that range, and colours and weights small enough that their products along a path of
MAX_DEPTH bounces, summed over every light, stay finite.
"""

from __future__ import annotations

import math
import numbers

# Any number that reaches the device: coordinates, lengths, attenuation, texture repeats.
MAX_MAGNITUDE = 1e30
# Strictly positive lengths (radius, height, checker size, repeat, mesh scale): smaller values
# flush to zero in float32 and then divide.
MIN_LENGTH = 1e-30
MAX_COLOR = 1e6  # every colour component: material, checker, light, background, ambient
MAX_WEIGHT = 1e6  # material ambient, diffuse and specular weights
MAX_SHININESS = 1e6
# reflect and transmit multiply the light once per bounce, and transmit once per surface a
# shadow ray crosses: above 1 the product has no bound.
MAX_BOUNCE_WEIGHT = 1.0
IOR_RANGE = (0.01, 100.0)
# A thin lens's aperture over its focus distance: the kernels aim each lens ray along
# aim - lens / focus_distance, which this keeps well inside float32 (an f-number of 1e-6,
# far beyond any lens).
MAX_APERTURE_RATIO = 1e6

MAX_IMAGE_SIZE = 16384  # output width and height
MAX_SPP = 4096
MAX_DEPTH = 256  # reflection/refraction bounces: POV-Ray's max_trace_level allows 256 too
MAX_SEED = 2**32 - 1  # the kernels hash the seed as a uint32
# A secondary ray whose weight (largest colour channel) is below min_weight is not traced:
# POV-Ray's adc_bailout. 0 traces every ray to max_depth.
MIN_WEIGHT_RANGE = (0.0, 1.0)
# Output exposure in stops, either way: 2**32 (about 4e9) is beyond any useful display range,
# and the bound makes a typo such as 1e9 an error rather than an all-white or black image.
MAX_EXPOSURE = 32.0
PNG_BITS = (8, 16)
PRECISIONS = ("float", "double")

# The [render] values that the command line's flags and RenderSettings can override too: one
# rule for every way a value arrives (clray.render.RenderSettings, clray.cli).
RENDER_INTEGERS = {
    "width": (1, MAX_IMAGE_SIZE),
    "height": (1, MAX_IMAGE_SIZE),
    "spp": (1, MAX_SPP),
    "max_depth": (0, MAX_DEPTH),
    "seed": (0, MAX_SEED),
}
RENDER_NUMBERS = {
    "min_weight": MIN_WEIGHT_RANGE,
    "exposure": (-MAX_EXPOSURE, MAX_EXPOSURE),
}
RENDER_CHOICES = {"png_bits": PNG_BITS}


def integer_problem(value: object, low: int, high: int) -> str | None:
    """What is wrong with `value` as an integer in [low, high] (None if nothing): the one
    wording the scene loader, the command line and RenderSettings all use."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        return "expected an integer"
    if not low <= value <= high:
        return f"must be an integer in [{low}, {high}]"
    return None


def number_problem(value: object, low: float, high: float) -> str | None:
    """What is wrong with `value` as a number in [low, high] (None if nothing)."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return "expected a number"
    if not isinstance(value, numbers.Integral) and not math.isfinite(value):  # ints are finite
        return "must be finite"
    if not low <= value <= high:
        return f"must be in [{low:g}, {high:g}]"
    return None


def is_choice(value: object, allowed: tuple) -> bool:
    """Whether `value` is one of `allowed`. Only a value of an allowed value's kind (any
    integer for an integer) is compared: `in` compares a numpy array element by element, so
    that one of two elements failed on its truth value and one of one element passed."""
    kinds = tuple({numbers.Integral if isinstance(a, numbers.Integral) else type(a)
                   for a in allowed})
    return isinstance(value, kinds) and not isinstance(value, bool) and value in allowed


def choice_problem(value: object, allowed: tuple) -> str | None:
    """What is wrong with `value` as one of `allowed` (None if nothing)."""
    if not is_choice(value, allowed):
        return f"expected {' or '.join(map(str, allowed))}"
    return None


MAX_INCLUDE_DEPTH = 16  # files including files including files ...
# [animation]: each keyframe is checked by loading the scene with its value put in, a bound on
# that work.
MAX_TRACKS = 1000
MAX_KEYFRAMES = 1000  # all tracks together
MAX_OBJECTS = 1_000_000
MAX_LIGHTS = 10_000
# Rect, disc and sphere lights' emitting area (|u x v|, pi radius^2): the kernels multiply
# radiance by it, and a sphere light's radius squares, in float32.
MAX_LIGHT_AREA = 1e30
# All meshes together, each instance counted: 33.5 M, about 12 GB of host memory at the
# 350 bytes a triangle that load, BVH and pack peak at (docs/scale.md); primitive
# references index 2^28.
MAX_TRIANGLES = 2**25
# A mesh given as arrays (inline, or a .npz file): three vertices a triangle of the limit
# above, as many as its faces could ever use. Checked before the arrays are converted.
MAX_MESH_VERTICES = 3 * MAX_TRIANGLES
MAX_BULK_SPHERES = 2**24  # all `spheres` objects together
MAX_ARRAY_BYTES = 256 * 2**20  # a .npy/.npz file of spheres
MAX_TEXTURE_SIDE = 16384
MAX_TEXELS = 2**26  # all distinct texture files together: 768 MiB as float32 RGB

MIB = 2**20
MAX_SCENE_BYTES = 64 * MIB
MAX_MESH_BYTES = 256 * MIB  # the OBJ reader peaks near 13 bytes of memory per byte of file
# A binary PLY or .npz mesh: numpy reads its blocks in place, so a file costs little more
# than its own size (21 M triangles as a binary PLY: 400 MB).
MAX_BINARY_MESH_BYTES = 1024 * MIB
# The mesh files read so (a binary PLY's header says so too, and read_ply holds an ASCII one
# to MAX_MESH_BYTES once it has read it).
BINARY_MESH_SUFFIXES = (".ply", ".npz", ".glb")
MAX_TEXTURE_BYTES = 256 * MIB


def mesh_bytes_limit(suffix: str) -> int:
    """The largest mesh file of this suffix (lower case, with its dot) that is read."""
    return MAX_BINARY_MESH_BYTES if suffix in BINARY_MESH_SUFFIXES else MAX_MESH_BYTES
