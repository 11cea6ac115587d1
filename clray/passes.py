"""Passes (AOVs; docs/passes.md): what a render's primary rays meet, as named arrays beside the
image. The kernel (kernels/passes.h, render.cl's render_passes) writes four raw outputs;
this module names the passes, turns those outputs into them (the primitive references into
the scene's object indices), writes them (layers of an OpenEXR image, else one PFM a pass
beside it) and draws their false-colour previews."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clray.denoise import DENOISE_GUIDES
from clray.device import layout as L
from clray.device.launch import PASS_OUTPUTS
from clray.errors import SettingsError
from clray.image_io import (
    Encoding,
    add_image,
    as_pixels,
    as_radiance,
    check_encoding,
    check_writer,
    image_bytes,
    pfm_bytes,
    png_bytes,
    to_png_samples,
)
from clray.output import WriteSet, write_set
from clray.scene import model as M
from clray.shapes import SHAPE_OF, SHAPES

# The passes a render can ask for, in the order files list them.
PASS_NAMES = ("depth", "normal", "albedo", "position", "object", "material", "instance")
# The passes of one number a pixel: depth float32, the indices int32 (-1 on a miss).
SCALAR_PASSES = ("depth", "object", "material", "instance")
INDEX_PASSES = ("object", "material", "instance")


def pass_problem(names: object) -> str | None:
    """What is wrong with a tuple of pass names, or None."""
    if not isinstance(names, tuple) or not all(isinstance(n, str) for n in names):
        return "expected a tuple of pass names"
    unknown = [n for n in names if n not in PASS_NAMES]
    if unknown:
        return (f"unknown pass {unknown[0]!r}; expected some of {', '.join(PASS_NAMES)}")
    if len(set(names)) != len(names):
        return "a pass is named twice"
    return None


# Each primitive kind's packed array, with the scene objects that pack into it
# (clray.device.pack._by_kind: each shape's, Triangle with Mesh) and the primitives each object
# makes there.
_KINDS = ((L.PRIM_PLANE, (M.Plane,)), *((shape.prim, shape.types) for shape in SHAPES),
          (L.PRIM_TRIANGLE, (M.Triangle, M.Mesh)))


def _primitives(obj: M.SceneObject) -> int:
    if type(obj) in SHAPE_OF:
        return SHAPE_OF[type(obj)].primitives(obj)
    if isinstance(obj, M.Mesh):
        return len(obj.faces)
    return 1


def object_of_primitive(scene: M.Scene) -> dict[int, np.ndarray]:
    """Per primitive kind (layout.PRIM_*), the scene object (index in scene.objects) of each
    primitive the packer stores in that kind's array, in its order: the scene's own objects
    first, in scene order, then the groups' (-1: the object is the instance the hit was in)."""
    instances = [obj for obj in scene.objects if isinstance(obj, M.Instance)]
    groups = list({id(inst.group): inst.group for inst in instances}.values())
    table = {}
    for kind, types in _KINDS:
        owners = [(i, obj) for i, obj in enumerate(scene.objects) if isinstance(obj, types)]
        if kind != L.PRIM_PLANE:
            owners += [(-1, obj) for group in groups for obj in group.objects
                       if isinstance(obj, types)]
        table[kind] = np.repeat(np.array([i for i, _ in owners], dtype=np.int32),
                                [_primitives(obj) for _, obj in owners]).astype(np.int32)
    return table


def instance_objects(scene: M.Scene) -> np.ndarray:
    """The index in scene.objects of each instance, in the order the packer numbers them."""
    return np.array([i for i, obj in enumerate(scene.objects) if isinstance(obj, M.Instance)],
                    dtype=np.int32)


def object_indices(scene: M.Scene, refs: np.ndarray, instances: np.ndarray) -> np.ndarray:
    """The scene object of each primitive reference (-1: none) met in instance `instances`
    (-1: in none): its own object's index, or the instance's."""
    objects = np.full(refs.shape, -1, dtype=np.int32)
    kinds = refs >> L.PRIM_TYPE_SHIFT
    index = refs & L.PRIM_INDEX_MASK
    for kind, table in object_of_primitive(scene).items():
        mine = (refs >= 0) & (kinds == kind)
        objects[mine] = table[index[mine]]
    inside = instances >= 0
    objects[inside] = instance_objects(scene)[instances[inside]]
    return objects


