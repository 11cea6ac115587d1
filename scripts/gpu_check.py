"""The steps behind `bash scripts/gpu_check.sh OUT_DIR [--cpu]` (docs/gpu.md).

One prepared run for a GPU machine reached without a network: it installs clray's needs from the
wheels in .gpu-wheels/ (scripts/gpu_wheels.sh fills it here), makes NVIDIA's OpenCL driver
visible to pyopencl's ICD loader, and then, each step in processes of its own under a time
limit of its own, lists the devices, runs the kernel tests on the GPU, compares every example
scene's GPU image with the CPU image made beforehand, profiles the spheres scene and the
327,680-triangle mesh at 1920x1080 and 3840x2160 with 1 and 16 samples, times cold and warm
kernel builds and reads the driver's register and spill figures, and runs `clray tune`. Every
figure goes to OUT_DIR/gpu_check.json, rewritten after each step, so a run stopped at any point
keeps what it measured; the log to OUT_DIR/gpu_check.log.

`--cpu` runs the same steps on PoCL's CPU device at tiny sizes (CI does, through
tests/test_gpu_check.py), so that a first GPU run can fail only for GPU reasons.

This file imports nothing beyond the standard library: it runs before clray can be imported.
The steps that need clray are scripts/gpu_check_steps.py's subcommands.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"
STEPS_SCRIPT = SCRIPTS / "gpu_check_steps.py"
WHEELS_DIR = REPO / ".gpu-wheels"
REFERENCE_FILE = "cpu_reference.npz"

# What comes back from the GPU machine: at most 8 files, each under 16 MiB.
MAX_OUT_FILES = 8
MAX_OUT_BYTES = 15 * 2**20
JSON_NAME = "gpu_check.json"
LOG_NAME = "gpu_check.log"
TESTS_LOG_NAME = "kernel_tests.log"
TUNE_REPORT_NAME = "tune_report.md"
PNG_NAMES = ("scene_gpu.png", "scene_cpu.png", "scene_diff.png")  # gpu_check_steps.py's
# A child's output copied into the log: its head and tail lines.
LOG_HEAD_LINES = 40
LOG_TAIL_LINES = 120

# NVIDIA's OpenCL driver and where drivers put it (container runtimes mount it read-only under
# /usr/local/nvidia); `ldconfig -p` is asked too.
NVIDIA_OPENCL = "libnvidia-opencl.so.1"
DRIVER_FOLDERS = ("/usr/local/nvidia/lib64", "/usr/local/nvidia/lib",
                  "/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib")
SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
ICD_NAME = "nvidia.icd"
# The NVIDIA driver's own cache of built kernels may hold 4 GiB at most.
CUDA_CACHE_BYTES = 4 * 2**30

# The kernel tests that run first on the GPU (the rest of the device tests follow, by file
# name): layouts, intersections and renders against the reference, then the files of the
# fixes made after the first GPU run (docs/gpu.md), which by name would come last and be the
# first that a step at its limit leaves out.
PRIORITY_TESTS = ("test_layout.py", "test_device_fixture.py", "test_intersect.py",
                  "test_render.py", "test_camera.py", "test_mesh_render.py",
                  "test_packets.py", "test_passes.py", "test_profile.py", "test_torus.py",
                  "test_tune.py", "test_tuning.py",
                  "test_area_lights.py", "test_fresnel.py", "test_shadow_rays.py",
                  "test_instances.py", "test_wide.py", "test_bvh.py")
# Never from the kernel-test step: this check itself, and Oclgrind's (a CPU simulator).
NOT_KERNEL_TESTS = ("test_gpu_check.py", "test_oclgrind.py")


@dataclass(frozen=True)
class StepLimit:
    cap_s: float  # the most this step may take
    min_s: float  # what later steps keep back for it from the steps before


@dataclass(frozen=True)
class Mode:
    """The sizes and limits of one kind of run."""

    name: str  # "gpu" or "cpu"
    device_type: str  # the OpenCL device type the steps run on
    platform: str  # preferred platform, a substring of its name
    sizes: tuple[tuple[int, int], ...]
    spps: tuple[int, ...]
    mesh_subdivisions: int
    profile_repeat: int
    min_profile_s: float  # what the profiles step keeps back for each run still to come
    reference_size: tuple[int, int]  # --cpu renders its own references at this size
    tune_size: tuple[int, int]
    kernel_tests: tuple[str, ...]  # test files, in order; "*": every other one after them
    build_examples: bool  # the builds step builds every example scene's configuration too
    deadline_s: float
    limits: dict[str, StepLimit] = field(default_factory=dict)
    # `clray tune`: seconds of searching, the least and the most, and the seconds its
    # reference renders, confirmation and report take beside them (the first GPU run's were
    # 45; 15 more for a late trial or a slow report, since the tune writes its results only
    # at its end and a step stopped at its limit loses them).
    tune_budget_range: tuple[float, float] = (5.0, 150.0)
    tune_overhead_s: float = 60.0

    def tune_budget(self, limit: float) -> float:
        """Seconds of searching for `clray tune` in a step of `limit` seconds: what its
        reference renders, confirmation and report leave."""
        least, most = self.tune_budget_range
        return max(least, min(most, limit - self.tune_overhead_s))

    def tune_needs_s(self) -> float:
        """The least time the tune step can finish in: its least search and the rest."""
        return self.tune_budget_range[0] + self.tune_overhead_s


# The walks the profiles step measures beside the device's default.
PACKET_TRAVERSALS = ("sample_packet", "group_packet")

STEP_ORDER = ("setup", "icd", "devices", "kernel_tests", "references", "scenes", "mesh_scene",
              "profiles", "builds", "cpu_beside", "tune")

GPU_MODE = Mode(
    name="gpu", device_type="GPU", platform="NVIDIA",
    sizes=((1920, 1080), (3840, 2160)), spps=(1, 16), mesh_subdivisions=7, profile_repeat=3,
    min_profile_s=10.0,
    reference_size=(160, 90), tune_size=(1920, 1080),
    kernel_tests=(*PRIORITY_TESTS, "*"), build_examples=True,
    deadline_s=450.0,
    limits={"setup": StepLimit(60, 10), "icd": StepLimit(10, 1), "devices": StepLimit(45, 10),
            "kernel_tests": StepLimit(110, 20), "references": StepLimit(20, 5),
            "scenes": StepLimit(75, 20), "mesh_scene": StepLimit(40, 10),
            "profiles": StepLimit(130, 30), "builds": StepLimit(60, 15),
            # tune: the least a search of 5 s needs with its 60 s of renders and report.
            "cpu_beside": StepLimit(45, 10), "tune": StepLimit(100, 65)})

CPU_MODE = Mode(
    name="cpu", device_type="CPU", platform="Portable Computing Language",
    sizes=((64, 36),), spps=(1, 4), mesh_subdivisions=3, profile_repeat=1,
    min_profile_s=4.0,
    reference_size=(32, 18), tune_size=(64, 36),
    kernel_tests=("test_layout.py",), build_examples=False,
    deadline_s=420.0,
    # About three times what each step takes on 2 busy cores: a slow CI machine is no failure.
    limits={"setup": StepLimit(60, 10), "icd": StepLimit(10, 1), "devices": StepLimit(45, 10),
            "kernel_tests": StepLimit(90, 15), "references": StepLimit(120, 15),
            "scenes": StepLimit(90, 15), "mesh_scene": StepLimit(30, 5),
            "profiles": StepLimit(150, 20), "builds": StepLimit(120, 15),
            "cpu_beside": StepLimit(60, 10), "tune": StepLimit(60, 15)},
    # A search of 3 s at 64x36: the step took 5 s on 2 cores.
    tune_budget_range=(3.0, 3.0), tune_overhead_s=12.0)


# --- NVIDIA's OpenCL driver for pyopencl's ICD loader --------------------------------------

def ldconfig_listing() -> str:
    """`ldconfig -p`'s output, or "" where it cannot be run."""
    for exe in ("ldconfig", "/sbin/ldconfig", "/usr/sbin/ldconfig"):
        try:
            return subprocess.run([exe, "-p"], capture_output=True, text=True, timeout=10,
                                  check=False).stdout
        except (OSError, subprocess.SubprocessError):
            continue
    return ""


