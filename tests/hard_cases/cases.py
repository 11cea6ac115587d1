"""Scenes built to break float32 ray tracers, each with an expectation that needs no reference
image: an analytic value, a uniformity, a symmetry or an invariance, checked in float64 here.

Every case also states how far its float image may differ from the double build of the same
kernel (`max_off`: pixels off by more than 2/255). Silhouette pixels whose centre ray is within
rounding of an edge may legitimately differ; the allowance is never widened just to pass.
`export_scenes` writes these dicts as the JSON scene files of the shipped study report.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clray.scene.model import Scene

Check = Callable[[np.ndarray, Scene], None]


@dataclass(frozen=True)
class HardCase:
    name: str
    scene: dict
    check: Check
    max_off: int = 0  # float vs double: pixels off by more than 2/255
    warns: str | None = None  # a substring the loader's warnings must contain
    float_checked: bool = True  # False: only the double image must meet `check` (the float
    # build is known to fail the case, and the loader's warning is its expectation)
    slow: bool = False
    in_study: bool = True
    tags: tuple[str, ...] = field(default=())


# -- float64 geometry for the expectations ------------------------------------------------------

def primary_rays(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(eye, unit directions (H, W, 3)) of the pixel-centre rays, as docs/rendering.md fixes."""
    w, h = scene.render.width, scene.render.height
    cam = scene.camera
    # The basis from the formula itself, not the model's Camera.basis that the kernels use.
    eye = np.asarray(cam.position, dtype=np.float64)
    forward = np.asarray(cam.look_at, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(cam.up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    if cam.hfov is not None:
        half_w = math.tan(math.radians(cam.hfov) / 2)
        half_h = half_w * h / w
    else:
        half_h = math.tan(math.radians(cam.vfov) / 2)
        half_w = half_h * w / h
    sx = (np.arange(w) + 0.5)[None, :, None]
    sy = (np.arange(h) + 0.5)[:, None, None]
    d = forward + (2 * sx / w - 1) * half_w * right + (1 - 2 * sy / h) * half_h * up
    return np.asarray(scene.camera.position, dtype=np.float64), d / np.linalg.norm(
        d, axis=-1, keepdims=True)


def impact(eye: np.ndarray, d: np.ndarray, centre: tuple) -> np.ndarray:
    """Distance from `centre` to each ray's line (rays pointing towards it)."""
    f = np.asarray(centre, dtype=np.float64) - eye
    along = np.sum(d * f, axis=-1)
    return np.linalg.norm(f - along[..., None] * d, axis=-1)


def sphere_t(eye: np.ndarray, d: np.ndarray, centre: tuple, radius: float) -> np.ndarray:
    """Nearest positive t, inf on a miss (stable form, float64)."""
    f = eye - np.asarray(centre, dtype=np.float64)
    b = d @ f
    l2 = np.sum((f - b[..., None] * d) ** 2, axis=-1)
    disc = radius * radius - l2
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
    t0, t1 = -b - sq, -b + sq
    t = np.where(t0 > 0, t0, np.where(t1 > 0, t1, np.inf))
    return np.where(disc >= 0, t, np.inf)


def box_hit(eye: np.ndarray, d: np.ndarray, lo: tuple, hi: tuple) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        a = (np.asarray(lo) - eye) * inv
        b = (np.asarray(hi) - eye) * inv
    near = np.nanmax(np.minimum(a, b), axis=-1)
    far = np.nanmin(np.maximum(a, b), axis=-1)
    return (near <= far) & (far > 0)


def close(image: np.ndarray, mask: np.ndarray, value: object, tol: float, what: str) -> None:
    got = image[mask]
    err = np.abs(got - np.asarray(value, dtype=np.float64))
    bad = int(np.count_nonzero(err.max(axis=-1) > tol)) if got.size else 0
    assert mask.any(), f"{what}: the expectation covers no pixel"
    assert bad == 0, f"{what}: {bad} of {int(mask.sum())} pixels off by more than {tol:g} " \
                     f"(worst {float(err.max()):.3g})"


def _scene(objects: list, *, camera: dict, materials: dict, lights: list | None = None,
           width: int = 48, height: int = 36, max_depth: int = 0,
           background: tuple = (0.0, 0.0, 0.0)) -> dict:
    return {"render": {"width": width, "height": height, "max_depth": max_depth,
                       "background": list(background), "ambient": [1.0, 1.0, 1.0]},
            "camera": camera, "materials": materials, "lights": lights or [],
            "objects": objects}


FLAT = {"color": [1.0, 0.5, 0.25], "ambient": 1.0, "diffuse": 0.0}  # ambient only: flat colour
MATTE = {"color": [1.0, 1.0, 1.0], "ambient": 0.1, "diffuse": 0.9}
COLOR = (1.0, 0.5, 0.25)


# -- the cases ----------------------------------------------------------------------------------

def far_sphere(distance: float, margin: float) -> HardCase:
    fov = 2 * math.degrees(math.atan(1.6 / distance))
    scene = _scene([{"type": "sphere", "center": [0, 0, -distance], "radius": 1.0,
                     "material": "m"}],
                   camera={"position": [0, 0, 0], "look_at": [0, 0, -1], "vfov": fov},
                   materials={"m": FLAT})

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        b = impact(eye, d, (0, 0, -distance))
        close(image, b < 1 - margin, COLOR, 1e-6, "inside the disc")
        close(image, b > 1 + margin, (0, 0, 0), 0.0, "outside the disc")

    flagged = "float32 cannot intersect" if distance >= 1e4 else None
    return HardCase(f"far_sphere_{distance:.0e}".replace("+0", ""), scene, check, max_off=0,
                    warns=flagged)


def huge_ground() -> HardCase:
    light = np.array([0.3, -1.0, -0.2]) / np.linalg.norm([0.3, -1.0, -0.2])
    scene = _scene([{"type": "sphere", "center": [0, -1e5, 0], "radius": 1e5, "material": "m"},
                    {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "material": "m"}],
                   camera={"position": [0, 1, 4], "look_at": [0, 0.5, 0], "vfov": 40},
                   materials={"m": MATTE},
                   lights=[{"type": "directional", "direction": light.tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        t_ground = sphere_t(eye, d, (0, -1e5, 0), 1e5)
        t_ball = sphere_t(eye, d, (0, 0.5, 0), 0.5)
        ground = np.isfinite(t_ground) & (impact(eye, d, (0, 0.5, 0)) > 0.5 * 1.03)
        p = eye + t_ground[..., None] * d
        n = (p - np.array([0, -1e5, 0])) / 1e5
        shadow_b = impact(p[ground], np.broadcast_to(-light, p[ground].shape), (0, 0.5, 0))
        lit = ground.copy()
        lit[ground] = shadow_b > 0.5 * 1.03
        dark = ground.copy()
        dark[ground] = shadow_b < 0.5 * 0.97
        expected = 0.1 + 0.9 * np.clip(n[lit] @ -light, 0, None)
        close(image, lit, expected[:, None], 2 / 255, "lit ground (acne shows as shadow)")
        close(image, dark, (0.1, 0.1, 0.1), 2 / 255, "ground in the ball's shadow")
        assert np.isfinite(t_ball).any()

    return HardCase("huge_ground_sphere", scene, check, max_off=0,
                    warns="float32 cannot intersect")


def curved_acne() -> HardCase:
    light = np.array([-1.0, 0.0, -0.05]) / np.linalg.norm([-1.0, 0.0, -0.05])
    c = (0.0, 0.0, -1000.0)
    fov = 2 * math.degrees(math.atan(1.3 / 1000))
    scene = _scene([{"type": "sphere", "center": list(c), "radius": 1.0, "material": "m"}],
                   camera={"position": [0, 0, 0], "look_at": [0, 0, -1], "vfov": fov},
                   materials={"m": MATTE},
                   lights=[{"type": "directional", "direction": light.tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        t = sphere_t(eye, d, c, 1.0)
        inside = impact(eye, d, c) < 0.98
        n = (eye + np.where(inside, t, 0)[..., None] * d - np.array(c))
        ndl = n @ -light
        lit = inside & (ndl > 0.02)
        close(image, lit, (0.1 + 0.9 * ndl[lit])[:, None], 2 / 255,
              "grazing-lit far sphere (acne shows as 0.1)")
        close(image, inside & (ndl < -0.02), (0.1, 0.1, 0.1), 1e-6, "unlit side")

    return HardCase("curved_acne_grazing", scene, check, max_off=0)


def camera_inside(gap: float) -> HardCase:
    """Camera inside a sphere, at the centre (gap = radius) or just under the surface."""
    scene = _scene([{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}],
                   camera={"position": [0, 0, 1 - gap], "look_at": [0, 0, 2], "vfov": 60},
                   materials={"m": FLAT})

    def check(image: np.ndarray, s: Scene) -> None:
        close(image, np.ones(image.shape[:2], bool), COLOR, 1e-6, "every ray hits the inside")

    name = "camera_at_centre" if gap == 1 else "camera_just_inside"
    return HardCase(name, scene, check, warns=None if gap == 1 else "float32 cannot intersect")


def tilted_plane_far() -> HardCase:
    n = np.array([1.0, 2.0, 3.0]) / math.sqrt(14)
    p0 = np.array([1e4, -2e4, 3e4])
    tangent = np.cross(n, [0, 0, 1])
    tangent /= np.linalg.norm(tangent)
    light = 0.05 * n + math.sqrt(1 - 0.05**2) * tangent
    eye = p0 + 5 * n + 0.5 * tangent
    scene = _scene([{"type": "plane", "point": p0.tolist(), "normal": n.tolist(),
                     "material": "m"}],
                   camera={"position": eye.tolist(), "look_at": p0.tolist(), "vfov": 40},
                   materials={"m": MATTE},
                   lights=[{"type": "directional", "direction": (-light).tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        close(image, np.ones(image.shape[:2], bool), 0.1 + 0.9 * 0.05, 1 / 255,
              "grazing light on a far tilted plane (acne shows as 0.1)")

    return HardCase("tilted_plane_far_grazing", scene, check)


def light_on_surface() -> HardCase:
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "m"}],
                   camera={"position": [0, 3, 0], "look_at": [0, 0, 0], "up": [0, 0, -1],
                           "vfov": 60},
                   materials={"m": MATTE}, width=47, height=35,
                   lights=[{"type": "point", "position": [0, 0, 0]}])

    def check(image: np.ndarray, s: Scene) -> None:
        # The light lies in the plane: n.l is 0 everywhere, and the centre pixel's hit point
        # is the light itself, which lights nothing.
        close(image, np.ones(image.shape[:2], bool), 0.1, 1e-4, "light in the plane")

    return HardCase("light_on_surface", scene, check)


def coplanar_ties() -> HardCase:
    tri = [[-1, 0.5, -1], [1, 0.5, -1], [0, 0.5, 1]]
    mats = {"red": {"color": [1, 0, 0], "ambient": 1.0, "diffuse": 0.0},
            "green": {"color": [0, 1, 0], "ambient": 1.0, "diffuse": 0.0},
            "blue": {"color": [0, 0, 1], "ambient": 1.0, "diffuse": 0.0},
            "yellow": {"color": [1, 1, 0], "ambient": 1.0, "diffuse": 0.0}}
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "green"},
                    {"type": "triangle", "vertices": tri, "material": "blue"},
                    {"type": "triangle", "vertices": tri, "material": "yellow"}],
                   camera={"position": [0.2, 3, 0.1], "look_at": [0, 0, 0],
                           "up": [0, 0, -1], "vfov": 70},
                   materials=mats)

    def check(image: np.ndarray, s: Scene) -> None:
        # docs/rendering.md: equal t goes to the object listed first.
        eye, d = primary_rays(s)
        t = (0.5 - eye[1]) / d[..., 1]
        p = eye + t[..., None] * d
        # Barycentric margins of the triangle in x-z.
        a, b, c = (np.array(v)[[0, 2]] for v in tri)
        q = p[..., [0, 2]]

        def edge(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            e = v - u
            return (e[0] * (q[..., 1] - u[1]) - e[1] * (q[..., 0] - u[0])) / np.linalg.norm(e)

        s0, s1, s2 = edge(a, b), edge(b, c), edge(c, a)
        sign = np.sign(s0 + s1 + s2)
        inside = (s0 * sign > 0.02) & (s1 * sign > 0.02) & (s2 * sign > 0.02)
        outside = (s0 * sign < -0.02) | (s1 * sign < -0.02) | (s2 * sign < -0.02)
        close(image, inside, (0, 0, 1), 0.0, "first of two equal triangles")
        close(image, outside, (1, 0, 0), 0.0, "first of two equal planes")

    return HardCase("coplanar_ties", scene, check)


def touching_spheres() -> HardCase:
    scene = _scene([{"type": "sphere", "center": [-1, 0, 0], "radius": 1.0, "material": "m"},
                    {"type": "sphere", "center": [1, 0, 0], "radius": 1.0, "material": "m"},
                    {"type": "plane", "point": [0, -1, 0], "normal": [0, 1, 0],
                     "material": "m"}],
                   camera={"position": [0, 0, 6], "look_at": [0, 0, 0], "vfov": 50},
                   materials={"m": MATTE}, width=48, height=35,
                   lights=[{"type": "point", "position": [0, 4, 4]}])

    def check(image: np.ndarray, s: Scene) -> None:
        # Mirror-symmetric about x = 0: the image equals its left-right flip.
        off = int(np.count_nonzero(np.abs(image - image[:, ::-1]).max(-1) > 2 / 255))
        assert off <= 2, f"{off} pixels break the left-right symmetry"
        # And the lit values: 0.1 + 0.9 n.l where the light is seen, 0.1 in shadow, away
        # from silhouettes, shadow edges and the terminator.
        eye, d = primary_rays(s)
        balls = ((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0))
        light = np.array([0.0, 4.0, 4.0])
        t_balls = [sphere_t(eye, d, c, 1.0) for c in balls]
        t_floor = np.where(d[..., 1] < 0, (-1 - eye[1]) / np.where(d[..., 1] < 0, d[..., 1], -1),
                           np.inf)
        t = np.minimum(np.minimum(*t_balls), t_floor)
        clear = np.isfinite(t) & np.all([np.abs(impact(eye, d, c) - 1) > 0.02 for c in balls],
                                        axis=0)
        p = eye + np.where(np.isfinite(t), t, 0)[..., None] * d
        n = np.where((t == t_floor)[..., None], [0.0, 1.0, 0.0],
                     p - np.where((t == t_balls[0])[..., None], balls[0], balls[1]))
        to_light = light - p
        ndl = np.sum(n * to_light, axis=-1) / np.linalg.norm(to_light, axis=-1)
        lit = np.ones(t.shape, bool)
        for c in balls:
            # The shadow segment p -> light against each ball: its closest approach.
            f = np.asarray(c) - p
            along = np.clip(np.sum(f * to_light, -1) / np.sum(to_light * to_light, -1), 0, 1)
            gap = np.linalg.norm(f - along[..., None] * to_light, axis=-1) - 1
            own = np.linalg.norm(f, axis=-1) < 1.001  # p lies on this ball
            clear &= own | (np.abs(gap) > 0.02)
            lit &= own | (gap > 0)
        clear &= np.abs(ndl) > 0.02
        expected = np.where(lit & (ndl > 0), 0.1 + 0.9 * np.maximum(ndl, 0), 0.1)
        assert (clear & lit & (ndl > 0)).sum() > 500 and (clear & ~lit & (t == t_floor)).any()
        close(image, clear, expected[clear][:, None], 1e-4, "lit spheres and floor")

    return HardCase("touching_spheres", scene, check, max_off=0)


def horizon() -> HardCase:
    bg = (0.2, 0.3, 0.4)
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": {"ambient": 0.1, "diffuse": 0.5}}],
                   camera={"position": [0, 1, 0], "look_at": [0, 1, -10], "vfov": 0.05},
                   materials={}, width=48, height=35, background=bg,
                   lights=[{"type": "directional", "direction": [0, -1, 0]}])

    def check(image: np.ndarray, s: Scene) -> None:
        _, d = primary_rays(s)
        close(image, d[..., 1] < -1e-7, (0.6, 0.6, 0.6), 1e-5, "plane below the horizon")
        close(image, d[..., 1] >= 0, bg, 1e-6, "sky at and above the horizon")

    return HardCase("horizon_near_parallel", scene, check)


def degenerate_triangles() -> HardCase:
    objs = [
        {"type": "triangle", "vertices": [[-1, -1, 0], [-1, -1, 0], [1, 1, 0]]},  # repeated
        {"type": "triangle", "vertices": [[-1, 1, 0], [0, 0, 0], [1, -1, 0]]},  # collinear
        {"type": "triangle", "vertices": [[0.5, -1, 0], [0.5 + 1e-7, -1, 0], [0.5, 1, 0]]},
    ]
    for o in objs:
        o["material"] = "m"
    scene = _scene(objs, camera={"position": [0, 0, 3], "look_at": [0, 0, 0], "vfov": 60},
                   materials={"m": FLAT})

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        x = eye[0] + d[..., 0] * (-eye[2] / d[..., 2])
        pixel = 2 * 3 * math.tan(math.radians(30)) / s.render.height
        away = np.abs(x - 0.5) > pixel
        close(image, away, (0, 0, 0), 0.0, "zero-area triangles are invisible")
        vals = image.reshape(-1, 3)
        ok = np.all(vals == 0, axis=1) | np.all(np.abs(vals - COLOR) < 1e-6, axis=1)
        assert ok.all(), "the needle triangle gives its colour or nothing"

    return HardCase("degenerate_triangles", scene, check)


_CUBE_V = [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
           [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]]
_CUBE_F = [[4, 5, 6], [4, 6, 7], [1, 0, 3], [1, 3, 2], [5, 1, 2], [5, 2, 6],
           [0, 4, 7], [0, 7, 3], [7, 6, 2], [7, 2, 3], [0, 1, 5], [0, 5, 4]]


def closed_mesh(eye: tuple, name: str) -> HardCase:
    scene = _scene([{"type": "mesh", "vertices": _CUBE_V, "faces": _CUBE_F, "material": "m"}],
                   camera={"position": list(eye), "look_at": [0, 0, 0], "vfov": 50},
                   materials={"m": FLAT}, width=41, height=41)

    def check(image: np.ndarray, s: Scene) -> None:
        e, d = primary_rays(s)
        # Rays through the shared edges and vertices must not leak between triangles.
        close(image, box_hit(e, d, (-0.999,) * 3, (0.999,) * 3), COLOR, 1e-6, "no leaks")
        close(image, ~box_hit(e, d, (-1.001,) * 3, (1.001,) * 3), (0, 0, 0), 0.0,
              "background")
        assert np.allclose(image[20, 20], COLOR), "the centre ray hits"

    return HardCase(name, scene, check)


def thin_box(edge_on: bool) -> HardCase:
    box = {"type": "box", "min": [-1, -1, 0], "max": [1, 1, 1e-6], "material": "m"}
    if edge_on:
        cam = {"position": [5, 0, 5e-7], "look_at": [0, 0, 5e-7], "vfov": 40}
    else:
        cam = {"position": [0, 0, 5], "look_at": [0, 0, 0], "vfov": 40}
    scene = _scene([box], camera=cam, materials={"m": FLAT}, width=47, height=35)

    def check(image: np.ndarray, s: Scene) -> None:
        e, d = primary_rays(s)
        if edge_on:
            # Only rays with a zero z component stay inside the 1e-6 slab long enough.
            hit = (d[..., 2] == 0) & (np.abs(d[..., 1] / d[..., 0] * -4) < 0.99)
            close(image, hit, COLOR, 1e-6, "the slab's edge")
            close(image, d[..., 2] != 0, (0, 0, 0), 0.0, "beside the slab")
        else:
            close(image, box_hit(e, d, (-0.99, -0.99, 0), (0.99, 0.99, 1e-6)), COLOR, 1e-6,
                  "face-on")
            close(image, ~box_hit(e, d, (-1.01, -1.01, 0), (1.01, 1.01, 1e-6)), (0, 0, 0), 0.0,
                  "outside")

    return HardCase("thin_box_edge_on" if edge_on else "thin_box_face_on", scene, check)


def slab_zero_direction() -> HardCase:
    scene = _scene([{"type": "box", "min": [-1, 0, -6], "max": [1, 1, -4], "material": "m"}],
                   camera={"position": [0, 1, 0], "look_at": [0, 1, -5], "vfov": 40},
                   materials={"m": FLAT}, width=47, height=35)

    def check(image: np.ndarray, s: Scene) -> None:
        e, d = primary_rays(s)
        assert np.all(d[17, :, 1] == 0), "the centre row has a zero y component"
        # The centre row starts on the box's top plane: a closed slab test counts it as a hit.
        row = np.zeros(image.shape[:2], bool)
        row[17] = np.abs(d[17, :, 0] / d[17, :, 2] * 4) < 0.99
        close(image, row, COLOR, 1e-6, "rays in the top plane")
        below = box_hit(e, d, (-0.99, 0.01, -5.99), (0.99, 1, -4.01)) & (d[..., 1] < 0)
        close(image, below, COLOR, 1e-6, "below the top plane")
        close(image, ~box_hit(e, d, (-1.01, -0.01, -6.01), (1.01, 1.01, -3.99)), (0, 0, 0), 0.0,
              "beside")

    return HardCase("slab_zero_direction_on_plane", scene, check)


def _mixed_scene(scale: float, shift: tuple = (0.0, 0.0, 0.0)) -> dict:
    def p(v: list) -> list:
        return [a * scale + b for a, b in zip(v, shift, strict=True)]

    return _scene(
        [{"type": "plane", "point": p([0, -1, 0]), "normal": [0, 1, 0], "material": "m"},
         {"type": "sphere", "center": p([-1, 0, 0]), "radius": scale, "material": "m"},
         {"type": "box", "min": p([0.3, -1, -0.5]), "max": p([1.3, 0, 0.5]), "material": "m"},
         {"type": "cylinder", "base": p([0, -1, -2]), "axis": [0, 1, 0], "radius": 0.5 * scale,
          "height": 1.5 * scale, "material": "m"},
         {"type": "triangle", "vertices": [p([-2, -1, -1]), p([-1.5, 1, -1.5]),
                                           p([-2.5, -1, -2])], "material": "m"}],
        camera={"position": p([0.5, 1.5, 5]), "look_at": p([0, -0.3, 0]), "vfov": 45},
        materials={"m": MATTE},
        lights=[{"type": "directional", "direction": [-0.4, -1, -0.3]}])


def scaled(scale: float) -> HardCase:
    def check(image: np.ndarray, s: Scene) -> None:
        from clray.render import RenderSettings, render
        from clray.scene.load import scene_from_dict

        base = render(scene_from_dict(_mixed_scene(1.0)), RenderSettings()).image
        off = int(np.count_nonzero(np.abs(image - base).max(-1) > 2 / 255))
        assert off <= 4, f"scale {scale:g}: {off} pixels differ from the unit-scale image"

    return HardCase(f"scale_{scale:.0e}".replace("+", ""), _mixed_scene(scale), check,
                    max_off=2)


def denormal_scale() -> HardCase:
    # Squared lengths of 1e-50 underflow float32 (hence the warning) but not double, whose
    # image must still be the unit-scale one.
    def check(image: np.ndarray, s: Scene) -> None:
        from clray.render import RenderSettings, render
        from clray.scene.load import scene_from_dict

        base = render(scene_from_dict(_mixed_scene(1.0)), RenderSettings()).image
        off = int(np.count_nonzero(np.abs(image - base).max(-1) > 2 / 255))
        assert off <= 4, f"scale 1e-25, double build: {off} pixels differ from unit scale"

    return HardCase("scale_1e-25_denormal", _mixed_scene(1e-25), check, max_off=-1,
                    warns="float32 can hold", in_study=False, float_checked=False)


def translated() -> HardCase:
    shift = (1e6, -2e6, 3e6)

    def check(image: np.ndarray, s: Scene) -> None:
        from clray.render import RenderSettings, render
        from clray.scene.load import scene_from_dict

        base = render(scene_from_dict(_mixed_scene(1.0)), RenderSettings()).image
        off = int(np.count_nonzero(np.abs(image - base).max(-1) > 2 / 255))
        assert off <= 4, f"{off} pixels differ from the scene at the origin"

    return HardCase("translated_far", _mixed_scene(1.0, shift), check, max_off=2)


def tir_critical() -> HardCase:
    glass = {"color": [1, 1, 1], "ambient": 0.0, "diffuse": 0.0, "transmit": 1.0, "ior": 1.5}
    sky = {"color": [1, 1, 1], "ambient": 1.0, "diffuse": 0.0}
    scene = _scene([{"type": "box", "min": [-50, -50, -50], "max": [50, 0, 50],
                     "material": "glass"},
                    {"type": "plane", "point": [0, 10, 0], "normal": [0, -1, 0],
                     "material": "sky"}],
                   camera={"position": [0, -1, 0], "look_at": [0, 0, 0], "up": [0, 0, -1],
                           "vfov": 110},
                   materials={"glass": glass, "sky": sky}, max_depth=2, width=48, height=48)

    def check(image: np.ndarray, s: Scene) -> None:
        _, d = primary_rays(s)
        angle = np.arccos(np.clip(d[..., 1], -1, 1))
        critical = math.asin(1 / 1.5)
        close(image, angle < critical - 1e-3, (1, 1, 1), 1e-5, "refracted out to the sky")
        close(image, angle > critical + 1e-3, (0, 0, 0), 1e-6, "totally reflected, cut")

    return HardCase("tir_critical_angle", scene, check)


def _nested(inner: bool) -> dict:
    glass = {"color": [1, 1, 1], "ambient": 0.0, "diffuse": 0.0, "transmit": 1.0, "ior": 1.5}
    wall = {"color": [1, 1, 1], "ambient": 1.0, "diffuse": 0.0,
            "texture": {"type": "checker", "size": 0.5, "color2": [0.1, 0.2, 0.6]}}
    objs = [{"type": "plane", "point": [0, 0, -5], "normal": [0, 0, 1], "material": "wall"},
            {"type": "sphere", "center": [0, 0, 0], "radius": 2.0, "material": "outer"}]
    if inner:
        objs.append({"type": "sphere", "center": [0.3, 0.2, 0.4], "radius": 1.0,
                     "material": "inner"})
    return _scene(objs, camera={"position": [0, 0, 6], "look_at": [0, 0, 0], "vfov": 45},
                  materials={"wall": wall, "outer": glass, "inner": dict(glass)},
                  max_depth=6)


def nested_equal_ior() -> HardCase:
    def check(image: np.ndarray, s: Scene) -> None:
        from clray.render import RenderSettings, render
        from clray.scene.load import scene_from_dict

        without = render(scene_from_dict(_nested(False)), RenderSettings()).image
        off = int(np.count_nonzero(np.abs(image - without).max(-1) > 2 / 255))
        assert off <= 2, f"an interface between equal IORs shows in {off} pixels"

    return HardCase("nested_equal_ior", _nested(True), check, max_off=2)


def facing_mirrors() -> HardCase:
    mirror = {"color": [1, 1, 1], "ambient": 0.2, "diffuse": 0.0, "reflect": 0.5}
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "m"},
                    {"type": "plane", "point": [0, 0, 2], "normal": [0, 0, -1],
                     "material": "m"}],
                   camera={"position": [0, 0, 1], "look_at": [0.3, 0.1, 0], "vfov": 40},
                   materials={"m": mirror}, max_depth=16)

    def check(image: np.ndarray, s: Scene) -> None:
        # Hits at depths 0..16 each add 0.2 times the weight 0.5^k; then the path is cut.
        expected = 0.2 * sum(0.5**k for k in range(17))
        close(image, np.ones(image.shape[:2], bool), expected, 1e-5, "geometric series")

    return HardCase("facing_mirrors_depth_16", scene, check)


def shininess_zero() -> HardCase:
    light = np.array([-0.5, -0.5, -1.0]) / np.linalg.norm([-0.5, -0.5, -1.0])
    scene = _scene([{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}],
                   camera={"position": [0, 0, 4], "look_at": [0, 0, 0], "vfov": 40},
                   materials={"m": {"ambient": 0.0, "diffuse": 0.0, "specular": 1.0,
                                    "shininess": 0.0}},
                   lights=[{"type": "directional", "direction": light.tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        t = sphere_t(eye, d, (0, 0, 0), 1.0)
        inside = impact(eye, d, (0, 0, 0)) < 0.98
        n = eye + np.where(inside, t, 0)[..., None] * d
        ndl = n @ -light
        r = 2 * ndl[..., None] * n + light
        rv = np.sum(r * -d, axis=-1)
        on = inside & (ndl > 1e-3) & (rv > 1e-3)
        off = inside & ((ndl < -1e-3) | (rv < -1e-3))
        close(image, on, (1, 1, 1), 0.0, "max(r.v, 0)^0 is 1 on the lit side")
        close(image, off, (0, 0, 0), 0.0, "and 0 elsewhere, never 0^0")

    return HardCase("shininess_zero", scene, check)


def _flip_symmetric(image: np.ndarray, axes: tuple[int, ...], allow: int, what: str) -> None:
    flipped = np.flip(image, axis=axes)
    off = int(np.count_nonzero(np.abs(image - flipped).max(-1) > 2 / 255))
    assert off <= allow, f"{what}: {off} pixels break the symmetry"


def cone_apex() -> HardCase:
    scene = _scene([{"type": "cone", "apex": [0, 0, 0], "axis": [0, 0, -1], "angle": 30,
                     "height": 2, "material": "m"}],
                   camera={"position": [0, 0, 5], "look_at": [0, 0, 0], "vfov": 40},
                   materials={"m": MATTE}, width=47, height=47,
                   lights=[{"type": "directional", "direction": [0, 0, -1]}])

    def check(image: np.ndarray, s: Scene) -> None:
        # Beside the apex the normal makes 60 degrees with the light; at the apex itself it
        # is the axis, by the documented limit choice (docs/rendering.md: apex normal).
        assert np.allclose(image[23, 25], 0.1 + 0.9 * math.sin(math.radians(30)), atol=2 / 255)
        _flip_symmetric(image, (0, 1), 4, "apex-on cone")
        # Every side point faces the light at 60 degrees: one value over the whole disc the
        # cone shows (its base rim has radius 2 tan 30 at distance 7), the apex pixel aside.
        _, d = primary_rays(s)
        rim = 2 * math.tan(math.radians(30))
        at_base = np.hypot(d[..., 0], d[..., 1]) / -d[..., 2] * 7
        side = at_base < rim * 0.98
        side[23, 23] = False
        close(image, side, 0.1 + 0.9 * 0.5, 1e-5, "side lit at n.l = 1/2")
        close(image, at_base > rim * 1.02, (0, 0, 0), 0.0, "beside the cone")

    # One pixel: the centre ray meets the apex, whose normal is a limit choice, and float may
    # land a rounding away from it on the side.
    return HardCase("cone_apex_on", scene, check, max_off=1)


def cylinder_rim() -> HardCase:
    scene = _scene([{"type": "cylinder", "base": [0, -1, 0], "axis": [0, 1, 0], "radius": 1,
                     "height": 2, "material": "m"}],
                   camera={"position": [0, 1, 5], "look_at": [0, 1, 0], "vfov": 50},
                   materials={"m": MATTE}, width=47, height=35,
                   lights=[{"type": "directional", "direction": [0.0, -0.3, -1.0]}])

    def check(image: np.ndarray, s: Scene) -> None:
        # The centre row runs in the top cap's plane, grazing the rim.
        _flip_symmetric(image, (1,), 2, "rim-on cylinder")
        eye, d = primary_rays(s)
        # The front of the side below the rim row: 0.1 + 0.9 n.l with n = (x, 0, z) there.
        light = np.array([0.0, 0.3, 1.0]) / math.hypot(0.3, 1.0)
        dxz = np.hypot(d[..., 0], d[..., 2])
        u = d[..., [0, 2]] / dxz[..., None]
        along = -(u[..., 1] * eye[2])  # the closest approach of the xz-ray to the axis
        miss2 = eye[2] ** 2 - along**2
        t_xz = along - np.sqrt(np.maximum(1 - miss2, 0))
        hit = np.stack([u[..., 0] * t_xz, eye[2] + u[..., 1] * t_xz], axis=-1)
        y = eye[1] + d[..., 1] * t_xz / dxz
        front = (miss2 < 0.98**2) & (y < 0.98) & (y > -0.98)
        expected = 0.1 + 0.9 * (hit[..., 1] * light[2])
        close(image, front, expected[front][:, None], 1e-4, "lit front of the side")
        x_at = np.abs(d[..., 0] / d[..., 2] * 4)
        close(image, (d[..., 1] > 0) | (x_at > 1.01), (0, 0, 0), 0.0, "above and beside")

    return HardCase("cylinder_rim_on", scene, check)


def coplanar_mixed_types() -> HardCase:
    # A triangle and a box's top face lying in a plane: three formulas reach the same points
    # with t a few roundings apart, which an exact tie rule turns into speckle.
    mats = {"red": {"color": [1, 0, 0], "ambient": 1.0, "diffuse": 0.0},
            "blue": {"color": [0, 0, 1], "ambient": 1.0, "diffuse": 0.0},
            "green": {"color": [0, 1, 0], "ambient": 1.0, "diffuse": 0.0}}
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "red"},
                    {"type": "triangle", "vertices": [[-3, 0, -3], [3, 0, -3], [0, 0, 3]],
                     "material": "blue"},
                    {"type": "box", "min": [0.7, -1, 0.9], "max": [2.3, 0, 2.1],
                     "material": "green"}],
                   camera={"position": [0.3, 2.0, 5.0], "look_at": [0, 0, 0], "vfov": 50},
                   materials=mats, width=64, height=48)

    def check(image: np.ndarray, s: Scene) -> None:
        # docs/rendering.md: crossings within a tie go to the plane (first in type order).
        _, d = primary_rays(s)
        ahead = d[..., 1] < -0.05  # rays that meet y = 0, away from the horizon
        close(image, ahead, (1, 0, 0), 0.0, "the plane wins every coplanar tie")

    return HardCase("coplanar_mixed_types", scene, check)


def light_in_floor_under_ball() -> HardCase:
    centre, radius, light = (0.0, 0.9, 0.0), 0.6, (0.3, 0.0, 0.4)
    scene = _scene([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "m"},
                    {"type": "sphere", "center": list(centre), "radius": radius,
                     "material": "m"}],
                   camera={"position": [0.0, 0.12, 2.2], "look_at": [0, 0.7, 0], "vfov": 50},
                   materials={"m": MATTE}, width=48, height=36,
                   lights=[{"type": "point", "position": list(light)}])

    def check(image: np.ndarray, s: Scene) -> None:
        # The ball's underside faces a light lying in the floor: nothing lies between them, so
        # it is lit by n.l (attenuation 1). Shadow rays aimed beside the light would cross the
        # floor first and leave a black band.
        eye, d = primary_rays(s)
        t = sphere_t(eye, d, centre, radius)
        p = eye + np.where(np.isfinite(t), t, 0)[..., None] * d
        n = (p - centre) / radius
        to_light = np.asarray(light) - p
        ndl = np.sum(n * to_light, axis=-1) / np.linalg.norm(to_light, axis=-1)
        body = np.isfinite(t) & (impact(eye, d, centre) < radius - 0.02) & (np.abs(ndl) > 0.02)
        expected = 0.1 + 0.9 * np.maximum(ndl, 0)
        close(image, body & (ndl > 0), expected[body & (ndl > 0)][:, None], 1e-3,
              "underside lit by the light in the floor")

    return HardCase("light_in_floor_under_ball", scene, check)


def group_rays(eye: np.ndarray, d: np.ndarray, matrix: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Rays in the frame of an object placed by x -> A x + t (matrix [A | t]), float64."""
    inverse = np.linalg.inv(matrix[:, :3])
    return (eye - matrix[:, 3]) @ inverse.T, d @ inverse.T


def _matrix(rows: list) -> np.ndarray:
    return np.asarray(rows, dtype=np.float64)[:3]


def thin_ellipsoid(edge_on: bool) -> HardCase:
    # A unit sphere squashed 1e4 times along one axis: a disc 2e-4 thick, intersected in the
    # sphere's own frame. Edge-on only the rays with a zero y component stay in it; face-on and
    # lit head-on, its Lambert shading must show no self-shadowing (the spawned shadow ray is
    # mapped back into the squashed frame) and the normal must follow the inverse transpose.
    squash = [1.0, 1e-4, 1.0] if edge_on else [1.0, 1.0, 1e-2]
    sphere = {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
              "transform": {"scale": squash}}
    if edge_on:
        scene = _scene([sphere], camera={"position": [0, 0, 5], "look_at": [0, 0, 0],
                                         "vfov": 40},
                       materials={"m": FLAT}, width=47, height=35)
    else:
        scene = _scene([sphere], camera={"position": [0, 0, 5], "look_at": [0, 0, 0],
                                         "vfov": 30},
                       materials={"m": MATTE}, width=47, height=47,
                       lights=[{"type": "directional", "direction": [0.3, -0.2, -1.0]}])
    matrix = np.diag([*squash, 0.0])[:3]

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        o, dl = group_rays(eye, d, matrix)
        unit = dl / np.linalg.norm(dl, axis=-1, keepdims=True)
        b = impact(o, unit, (0, 0, 0))
        if edge_on:
            hit = (d[..., 1] == 0) & (b < 0.99)
            close(image, hit, COLOR, 1e-6, "the disc's rim row")
            close(image, d[..., 1] != 0, (0, 0, 0), 0.0, "beside the disc")
            return
        t = sphere_t(o, unit, (0, 0, 0), 1.0) / np.linalg.norm(dl, axis=-1)
        p = eye + np.where(np.isfinite(t), t, 0)[..., None] * d
        n = p / np.square(np.asarray(squash))  # the gradient of the ellipsoid's equation
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        light = -np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
        lit = 0.1 + 0.9 * np.clip(n @ light, 0, None)
        inside = b < 0.97
        close(image, inside, lit[inside][:, None], 1e-4, "Lambert over the face, no acne")
        close(image, b > 1.03, (0, 0, 0), 0.0, "beside")

    return HardCase("thin_ellipsoid_edge_on" if edge_on else "thin_ellipsoid_lit", scene, check)


def rotated_box() -> HardCase:
    # A box turned off the axes (intersected in its own frame) and lit: each face one Lambert
    # value, its normal the rotated axis, no acne on any face.
    turn = {"rotate": [25, 40, 0], "translate": [0, 0, 0]}
    box = {"type": "box", "min": [-1, -1, -1], "max": [1, 1, 1], "material": "m",
           "transform": turn}
    light_dir = np.array([-0.4, -0.7, -0.6])
    scene = _scene([box], camera={"position": [0, 0, 6], "look_at": [0, 0, 0], "vfov": 45},
                   materials={"m": MATTE}, width=47, height=47,
                   lights=[{"type": "directional", "direction": light_dir.tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        rot = s.objects[0].matrix
        eye, d = primary_rays(s)
        o, dl = group_rays(eye, d, rot)
        inner = box_hit(o, dl, (-0.97,) * 3, (0.97,) * 3)
        close(image, ~box_hit(o, dl, (-1.03,) * 3, (1.03,) * 3), (0, 0, 0), 0.0, "beside")
        # The face each ray enters: where the slab entry is latest, in the box's frame.
        with np.errstate(divide="ignore", invalid="ignore"):
            t_near = np.minimum((-1 - o) / dl, (1 - o) / dl)
        axis = np.argmax(t_near, axis=-1)
        side = -np.sign(np.take_along_axis(dl, axis[..., None], -1)[..., 0])
        n_local = np.zeros(d.shape)
        np.put_along_axis(n_local, axis[..., None], side[..., None], -1)
        n = n_local @ rot[:, :3].T  # a rotation: the inverse transpose is itself
        light = -light_dir / np.linalg.norm(light_dir)
        lit = 0.1 + 0.9 * np.clip(n @ light, 0, None)
        # Away from the edges between faces, where a pixel may see either face.
        second = np.sort(t_near, axis=-1)[..., 1]
        clear = inner & (np.max(t_near, axis=-1) - second > 0.05)
        close(image, clear, lit[clear][:, None], 1e-4, "faces lit, no acne")

    return HardCase("rotated_box", scene, check)


def ellipsoid_hit(eye: np.ndarray, d: np.ndarray, radii: tuple, centre: tuple
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, point, unit outward normal) where unit rays first meet the ellipsoid with these
    semi-axes about `centre` (a unit sphere scaled, then moved), float64; t = inf on a miss."""
    r = np.asarray(radii, dtype=np.float64)
    o, dl = (eye - np.asarray(centre, dtype=np.float64)) / r, d / r
    scale = np.linalg.norm(dl, axis=-1)
    t = sphere_t(o, dl / scale[..., None], (0, 0, 0), 1.0) / scale
    p = eye + np.where(np.isfinite(t), t, 0)[..., None] * d
    n = (p - np.asarray(centre)) / r**2  # the gradient of the ellipsoid's equation
    return t, p, n / np.linalg.norm(n, axis=-1, keepdims=True)


def stretched_ground() -> HardCase:
    # The ground is a unit sphere stretched 1e4 along x and z (an instance), a ball stands on
    # it. A spawned ray starts err |n|_1 along the normal; a bound scaled by the transform's
    # largest stretch rather than its stretch along the normal (1 here) puts shadow rays about
    # 0.4 up, inside the ball, and darkens the lit ground around it.
    light = np.array([0.6, -1.0, 0.3]) / np.linalg.norm([0.6, -1.0, 0.3])
    ball, radius = (0.0, 0.5, 0.0), 0.5
    radii, centre = (1e4, 1.0, 1e4), (0.0, -1.0, 0.0)
    ground = {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
              "transform": {"scale": list(radii), "translate": list(centre)}}
    scene = _scene([ground, {"type": "sphere", "center": list(ball), "radius": radius,
                             "material": "m"}],
                   camera={"position": [0, 1.2, 2.5], "look_at": [0, 0.3, 0], "vfov": 45},
                   materials={"m": MATTE}, width=64, height=48,
                   lights=[{"type": "directional", "direction": light.tolist()}])

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        t, p, n = ellipsoid_hit(eye, d, radii, centre)
        seen = np.isfinite(t) & (impact(eye, d, ball) > radius * 1.03)
        shadow_b = impact(p[seen], np.broadcast_to(-light, p[seen].shape), ball)
        lit, dark = seen.copy(), seen.copy()
        lit[seen] = shadow_b > radius * 1.03
        dark[seen] = shadow_b < radius * 0.97
        close(image, lit, (0.1 + 0.9 * np.clip(n[lit] @ -light, 0, None))[:, None], 2 / 255,
              "lit ground (shadow rays started inside the ball show as 0.1)")
        close(image, dark, (0.1, 0.1, 0.1), 2 / 255, "ground in the ball's shadow")

    return HardCase("stretched_ground", scene, check)


def stretched_wall() -> HardCase:
    # A unit sphere stretched 1e19 along y and z: a wall 2 thick at x in [-1, 1], lit by a
    # point light. Inverting its transform scaled by one power of two for the whole matrix,
    # the two small rows' cofactor (1e-38) underflows float32 and every hit maps to one point.
    radii, light = (1.0, 1e19, 1e19), (3.0, 0.4, -0.3)
    wall = {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
            "transform": {"scale": list(radii)}}
    scene = _scene([wall], camera={"position": [4, 0, 0], "look_at": [0, 0, 0], "vfov": 60},
                   materials={"m": MATTE}, width=47, height=35,
                   lights=[{"type": "point", "position": list(light)}])

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        t, p, n = ellipsoid_hit(eye, d, radii, (0, 0, 0))
        to_light = np.asarray(light) - p
        ndl = np.sum(n * to_light, axis=-1) / np.linalg.norm(to_light, axis=-1)
        lit = np.isfinite(t)
        close(image, lit, (0.1 + 0.9 * np.clip(ndl[lit], 0, None))[:, None], 2 / 255,
              "Lambert over the wall from a point light")
        assert lit.all()

    return HardCase("stretched_wall_1e19", scene, check)


def cylinder_hit(o: np.ndarray, d: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Whether rays cross the capped cylinder about +y from y = 0 to height (float64)."""
    a = d[..., 0] ** 2 + d[..., 2] ** 2
    b = o[..., 0] * d[..., 0] + o[..., 2] * d[..., 2]
    c = o[..., 0] ** 2 + o[..., 2] ** 2 - radius**2
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(b * b - a * c, 0))
        hit = np.zeros(d.shape[:-1], bool)
        for t in ((-b - sq) / a, (-b + sq) / a):
            y = o[..., 1] + t * d[..., 1]
            hit |= (b * b - a * c >= 0) & (t > 0) & (y >= 0) & (y <= height)
        for cap in (0.0, height):
            t = (cap - o[..., 1]) / d[..., 1]
            x, z = o[..., 0] + t * d[..., 0], o[..., 2] + t * d[..., 2]
            hit |= (t > 0) & (x * x + z * z <= radius**2)
    return hit


def sheared_cylinder() -> HardCase:
    # A cylinder sheared along x as it rises: an oblique elliptic cylinder, only possible in
    # its own frame. Its silhouette must be the sheared one exactly.
    shear = [[1, 0.6, 0, 0], [0, 1, 0, -1], [0, 0, 1, 0], [0, 0, 0, 1]]
    cyl = {"type": "cylinder", "base": [0, 0, 0], "axis": [0, 1, 0], "radius": 0.7,
           "height": 2, "material": "m", "transform": {"matrix": shear}}
    scene = _scene([cyl], camera={"position": [1, 2, 6], "look_at": [0.6, 0, 0], "vfov": 40},
                   materials={"m": FLAT}, width=47, height=47)

    def check(image: np.ndarray, s: Scene) -> None:
        eye, d = primary_rays(s)
        o, dl = group_rays(eye, d, _matrix(shear))
        # The cylinder shrunk and grown by 0.02 in radius and at both caps.
        lift = np.array([0, 0.02, 0])
        shrunk = cylinder_hit(o - lift, dl, 0.68, 1.96)
        grown = cylinder_hit(o + lift, dl, 0.72, 2.04)
        close(image, shrunk, COLOR, 1e-6, "inside")
        close(image, ~grown, (0, 0, 0), 0.0, "outside")

    return HardCase("sheared_cylinder", scene, check)


def meridian_hit(d: np.ndarray, height: float, major: float, minor: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """For unit rays from an eye on a torus's axis (the y axis through the origin, the eye at y
    = height), each in a plane through the axis where the tube is a circle of radius `minor`
    about (rho, y) = (major, 0): (the ray's distance from that circle's centre, the y of the
    outward normal where it first crosses it; NaN where it does not)."""
    dy = d[..., 1]
    dh = np.hypot(d[..., 0], d[..., 2])
    dist = np.abs(major * dy + height * dh)
    along = major * dh - height * dy
    with np.errstate(invalid="ignore"):
        t = along - np.sqrt(minor * minor - dist * dist)
    return dist, (height + t * dy) / minor


def torus_on_axis(name: str, height: float, major: float, minor: float, look_at: list,
                  vfov: float, lit: bool) -> HardCase:
    """A torus seen from a point of its axis: thin (minor/major 1e-4), far (the eye 2,000
    units off, the ray's origin that far from the tube in the kernel), or lit from above,
    where acne would show as the ambient 0.1. Flat-coloured, each pixel must be the colour where
    its ray passes the tube's circle within 0.97 minor and black beyond 1.03 minor; lit, the
    Lambert value of the closed-form normal (a light straight down the axis casts no shadow of
    the torus on itself)."""
    torus = {"type": "torus", "center": [0, 0, 0], "axis": [0, 1, 0], "major_radius": major,
             "minor_radius": minor, "material": "m"}
    scene = _scene([torus], camera={"position": [0, height, 0], "look_at": look_at,
                                    "up": [0, 0, 1], "vfov": vfov},
                   materials={"m": MATTE if lit else FLAT}, width=47, height=35,
                   lights=[{"type": "directional", "direction": [0, -1, 0]}] if lit else None)

    def check(image: np.ndarray, s: Scene) -> None:
        _, d = primary_rays(s)
        dist, normal_y = meridian_hit(d, height, major, minor)
        inside = dist < 0.97 * minor
        value = (0.1 + 0.9 * normal_y[inside])[:, None] if lit else COLOR
        close(image, inside, value, 2 / 255 if lit else 1e-6,
              "on the tube" + (" (acne shows as 0.1)" if lit else ""))
        close(image, dist > 1.03 * minor, (0, 0, 0), 0.0, "beside the tube")

    return HardCase(name, scene, check)


CASES: tuple[HardCase, ...] = (
    far_sphere(1e3, 1e-3),
    far_sphere(1e4, 1e-2),
    huge_ground(),
    curved_acne(),
    camera_inside(1.0),
    camera_inside(1e-5),
    tilted_plane_far(),
    light_on_surface(),
    coplanar_ties(),
    coplanar_mixed_types(),
    light_in_floor_under_ball(),
    touching_spheres(),
    horizon(),
    degenerate_triangles(),
    closed_mesh((0.0, 0.0, 5.0), "closed_mesh_edges"),
    closed_mesh((4.0, 4.0, 4.0), "closed_mesh_vertex"),
    thin_box(edge_on=False),
    thin_box(edge_on=True),
    slab_zero_direction(),
    scaled(1e-12),
    scaled(1e12),
    denormal_scale(),
    translated(),
    tir_critical(),
    nested_equal_ior(),
    facing_mirrors(),
    shininess_zero(),
    cone_apex(),
    cylinder_rim(),
    thin_ellipsoid(edge_on=True),
    thin_ellipsoid(edge_on=False),
    rotated_box(),
    stretched_ground(),
    stretched_wall(),
    sheared_cylinder(),
    torus_on_axis("torus_down_the_axis", 3.0, 1.0, 0.5, [0, 0, 0], 70, lit=False),
    torus_on_axis("torus_thin_1e-4", 1.0, 1.0, 1e-4, [1, 0, 0], 0.06, lit=False),
    torus_on_axis("torus_far_2e3", 2000.0, 1.0, 0.25, [1, 0, 0], 0.03, lit=False),
    torus_on_axis("torus_lit_acne", 4.0, 1.0, 0.4, [0, 0, 0], 50, lit=True),
)


def export_scenes(folder: Path) -> list[Path]:
    """Write the study's cases as JSON scene files (the inputs of the shipped report)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for case in CASES:
        if case.in_study:
            path = folder / f"{case.name}.json"
            path.write_text(json.dumps(case.scene, indent=1) + "\n", encoding="utf-8")
            paths.append(path)
    return paths