def passes_of(raw: dict[str, np.ndarray], scene: M.Scene,
              names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The passes `names` from render_passes' outputs (clray.device.launch.PASS_OUTPUTS, by
    name, (H, W, 4) each)."""
    geometry, indices = raw["geometry"], raw["indices"]
    made = {
        "depth": lambda: geometry[..., 3],
        "normal": lambda: geometry[..., :3],
        "albedo": lambda: raw["albedo"][..., :3],
        "position": lambda: raw["position"][..., :3],
        "object": lambda: object_indices(scene, indices[..., 0], indices[..., 1]),
        "instance": lambda: indices[..., 1],
        "material": lambda: indices[..., 2],
    }
    return {name: np.ascontiguousarray(made[name]()) for name in names}


def preview(name: str, values: np.ndarray) -> np.ndarray:
    """A false-colour (H, W, 3) float32 picture of pass `name` in [0, 1] for a PNG: depth as
    inverse depth (white nearest, darker farther), normals from [-1, 1] and positions from their
    range over the hits to [0, 1] per axis, albedo as it is (linear: preview_png sRGB-encodes
    it), indices as distinct hues; black on a miss."""
    if name == "albedo":
        return np.clip(values, 0.0, 1.0).astype(np.float32)
    if name in INDEX_PASSES:
        # A golden-ratio walk round the hue circle: neighbouring indices far apart.
        hue = (values.astype(np.float64) * 0.618033988749895) % 1.0
        rgb = np.clip(np.abs((hue[..., None] * 6.0 + np.array([0.0, 4.0, 2.0])) % 6.0 - 3.0)
                      - 1.0, 0.0, 1.0)
        rgb[values < 0] = 0.0
        return rgb.astype(np.float32)
    if name == "depth":
        # Inverse depth, nearest / depth: a ground plane running to the horizon, whose far
        # end would squeeze a linear scale's near objects into one grey, falls off smoothly.
        finite = np.isfinite(values) & (values > 0)
        near = values[finite].min() if finite.any() else 1.0
        grey = np.where(finite, near / np.where(finite, values, 1.0), 0.0)
        return np.repeat(grey[..., None], 3, axis=2).astype(np.float32)
    if name == "normal":
        rgb = np.clip(0.5 * values + 0.5, 0.0, 1.0)
        rgb[~values.any(axis=2)] = 0.0
        return rgb.astype(np.float32)
    # Positions: a miss is (0, 0, 0), which would stretch the range and show as any colour of
    # it; the range is the hits' alone, and a miss black. (A hit exactly at the world origin
    # shows black too.)
    hit = values.any(axis=2)
    rgb = np.zeros(values.shape, dtype=np.float32)
    if hit.any():
        lo, hi = values[hit].min(axis=0), values[hit].max(axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        rgb[hit] = np.clip((values[hit] - lo) / span, 0.0, 1.0)
    return rgb


def preview_png(name: str, values: np.ndarray) -> bytes:
    """The PNG of pass `name`'s preview, tagged sRGB, as a viewer should show its codes."""
    shown = preview(name, values)
    if name == "albedo":
        # Linear reflectance, light's own scale: the sRGB curve, as the image has.
        return image_bytes(".png", shown, Encoding())
    # The other previews' values are the display codes themselves (no light to encode): as
    # they are, but tagged sRGB, not linear (gAMA 1.0), which colour-managed viewers would
    # show washed out.
    return png_bytes(to_png_samples(shown, Encoding(linear=True)), linear=False)


# Each pass's channels in an OpenEXR file: layer "name", channels "name.X" ... (the indices
# as float32, exact below 2**24, as EXR has no signed integers).
EXR_CHANNELS = {"depth": ("Z",), "normal": ("X", "Y", "Z"), "albedo": ("R", "G", "B"),
                "position": ("X", "Y", "Z"), "object": ("id",), "material": ("id",),
                "instance": ("id",)}