def libraries_in_listing(listing: str, name: str) -> list[Path]:
    """The paths `ldconfig -p` gives for the library `name` ("\\tNAME (libc6,x86-64) =>
    PATH" lines)."""
    found = []
    for line in listing.splitlines():
        left, sep, right = line.partition("=>")
        if sep and left.strip().split(" ")[0] == name:
            found.append(Path(right.strip()))
    return found


def find_nvidia_opencl(folders: Iterable[str | Path] = DRIVER_FOLDERS,
                       listing: str | None = None) -> tuple[Path | None, list[str]]:
    """NVIDIA's OpenCL driver library: libnvidia-opencl.so.1 in the first of `folders` that
    has it (or a versioned libnvidia-opencl.so.NNN there), else where `ldconfig -p` puts it.
    Also every place looked at, for the message that says there is none."""
    looked: list[str] = []
    for folder in map(Path, folders):
        looked.append(str(folder))
        exact = folder / NVIDIA_OPENCL
        if exact.exists():
            return exact, looked
        versioned = sorted(folder.glob("libnvidia-opencl.so.*[0-9]"))
        if versioned:
            return versioned[-1], looked
    looked.append("ldconfig -p")
    for path in libraries_in_listing(ldconfig_listing() if listing is None else listing,
                                     NVIDIA_OPENCL):
        if path.exists():
            return path, looked
    return None, looked


def icd_library(icd_file: Path) -> str:
    try:
        return icd_file.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return ""


