"""POV-Ray 3.7 on the render benchmark's scenes: its trace time, for comparison with clray's kernel.

benchmarks/povray/ holds POV-Ray versions of scenes/spheres.toml (spheres.pov) and of the
generated mesh scene (bumpy.pov, whose mesh2 `write_mesh_pov` writes from the generator's OBJ).
`bench.py --povray auto` runs them through `Interleaved`, one POV-Ray trace after each timed clray
render at the same samples per pixel: 1 (no antialiasing) and, by default, 16 (`+AM1 +A0.0 +R4`),
after one untimed warm-up trace at each count.
Only POV-Ray's own statistics are used: its trace time, with the parse time apart.

Imported by bench.py from its file (benchmarks/ is not a package).
"""

from __future__ import annotations

import math
import re
import shutil
import statistics
import subprocess
from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent
POV_DIR = HERE / "povray"
# The POV-Ray file of each benchmark scene, by bench.py's scene name.
POV_FILES = {"spheres": "spheres.pov", "mesh": "bumpy.pov"}
MESH_INCLUDE = "bumpy_mesh.inc"

# "Trace Time: 0 hours 0 minutes 1 seconds (1.395 seconds)\n using 2 thread(s) with 2.623
# CPU-seconds total": the wall time of that phase, then the CPU time of its threads.
_TIMES = {"parse": "Parse Time", "trace": "Trace Time"}
_TIME = r"{}:.*?\(([0-9.]+) seconds\)\s*using \d+ thread\(s\) with ([0-9.]+) CPU-seconds"
_COUNTS = {"traced": "Rays", "reflected": "Reflected Rays", "shadow_tests": "Shadow Ray Tests"}
# "Pixels:  15330   Samples:  230400   Smpls/Pxl: 15.03": the antialiasing samples (0 without
# antialiasing). Smpls/Pxl divides by POV-Ray's pixel count, which with antialiasing counts
# more pixels than the image has (those it traces again for its neighbour tests), so the image's
# own size divides here.
_SAMPLES = r"^Pixels:\s+\d+\s+Samples:\s+(\d+)"
# POV-Ray's Antialias_Depth (+R) is 1 to 9; method 1 samples a pixel on a depth x depth grid.
MAX_AA_DEPTH = 9


def available() -> bool:
    return shutil.which("povray") is not None


def antialias_options(samples: int) -> list[str]:
    """POV-Ray's options for `samples` camera rays a pixel: `-A` for 1; otherwise non-adaptive
    supersampling (method 1) of every pixel (threshold 0.0) on a grid of sqrt(samples) squared,
    the counterpart of clray's stratified samples. `samples` must be 1 or a square up to 81."""
    if samples == 1:
        return ["-A"]
    depth = math.isqrt(max(samples, 0))
    if depth * depth != samples or not 2 <= depth <= MAX_AA_DEPTH:
        raise ValueError(f"POV-Ray samples a pixel on a square grid: expected 1 or a square "
                         f"from 4 to {MAX_AA_DEPTH ** 2}, got {samples}")
    return ["+AM1", "+A0.0", f"+R{depth}"]


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, normals and 0-based faces of an OBJ in make_mesh_scene.py's form (`v`, `vn`,
    `f a//a b//b c//c`): not a general OBJ reader."""
    rows: dict[str, list[str]] = {"v": [], "vn": [], "f": []}
    with path.open(encoding="ascii") as f:
        for line in f:
            key, _, rest = line.partition(" ")
            if key in rows:
                rows[key].append(rest)
    vertices = np.array(" ".join(rows["v"]).split(), dtype=np.float64).reshape(-1, 3)
    normals = np.array(" ".join(rows["vn"]).split(), dtype=np.float64).reshape(-1, 3)
    refs = np.array(" ".join(rows["f"]).replace("//", " ").split(), dtype=np.int64).reshape(-1, 6)
    # mesh2 without normal_indices takes each vertex's normal from the same index.
    if not np.array_equal(refs[:, 0::2], refs[:, 1::2]):
        raise ValueError(f"{path.name}: faces must use the vertex's own normal (a//a)")
    return vertices, normals, refs[:, 0::2] - 1


def write_mesh_pov(obj_scene_dir: Path, out_dir: Path) -> Path:
    """Write `out_dir`/bumpy_mesh.inc, a mesh2 of `obj_scene_dir`/bumpy.obj (the mesh clray
    renders, numbers as written), and a copy of bumpy.pov beside it; return that copy's path."""
    vertices, normals, faces = _read_obj(obj_scene_dir / "bumpy.obj")
    out_dir.mkdir(parents=True, exist_ok=True)
    with (out_dir / MESH_INCLUDE).open("w", encoding="ascii") as f:
        f.write("#declare Bumpy_Mesh = mesh2 {\n")
        for block, values, fmt in (("vertex_vectors", vertices, ",<%.9g,%.9g,%.9g>"),
                                   ("normal_vectors", normals, ",<%.9g,%.9g,%.9g>"),
                                   ("face_indices", faces, ",<%d,%d,%d>")):
            f.write(f"{block} {{ {len(values)}\n")
            np.savetxt(f, values, fmt=fmt)
            f.write("}\n")
        f.write("}\n")
    return Path(shutil.copy(POV_DIR / POV_FILES["mesh"], out_dir))


