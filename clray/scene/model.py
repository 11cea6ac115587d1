"""The scene model: frozen dataclasses in float64 world units.

This module knows nothing about OpenCL or buffer layouts. Everything here is already
validated by `clray.scene.load`; directions are unit length, angles are in degrees.
Objects refer to materials by index into `Scene.materials`.
"""

from __future__ import annotations

import functools
import operator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# The analytic shapes and the light kinds live in clray.shapes and clray.lights, one module
# each; re-exported here, where scenes are built in Python.
from clray.lights import LIGHTS, LISTED
from clray.lights.directional import DirectionalLight as DirectionalLight
from clray.lights.disc import DiscLight as DiscLight
from clray.lights.mesh import MeshLight as MeshLight
from clray.lights.point import PointLight as PointLight
from clray.lights.rect import RectLight as RectLight
from clray.lights.rect import rect_area as rect_area
from clray.lights.sphere import SphereLight as SphereLight
from clray.lights.spot import SpotLight as SpotLight
from clray.lights.triangle import TriangleLight as TriangleLight
from clray.shapes import SHAPES
from clray.shapes.box import Box as Box
from clray.shapes.cone import Cone as Cone
from clray.shapes.cylinder import Cylinder as Cylinder
from clray.shapes.sphere import Sphere as Sphere
from clray.shapes.sphere import Spheres as Spheres
from clray.shapes.torus import Torus as Torus
from clray.vectors import Vec3 as Vec3
from clray.vectors import unit


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


# The lights a scene file names (an emissive mesh face's TriangleLight, and the MeshLight of
# many such faces, are made by the loader)
# and those sampled over their area, from the registry (clray.lights.LIGHTS).
Light = functools.reduce(operator.or_, (light.model for light in LISTED.values()))
AreaLight = functools.reduce(operator.or_, (light.model for light in LIGHTS if light.area))


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
class Plane:
    point: Vec3
    normal: Vec3  # unit
    material: int


@dataclass(frozen=True)
class Triangle:
    vertices: tuple[Vec3, Vec3, Vec3]
    material: int


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh, already transformed to world space on the host (in float64 where a
    transform moved it)."""

    # (V, 3) float64; float32 where a PLY file stores them so (half the bytes): each use
    # widens them to float64 before any arithmetic, which is exact.
    vertices: np.ndarray
    faces: np.ndarray  # (F, 3) int64 indices into vertices; int32 as a PLY file stores them
    material: int
    normals: np.ndarray | None = None  # (V, 3) float64 unit vertex normals: smooth shading
    uvs: np.ndarray | None = None  # (V, 2) float64 texture coordinates
    # (F,) int64 indices into Scene.materials, one per face (an OBJ file's `usemtl`); None:
    # every face takes `material`.
    face_materials: np.ndarray | None = None
    # (V, 3) float64 linear vertex colours in [0, 1], blended across each face and multiplying
    # its material's colour (a PLY file's red, green, blue; glTF's COLOR_0).
    colors: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Group:
    """Objects defined once, in their own frame, to be placed by instances. Identity matters:
    instances of one Group share its primitives and BVH on the device."""

    name: str
    objects: tuple[SceneObject, ...]  # bounded ones: no planes, no instances


@dataclass(frozen=True, eq=False)
class Instance:
    """A group placed by x -> A x + t (the (3, 4) float64 `matrix` [A | t], A invertible) and
    intersected in the group's frame. `material` replaces every material of the group."""

    group: Group
    matrix: np.ndarray
    material: int | None = None


# Planes, triangles, meshes, instances and every shape of the registry (clray.shapes.SHAPES).
SceneObject = functools.reduce(operator.or_, (t for shape in SHAPES for t in shape.types),
                               Plane | Triangle | Mesh | Instance)


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