def write_vendors(folder: Path, library: Path, system_vendors: Path = SYSTEM_VENDORS
                  ) -> list[Path]:
    """An ICD vendors folder for OCL_ICD_VENDORS: the system's .icd files (other drivers stay
    visible) less any that already names NVIDIA's OpenCL library, and nvidia.icd naming
    `library` by its absolute path (the driver's folder may be on no loader path). Returns
    the .icd files written."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    if system_vendors.is_dir():
        for icd in sorted(system_vendors.glob("*.icd")):
            if "libnvidia-opencl" in icd_library(icd) or icd.name == ICD_NAME:
                continue
            target = folder / icd.name
            shutil.copyfile(icd, target)
            written.append(target)
    nvidia = folder / ICD_NAME
    nvidia.write_text(f"{library.absolute()}\n", encoding="utf-8")
    written.append(nvidia)
    return written


def driver_version_from_name(library: Path) -> str | None:
    """580.159.03 from libnvidia-opencl.so.580.159.03 (the file the .so.1 link names)."""
    match = re.search(r"\.so\.(\d+\.\d+(?:\.\d+)?)$", library.resolve().name)
    return match.group(1) if match else None


# --- Wheels -------------------------------------------------------------------------------

def unzip_wheels(wheels: Sequence[Path], target: Path) -> None:
    """What `pip install --no-deps --target` does with these wheels, for a Python without pip:
    each wheel's files under `target`, a wheel's .data/purelib and .data/platlib folders
    merged into it, its scripts and headers left out."""
    target.mkdir(parents=True, exist_ok=True)
    for wheel in wheels:
        with zipfile.ZipFile(wheel) as archive:
            for info in archive.infolist():
                parts = info.filename.split("/")
                if parts[0].endswith(".data"):
                    if len(parts) < 3 or parts[1] not in ("purelib", "platlib"):
                        continue
                    parts = parts[2:]
                if not parts or not parts[-1] or ".." in parts:
                    continue
                dest = target.joinpath(*parts)
                dest.parent.mkdir(parents=True, exist_ok=True)
                with archive.open(info) as src, open(dest, "wb") as out:
                    shutil.copyfileobj(src, out)
                mode = info.external_attr >> 16
                if mode & 0o111:
                    dest.chmod(0o755)


def assemble_package(repo: Path, root: Path) -> Path:
    """clray as its wheel lays it out, under `root`: the clray package with the top-level
    kernels/ folder as clray/kernels (pyproject.toml's package-dir), beside a link to tests/
    (the suite imports `tests.reference_check`). Without setuptools, without a network."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    package = root / "clray"
    if package.exists():
        shutil.rmtree(package)
    shutil.copytree(repo / "clray", package, ignore=ignore)
    shutil.copytree(repo / "kernels", package / "kernels", ignore=ignore)
    tests = root / "tests"
    if not tests.exists():
        try:
            tests.symlink_to(repo / "tests", target_is_directory=True)
        except OSError:
            shutil.copytree(repo / "tests", tests, ignore=ignore)
    return package


def wheel_pythons(wheels: Iterable[Path]) -> set[str]:
    """The CPython versions ("3.12") the wheels of compiled code were built for, by their ABI
    tag (cp312); a pure wheel (none) or one of the stable ABI (abi3) names none."""
    found = set()
    for wheel in wheels:
        parts = wheel.name.removesuffix(".whl").split("-")
        if len(parts) < 5:
            continue
        for abi in parts[-2].split("."):
            match = re.fullmatch(r"cp(\d)(\d+)", abi)
            if match:
                found.add(f"{match.group(1)}.{match.group(2)}")
    return found


def python_version(python: str) -> str | None:
    """`python`'s version as major.minor, or None where it does not run."""
    try:
        done = subprocess.run([python, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                              capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or None


# --- Output limits ------------------------------------------------------------------------

def cap_file(path: Path, max_bytes: int = MAX_OUT_BYTES) -> bool:
    """Cut a text file that outgrew `max_bytes` to its head and tail; True where cut."""
    size = path.stat().st_size
    if size <= max_bytes:
        return False
    keep = max_bytes // 2 - 1024
    with open(path, "rb") as f:
        head = f.read(keep)
        f.seek(size - keep)
        tail = f.read()
    note = f"\n\n[... {size - 2 * keep} bytes cut to keep the file under {max_bytes} ...]\n\n"
    path.write_bytes(head + note.encode() + tail)
    return True


def head_and_tail(text: str, head: int = LOG_HEAD_LINES, tail: int = LOG_TAIL_LINES) -> str:
    lines = text.splitlines()
    if len(lines) <= head + tail:
        return text
    return "\n".join([*lines[:head], f"[... {len(lines) - head - tail} lines ...]",
                      *lines[-tail:]])


# --- Running children ---------------------------------------------------------------------

@dataclass
class ChildResult:
    cmd: list[str]
    rc: int | None
    seconds: float
    timed_out: bool
    output: str  # stdout and stderr together (stdout alone where it went to a file)

    @property
    def ok(self) -> bool:
        return self.rc == 0 and not self.timed_out


# How long a stopped child's process group has to end after SIGTERM, and after SIGKILL: at a
# step's time limit, and when the run itself is stopped (the shell's `timeout -k` leaves the
# driver 10 s for that and for writing its JSON and log).
STOP_WAITS_S = (5.0, 5.0)
STOP_WAITS_ON_SIGNAL_S = (3.0, 2.0)


def group_alive(pgid: int) -> bool:
    """Whether a process of group `pgid` still runs (a zombie waiting for its parent to read
    its exit does not)."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        entries = os.scandir("/proc")
    except OSError:
        return True  # no /proc: the group exists
    with entries:
        for entry in entries:
            if not entry.name.isdigit():
                continue
            try:
                with open(os.path.join(entry.path, "stat"), encoding="ascii",
                          errors="replace") as f:
                    stat = f.read()
            except OSError:
                continue  # ended meanwhile
            # pid (comm) state ppid pgrp ...: comm may hold spaces and parentheses.
            fields = stat[stat.rfind(")") + 2:].split()
            if len(fields) > 2 and fields[2] == str(pgid) and fields[0] not in ("Z", "X"):
                return True
    return False


def _stop_group(proc: subprocess.Popen, waits: tuple[float, float] = STOP_WAITS_S) -> None:
    """SIGTERM to the child's process group (pytest's workers, clray's build processes), then
    SIGKILL to what is left of it after waits[0] seconds; each time the child and every other
    process of its group have to end, not the child alone."""
    for sig, wait in zip((signal.SIGTERM, signal.SIGKILL), waits, strict=True):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            break  # the group is gone
        give_up = time.monotonic() + wait
        while True:
            done = proc.poll() is not None
            if done and not group_alive(proc.pid):
                return
            if time.monotonic() >= give_up:
                break
            time.sleep(0.05)
    try:
        proc.wait(timeout=1.0)
    except subprocess.TimeoutExpired:
        pass


# The file scripts/gpu_check.sh names for the running child's process group id.
GROUP_FILE_ENV = "GPU_CHECK_GROUP_FILE"


def note_group(pgid: int | None) -> None:
    """Write the running child's process group id to the file GPU_CHECK_GROUP_FILE names (an
    empty file once the group has ended). A child's group has a session of its own, so no
    signal to the driver's group reaches it: where the driver is SIGKILLed (the shell's
    `timeout -k`), the shell kills the group this file names."""
    path = os.environ.get(GROUP_FILE_ENV)
    if not path:
        return
    try:
        with open(path, "w", encoding="ascii") as f:
            f.write(f"{pgid}\n" if pgid else "")
    except OSError:
        pass


def run_child(cmd: Sequence[str], limit_s: float, *, env: dict[str, str], cwd: Path,
              output: Path, stdout: Path | None = None) -> ChildResult:
    """Run `cmd` in a new process session within `limit_s` seconds, its output appended to
    `output` (stdout to `stdout` instead, where given). Past the limit the whole process
    group is stopped, as it is when the child ends leaving processes of its group behind, and
    when this run is stopped meanwhile (Stopped, KeyboardInterrupt: the exception goes on)."""
    start = time.monotonic()
    offset = output.stat().st_size if output.exists() else 0
    with open(output, "ab") as out:
        sink = open(stdout, "wb") if stdout else out  # closed below
        try:
            proc = subprocess.Popen(list(cmd), cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                    stdout=sink, stderr=out, start_new_session=True)
            note_group(proc.pid)
            timed_out = False
            try:
                try:
                    rc: int | None = proc.wait(timeout=max(1.0, limit_s))
                except subprocess.TimeoutExpired:
                    timed_out = True
                    _stop_group(proc)
                    rc = proc.returncode
                else:
                    if group_alive(proc.pid):  # its children, left running
                        _stop_group(proc)
            except BaseException:  # this run stopped meanwhile, even while stopping the child
                _stop_group(proc, STOP_WAITS_ON_SIGNAL_S)
                raise
            finally:
                if not group_alive(proc.pid):
                    note_group(None)
        finally:
            if stdout:
                sink.close()
    with open(output, "rb") as f:
        f.seek(offset)
        text = f.read().decode("utf-8", errors="replace")
    return ChildResult(list(cmd), rc, time.monotonic() - start, timed_out, text)


# --- The kernel tests' per-test limit --------------------------------------------------------

# Each kernel test's limit (pytest-timeout), and how much sooner Python's faulthandler writes
# every thread's stack to the worker's stderr.
TEST_TIMEOUT_S = {"gpu": 60, "cpu": 120}
STACKS_BEFORE_TIMEOUT_S = 5


def kernel_test_limit_args(timeout_s: float) -> list[str]:
    """pytest's options for a per-test limit of `timeout_s`. pytest-timeout's thread method:
    a test hung in the driver (a clFinish that never returns) takes no signal, so the signal
    method would wait as long as it does. That method writes its stack dump to the terminal,
    which an xdist worker has not: the worker exits, pytest-xdist replaces it and records the
    test as an error ("worker 'gw0' crashed"), and the log would say no more. So pytest's
    faulthandler dumps every thread's stack a little before (`faulthandler_timeout`): from a
    thread of its own that needs no GIL, to the worker's stderr, which is the step's log."""
    stacks_at = max(timeout_s - STACKS_BEFORE_TIMEOUT_S, timeout_s / 2)
    return ["--timeout", f"{timeout_s:g}", "--timeout-method", "thread",
            "-o", f"faulthandler_timeout={stacks_at:g}"]


# --- The run --------------------------------------------------------------------------------

def read_json(path: Path) -> dict | list | None:
    """A step's result file, or None where there is none or it does not read (a child stopped
    while writing it, or before)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


class StepError(Exception):
    """A step's failure, said in one line."""


class Skip(Exception):
    """A step that cannot run here, said in one line."""