def trace_time(pov_file: Path, width: int, height: int, threads: int = 2,
               samples: int = 1) -> dict:
    """Render `pov_file` once, in its own folder, with `samples` camera rays a pixel
    (`antialias_options`), and return `read_statistics` of its log with `threads` and `image`
    (the PNG it wrote) added."""
    image = pov_file.with_name(f"{pov_file.stem}_{samples}spp.png")
    # Every option that changes the work is given, so povray.ini settings cannot. The working
    # folder is the scene's: POV-Ray's default I/O restrictions allow reads and writes there.
    cmd = ["povray", pov_file.name, f"+W{width}", f"+H{height}", "-D",
           *antialias_options(samples), "+Q9", f"+WT{threads}", "+FN", f"+O{image.name}",
           "File_Gamma=1.0"]
    proc = subprocess.run(cmd, cwd=pov_file.parent, capture_output=True, text=True)
    log = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise RuntimeError(f"povray failed on {pov_file.name} ({proc.returncode}):\n{log[-2000:]}")
    return {**read_statistics(log, width * height, pov_file.name), "threads": threads,
            "image": image}


def read_statistics(log: str, pixels: int, name: str) -> dict:
    """POV-Ray's figures from the log of a render of `pixels` pixels (`name` for messages):
    `version`, `parse_s`, `trace_s` (wall), `parse_cpu_s`, `trace_cpu_s` (all threads), `rays`
    (its ray counts) and `samples_per_pixel` (its antialiasing samples over the image's pixels;
    1 without antialiasing)."""
    version = re.search(r"Ray Tracer Version (\S+)", log)
    result: dict = {"version": version.group(1) if version else None}
    for key, label in _TIMES.items():
        found = re.search(_TIME.format(label), log)
        if found is None:
            raise RuntimeError(f"povray printed no '{label}' for {name}")
        result[f"{key}_s"], result[f"{key}_cpu_s"] = float(found.group(1)), float(found.group(2))
    # POV-Ray leaves out a counter that stayed 0 (no "Reflected Rays" without reflection).
    result["rays"] = {key: int(m.group(1)) if (m := re.search(rf"^{label}:\s+(\d+)", log, re.M))
                      else 0 for key, label in _COUNTS.items()}
    found = re.search(_SAMPLES, log, re.M)
    aa_samples = int(found.group(1)) if found else 0
    result["samples_per_pixel"] = aa_samples / pixels if aa_samples else 1.0
    return result


def mean_abs_diff(png: Path, clray_image: np.ndarray) -> float:
    """Mean over pixels and channels of |POV-Ray - clray|, both linear in [0, 1], clray clamped
    as its PNG output is."""
    pov = np.asarray(Image.open(png).convert("RGB"), dtype=np.float64) / 255.0
    return float(np.mean(np.abs(pov - np.clip(clray_image, 0.0, 1.0))))


class Interleaved:
    """POV-Ray traces of one benchmark scene, taken one at a time between clray's renders, at
    one or more sample counts (camera rays a pixel), each with its own runs."""

    def __init__(self, scene: str, clray_scene: Path, work_dir: Path, width: int, height: int,
                 threads: int) -> None:
        work_dir.mkdir(parents=True, exist_ok=True)
        if scene == "mesh":
            self.pov_file = write_mesh_pov(clray_scene.parent, work_dir)
        else:
            self.pov_file = Path(shutil.copy(POV_DIR / POV_FILES[scene], work_dir))
        self.scene, self.width, self.height, self.threads = scene, width, height, threads
        self.runs: dict[int, list[dict]] = {}

    def warm_up(self, samples: int = 1) -> None:
        """One untimed trace at `samples`, as clray renders once before its timed renders: the
        first run also pays POV-Ray's reads of its program and the scene's files."""
        trace_time(self.pov_file, self.width, self.height, self.threads, samples)

    def trace(self, samples: int = 1) -> None:
        self.runs.setdefault(samples, []).append(
            trace_time(self.pov_file, self.width, self.height, self.threads, samples))

    def summary(self, samples: int, kernel_s: float, clray_image: np.ndarray) -> dict:
        """One entry of a scene's `povray` object in bench.py's JSON (benchmarks/README.md):
        the traces at `samples` against clray's median `kernel_s` at as many samples."""
        runs = self.runs[samples]
        trace_runs = [run["trace_s"] for run in runs]
        trace_s = statistics.median(trace_runs)
        last = runs[-1]
        return {
            "version": last["version"],
            "threads": self.threads,
            "file": str((POV_DIR / POV_FILES[self.scene]).relative_to(HERE.parent)),
            "options": antialias_options(samples),
            "samples_per_pixel": last["samples_per_pixel"],
            "trace_s_runs": trace_runs,
            "trace_s": trace_s,
            "parse_s": statistics.median(run["parse_s"] for run in runs),
            "trace_cpu_s": statistics.median(run["trace_cpu_s"] for run in runs),
            "ratio_trace_over_kernel": trace_s / kernel_s,
            "rays": last["rays"],
            "mean_abs_diff": mean_abs_diff(last["image"], clray_image),
        }
