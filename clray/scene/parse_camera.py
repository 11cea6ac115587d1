"""The [camera] table: a perspective or orthographic camera, with an optional thin lens."""

from __future__ import annotations

import numpy as np

from clray.scene import limits as L
from clray.scene.model import Camera
from clray.scene.values import Values, show
from clray.vectors import unit

CAMERA_KEYS = ("position", "look_at", "up", "vfov", "hfov", "type", "width", "height",
               "aperture", "focus_distance")
CAMERA_TYPES = ("perspective", "orthographic")


def parse_camera(spec: dict, v: Values) -> Camera:
    v.keys(spec, "camera", CAMERA_KEYS, ("position", "look_at"))
    position = v.vec3(spec["position"], "camera.position")
    look_at = v.vec3(spec["look_at"], "camera.look_at")
    up = v.vec3(spec.get("up", (0.0, 1.0, 0.0)), "camera.up")
    if position == look_at:
        raise v.error("camera.look_at", "must differ from camera.position")
    if not any(up):
        raise v.error("camera.up", f"must be a nonzero vector, got {show(spec['up'])}")
    # On unit vectors (scaled first, so that neither tiny nor huge lengths under- or
    # overflow) the test is relative: the right vector normalize(cross(forward, up)) only
    # needs the two directions not to be parallel, whatever their lengths.
    forward = unit(np.subtract(look_at, position))
    if np.linalg.norm(np.cross(forward, unit(up))) <= 1e-9:
        raise v.error("camera.up", "must not be parallel to the view direction")
    kind = v.choice(spec.get("type", "perspective"), "camera.type", CAMERA_TYPES)
    lens = _lens(spec, v, float(np.linalg.norm(np.subtract(look_at, position))))
    if kind == "orthographic":
        return Camera(position, look_at, up, vfov=None, hfov=None, type=kind,
                      **_orthographic_extent(spec, v), **lens)
    for name in ("width", "height"):
        if name in spec:
            raise v.error(f"camera.{name}", 'only with type = "orthographic" (a '
                          "perspective camera takes vfov or hfov)")
    if "vfov" in spec and "hfov" in spec:
        raise v.error("camera", "give vfov or hfov, not both")
    if "hfov" in spec:
        return Camera(
            position,
            look_at,
            up,
            vfov=None,
            hfov=v.open_range(spec["hfov"], "camera.hfov", 0, 180),
            **lens,
        )
    vfov = v.open_range(spec.get("vfov", 40.0), "camera.vfov", 0, 180)
    return Camera(position, look_at, up, vfov=vfov, hfov=None, **lens)


def _lens(spec: dict, v: Values, look_distance: float) -> dict[str, float]:
    """The thin lens: aperture, and focus_distance if given (the look_at distance if not)."""
    lens = {"aperture": v.bounded(spec.get("aperture", 0.0), "camera.aperture", 0)}
    if "focus_distance" in spec:
        lens["focus_distance"] = v.length(spec["focus_distance"], "camera.focus_distance")
    elif lens["aperture"] > 0 and look_distance < L.MIN_LENGTH:
        # The look distance focuses instead, and the kernel takes 1 / focus as a float32:
        # under MIN_LENGTH that is inf, and inf times the lens offset NaN in every ray.
        raise v.error("camera.look_at", f"with an aperture and no focus_distance, look_at's "
                      f"distance from position is the focus distance and must be >= "
                      f"{L.MIN_LENGTH:g}, got {look_distance:g}")
    focus = lens.get("focus_distance", look_distance)
    if lens["aperture"] > L.MAX_APERTURE_RATIO * focus:
        raise v.error("camera.aperture", f"must be at most {L.MAX_APERTURE_RATIO:g} "
                      f"times the focus distance ({focus:g}), got {lens['aperture']:g}")
    return lens


def _orthographic_extent(spec: dict, v: Values) -> dict[str, float]:
    """An orthographic camera's width or height, in scene units."""
    for name in ("vfov", "hfov"):
        if name in spec:
            raise v.error(f"camera.{name}", "an orthographic camera has no field of "
                          "view: give width or height")
    if "width" in spec and "height" in spec:
        raise v.error("camera", "give width or height, not both")
    if "width" not in spec and "height" not in spec:
        raise v.error("camera.height", "missing required key (an orthographic "
                      "camera needs width or height)")
    return {name: v.length(spec[name], f"camera.{name}")
            for name in ("width", "height") if name in spec}