class Stopped(BaseException):
    """The run stopped by a signal: SIGTERM (the shell's `timeout`, the device tool), SIGINT
    (^C). A BaseException, so that no step's `except Exception` takes it for its own failure."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


# A step's status: "running" while it runs (what a JSON read mid-step, or left by a SIGKILL,
# says), then "ok", "skipped" (it cannot run here, for the reason its note gives: not a
# failure), "failed", "timeout" (stopped at its time limit, or not started for want of time)
# or "killed" (the run was stopped by a signal while it ran).
FAILING = ("failed", "timeout", "killed", "running")


@dataclass
class StepOutcome:
    status: str  # "ok", "skipped", "failed", "timeout" or "killed"
    note: str = ""


class Check:
    def __init__(self, out: Path, mode: Mode, *, wheels: Path | None, python: str,
                 work: Path, reference: Path | None = None,
                 test_workers: int | None = None) -> None:
        self.out = out
        self.test_workers = test_workers
        self.given_reference = reference
        self.mode = mode
        self.wheels = wheels
        self.python = python
        self.work = work
        self.started = time.monotonic()
        self.deadline = self.started + mode.deadline_s
        self.log_path = out / LOG_NAME
        self.json_path = out / JSON_NAME
        self.target: str | None = None  # the device spec the steps run on
        self.test_device: str | None = None  # the suite's id prefix for it (--cl-device)
        self.mesh_scene: Path | None = None
        self.step_end = float("inf")  # when the running step's limit runs out
        self.stopped_by: int | None = None  # the signal that stopped the run
        self.signals_stop = False  # while the steps run, a signal raises Stopped
        self.reference: Path | None = None
        self.data: dict = {
            "schema": 1,
            "mode": mode.name,
            "started_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "deadline_s": mode.deadline_s,
            "host": {"python": sys.version.split()[0], "executable": python,
                     "platform": sys.platform, "machine": os.uname().machine,
                     "cpu_count": os.cpu_count()},
            "git": git_state(REPO),
            "steps": {},
        }
        self.env = self._base_env()

    # -- environment

    def _base_env(self) -> dict[str, str]:
        env = dict(os.environ)
        paths = [str(self.work / "root")]
        if self.wheels is not None:
            paths.append(str(self.work / "site"))
        if env.get("PYTHONPATH"):
            paths.append(env["PYTHONPATH"])
        env["PYTHONPATH"] = os.pathsep.join(paths)
        # PoCL's kernel cache stays where the user has it (as tests/conftest.py keeps it);
        # everything else cached starts empty: no tuning file, no stale built kernels.
        if "POCL_CACHE_DIR" not in env:
            user_cache = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
            env["POCL_CACHE_DIR"] = str(Path(user_cache) / "pocl" / "kcache")
        env["XDG_CACHE_HOME"] = str(self.work / "xdg-cache")
        env["CUDA_CACHE_PATH"] = str(self.work / "nv-cache")
        env["CUDA_CACHE_MAXSIZE"] = str(CUDA_CACHE_BYTES)
        env["PYTHONUNBUFFERED"] = "1"
        env["MPLBACKEND"] = "Agg"
        for name in ("CLRAY_DEVICE", "PYOPENCL_CTX", "CLRAY_TEST_DEVICES", "PYOPENCL_NO_CACHE",
                     GROUP_FILE_ENV):
            env.pop(name, None)
        return env

    # -- log and JSON

    def say(self, message: str) -> None:
        stamp = f"[{time.monotonic() - self.started:6.1f}s]"
        lines = message.rstrip("\n").splitlines() or [""]
        text = "\n".join(f"{stamp} {line}" for line in lines) + "\n"
        sys.stdout.write(text)
        sys.stdout.flush()
        with open(self.log_path, "a", encoding="utf-8") as f:
            f.write(text)

    def log_raw(self, text: str) -> None:
        with open(self.log_path, "a", encoding="utf-8") as f:
            f.write(text if text.endswith("\n") else text + "\n")

    def write_json(self) -> None:
        self.data["seconds"] = round(time.monotonic() - self.started, 2)
        tmp = self.json_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self.data, indent=2, default=str) + "\n", encoding="utf-8")
        tmp.replace(self.json_path)

    # -- time

    def remaining(self) -> float:
        return self.deadline - time.monotonic()

    def limit_for(self, name: str) -> float:
        """The step's cap, or what the deadline leaves once later steps' minimums are kept."""
        later = STEP_ORDER[STEP_ORDER.index(name) + 1:]
        reserve = sum(self.mode.limits[s].min_s for s in later)
        return max(0.0, min(self.mode.limits[name].cap_s, self.remaining() - reserve))

    # -- children

    def child(self, name: str, cmd: Sequence[str], limit_s: float, *, cwd: Path | None = None,
              env: dict[str, str] | None = None, output: Path | None = None,
              stdout: Path | None = None, log_output: bool = True) -> ChildResult:
        # No child outlives its step's limit, whatever the step asked for.
        limit_s = max(1.0, min(limit_s, self.step_end - time.monotonic()))
        self.say(f"{name}: $ {' '.join(map(str, cmd))}   (limit {limit_s:.0f} s)")
        result = run_child([str(c) for c in cmd], limit_s, env=env or self.env,
                           cwd=cwd or self.work / "root",
                           output=output or self.work / f"{name}.out", stdout=stdout)
        if log_output and result.output.strip():
            self.log_raw(head_and_tail(result.output))
        ending = "timed out" if result.timed_out else f"exit {result.rc}"
        self.say(f"{name}: {ending} after {result.seconds:.1f} s")
        return result

    def steps_child(self, name: str, args: Sequence[str], limit_s: float,
                    **kwargs: object) -> ChildResult:
        return self.child(name, [self.python, STEPS_SCRIPT, *args], limit_s, **kwargs)

    # -- steps

    def on_signal(self, signum: int, frame: object) -> None:
        """SIGTERM or SIGINT: the first one, while the steps run, stops the running step (its
        children's process group too: run_child) and the run, which then writes what it has
        (Check.run); any later one, or one during that clean-up, is noted and ignored."""
        if self.stopped_by is None:
            self.stopped_by = signum
            if self.signals_stop:
                self.signals_stop = False
                raise Stopped(signum)

    def run(self) -> int:
        """Every step, then the summary. Exits 0 when no step failed, ran out of time or was
        killed (a step skipped for a stated reason is no failure), else 1; 128 + the signal's
        number when a signal stopped the run, after the JSON and the log are written."""
        caught = (signal.SIGTERM, signal.SIGINT)
        previous = {sig: signal.signal(sig, self.on_signal) for sig in caught}
        try:
            self.say(f"gpu_check ({self.mode.name} mode): output in {self.out}, work in "
                     f"{self.work}, {self.mode.deadline_s:.0f} s in all")
            self.signals_stop = self.stopped_by is None
            try:
                if self.stopped_by is not None:  # before the handler could raise
                    raise Stopped(self.stopped_by)
                self.write_json()
                for name in STEP_ORDER:
                    self.step(name, getattr(self, f"step_{name}"))
                self.signals_stop = False
            except Stopped as stop:
                self.after_stop(stop)
            return self.finish()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def after_stop(self, stop: Stopped) -> None:
        """The steps' records once a signal stopped the run: the one running marked killed
        (Check.step does; here too where the signal came between its parts), the later ones
        not run."""
        self.say(f"stopped by {stop.name}: the running step's processes were stopped; the "
                 "JSON and this log keep what the steps finished")
        for name in STEP_ORDER:
            record = self.data["steps"].get(name)
            if record is None:
                self.data["steps"][name] = {"status": "skipped", "seconds": 0.0,
                                            "note": f"not run: the run was stopped by "
                                                    f"{stop.name}"}
            elif record.get("status") == "running":
                record.update(status="killed", note=f"stopped by {stop.name}")

    def step(self, name: str, body: Callable[[float], StepOutcome]) -> None:
        limit = self.limit_for(name)
        record: dict = {"status": "running", "limit_s": round(limit, 1)}
        self.data["steps"][name] = record
        start = time.monotonic()
        self.step_end = start + limit
        stopped: Stopped | None = None
        if limit < 1.0:
            outcome = StepOutcome("timeout", "not started: no time left before the deadline")
        else:
            self.say(f"== {name} (limit {limit:.0f} s)")
            self.write_json()  # the step running, should the run end before its own record
            try:
                outcome = body(limit)
            except Skip as why:
                outcome = StepOutcome("skipped", str(why))
            except StepError as err:
                outcome = StepOutcome("failed", str(err))
            except Stopped as stop:
                stopped = stop
                outcome = StepOutcome("killed", f"stopped by {stop.name} after "
                                                f"{time.monotonic() - start:.0f} s")
            except Exception as err:  # a bug here must not lose the later steps
                self.log_raw(traceback.format_exc())
                outcome = StepOutcome("failed", f"{type(err).__name__}: {err}")
        record.update(status=outcome.status, seconds=round(time.monotonic() - start, 2),
                      note=outcome.note)
        self.say(f"{name}: {outcome.status.upper()}" + (f": {outcome.note}" if outcome.note
                                                         else ""))
        self.write_json()
        if stopped is not None:
            raise stopped

    def jobs(self) -> int:
        """Processes that build kernels at once: half the GPU machine's cores, at most 8 (the
        driver compiles on the host); two with --cpu."""
        if self.mode.name == "cpu":
            return 2
        return max(1, min(8, (os.cpu_count() or 2) // 2))

    def need_device(self) -> str:
        if self.target is None:
            raise Skip("no device to run on (see the devices step)")
        return self.target

    def step_setup(self, limit: float) -> StepOutcome:
        notes = []
        if self.wheels is not None:
            wheels = sorted(self.wheels.glob("*.whl"))
            if not wheels:
                raise StepError(f"no wheels in {self.wheels}: run scripts/gpu_wheels.sh on a "
                                "machine with a network and carry the folder")
            site = self.work / "site"
            self.data["wheels"] = [w.name for w in wheels]
            have = python_version(self.python)
            wrong = sorted(wheel_pythons(wheels) - {have})
            if have and wrong:
                raise StepError(f"the wheels in {self.wheels} are for Python {', '.join(wrong)}, "
                                f"{self.python} is Python {have}: pick that Python (PYTHON=) or "
                                f"run scripts/gpu_wheels.sh with GPU_PYTHON={have}")
            has_pip = subprocess.run([self.python, "-m", "pip", "--version"],
                                     capture_output=True, check=False, timeout=30).returncode == 0
            if has_pip:
                result = self.child("setup", [
                    self.python, "-m", "pip", "install", "-q", "--no-index", "--no-deps",
                    "--no-compile", "--no-cache-dir", "--disable-pip-version-check",
                    "--target", site, *wheels], limit / 2, cwd=self.work)
                if not result.ok:
                    raise StepError("pip could not install the carried wheels (see the log)")
                notes.append(f"{len(wheels)} wheels installed with pip into {site}")
            else:
                unzip_wheels(wheels, site)
                notes.append(f"no pip: {len(wheels)} wheels unpacked into {site}")
        package = assemble_package(REPO, self.work / "root")
        probe = self.steps_child("setup", ["software", "--json", self.work / "software.json"],
                                 max(5.0, limit / 2))
        if not probe.ok:
            raise StepError("clray or its dependencies do not import (see the log)")
        software = json.loads((self.work / "software.json").read_text(encoding="utf-8"))
        self.data["software"] = software
        if not str(software.get("clray_file", "")).startswith(str(package)):
            raise StepError(f"clray imported from {software.get('clray_file')}, not from the "
                            f"assembled package {package}")
        missing = [name for name, version in software["packages"].items() if version is None
                   and name in ("pyopencl", "numpy", "PIL", "tqdm", "kernel_tuner", "pytest")]
        if missing:
            notes.append(f"missing: {', '.join(missing)}")
        return StepOutcome("ok", "; ".join(notes))

    def step_icd(self, limit: float) -> StepOutcome:
        library, looked = find_nvidia_opencl()
        driver: dict = {"searched": looked, "opencl_library": str(library) if library else None}
        self.data["driver"] = driver
        if library is None:
            message = (f"no NVIDIA OpenCL driver: {NVIDIA_OPENCL} is in none of "
                       f"{', '.join(looked)}")
            self.say(message)
            if self.mode.name == "cpu":
                return StepOutcome("ok", f"{message} (--cpu: the steps run on PoCL)")
            raise StepError(message)
        driver["resolved"] = str(library.resolve())
        driver["version_from_library_name"] = driver_version_from_name(library)
        if self.mode.name == "cpu":
            return StepOutcome("ok", f"found {library}; --cpu leaves the ICD loader as it is")
        vendors = self.work / "vendors"
        icds = write_vendors(vendors, library)
        driver["icd_files"] = {icd.name: icd_library(icd) for icd in icds}
        self.env["OCL_ICD_VENDORS"] = str(vendors)
        self.env["LD_LIBRARY_PATH"] = os.pathsep.join(
            p for p in (str(library.parent), self.env.get("LD_LIBRARY_PATH", "")) if p)
        return StepOutcome("ok", f"{library} registered in {vendors / ICD_NAME}; "
                                 f"OCL_ICD_VENDORS={vendors}")

    def step_devices(self, limit: float) -> StepOutcome:
        listed = self.child("devices", [self.python, "-m", "clray", "devices"], limit / 3)
        self.data["clray_devices"] = listed.output.strip().splitlines()
        if shutil.which("nvidia-smi"):
            smi = self.child("devices", [
                "nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm,"
                "clocks.sm,power.limit,temperature.gpu", "--format=csv"], 15)
            self.data["nvidia_smi"] = smi.output.strip().splitlines()
        info_file = self.work / "devices.json"
        info = self.steps_child("devices", [
            "device-info", "--json", info_file, "--type", self.mode.device_type,
            "--platform", self.mode.platform], max(5.0, limit / 2))
        if not info_file.exists():
            raise StepError("the device listing failed (see the log)")
        found = json.loads(info_file.read_text(encoding="utf-8"))
        self.data["devices"] = found["devices"]
        target = found.get("target")
        if target is not None:  # the later steps run on it even where this step fails
            self.data["device"] = target
            self.target = target["spec"]
            self.test_device = target.get("test_id")
            self.env["CLRAY_DEVICE"] = self.target
        if not listed.ok or not info.ok:
            raise StepError("`clray devices` or the device listing failed (see the log)" +
                            (f"; the steps run on {self.target}" if self.target else ""))
        if target is None:
            if self.mode.name == "gpu":  # the ICD loader says what it tried, into the log
                self.child("devices", [self.python, "-c", "import pyopencl as cl; print("
                           "[p.name for p in cl.get_platforms()])"], 20,
                           env=dict(self.env, OCL_ICD_DEBUG="15"))
            raise StepError(f"no {self.mode.device_type} OpenCL device among "
                            f"{len(found['devices'])} found")
        note = (f"{target['name']} ({target['platform']}, driver {target['driver_version']}, "
                f"{target['version']}) as {self.target}")
        if target.get("query_errors"):
            note += f"; queries it did not answer: {', '.join(target['query_errors'])}"
        return StepOutcome("ok", note)

    def kernel_test_paths(self) -> list[str]:
        tests = REPO / "tests"
        if "*" in self.mode.kernel_tests:
            return [str(tests)]
        return [str(tests / name) for name in self.mode.kernel_tests if (tests / name).exists()]

    def step_kernel_tests(self, limit: float) -> StepOutcome:
        self.need_device()
        results = self.work / "kernel_tests.jsonl"
        results.unlink(missing_ok=True)
        software = self.data.get("software", {}).get("packages", {})
        cmd = [self.python, "-m", "pytest", "-q", "-rfE", "-p", "gpu_check_plugin",
               "-p", "no:cacheprovider", "--rootdir", str(REPO), "-m", "not slow",
               "--cl-device", self.test_device or self.mode.platform.split()[0].lower()]
        cmd += [f"--ignore={REPO / 'tests' / name}" for name in NOT_KERNEL_TESTS]
        workers = self.test_workers
        if workers is None:
            workers = self.jobs() if self.mode.name == "gpu" else 0
        if workers and not software.get("xdist"):
            self.say("kernel_tests: no pytest-xdist: the tests run in one process")
            workers = 0
        if workers:
            cmd += ["-n", str(workers)]
        if software.get("pytest_timeout"):
            cmd += kernel_test_limit_args(TEST_TIMEOUT_S[self.mode.name])
        cmd += self.kernel_test_paths()
        first = ",".join(name for name in self.mode.kernel_tests if name != "*")
        env = dict(self.env, GPU_CHECK_DEVICE_ONLY="1", GPU_CHECK_RESULTS=str(results),
                   GPU_CHECK_FIRST=first,
                   PYTHONPATH=os.pathsep.join([str(SCRIPTS), self.env["PYTHONPATH"]]))
        log = self.out / TESTS_LOG_NAME
        start = time.monotonic()
        result: ChildResult | None = None
        try:
            result = self.child("kernel_tests", cmd, limit, env=env, output=log,
                                log_output=False)
        finally:  # also when the run is stopped meanwhile: what ran, and how
            summary = summarise_test_results(results)
            summary.update(workers=workers, command=" ".join(cmd[1:]),
                           rc=result and result.rc, timed_out=bool(result and result.timed_out),
                           seconds=round(time.monotonic() - start, 1))
            if result is None:
                summary["stopped"] = True
            else:
                summary["pytest_summary"] = last_summary_line(result.output)
            self.data["kernel_tests"] = summary
        self.log_raw(head_and_tail(result.output, 10, 30))
        counts = summary["counts"]
        text = ", ".join(f"{n} {k}" for k, n in counts.items() if n) or "no test ran"
        if result.timed_out:
            return StepOutcome("timeout", f"stopped at {limit:.0f} s after {text}")
        if result.rc != 0:
            raise StepError(f"pytest exit {result.rc}: {text}")
        return StepOutcome("ok", text)

    def step_references(self, limit: float) -> StepOutcome:
        device = self.need_device()
        if self.given_reference is not None:
            self.reference = self.given_reference
            if not self.reference.exists():
                raise StepError(f"--reference {self.reference}: no such file")
        elif self.mode.name == "cpu":
            # Made here as scripts/gpu_wheels.sh makes the GPU run's, at a tiny size.
            self.reference = self.work / REFERENCE_FILE
            w, h = self.mode.reference_size
            made = self.steps_child("references", [
                "references", "--out", self.reference, "--size", f"{w}x{h}",
                "--device", device], limit)
            if not made.ok:
                raise StepError("rendering the CPU references failed" +
                                (" (timed out)" if made.timed_out else ""))
        else:
            self.reference = (self.wheels or WHEELS_DIR) / REFERENCE_FILE
            if not self.reference.exists():
                self.reference = None
                raise StepError(f"no {REFERENCE_FILE} in {self.wheels or WHEELS_DIR}: run "
                                "scripts/gpu_wheels.sh and carry the folder")
        info_file = self.work / "reference.json"
        info = self.steps_child("references", ["reference-info", "--reference", self.reference,
                                               "--json", info_file], max(5.0, limit / 4))
        if not info.ok:
            raise StepError("the reference file does not read (see the log)")
        meta = json.loads(info_file.read_text(encoding="utf-8"))
        self.data["reference"] = meta
        note = (f"{len(meta['scenes'])} scenes at {meta['width']}x{meta['height']} from "
                f"{meta['device']}")
        if not meta["current"]:
            note += ("; made from other clray sources than these (run scripts/gpu_wheels.sh "
                     "again): differences may not be the GPU's")
        return StepOutcome("ok", note)

    def step_scenes(self, limit: float) -> StepOutcome:
        device = self.need_device()
        if self.reference is None:
            raise Skip("no CPU references (see the references step)")
        result_file = self.work / "scenes.json"
        try:
            run = self.steps_child("scenes", [
                "compare", "--reference", self.reference, "--device", device, "--json",
                result_file, "--png-dir", self.out, "--jobs", str(self.jobs())], limit)
        finally:  # rewritten after each scene: what was compared, even when stopped
            found = read_json(result_file)
            if found is not None:
                self.data["scenes"] = found
        scenes = self.data.get("scenes", {}).get("results", {})
        failing = [name for name, r in scenes.items() if r.get("status") != "pass"]
        text = f"{len(scenes) - len(failing)} of {len(scenes)} scenes agree"
        if failing:
            text += f"; differ or failed: {', '.join(failing)}"
        if run.timed_out:
            return StepOutcome("timeout", f"stopped at {limit:.0f} s: {text}")
        if not run.ok or failing:
            raise StepError(text if scenes else "the comparison failed (see the log)")
        return StepOutcome("ok", text)

    def step_mesh_scene(self, limit: float) -> StepOutcome:
        folder = self.work / "mesh"
        run = self.child("mesh_scene", [
            self.python, REPO / "scripts" / "make_mesh_scene.py", "--out", folder,
            "--subdivisions", str(self.mode.mesh_subdivisions)], limit)
        if not run.ok:
            raise StepError("scripts/make_mesh_scene.py failed")
        self.mesh_scene = folder / "bumpy.toml"
        triangles = 20 * 4 ** self.mode.mesh_subdivisions
        self.data["mesh_scene"] = {"subdivisions": self.mode.mesh_subdivisions,
                                   "triangles": triangles}
        return StepOutcome("ok", f"{triangles:,} triangles")

    def profile_scenes(self) -> dict[str, Path]:
        scenes = {"spheres": REPO / "scenes" / "spheres.toml"}
        if self.mesh_scene is not None:
            scenes["mesh"] = self.mesh_scene
        return scenes

    def profile_runs(self) -> list[tuple[str, Path, tuple[int, int], int, str | None]]:
        """The profiles step's runs, in order: (scene, its file, size, spp, traversal or None
        for the device's default). The default walk at the first size, the two packet schemes
        there at the most samples (issue 41 asks for the packets measured on a GPU, or
        removed), then the default walk at the other sizes: a step at its limit leaves out
        the last runs."""
        scenes = self.profile_scenes().items()
        first, *others = self.mode.sizes
        runs = [(scene, path, first, spp, None) for scene, path in scenes
                for spp in self.mode.spps]
        runs += [(scene, path, first, max(self.mode.spps), traversal)
                 for traversal in PACKET_TRAVERSALS for scene, path in scenes]
        runs += [(scene, path, size, spp, None) for size in others
                 for scene, path in scenes for spp in self.mode.spps]
        return runs

    def step_profiles(self, limit: float) -> StepOutcome:
        device = self.need_device()
        end = time.monotonic() + limit
        runs = self.profile_runs()
        records = []
        self.data["profiles"] = records
        for i, (scene, path, (w, h), spp, traversal) in enumerate(runs):
            left = end - time.monotonic()
            record: dict = {"scene": scene, "width": w, "height": h, "spp": spp,
                            "traversal": traversal or "default"}
            records.append(record)
            if left < 3:
                record["status"] = "skipped"
                continue
            # The first runs build the kernels (later ones find them in the driver's cache):
            # a run may take what is left but a few seconds for each run after it.
            after = len(runs) - i - 1
            run_limit = max(left / (after + 1), left - after * self.mode.min_profile_s)
            out_file = self.work / f"profile_{i}.json"
            try:
                run = self.child("profiles", [
                    self.python, "-m", "clray", "profile", path, "-W", str(w), "-H", str(h),
                    "--spp", str(spp), "--repeat", str(self.mode.profile_repeat), "--json",
                    "--no-tuning", "--device", device,
                    *(["--traversal", traversal] if traversal else [])], run_limit,
                    stdout=out_file)
            except Stopped:
                record["status"] = "killed"
                raise
            record["seconds"] = round(run.seconds, 2)
            profile = read_json(out_file) if run.ok else None
            if profile is not None:
                record["status"] = "ok"
                record["profile"] = profile
            elif run.ok:
                record.update(status="failed", error="no JSON on its stdout")
            else:
                record["status"] = "timeout" if run.timed_out else "failed"
            self.write_json()
        done = [r for r in records if r["status"] == "ok"]
        text = f"{len(done)} of {len(runs)} profiles"
        if len(done) == len(runs):
            return StepOutcome("ok", text)
        if any(r["status"] == "timeout" for r in records):
            return StepOutcome("timeout", text)
        raise StepError(text + " (see the log)")

    def step_builds(self, limit: float) -> StepOutcome:
        device = self.need_device()
        result_file = self.work / "builds.json"
        args = ["builds", "--json", result_file, "--device", device,
                "--scenes-dir", REPO / "scenes", "--time-limit", f"{max(1.0, limit - 10):.0f}"]
        for name, path in self.profile_scenes().items():
            args += ["--scene", f"{name}={path}"]
        for spp in self.mode.spps:
            args += ["--spp", str(spp)]
        if not self.mode.build_examples:
            args.append("--no-examples")
        try:
            run = self.steps_child("builds", args, limit)
        finally:  # rewritten after each build: what was built, even when stopped
            found = read_json(result_file)
            if found is not None:
                self.data["builds"] = found
        builds = self.data.get("builds", {})
        configs = builds.get("configurations", [])
        built = [c for c in configs if c.get("status") == "ok"]
        whole = [name for name, times in builds.get("cold_warm", {}).items()
                 if not times.get("errors") and not times.get("unfinished")]
        text = (f"cold/warm for {len(whole)} of {len(builds.get('cold_warm', {}))} scenes, "
                f"{len(built)} of {len(configs)} configurations built")
        if builds.get("verbose"):
            text += ", register figures from -cl-nv-verbose"
        if run.timed_out:
            return StepOutcome("timeout", text)
        if not run.ok or len(built) < len(configs) or builds.get("unfinished"):
            raise StepError(text + " (see the log)")
        return StepOutcome("ok", text)

    def step_cpu_beside(self, limit: float) -> StepOutcome:
        """The profiled scenes rendered whole at the first size and the most samples, by the
        device a render takes with no --device (clray.device.context.default_device: a GPU
        with its own memory where there is one) and by the machine's CPU device: the figures
        behind that default. In --cpu mode both are PoCL's device."""
        self.need_device()
        cpus = [d for d in self.data.get("devices", []) if d["type"] == "CPU"]
        if not cpus:
            return StepOutcome("skipped", "no CPU device beside the target")
        (w, h), spp = self.mode.sizes[0], max(self.mode.spps)
        env = {k: v for k, v in self.env.items() if k != "CLRAY_DEVICE"}
        renders: dict = {}
        self.data["cpu_beside"] = {"width": w, "height": h, "spp": spp,
                                   "cpu": cpus[0]["name"], "renders": renders}
        for scene, path in self.profile_scenes().items():
            for label, flags in (("default", []), ("cpu", ["--device", cpus[0]["spec"]])):
                stats = self.work / f"beside_{scene}_{label}.json"
                run = self.child("cpu_beside", [
                    self.python, "-m", "clray", "render", path, "-W", str(w), "-H", str(h),
                    "--spp", str(spp), "--no-tuning", "-q", "-o",
                    self.work / f"beside_{scene}_{label}.png", "--stats-json", stats, *flags],
                    limit, env=env)
                if not run.ok or not stats.exists():
                    self.write_json()
                    if run.timed_out:
                        return StepOutcome("timeout", f"{scene} on the {label} device")
                    raise StepError(f"{scene} on the {label} device: exit {run.rc}")
                found = json.loads(stats.read_text(encoding="utf-8"))
                renders.setdefault(scene, {})[label] = {
                    k: found[k] for k in ("device", "traversal", "build_s", "kernel_s",
                                          "render_s", "total_s")}
            pair = renders[scene]
            pair["cpu_over_default_kernel"] = pair["cpu"]["kernel_s"] / max(
                pair["default"]["kernel_s"], 1e-9)
            self.write_json()
        chosen = {r["default"]["device"] for r in renders.values()}
        ratios = ", ".join(f"{scene} x{r['cpu_over_default_kernel']:.1f}"
                           for scene, r in renders.items())
        return StepOutcome("ok", f"default device {' / '.join(sorted(chosen))}; the CPU's "
                                 f"kernel time over the default's: {ratios}")

    def step_tune(self, limit: float) -> StepOutcome:
        device = self.need_device()
        w, h = self.mode.tune_size
        needs = self.mode.tune_needs_s()
        if limit < needs:  # it would be stopped before its report
            return StepOutcome("timeout", f"not started: {limit:.0f} s left, clray tune needs "
                                          f"{needs:.0f} s ({self.mode.tune_budget_range[0]:.0f}"
                                          f" s of search, {self.mode.tune_overhead_s:.0f} s of "
                                          "renders and report)")
        budget = self.mode.tune_budget(limit)
        folder = self.work / "tune"
        tune: dict = {"width": w, "height": h, "budget_s": round(budget)}
        self.data["tune"] = tune
        try:
            run = self.child("tune", [
                self.python, "-m", "clray", "tune", REPO / "scenes" / "spheres.toml", "-W",
                str(w), "-H", str(h), "--budget", f"{budget:.0f}", "--out", folder,
                "--no-save", "--device", device], limit)
        finally:  # what it wrote, even when stopped
            results = read_json(folder / "results.json")
            if results is not None:
                tune["results"] = results
            if (folder / "report.md").exists():
                shutil.copyfile(folder / "report.md", self.out / TUNE_REPORT_NAME)
        if run.timed_out:
            return StepOutcome("timeout", f"stopped at {limit:.0f} s")
        if not run.ok:
            raise StepError(f"clray tune exit {run.rc}")
        best = tune.get("results", {}).get("best", {}).get("label")
        return StepOutcome("ok", f"budget {budget:.0f} s, best: {best}")

    # -- the end

    def finish(self) -> int:
        """The summary in the log and the JSON, the output files' sizes; the exit status."""
        self.data["finished_utc"] = datetime.datetime.now(datetime.UTC).isoformat(
            timespec="seconds")
        steps = self.data["steps"]
        not_ok = {name: s["status"] for name, s in steps.items() if s["status"] in FAILING}
        skipped = {name: s.get("note", "") for name, s in steps.items()
                   if s["status"] == "skipped"}
        if self.stopped_by is not None:
            status = 128 + self.stopped_by
            verdict = f"stopped by {signal.Signals(self.stopped_by).name}"
        else:
            status = 1 if not_ok else 0
            verdict = ("every step passed or was skipped for its reason" if not not_ok else
                       "not every step passed")
        self.data["result"] = {"exit_status": status, "verdict": verdict,
                               "not_ok": not_ok, "skipped": skipped}
        self.say("summary:")
        for name, step in steps.items():
            self.say(f"  {name:<13} {step['status']:<8} {step.get('seconds', 0):7.1f} s  "
                     f"{step.get('note', '')}")
        self.say(f"exit {status}: {verdict}" + (
            f" ({', '.join(f'{n} {s}' for n, s in not_ok.items())})" if not_ok else "") + (
            f"; skipped: {', '.join(skipped)}" if skipped else ""))
        self.data["outputs"] = {}
        self.write_json()
        for path in sorted(self.out.iterdir()):
            if path.is_file() and path.suffix in (".log", ".md") and cap_file(path):
                self.say(f"{path.name} cut to {MAX_OUT_BYTES} bytes")
        files = sorted(p for p in self.out.rglob("*") if p.is_file())
        if len(files) > MAX_OUT_FILES:
            self.say(f"warning: {len(files)} files under {self.out}, more than the "
                     f"{MAX_OUT_FILES} that come back from the GPU machine")
        self.data["outputs"] = {str(p.relative_to(self.out)): p.stat().st_size for p in files}
        self.write_json()
        return status


