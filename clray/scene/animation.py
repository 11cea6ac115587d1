"""The [animation] table: numeric values of a scene keyframed over a sequence of frames.

A track names one value of the scene by its key path as the loader reports it
(`camera.position`, `materials.red.reflect`, `objects[2].center`,
`objects[0].transform.rotate`) and gives its value at some frames; every other frame takes a
value interpolated between them, linearly or along a Catmull-Rom spline. A frame's scene is
the file's data with each track's value put in and loaded again, so it meets every check a scene
file meets (docs/scene_format.md, "Animation").
"""

from __future__ import annotations

import bisect
import copy
import itertools
import re
from dataclasses import dataclass
from typing import Any

from clray.scene import limits as L
from clray.scene.values import Values

ANIMATION_KEYS = ("frames", "fps", "interpolation", "tracks")
TRACK_KEYS = ("key", "frames", "values", "interpolation")
INTERPOLATIONS = ("linear", "catmull-rom")
MAX_FRAMES = 1_000_000
MAX_FPS = 1000.0

# An index is at most 9 ASCII digits, beyond any array's length (MAX_OBJECTS, MAX_LIGHTS):
# int() of more than 4300 digits raises ValueError, and \d takes other scripts' digits too.
_INDEX_DIGITS = r"[0-9]{1,9}"
_SEGMENT = re.compile(rf"([A-Za-z0-9_-]+)((?:\[{_INDEX_DIGITS}\])*)")
_INDEX = re.compile(rf"\[({_INDEX_DIGITS})\]")

Path = tuple[str | int, ...]
Value = float | list[float]


@dataclass(frozen=True)
class Track:
    key: str  # as written
    path: Path  # table keys (str) and array indices (int) from the top of the scene
    frames: tuple[int, ...]  # strictly increasing
    values: tuple[Value, ...]  # one per frame: all numbers, or all lists of one length
    interpolation: str

    def at(self, frame: int) -> Value:
        """The value at `frame`: a keyframe's own value exactly at its frame, the first before
        it and the last after it, else interpolated."""
        frames, values = self.frames, self.values
        if frame <= frames[0]:
            return values[0]
        if frame >= frames[-1]:
            return values[-1]
        i = bisect.bisect_right(frames, frame) - 1
        if frames[i] == frame:
            return values[i]
        v0, v1 = _vector(values[i]), _vector(values[i + 1])
        span = frames[i + 1] - frames[i]
        s = (frame - frames[i]) / span
        if self.interpolation == "linear":
            out = [a + (b - a) * s for a, b in zip(v0, v1, strict=True)]
        else:
            # Hermite form of Catmull-Rom over uneven key spacing: the tangent at a key is the
            # slope between its neighbours (one-sided at the ends), per frame, scaled by the
            # span, so that a path keeps its speed through keys at uneven frames.
            m0 = self._slope(i)
            m1 = self._slope(i + 1)
            h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
            h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
            out = [h00 * a + h10 * span * ma + h01 * b + h11 * span * mb
                   for a, b, ma, mb in zip(v0, v1, m0, m1, strict=True)]
        return out if isinstance(values[0], list) else out[0]

    def _slope(self, i: int) -> list[float]:
        lo, hi = max(i - 1, 0), min(i + 1, len(self.frames) - 1)
        a, b = _vector(self.values[lo]), _vector(self.values[hi])
        return [(y - x) / (self.frames[hi] - self.frames[lo]) for x, y in zip(a, b, strict=True)]


@dataclass(frozen=True)
class Animation:
    frames: int  # frames 0 .. frames - 1
    fps: float
    tracks: tuple[Track, ...]

    def data_at(self, data: dict, frame: int) -> dict:
        """The scene data (without its [animation] table) with every track's value at `frame`
        put in; `data` itself is left as it was."""
        out = copy.deepcopy({k: v for k, v in data.items() if k != "animation"})
        for track in self.tracks:
            put(out, track.path, track.at(frame))
        return out


def _vector(value: Value) -> list[float]:
    return value if isinstance(value, list) else [value]


def parse_path(text: str) -> Path | None:
    """`camera.position`, `objects[2].transform.rotate` -> ('camera', 'position'),
    ('objects', 2, 'transform', 'rotate'); None if `text` is not such a path."""
    path: list[str | int] = []
    for part in text.split("."):
        match = _SEGMENT.fullmatch(part)
        if not match:
            return None
        path.append(match.group(1))
        path += [int(i) for i in _INDEX.findall(match.group(2))]
    return tuple(path)