def exr_channels(aovs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The passes as OpenEXR channels by full name ("normal.X"), float32 (H, W) each."""
    out = {}
    for name, values in aovs.items():
        planes = values[..., None] if values.ndim == 2 else values
        for k, channel in enumerate(EXR_CHANNELS[name]):
            out[f"{name}.{channel}"] = planes[..., k].astype(np.float32)
    return out


def beside(image_path: str | Path, name: str, suffix: str) -> Path:
    """A pass's file beside the image: out.png -> out.depth.pfm."""
    path = Path(image_path)
    return path.with_name(f"{path.stem}.{name}{suffix}")


def pass_paths(image_path: str | Path, names: tuple[str, ...], previews: bool
               ) -> list[Path]:
    """The files besides the image that writing passes `names` with it makes: one PFM a pass
    (none for an OpenEXR image, whose layers hold them) and, with `previews`, one PNG a pass."""
    exr = Path(image_path).suffix.lower() == ".exr"
    files = [] if exr else [beside(image_path, name, ".pfm") for name in names]
    return files + ([beside(image_path, name, ".png") for name in names] if previews else [])


def exr_holds_passes(path: Path, names: tuple[str, ...]) -> bool:
    """Whether the OpenEXR image at `path` has every pass of `names` among its layers (a frame
    that --resume may skip); False for a file OpenEXR cannot read, or without OpenEXR."""
    try:
        import OpenEXR

        channels = OpenEXR.File(str(path), header_only=True).header()["channels"]
    except (ImportError, RuntimeError, KeyError):  # OpenEXR's "Unable to open ... for read"
        return False
    held = {channel.name for channel in channels}
    return all(f"{name}.{channel}" in held for name in names for channel in EXR_CHANNELS[name])


def as_passes(aovs: object, size: tuple[int, ...]) -> dict[str, np.ndarray]:
    """`aovs` as RenderResult.aovs holds passes, arrays by name, or SettingsError: a dict of
    known pass names, each an array of real numbers (nested lists too) of the image's `size`
    (H, W), with 3 values a pixel but for the scalar passes."""
    if not isinstance(aovs, dict):
        raise SettingsError(f"aovs: expected a dict of pass arrays by name, got "
                            f"{type(aovs).__name__}")
    problem = pass_problem(tuple(aovs))
    if problem:
        raise SettingsError(f"aovs: {problem}")
    passes = {}
    for name, values in aovs.items():
        shape = size + (() if name in SCALAR_PASSES else (3,))
        passes[name] = as_pixels(values, f"aovs[{name!r}]", grey=True)
        if passes[name].shape != shape:
            raise SettingsError(f"aovs[{name!r}]: expected shape {shape} (the image's size), "
                                f"got {passes[name].shape}")
    return passes


def write_with_passes(path: str | Path, image: np.ndarray, encoding: Encoding,
                      aovs: dict[str, np.ndarray], previews: bool = False) -> None:
    """The image at `path` (its suffix picks the format), with its passes as layers of the
    same file where that is OpenEXR, else one PFM a pass beside it (pass_paths), and with
    `previews` a false-colour PNG of each. Every file whole, and none in place unless all are
    written (clray.output.WriteSet), the image last: where it exists, so do its passes' files
    (what --frames --resume relies on). Bad arguments are refused before any file is written,
    and so is a folder where one of the files goes."""
    with write_set() as files:
        stage_with_passes(files, path, image, encoding, aovs, previews)


def stage_with_passes(files: WriteSet, path: str | Path, image: np.ndarray,
                      encoding: Encoding, aovs: dict[str, np.ndarray],
                      previews: bool = False) -> None:
    """write_with_passes' files added to `files`, the image last, for its caller to commit
    with more of its own (the command's stats)."""
    suffix = check_writer(path)
    check_encoding(encoding)
    aovs = as_passes(aovs, as_radiance(image).shape[:2])
    for name, values in aovs.items():
        if suffix != ".exr":
            files.add(beside(path, name, ".pfm"), pfm_bytes(values))
        if previews:
            files.add(beside(path, name, ".png"), preview_png(name, values))
    add_image(files, path, image, encoding, exr_channels(aovs) if suffix == ".exr" else None)


def pass_pixel_bytes(name: str) -> int:
    """Host bytes a pixel of pass `name` as passes_of makes it: one float32 or int32, or three
    float32."""
    return 4 if name in SCALAR_PASSES else 12


# Host bytes a pixel, beside the passes, of each stage that makes or writes them (tracemalloc's
# figures; tests/test_passes.py checks the sum against a render and its write). The passes
# kernel's raw outputs, held while passes_of reads them: a float4 or int4 each.
RAW_PASS_BYTES = 16 * len(PASS_OUTPUTS)
# object_indices' temporaries: the references' kinds and indices (int32 each), a kind's three
# masks, and the indices and objects it gathers (int32 each).
OBJECT_PASS_TEMPORARY_BYTES = 4 + 4 + 3 + 4 + 4
# clray.denoise.denoise's float32 images at OIDN's call: the colour and the output, and each
# guide's clipped copy and its denoised copy, and the output's crop copied out of its padded
# frame; the guide filters keep the guides' after it. All but the crop are padded 16 px on
# each side (clray.denoise.PAD), which a large image's pixels do not notice (1920x1080: 5 %).
DENOISE_WORK_BYTES = 12 * (3 + 2 * len(DENOISE_GUIDES))
DENOISE_KEPT_BYTES = 12 * 2 * len(DENOISE_GUIDES)


def passes_host_bytes(aovs: tuple[str, ...], denoise: bool, suffix: str) -> int:
    """About the most host memory a pixel that tracing the passes `aovs` (and the denoiser's
    guides with `denoise`) and writing them beside an image of `suffix` adds to the image's
    own (clray.image_io.image_host_bytes): the largest of making the passes (the raw outputs
    beside them), denoising (the denoiser's images beside them) and writing (the passes kept,
    with a PFM's copies of the largest, or OpenEXR's float32 channels of them).
    With `denoise`, the render's noisy image is kept beside the denoised one. OIDN's own
    buffers come on top."""
    traced = aovs + tuple(name for name in DENOISE_GUIDES if denoise and name not in aovs)
    if not traced:
        return 0
    made = sum(pass_pixel_bytes(name) for name in traced)
    kept = sum(pass_pixel_bytes(name) for name in aovs)
    making = RAW_PASS_BYTES + made + (OBJECT_PASS_TEMPORARY_BYTES if "object" in traced else 0)
    denoising = made + DENOISE_WORK_BYTES if denoise else 0
    if suffix == ".exr":  # exr_channels' copies; OpenEXR writes the file from them
        write = kept
    else:  # pfm_bytes: a float32 copy of an integer pass, its rows flipped, their bytes
        write = max((pass_pixel_bytes(name) * (3 if name in INDEX_PASSES else 2)
                     for name in aovs), default=0)
    writing = kept + write + (DENOISE_KEPT_BYTES if denoise else 0)
    return max(making, denoising, writing) + (12 if denoise else 0)