def summarise_test_results(path: Path) -> dict:
    """Counts by outcome, the failing tests and the slowest, from gpu_check_plugin's lines."""
    outcomes: dict[str, str] = {}
    durations: dict[str, float] = {}
    messages: dict[str, str] = {}
    collected = None
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut short by the step's end
            if "collected" in record:
                collected = record["collected"]
                continue
            node = record["nodeid"]
            durations[node] = durations.get(node, 0.0) + record.get("duration_s", 0.0)
            # A failed call followed by a teardown error stays failed.
            if outcomes.get(node) not in ("failed", "error"):
                outcomes[node] = record["outcome"]
            if record.get("message") and record["outcome"] in ("failed", "error"):
                messages.setdefault(node, record["message"])
    counts = {k: 0 for k in ("passed", "failed", "error", "skipped")}
    for outcome in outcomes.values():
        counts[outcome] = counts.get(outcome, 0) + 1
    slowest = sorted(durations.items(), key=lambda kv: -kv[1])[:15]
    return {"collected": collected, "counts": counts,
            "failures": {node: messages.get(node, "") for node, o in outcomes.items()
                         if o in ("failed", "error")},
            "slowest": [{"nodeid": n, "seconds": round(s, 2)} for n, s in slowest]}


def last_summary_line(output: str) -> str | None:
    for line in reversed(output.strip().splitlines()):
        if re.search(r"\b(passed|failed|error|skipped|deselected|no tests ran)\b", line):
            return line.strip("= ")
    return None