def put(data: Any, path: Path, value: Value) -> None:
    """Set the value at `path`. Every table and array on the way must exist; the last key may
    be new (a value left at its default in the file). KeyError names the first missing step."""
    for depth, step in enumerate(path[:-1]):
        data = _step(data, step, path[:depth + 1])
    last = path[-1]
    if isinstance(last, int):
        _step(data, last, path)
        data[last] = value
    elif isinstance(data, dict):
        data[last] = value
    else:
        raise KeyError(path)


def _step(data: Any, step: str | int, where: Path) -> Any:
    if isinstance(step, int) and isinstance(data, list) and step < len(data):
        return data[step]
    if isinstance(step, str) and isinstance(data, dict) and step in data:
        return data[step]
    raise KeyError(where)


def show_path(path: Path) -> str:
    text = ""
    for step in path:
        text += f"[{step}]" if isinstance(step, int) else f".{step}" if text else step
    return text


# The [render] table's integers and integer choices (png_bits), and a mesh's or spheres
# object's per-face or per-sphere material indices (`material_index`, or one of them).
_INTEGER_RENDER_PATHS = {("render", name) for name in L.RENDER_INTEGERS} | {
    ("render", name) for name, allowed in L.RENDER_CHOICES.items()
    if all(isinstance(a, int) for a in allowed)}


def _integer(path: Path) -> bool:
    """Whether the loader takes only integers at `path`."""
    names = [step for step in path if isinstance(step, str)]  # a path starts with a name
    return path in _INTEGER_RENDER_PATHS or names[-1] == "material_index"


def parse_animation(spec: dict, v: Values) -> Animation:
    """The [animation] table checked by the scene's value checks (errors name `animation.*`
    keys). The tracks' paths and values are checked against the scene by the loader itself."""
    v.keys(spec, "animation", ANIMATION_KEYS, ("frames",))
    frames = v.integer(spec["frames"], "animation.frames", 1, MAX_FRAMES)
    fps = v.bounded(spec.get("fps", 24.0), "animation.fps", 0, MAX_FPS)
    if fps == 0:
        raise v.error("animation.fps", "must be > 0, got 0")
    default = v.choice(spec.get("interpolation", "linear"), "animation.interpolation",
                            INTERPOLATIONS)
    tracks = []
    keyframes = 0
    for i, track in enumerate(v.items(spec.get("tracks", []), "animation.tracks",
                                           L.MAX_TRACKS)):
        key = f"animation.tracks[{i}]"
        tracks.append(_track(track, key, frames, default, v))
        keyframes += len(tracks[-1].frames)
        if keyframes > L.MAX_KEYFRAMES:
            raise v.error(key, f"over the limit of {L.MAX_KEYFRAMES} keyframes in all tracks")
    return Animation(frames=frames, fps=fps, tracks=tuple(tracks))


def _track(spec: dict, key: str, n_frames: int, default: str, v: Values) -> Track:
    v.keys(spec, key, TRACK_KEYS, ("key", "frames", "values"))
    name = v.string(spec["key"], f"{key}.key")
    path = parse_path(name)
    if path is None:
        raise v.error(f"{key}.key", f"expected a key path such as camera.position or "
                           f"objects[0].center, got {name!r:.60}")
    if _integer(path):
        raise v.error(f"{key}.key", f"{name} cannot be animated: it takes integers, and a "
                      "track's values are real numbers (1 is read as 1.0, and between keys "
                      "they take fractions)")
    fkey, vkey = f"{key}.frames", f"{key}.values"
    raw_frames = spec["frames"]
    if not isinstance(raw_frames, list) or not raw_frames:
        raise v.error(fkey, "expected a non-empty array of frame numbers")
    frames = tuple(v.integer(f, f"{fkey}[{j}]", 0, n_frames - 1)
                   for j, f in enumerate(raw_frames))
    if any(b <= a for a, b in itertools.pairwise(frames)):
        raise v.error(fkey, "must be strictly increasing")
    raw_values = spec["values"]
    if not isinstance(raw_values, list) or len(raw_values) != len(frames):
        raise v.error(vkey, f"expected one value per keyframe ({len(frames)})")
    values: list[Value] = []
    for j, value in enumerate(raw_values):
        if isinstance(value, list):
            values.append(list(v.numbers(value, f"{vkey}[{j}]", len(value))))
        else:
            values.append(v.number(value, f"{vkey}[{j}]"))
        shape = len(values[-1]) if isinstance(values[-1], list) else None
        first = len(values[0]) if isinstance(values[0], list) else None
        if shape != first or shape == 0:
            raise v.error(f"{vkey}[{j}]", "expected the shape of values[0] (all numbers, "
                               "or all arrays of one length)")
    interpolation = v.choice(spec.get("interpolation", default), f"{key}.interpolation",
                                  INTERPOLATIONS)
    return Track(key=name, path=path, frames=frames, values=tuple(values),
                 interpolation=interpolation)
