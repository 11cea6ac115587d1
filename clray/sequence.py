"""Sequences of frames: a scene file's [animation] table turned into one scene per frame, the
frame numbers and file names of `clray render --frames`, and the frames rendered in a loop."""

from __future__ import annotations

import operator
import os
import re
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from clray.device.context import queue_for
from clray.device.pack import SceneGeometry, pack_geometry
from clray.errors import SceneError, SettingsError
from clray.passes import exr_holds_passes, pass_paths
from clray.render import (
    GeometrySource,
    RenderResult,
    RenderSettings,
    progress_parts,
    render,
    settings_or_default,
)
from clray.scene.animation import Animation
from clray.scene.files import KeptFiles
from clray.scene.load import read_scene_data, scene_and_animation, scene_from_dict
from clray.scene.model import Scene
from clray.shapes import SHAPE_KINDS

# The object types a track may move without each frame packed afresh where they have no
# transform: each is one record of its kind's array in every frame, made again as it moves.
MOVABLE_TYPES = frozenset({"plane", *SHAPE_KINDS})

if TYPE_CHECKING:
    import pyopencl as cl

    from clray.device.policy import DevicePlan


@dataclass(frozen=True)
class Sequence:
    """An animated scene file: its data as parsed, its checked [animation] table, and the files
    it names (included scenes, meshes, textures) as they were read then, each mesh and MTL
    file parsed and each image decoded once for all frames. Picklable: a Dask cluster gets it
    once (the bytes, not what they parse to) and makes each frame's scene where it renders
    it, with no file."""

    path: Path  # absolute: the names in `data` are relative to its folder, wherever it is used
    data: dict
    animation: Animation
    files: KeptFiles = field(default_factory=KeptFiles)
    # Unless each frame packs afresh: frame 0's objects packed for all the frames this
    # process renders, with the device, BVH width and knobs they were packed for
    # (packed_objects). Not pickled: a Dask worker packs its own.
    _packed: tuple[tuple, SceneGeometry] | None = field(default=None, init=False, repr=False,
                                                       compare=False)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_packed": None}

    def packs_each_frame(self) -> bool:
        """Whether a track keys a value that each frame must be packed afresh for: a group's
        (groups.g.objects[0].radius), or an object's but an instance's (its transform, an
        inline material) and a plane's or shape's without a transform table (the center of
        a sphere without one moves with the packing kept; a mesh's transform, or a sphere's
        center beside its transform, is packed afresh). A mesh's and a triangle's vertices
        are taken once for all frames, with their normals; a transform can make a shape an
        instance of its own group (an ellipsoid) in some frames only. Otherwise each frame
        moves frame 0's packing (packed_objects)."""
        objects = self.data.get("objects")

        def moved_in_place(path: tuple) -> bool:
            # load_sequence checked every path against the data: objects[N] is a table.
            spec = objects[path[1]] if path[0] == "objects" else {}
            return spec.get("type") == "instance" or (spec.get("type") in MOVABLE_TYPES
                                                      and "transform" not in spec)
        return any(track.path[0] in ("objects", "groups") and not moved_in_place(track.path)
                   for track in self.animation.tracks)

    def frame_geometry(self) -> GeometrySource | None:
        """What gives each frame's render its objects packed (render's geometry_for), or None
        where each frame is packed afresh (packs_each_frame)."""
        return None if self.packs_each_frame() else self.packed_objects

    def forget_packed_objects(self) -> None:
        """Lets go of the objects packed for the frames (packed_objects packs them again)."""
        object.__setattr__(self, "_packed", None)

    def packed_objects(self, device: cl.Device, plan: DevicePlan) -> SceneGeometry:
        """Frame 0's objects packed for a render on `device` as `plan` packs them: once, and
        again only for another device, BVH width or knobs (one packing kept at a time). Each
        frame's render moves them to its own eye, with the BVH refitted instead of built
        (clray.device.pack.pack_geometry; docs/distributed.md). Frame 0's whichever frames
        render: a frame's image does not depend on how a run splits the frames (--resume,
        Dask's tasks). Instances and shapes moved by tracks are placed anew in each frame, the
        groups' trees kept; where that makes the scene's tree too costly, the frame is packed
        afresh (clray.device.pack.REFIT_COST_LIMIT)."""
        key = (device.int_ptr, plan.bvh_width, plan.tuning)
        if self._packed is None or self._packed[0] != key:
            self.forget_packed_objects()  # its arrays go before the new ones
            geometry = pack_geometry(self.scene(0), bvh_width=plan.bvh_width,
                                     queue=queue_for(device), tuning=plan.tuning)
            object.__setattr__(self, "_packed", (key, geometry))
        return self._packed[1]

    def check_frame(self, frame: int) -> int:
        """`frame` if the animation has it; SettingsError if not (a track would hold its first
        or last value there, a frame the animation does not have)."""
        last = self.animation.frames - 1
        try:
            number = operator.index(frame)
        except TypeError:
            raise SettingsError(f"frame: expected a frame number, 0 to {last}, got "
                                f"{type(frame).__name__}") from None
        if not 0 <= number <= last:
            raise SettingsError(f"frame {number}: the animation has frames 0 to {last}")
        return number

    def scene(self, frame: int) -> Scene:
        """The scene at `frame`; SceneError names the key and the frame where an interpolated
        value is out of range (a Catmull-Rom curve may overshoot its keys)."""
        frame = self.check_frame(frame)
        try:
            with self.files.used():
                return scene_from_dict(self.animation.data_at(self.data, frame), self.path)
        except SceneError as err:
            raise SceneError(err.file, err.key, f"{err.message} (animated, frame {frame})"
                             ) from None


