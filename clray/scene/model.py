"""The scene model: frozen dataclasses in float64 world units.

This module knows nothing about OpenCL or buffer layouts. Everything here is already
validated by `clray.scene.load`; directions are unit length, angles are in degrees.
Objects refer to materials by index into `Scene.materials`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

Vec3 = tuple[float, float, float]


def unit(v: np.ndarray) -> np.ndarray:
    """`v` (..., 3) scaled to unit length along its last axis. Dividing by the largest
    component first keeps the squares in range: a vector such as (1e-200, 1e-200, 0) would
    otherwise have a norm of 0, and one near 1e200 an infinite one. Zero rows stay zero."""
    a = np.asarray(v, dtype=np.float64)
    peak = np.max(np.abs(a), axis=-1, keepdims=True)
    a = np.divide(a, peak, out=np.zeros_like(a), where=peak > 0)
    norm = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, norm, out=np.zeros_like(a), where=norm > 0)


@dataclass(frozen=True)
class Texture:
    """A checker (3D, in world space) or an image texture mapped through (u, v)."""

    kind: str  # "checker" | "image"
    size: float = 1.0  # checker cell size, world units
    color2: Vec3 = (0.0, 0.0, 0.0)  # checker's second colour
    file: Path | None = None
    repeat: tuple[float, float] = (1.0, 1.0)  # j x k repetitions of the image over (u, v)
    blend: float = 1.0  # surface colour = blend * texel + (1 - blend) * material colour
    # An image's file held "srgb" values (decoded to the linear `image` when loaded) or "linear".
    colorspace: str | None = None
    # (H, W, 3) float32 linear texels in [0, 1], row 0 at the top of the image (v = 1).
    image: np.ndarray | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class Material:
    name: str
    color: Vec3 = (1.0, 1.0, 1.0)
    ambient: float = 0.0
    diffuse: float = 1.0
    specular: float = 0.0
    shininess: float = 32.0
    reflect: float = 0.0
    transmit: float = 0.0
    ior: float = 1.5
    texture: Texture | None = None
    # Split `transmit` between the refracted and reflected rays by the dielectric Fresnel
    # reflectance instead of the fixed weights (docs/rendering.md, Fresnel).
    fresnel: bool = False
    # Radiance the surface emits (MTL Ke), seen by the rays that hit it; a scene mesh's faces
    # of such a material also light the scene (clray.scene.emitters).
    emission: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PointLight:
    position: Vec3
    color: Vec3 = (1.0, 1.0, 1.0)
    attenuation: Vec3 = (1.0, 0.0, 0.0)  # constant, linear, quadratic


@dataclass(frozen=True)
class DirectionalLight:
    direction: Vec3  # unit; the way the light travels
    color: Vec3 = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class SpotLight:
    """A point light lighting only a cone: full inside `inner_angle`, nothing outside
    `angle` (half-angles in degrees), smoothstep in cos between."""

    position: Vec3
    direction: Vec3  # unit; the cone's axis, the way the light travels
    angle: float
    color: Vec3 = (1.0, 1.0, 1.0)
    attenuation: Vec3 = (1.0, 0.0, 0.0)  # constant, linear, quadratic
    inner_angle: float | None = None  # None: equal to `angle`, a hard edge


# Area lights: `color` is the emitted radiance, the same from every point and in every
# direction the light emits in (docs/rendering.md, Lights).


@dataclass(frozen=True)
class RectLight:
    """The parallelogram corner + s u + t v (s, t in [0, 1]); emits to the side of
    cross(u, v) only."""

    corner: Vec3
    u: Vec3
    v: Vec3
    color: Vec3 = (1.0, 1.0, 1.0)


def rect_area(u: Vec3, v: Vec3) -> float:
    """|u x v|, the parallelogram's area, computed with both edges scaled to unit length first
    so that no product underflows or overflows."""
    nu, nv = float(np.max(np.abs(u))), float(np.max(np.abs(v)))
    if nu == 0.0 or nv == 0.0:
        return 0.0
    return float(np.linalg.norm(np.cross(np.asarray(u) / nu, np.asarray(v) / nv))) * nu * nv


@dataclass(frozen=True)
class DiscLight:
    """A disc that emits to the side its (unit) normal points to."""

    center: Vec3
    normal: Vec3
    radius: float
    color: Vec3 = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class SphereLight:
    """A sphere that emits outwards from every point of its surface."""

    center: Vec3
    radius: float
    color: Vec3 = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class TriangleLight:
    """An emissive mesh face (clray.scene.emitters): emits to the side of
    cross(v1 - v0, v2 - v0) only. Made from the meshes, never given in a scene file."""

    vertices: tuple[Vec3, Vec3, Vec3]
    color: Vec3 = (1.0, 1.0, 1.0)


AreaLight = RectLight | DiscLight | SphereLight | TriangleLight
Light = PointLight | DirectionalLight | SpotLight | RectLight | DiscLight | SphereLight


@dataclass(frozen=True)
class Camera:
    position: Vec3
    look_at: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    vfov: float | None = 40.0  # degrees; a perspective camera sets exactly one of vfov, hfov
    hfov: float | None = None
    type: str = "perspective"  # "perspective" | "orthographic"
    # Orthographic: the view's extent in world units, exactly one of the two set.
    width: float | None = None
    height: float | None = None
    aperture: float = 0.0  # thin-lens diameter, world units; 0 is a pinhole
    focus_distance: float | None = None  # along the view direction; None: to look_at

    def basis(self, width: int, height: int) -> tuple[np.ndarray, ...]:
        """(forward, right, up, half_w, half_h): unit vectors and image-plane half extents at
        distance 1 (orthographic: the view's half extents in world units). right =
        normalize(cross(forward, up)), as docs/rendering.md fixes it."""
        eye = np.asarray(self.position, dtype=np.float64)
        forward = unit(np.asarray(self.look_at, dtype=np.float64) - eye)
        right = unit(np.cross(forward, unit(self.up)))
        true_up = np.cross(right, forward)
        aspect = width / height
        if self.type == "orthographic":
            if self.width is not None:
                return forward, right, true_up, self.width / 2.0, self.width / 2.0 / aspect
            return forward, right, true_up, self.height / 2.0 * aspect, self.height / 2.0
        if self.hfov is not None:
            half_w = np.tan(np.radians(self.hfov) / 2.0)
            half_h = half_w / aspect
        else:
            half_h = np.tan(np.radians(self.vfov) / 2.0)
            half_w = half_h * aspect
        return forward, right, true_up, half_w, half_h


@dataclass(frozen=True)
class Background:
    """What rays that miss see beyond a plain colour (docs/rendering.md, Background)."""

    kind: str  # "gradient" | "image"
    bottom: Vec3 = (0.0, 0.0, 0.0)  # gradient: straight down
    top: Vec3 = (1.0, 1.0, 1.0)  # gradient: straight up
    file: Path | None = None
    colorspace: str | None = None  # as Texture.colorspace
    # (H, W, 3) float32 linear texels, equirectangular, row 0 at the top (straight up).
    image: np.ndarray | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class RenderOptions:
    width: int = 640
    height: int = 480
    spp: int = 1
    max_depth: int = 4
    background: Vec3 | Background = (0.0, 0.0, 0.0)
    ambient: Vec3 = (1.0, 1.0, 1.0)
    seed: int = 0
    min_weight: float = 0.0  # secondary rays of a smaller weight are not traced
    # PNG output (clray.image_io.Encoding): sRGB curve or linear, exposure in stops, bits.
    linear: bool = False
    exposure: float = 0.0
    png_bits: int = 8


@dataclass(frozen=True)
class Sphere:
    center: Vec3
    radius: float
    material: int


@dataclass(frozen=True, eq=False)
class Spheres:
    """Many spheres given as arrays (particles, molecules): one object in the scene, packed and
    intersected exactly as that many Sphere objects in this order would be."""

    centers: np.ndarray  # (N, 3) float64
    radii: np.ndarray  # (N,) float64, each > 0
    materials: np.ndarray  # (N,) int64 indices into Scene.materials


@dataclass(frozen=True)
class Plane:
    point: Vec3
    normal: Vec3  # unit
    material: int


@dataclass(frozen=True)
class Box:
    min: Vec3
    max: Vec3
    material: int


@dataclass(frozen=True)
class Triangle:
    vertices: tuple[Vec3, Vec3, Vec3]
    material: int


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh, already transformed to world space on the host in float64."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64 indices into vertices
    material: int
    normals: np.ndarray | None = None  # (V, 3) float64 unit vertex normals: smooth shading
    uvs: np.ndarray | None = None  # (V, 2) float64 texture coordinates
    # (F,) int64 indices into Scene.materials, one per face (an OBJ file's `usemtl`); None:
    # every face takes `material`.
    face_materials: np.ndarray | None = None
    # (V, 3) float64 linear vertex colours in [0, 1], blended across each face and multiplying
    # its material's colour (a PLY file's red, green, blue; glTF's COLOR_0).
    colors: np.ndarray | None = None


@dataclass(frozen=True)
class Cylinder:
    base: Vec3  # centre of the bottom cap
    axis: Vec3  # unit, from the bottom cap to the top cap
    radius: float
    height: float
    material: int
    capped: bool = True


@dataclass(frozen=True)
class Cone:
    """One nappe: the apex, widening along `axis` to a base disc at distance `height`."""

    apex: Vec3
    axis: Vec3  # unit, from the apex towards the base
    angle: float  # half-angle, degrees, in (0, 90)
    height: float
    material: int
    capped: bool = True


@dataclass(frozen=True)
class Torus:
    """The points at distance `minor_radius` from the circle of radius `major_radius` about
    `axis` through `center` (a ring: minor_radius <= major_radius)."""

    center: Vec3
    axis: Vec3  # unit, the circle's normal
    major_radius: float
    minor_radius: float
    material: int


@dataclass(frozen=True, eq=False)
class Group:
    """Objects defined once, in their own frame, to be placed by instances. Identity matters:
    instances of one Group share its primitives and BVH on the device."""

    name: str
    objects: tuple[Sphere | Spheres | Box | Triangle | Mesh | Cylinder | Cone | Torus, ...]


@dataclass(frozen=True, eq=False)
class Instance:
    """A group placed by x -> A x + t (the (3, 4) float64 `matrix` [A | t], A invertible) and
    intersected in the group's frame. `material` replaces every material of the group."""

    group: Group
    matrix: np.ndarray
    material: int | None = None


SceneObject = (Sphere | Spheres | Plane | Box | Triangle | Mesh | Cylinder | Cone | Torus
               | Instance)


@dataclass(frozen=True)
class Scene:
    path: Path | None
    render: RenderOptions
    camera: Camera
    materials: tuple[Material, ...]
    lights: tuple[Light, ...]
    objects: tuple[SceneObject, ...]
    warnings: tuple[str, ...] = ()
    # Set by the loader on the scenes it makes. A scene built or changed in Python (even with
    # dataclasses.replace, which does not copy it) starts False and is checked by the file
    # format's rules before it renders (clray.scene.check).
    checked: bool = field(default=False, init=False, compare=False, repr=False)
