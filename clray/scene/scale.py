"""Load-time scale analysis: which primitives float32 cannot intersect accurately.

The kernels run in float32 on camera-relative coordinates (packed in float64 on the host), so
what limits accuracy is how large the numbers inside one intersection are compared with the
feature that has to be resolved. The thresholds come from the float32-vs-float64 experiments in
the numerics notes: a sphere whose distance from the eye is about 1e4 times its radius (or a
ground sphere of radius 1e5 under a camera 1 unit above it) is intersected with surface errors
near float32's floor, far above what shading and shadow rays tolerate.

Spheres so flagged are intersected in float64 inside the float build (KernelConfig.fp64_spheres,
compiled in only when a scene needs it and the device has cl_khr_fp64). Other primitives have no
such path: they only get a warning, never a silently wrong image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clray.scene import model as M
from clray.shapes import SHAPE_OF, SHAPES
from clray.vectors import bounds

# Distance (or coordinate magnitude) over the length to resolve above which float32 is not enough.
RATIO_LIMIT = 1e4
# Lengths whose squares fall outside float32's normal range, with a margin of 100: products of
# coordinates then flush to zero (denormals) or overflow.
TINY_LENGTH = 1e-18
HUGE_LENGTH = 1e18
# The same for triangles and meshes, whose watertight test (kernels/triangle.h) multiplies
# three lengths: its t scaled by det is edge functions (products of two of the corners' sheared
# lateral coordinates, about the size) times a corner's depth along the ray (about the
# distance). Float32 holds that product, size^2 x max(size, distance), between its smallest
# normal number (1.2e-38) and its largest (3.4e38); within a factor of ten of the bounds below,
# an octahedron of size 2e13 seen from 5.2e13 rendered nothing, one of 2e-14 lost pixels, and
# the study's scale_1e12 (size 2e12 at 7.1e12: 2.8e37) rendered right.
TINY_TRIANGLE_PRODUCT = 1e-37
HUGE_TRIANGLE_PRODUCT = 1e38

_KIND = {M.Triangle: "triangle", M.Mesh: "mesh", **{shape.model: shape.kind for shape in SHAPES}}


@dataclass(frozen=True)
class ScaleReport:
    median_size: float  # of the bounded objects; 0.0 when there are none
    fp64_spheres: tuple[int, ...]  # indices into Scene.objects
    warnings: tuple[str, ...]


def _centre_size(obj: M.SceneObject) -> tuple[np.ndarray, float]:
    """A representative centre and the length the intersection has to resolve."""
    if type(obj) in SHAPE_OF:
        return SHAPE_OF[type(obj)].centre_size(obj)
    lo, hi = bounds(np.asarray(obj.vertices))  # Triangle or Mesh
    return (lo + hi) / 2.0, float(np.max(hi - lo))


def _median(values: np.ndarray) -> float:
    """np.median of finite values, without its NaN check: that imports numpy.ma, a tenth of
    the time `clray render` takes to load a scene."""
    n = len(values)
    middle = np.partition(values, [(n - 1) // 2, n // 2])
    return float((middle[(n - 1) // 2] + middle[n // 2]) / 2.0)


def _beyond_float32(obj: object, size: float, dist: float) -> str | None:
    """What of an object's intersection float32 cannot hold at this size and distance (the
    warning's words), or None."""
    if size > HUGE_LENGTH or dist > HUGE_LENGTH or 0 < size < TINY_LENGTH:
        return "squares"
    if isinstance(obj, M.Triangle | M.Mesh) and size > 0:
        product = size * size * max(size, dist)
        if not TINY_TRIANGLE_PRODUCT <= product <= HUGE_TRIANGLE_PRODUCT:
            return "products of three lengths"
    return None