def load_sequence(path: str | os.PathLike) -> Sequence:
    """Read and check an animated scene file: the scene, its [animation] table and each
    keyframe by the loader's rules, keeping the files they read; SceneError if it has no
    [animation] table."""
    path = Path(path).absolute()
    data = read_scene_data(path)
    files = KeptFiles()
    with files.used():
        animation = scene_and_animation(data, path)[1]
    if animation is None:
        raise SceneError(path, "animation", "missing: --frames renders an [animation] table "
                         "(docs/scene_format.md)")
    return Sequence(path, data, animation, files)


def parse_frames(text: str) -> range:
    """`A:B` (frames A to B - 1, as Python slices), `A:` (A to the last), `N` (one frame);
    bounds are checked against the animation by frames_in."""
    start, colon, stop = text.partition(":")
    try:
        first = int(start) if start else 0
        end = (int(stop) if stop else None) if colon else first + 1
    except ValueError:
        raise SettingsError(f"--frames: expected A:B, A: or N (frame numbers), got "
                            f"{text[:40]!r}") from None
    if first < 0 or (end is not None and end <= first):
        raise SettingsError(f"--frames: expected 0 <= A < B, got {text[:40]!r}")
    return range(first, -1 if end is None else end)


def frames_in(frames: range, animation: Animation) -> range:
    """`frames` (stop -1: to the last frame) within the animation's 0 .. frames - 1."""
    last = animation.frames - 1
    if frames.stop == -1:
        # `A:` past the last frame would be no frames at all, not an error, without this.
        if frames.start > last:
            raise SettingsError(f"--frames: the animation has frames 0 to {last}, asked for "
                                f"{frames.start} to the last")
        return range(frames.start, animation.frames)
    if frames.stop - 1 > last:
        raise SettingsError(f"--frames: the animation has frames 0 to {last}, asked for up to "
                            f"{frames.stop - 1}")
    return frames


# A printf conversion as Python's % takes it, with the width and precision that make its text
# that long; `%%` too, so that the `%5d` of `%%5d` (a literal `%` and `5d`) is not taken for
# one. Only whole conversions: `a%1000.png` has none (`p` is no conversion type), and is a
# still's name as it stands.
_CONVERSION = re.compile(r"%%|%[-+ #0]*(\d*)(?:\.(\d*))?[hlL]?[diouxXeEfFgGcrsa]")
# No file name is longer than this (NAME_MAX on the usual file systems).
_MAX_NAME = 255