def git_state(repo: Path) -> dict:
    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(repo), *args], capture_output=True,
                                  text=True, timeout=10, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "modified_files": None if status is None
            else len(status.splitlines())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="scripts/gpu_check.py", description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="output folder (created)")
    parser.add_argument("--cpu", action="store_true",
                        help="the same steps on PoCL's CPU device at tiny sizes")
    parser.add_argument("--from-wheels", action="store_true",
                        help="with --cpu: install from the wheel folder too, as on the GPU "
                             "machine (a Python of the wheels' version)")
    parser.add_argument("--wheels", type=Path, default=WHEELS_DIR,
                        help=f"the wheel folder (default: {WHEELS_DIR.relative_to(REPO)})")
    parser.add_argument("--reference", type=Path, default=None,
                        help=f"the CPU images to compare with (default: the wheel folder's "
                             f"{REFERENCE_FILE}; with --cpu, rendered in the run)")
    parser.add_argument("--deadline", type=float, default=None,
                        help="seconds for all steps (default: 450, with --cpu 420)")
    parser.add_argument("--test-workers", type=int, default=None,
                        help="pytest-xdist processes for the kernel tests (default: half the "
                             "cores, at most 8, on the GPU; none with --cpu)")
    parser.add_argument("--keep-work", action="store_true",
                        help="keep the work folder (installed wheels, caches, outputs)")
    args = parser.parse_args(argv)

    mode = CPU_MODE if args.cpu else GPU_MODE
    if args.deadline is not None:
        mode = Mode(**{**mode.__dict__, "deadline_s": args.deadline})
    wheels = args.wheels if (not args.cpu or args.from_wheels) else None
    args.out.mkdir(parents=True, exist_ok=True)
    for name in (JSON_NAME, LOG_NAME, TESTS_LOG_NAME, TUNE_REPORT_NAME, *PNG_NAMES):
        (args.out / name).unlink(missing_ok=True)
    work = Path(tempfile.mkdtemp(prefix="clray-gpu-check-"))
    try:
        check = Check(args.out.resolve(), mode, wheels=wheels, python=sys.executable,
                      work=work, reference=args.reference and args.reference.resolve(),
                      test_workers=args.test_workers)
        return check.run()
    finally:
        if not args.keep_work:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