def analyze(scene: M.Scene) -> ScaleReport:
    eye = np.asarray(scene.camera.position, dtype=np.float64)
    bounded = [(i, obj) for i, obj in enumerate(scene.objects)
               if not isinstance(obj, M.Plane | M.Spheres | M.Instance)]
    bulk = [(i, obj) for i, obj in enumerate(scene.objects) if isinstance(obj, M.Spheres)]
    measured = [(i, obj, *_centre_size(obj)) for i, obj in bounded]
    sizes = np.concatenate([np.array([size for *_, size in measured], dtype=np.float64),
                            *(obj.radii for _, obj in bulk)])
    sizes = sizes[sizes > 0]
    median = _median(sizes) if len(sizes) else 0.0
    fp64: list[int] = []
    warnings: list[str] = []
    for i, obj in bulk:
        if _bulk_warnings(f"objects[{i}] (spheres)", obj, eye, median, warnings):
            fp64.append(i)
    for i, obj, centre, size in measured:
        kind = _KIND[type(obj)]
        where = f"objects[{i}] ({kind})"
        dist = float(np.linalg.norm(centre - eye))
        what = _beyond_float32(obj, size, dist)
        if what:
            warnings.append(f"{where}: size {size:.3g} at distance {dist:.3g} from the camera "
                            f"is outside the range whose {what} float32 can hold; expect "
                            "missing or wrong surfaces (rescale the scene)")
            continue
        if isinstance(obj, M.Sphere):
            # Intersection works on |centre - eye| + r; it must resolve both the radius and,
            # when the eye is close to the surface, the gap between them.
            gap = abs(dist - size)
            resolve = min(size, gap) if gap > 0 else size
            ratio = (dist + size) / resolve
            huge = median > 0 and size > RATIO_LIMIT * median
            if ratio > RATIO_LIMIT or huge:
                fp64.append(i)
                why = (f"radius {size:.3g} is over {RATIO_LIMIT:.0e} times the median object "
                       f"size {median:.3g}" if huge else
                       f"its distance from the camera over the length to resolve is "
                       f"{ratio:.3g} (> {RATIO_LIMIT:.0e})")
                warnings.append(f"{where}: float32 cannot intersect it accurately ({why}); "
                                "it is intersected in float64 where the device has "
                                "cl_khr_fp64, otherwise expect ragged edges and shadow acne "
                                "(a plane is exact for a ground)")
        elif size > 0 and dist / size > RATIO_LIMIT:
            warnings.append(f"{where}: size {size:.3g} at distance {dist:.3g} from the camera "
                            f"(ratio {dist / size:.3g} > {RATIO_LIMIT:.0e}): float32 cannot "
                            "resolve it; expect ragged edges (move the camera closer)")
        shape = SHAPE_OF.get(type(obj))
        if shape is not None and shape.proportion is not None:
            ratio, what = shape.proportion(obj)
            if ratio > RATIO_LIMIT:
                warnings.append(f"{where}: {what} (> {RATIO_LIMIT:.0e}): float32 cannot "
                                "resolve its shape; expect stray hits and holes "
                                "wherever it is seen from")
    return ScaleReport(median, tuple(fp64), tuple(warnings))


def _bulk_warnings(where: str, obj: M.Spheres, eye: np.ndarray, median: float,
                   warnings: list[str]) -> bool:
    """The single-sphere rules of analyze() on a `spheres` array at once, told as one warning
    per rule with a count; whether any of its spheres needs float64."""
    size = obj.radii
    dist = np.linalg.norm(obj.centers - eye, axis=1)
    outside = (size > HUGE_LENGTH) | (dist > HUGE_LENGTH) | (size < TINY_LENGTH)
    if outside.any():
        warnings.append(f"{where}: {int(outside.sum())} of {len(size)} spheres (the first is "
                        f"[{int(np.flatnonzero(outside)[0])}]) are outside the range whose "
                        "squares float32 can hold; expect missing or wrong surfaces")
    gap = np.abs(dist - size)
    resolve = np.where(gap > 0, np.minimum(size, gap), size)
    ratio = (dist + size) / resolve
    flagged = ~outside & ((ratio > RATIO_LIMIT) | ((median > 0) & (size > RATIO_LIMIT * median)))
    if flagged.any():
        warnings.append(f"{where}: float32 cannot intersect {int(flagged.sum())} of {len(size)} "
                        f"spheres accurately (the first is [{int(np.flatnonzero(flagged)[0])}]): "
                        "they are intersected in float64 where the device has cl_khr_fp64, "
                        "otherwise expect ragged edges and shadow acne")
    return bool(flagged.any())


def scene_warnings(scene: M.Scene) -> tuple[str, ...]:
    """Warnings about float32 accuracy, for Scene.warnings."""
    return analyze(scene).warnings


def needs_fp64_spheres(scene: M.Scene) -> bool:
    """Whether the float build should intersect spheres in float64 (KernelConfig.fp64_spheres)."""
    return bool(analyze(scene).fp64_spheres)