def frame_path(pattern: Path, frame: int) -> Path:
    """The file of `frame`: `pattern` with its printf-style number filled in; a name without
    one (a single frame) as it is. SettingsError for a width or precision past a file name's
    length: `%99999999999d` would build a string of that many characters first."""
    for conversion in _CONVERSION.finditer(str(pattern)):
        if any(len(digits) > 3 or int(digits) > _MAX_NAME
               for digits in conversion.groups() if digits):
            raise SettingsError(f"-o {pattern}: a frame number's width is at most {_MAX_NAME} "
                                f"(a file name's length), got {conversion.group()}")
    try:
        return Path(str(pattern) % frame)
    except (TypeError, ValueError):
        return pattern


def check_pattern(pattern: Path, n_frames: int) -> None:
    """Each frame needs a file of its own: a printf-style frame number (`frame_%04d.png`), one
    and decimal, which names every frame apart and holds no path separator: %.1e gave frames
    100 and 101 one name, %c a `/` for frame 47."""
    numbers = [c.group() for c in _CONVERSION.finditer(str(pattern)) if c.group() != "%%"]
    if len(numbers) > 1 or any(number[-1] not in "diu" for number in numbers):
        raise SettingsError(f"-o {pattern}: expected one decimal frame number (%d, %04d, %i or "
                            f"%u), got {' '.join(numbers)}")
    if n_frames > 1 and frame_path(pattern, 0) == frame_path(pattern, 1):
        raise SettingsError(f"-o {pattern}: several frames need a frame number in the name, "
                            "such as out/frame_%04d.png")


def frame_files(pattern: Path, frame: int, aovs: tuple[str, ...], previews: bool) -> list[Path]:
    """The files that rendering `frame` writes: its image and its passes' files beside it."""
    image = frame_path(pattern, frame)
    return [image, *pass_paths(image, aovs, previews)]


def frames_to_render(frames: range, pattern: Path, resume: bool, aovs: tuple[str, ...] = (),
                     previews: bool = False) -> list[int]:
    """The frames to render: with `resume`, those not complete yet. A frame is complete when its
    image and each of its passes' files is a regular file: each is written to a temporary name
    and renamed, so one that exists is whole. A folder of that name is not a frame, and a frame
    written without the passes asked for now lacks them."""
    return [f for f in frames if not (resume and frame_complete(pattern, f, aovs, previews))]


def frame_complete(pattern: Path, frame: int, aovs: tuple[str, ...], previews: bool) -> bool:
    """Whether `frame`'s files are all there whole, its passes included: beside the image, or
    as an OpenEXR image's layers."""
    files = frame_files(pattern, frame, aovs, previews)
    if not all(path.is_file() for path in files):
        return False
    image = files[0]
    return not aovs or image.suffix.lower() != ".exr" or exr_holds_passes(image, aovs)


def render_frames(sequence: Sequence, frames: Iterable[int], settings: RenderSettings | None,
                  done: Callable[[int, RenderResult], None]) -> None:
    """Render frames one after another in this process, `done(frame, result)` after each; the
    stats' load_s is the time the frame's scene took to make from the file's data.
    settings.progress hears the pixel-samples of all the frames, each frame's as it renders
    after those of the frames before it."""
    settings = settings_or_default(settings)
    frames = [sequence.check_frame(f) for f in frames]  # each, before any is rendered
    reports = progress_parts(settings.progress, len(frames))
    try:
        for frame, report in zip(frames, reports, strict=True):
            started = time.perf_counter()
            scene = sequence.scene(frame)
            load_s = time.perf_counter() - started
            result = render(scene, replace(settings, progress=report),
                            geometry_for=sequence.frame_geometry())
            result.stats["load_s"] = load_s
            done(frame, result)
    finally:
        # The frames' packing goes with the run, not with the sequence a caller may keep.
        sequence.forget_packed_objects()
