"""Shared fixtures: the OpenCL devices the suite runs on, and a helper that writes scene files;
and a loader of the benchmarks' and scripts' files as modules (they are not packages).

A test that asks for `cl_device` (or `cl_ctx`) runs once per OpenCL device, with ids such as
`pocl-cpu` and `intel-cpu`: all devices found, or those named by `--cl-device` or
CLRAY_TEST_DEVICES. While it runs, CLRAY_DEVICE names that device, so render(), the CLI and any
subprocess it starts use the same device as the test. Without an OpenCL platform such tests
skip, except under CI (CI set) or CLRAY_REQUIRE_DEVICE=1, where a missing device must fail.

The machines the suite runs on differ in vector width (AVX2: 8 floats, AVX-512: 16), and the
device's width picks the default packet lanes and BVH width. `--lanes 8` or `--lanes 16` (or
CLRAY_TEST_LANES) makes every real device report that float width (half of it for double) to
clray in this process, so one machine runs the suite as the other kind would; `--lanes other`
gives each device the width it does not have (16 where it has 8 or fewer, else 8), which is
how .ci/run checks both kinds on whichever it gets.

The CPU drivers' sin, cos, atan2 and the like are within an ulp; OpenCL lets a device be
3 to 6 ulps off, and a GPU may be; and it lets dot, length and normalize fuse their products,
which the CPU drivers' do not. `--opencl-ulps 1` (or -1, or CLRAY_TEST_OPENCL_ULPS) builds the
render kernels in this process with those builtins off by the whole of their bounds in that
direction, and the geometric ones fused (kernels/real.h, MATH_ULPS_OFF), so the tests that
compare against an oracle, or a ray with its lane-wise twins, show whether they hold on any
OpenCL device, not only on the CPU's (`make test-opencl-ulps`).

A GPU's render kernels are built with GPU_BUILD_OPTIONS (a pixel a work-item, no row segments).
`--gpu-build` (or CLRAY_TEST_GPU_BUILD=1) builds this process's kernels so on every device, so
a CPU device runs the code a GPU's work-items run (`make test-opencl-ulps` does,
with the builtins off as above: as a GPU may build and round).
"""

from __future__ import annotations

import importlib.util
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pyopencl as cl
import pytest

import clray
from clray import kernels as clray_kernels
from clray.device import policy as policy_module
from clray.device import program as program_module
from clray.device.context import DeviceInfo, context_for, has_fp64, list_devices, select_device
from clray.errors import DeviceError

SELECT_ENV = "CLRAY_TEST_DEVICES"
LANES_ENV = "CLRAY_TEST_LANES"
ULPS_ENV = "CLRAY_TEST_OPENCL_ULPS"
GPU_BUILD_ENV = "CLRAY_TEST_GPU_BUILD"
OTHER_LANES = "other"
# A platform's first word names it well ("Intel(R) OpenCL", "NVIDIA CUDA", "AMD Accelerated
# Parallel Processing"), except PoCL's.
PLATFORM_SHORT_NAMES = {"portable computing language": "pocl"}

# Test id -> device; empty, with NO_DEVICE_KEY saying why, where no OpenCL platform exists.
DEVICES_KEY = pytest.StashKey[dict[str, DeviceInfo]]()
NO_DEVICE_KEY = pytest.StashKey[str]()


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--cl-device", action="append", default=[], metavar="ID",
                     help="run device tests only on these OpenCL devices: ids such as pocl-cpu "
                          "or prefixes such as pocl, comma-separated or repeated (default: "
                          f"${SELECT_ENV}, else every device found)")
    parser.addoption("--lanes", choices=("4", "8", "16", OTHER_LANES), default=None,
                     help="make every device report this float vector width to clray, as a "
                          "machine of that width would; 'other': 16 where the device has 8 or "
                          f"fewer, else 8 (default: ${LANES_ENV}, else the device's own)")
    parser.addoption("--opencl-ulps", choices=("1", "-1"), default=None,
                     help="build the render kernels with sin, cos, tan, asin, atan2, exp2 and "
                          "log2 off by OpenCL's whole error bound for them, upwards (1) or "
                          "downwards (-1), and dot, length and normalize fused (default: "
                          f"${ULPS_ENV}, else the device's own)")
    parser.addoption("--gpu-build", action="store_true", default=None,
                     help="build the render kernels as for a GPU (one pixel a work-item) on "
                          f"every device (default: ${GPU_BUILD_ENV}=1)")


def _device_required() -> bool:
    ci = os.environ.get("CI", "").strip().lower()
    return ci not in ("", "0", "false") or os.environ.get("CLRAY_REQUIRE_DEVICE") == "1"


def _test_id(info: DeviceInfo) -> str:
    platform = info.platform.lower()
    short = PLATFORM_SHORT_NAMES.get(platform) or (re.findall(r"[a-z0-9]+", platform)
                                                   or ["opencl"])[0]
    return f"{short}-{info.type.lower()}"


def _all_test_devices() -> dict[str, DeviceInfo]:
    devices: dict[str, DeviceInfo] = {}
    for info in list_devices():
        base = _test_id(info)
        test_id, n = base, 1
        while test_id in devices:  # two alike devices: pocl-cpu, pocl-cpu-2
            n += 1
            test_id = f"{base}-{n}"
        devices[test_id] = info
    return devices


def _chosen(devices: dict[str, DeviceInfo], wanted: list[str]) -> dict[str, DeviceInfo]:
    if not wanted:
        return devices
    chosen = {}
    for name in wanted:
        hits = {i: d for i, d in devices.items() if i == name or i.startswith(f"{name}-")}
        if not hits:
            raise pytest.UsageError(f"OpenCL device {name!r} not found; the devices are: "
                                    f"{', '.join(devices)}")
        chosen.update(hits)
    return chosen


def _check_checkout() -> None:
    """Refuse to test another checkout's code: an editable install maps `clray.kernels` to the
    kernels/ folder of the checkout it was made from, so a second checkout (a git worktree)
    that borrows its environment would test its own Python against the other's kernels. An
    installed clray (a wheel, or scripts/gpu_check.py's assembled package) is no checkout."""
    root = Path(__file__).resolve().parents[1]
    used = {"clray": Path(clray.__file__).resolve().parent,
            "clray.kernels": Path(next(iter(clray_kernels.__path__))).resolve()}
    for name, path in used.items():
        checkout = path.parent
        if (checkout / "pyproject.toml").is_file() and checkout != root:
            raise pytest.UsageError(
                f"{name} is imported from {path}, another checkout than this one ({root}): "
                f"run `make setup` here for an environment of its own (docs/testing.md)")


def pytest_configure(config: pytest.Config) -> None:
    _check_checkout()
    wanted = ",".join(config.getoption("cl_device")) or os.environ.get(SELECT_ENV, "")
    try:
        devices = _all_test_devices()
    except DeviceError as err:
        config.stash[DEVICES_KEY] = {}
        config.stash[NO_DEVICE_KEY] = str(err)
        return
    config.stash[DEVICES_KEY] = _chosen(devices, [w.strip().lower() for w in wanted.split(",")
                                                  if w.strip()])


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter,
                            config: pytest.Config) -> None:
    # Also under -q (which hides the header): a log must show which devices the run covered.
    devices = config.stash[DEVICES_KEY]
    listed = ", ".join(f"{test_id} ({d.platform}: {d.name})" for test_id, d in devices.items())
    if not listed:
        listed = f"none ({config.stash[NO_DEVICE_KEY]})"
    terminalreporter.write_line(f"OpenCL test devices: {listed}")
    lanes = forced_lanes(config)
    if lanes:
        width = ("the width each device lacks (16 where it has 8 or fewer, else 8)"
                 if lanes == OTHER_LANES else f"{lanes} floats")
        terminalreporter.write_line(f"Vector width forced to {width}")
    ulps = forced_ulps(config)
    if ulps:
        terminalreporter.write_line(f"Builtins off by OpenCL's bounds (MATH_ULPS_OFF={ulps})")
    if forced_gpu_build(config):
        terminalreporter.write_line("Render kernels built as for a GPU "
                                    f"({' '.join(program_module.GPU_BUILD_OPTIONS)})")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[object]:
    # A device without cl_khr_fp64 (many GPUs; Mesa's rusticl on llvmpipe) cannot build the
    # double kernels that many tests take as their oracle: there such a test skips, naming why,
    # where the refusal reaches it. On a device with doubles the error fails the test as ever.
    try:
        return (yield)
    except DeviceError as err:
        device = getattr(item, "funcargs", {}).get("cl_device")
        if device is not None and not has_fp64(device) and program_module.NO_FP64 in str(err):
            pytest.skip(f"the double build is this test's oracle: {err}")
        raise


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    # Only tests that need a device are multiplied; the rest run once.
    if "cl_device" in metafunc.fixturenames:
        devices = metafunc.config.stash[DEVICES_KEY]
        # The param is the "platform:device" spec that select_device and CLRAY_DEVICE take.
        specs = [d.spec for d in devices.values()]
        metafunc.parametrize("cl_device", specs or [None], indirect=True,
                             ids=list(devices) or ["no-device"], scope="session")


@pytest.fixture(scope="session")
def cl_device(request: pytest.FixtureRequest) -> cl.Device:
    if request.param is None:
        reason = request.config.stash[NO_DEVICE_KEY]
        if _device_required():
            pytest.fail(f"no OpenCL device, and CI or CLRAY_REQUIRE_DEVICE=1 needs one: {reason}",
                        pytrace=False)
        pytest.skip(reason)
    return select_device(request.param)


@pytest.fixture(autouse=True)
def _default_device_is_the_tests(request: pytest.FixtureRequest,
                                 monkeypatch: pytest.MonkeyPatch) -> None:
    # Code under test that picks the default device (render() without a device, the CLI, a
    # subprocess) must land on the device this test is parametrised with.
    if "cl_device" in request.fixturenames:
        request.getfixturevalue("cl_device")
        monkeypatch.setenv("CLRAY_DEVICE", request.node.callspec.params["cl_device"])


@pytest.fixture(autouse=True)
def _own_cache_directory(tmp_path_factory: pytest.TempPathFactory,
                         monkeypatch: pytest.MonkeyPatch) -> None:
    # A tuning file the user's `clray tune` left in ~/.cache/clray must not change what a test
    # renders: every test (and its subprocesses) gets an empty cache directory of its own.
    # PoCL keeps its kernel cache under the same directory: it stays where it was, or every
    # subprocess would build its kernels cold.
    if "POCL_CACHE_DIR" not in os.environ:
        user_cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        monkeypatch.setenv("POCL_CACHE_DIR", str(Path(user_cache) / "pocl" / "kcache"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg-cache")))


def forced_lanes(config: pytest.Config) -> str | None:
    """The float vector width the run forces on its devices (--lanes, CLRAY_TEST_LANES):
    "4", "8", "16" or "other"."""
    return config.getoption("lanes") or os.environ.get(LANES_ENV, "").strip() or None


def force_vector_width(monkeypatch: pytest.MonkeyPatch, lanes: int | str) -> None:
    """Real devices report `lanes` floats (lanes // 2 doubles) to clray's vector_width, which
    picks the default packet lanes and BVH width; with "other", the width the device does not
    have. Stand-in devices (SimpleNamespace) keep the real function, which tests of
    vector_width itself call."""
    own = policy_module.vector_width

    def forced(device, precision: str = "float") -> int:
        if not isinstance(device, cl.Device):
            return own(device, precision)
        floats = int(lanes) if lanes != OTHER_LANES else (8 if own(device) >= 16 else 16)
        return floats // 2 if precision == "double" else floats

    monkeypatch.setattr(policy_module, "vector_width", forced)


@pytest.fixture(autouse=True)
def _forced_lanes(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    lanes = forced_lanes(request.config)
    if lanes:
        force_vector_width(monkeypatch, lanes)


def forced_ulps(config: pytest.Config) -> str | None:
    """The direction ("1" or "-1") in which the run's kernels have their builtins off by
    OpenCL's bounds (--opencl-ulps, CLRAY_TEST_OPENCL_ULPS), or None."""
    return config.getoption("opencl_ulps") or os.environ.get(ULPS_ENV, "").strip() or None


@pytest.fixture(autouse=True)
def _forced_ulps(request: pytest.FixtureRequest) -> Iterator[None]:
    # The builds of this process only: a subprocess (the CLI's tests) builds as it always does.
    ulps = forced_ulps(request.config)
    if not ulps:
        yield
        return
    with program_module.math_ulps_off(int(ulps)):
        yield


def forced_gpu_build(config: pytest.Config) -> bool:
    """Whether the run builds its render kernels as for a GPU (--gpu-build,
    CLRAY_TEST_GPU_BUILD=1)."""
    return bool(config.getoption("gpu_build")) or os.environ.get(GPU_BUILD_ENV, "").strip() == "1"


@pytest.fixture(autouse=True)
def _forced_gpu_build(request: pytest.FixtureRequest) -> Iterator[None]:
    # The builds of this process only, as with --opencl-ulps.
    if not forced_gpu_build(request.config):
        yield
        return
    with program_module.built_as_for_a_gpu():
        yield


@pytest.fixture(params=(8, 16), ids=("lanes8", "lanes16"))
def lane_width(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    """A test that depends on the device's vector width runs at both widths on any machine."""
    force_vector_width(monkeypatch, request.param)
    return request.param


@pytest.fixture
def bvh_builds(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A list that grows by one at each BVH build of a pack (clray.device.pack._pack_bvh):
    how many packs a run of frames made afresh."""
    from clray.device import pack

    builds: list[int] = []
    build = pack._pack_bvh
    monkeypatch.setattr(pack, "_pack_bvh", lambda *a, **k: builds.append(1) or build(*a, **k))
    return builds


@pytest.fixture(scope="session")
def cl_ctx(cl_device: cl.Device) -> cl.Context:
    return context_for(cl_device)


@pytest.fixture
def tmp_scene(tmp_path: Path) -> Callable[..., Path]:
    """`tmp_scene(text, name="scene.toml")` writes `text` under tmp_path and returns its path."""

    def write(text: str, name: str = "scene.toml") -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path

    return write


def module_from_file(path: Path, name: str) -> ModuleType:
    """The Python file at path, executed as a module named name: benchmarks/ and scripts/ are
    not packages, so the tests load what they check of them straight from their files."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_mesh_generator() -> ModuleType:
    """scripts/make_mesh_scene.py (bumpy_mesh, icosphere, main, ...) as a module."""
    return module_from_file(
        Path(__file__).resolve().parents[1] / "scripts" / "make_mesh_scene.py", "make_mesh_scene")


_ROOT = Path(__file__).resolve().parents[1]


def shared_packing_scene(tmp_path: Path, name: str) -> Path:
    """An animation whose frames share frame 0's packing (clray.sequence.Sequence
    .packs_each_frame false): orbit.toml's camera and material tracks, a mesh beside its
    spheres ("orbit"), and its sphere's rise too ("rising"); instances.toml's groups placed
    by instances under an orbiting camera ("instances"), and besides that two of its
    instances turned and slid ("turntable")."""
    meshes = (_ROOT / "scenes" / "meshes").as_posix()
    if name in ("orbit", "rising"):
        blocks = (_ROOT / "scenes" / "orbit.toml").read_text().split("[[animation.tracks]]")
        text = "[[animation.tracks]]".join(b for b in blocks if name == "rising"
                                           or "objects[" not in b)
        assert len(blocks) == text.count("[[animation.tracks]]") + 1 + (name == "orbit")
        text = text.replace("[animation]", f'[[objects]]\ntype = "mesh"\nfile = "{meshes}/'
                            'bumpy_ico2.obj"\nmaterial = "blue"\ntransform = { scale = 0.6, '
                            'translate = [0.2, 0.6, 1.6] }\n\n[animation]')
    else:
        text = (_ROOT / "scenes" / "instances.toml").read_text().replace('"meshes/',
                                                                         f'"{meshes}/')
        text += ('\n[animation]\nframes = 6\n\n[[animation.tracks]]\nkey = "camera.position"\n'
                 'frames = [0, 5]\nvalues = [[0, 3, 9], [6, 4, 6]]\n')
        if name == "turntable":
            text += ('\n[[animation.tracks]]\nkey = "objects[1].transform.rotate"\n'
                     'frames = [0, 5]\nvalues = [[0, 0, 0], [0, 150, 0]]\n'
                     '\n[[animation.tracks]]\nkey = "objects[4].transform.translate"\n'
                     'frames = [0, 5]\nvalues = [[1.5, 0, -1.5], [0.5, 0.8, 0.5]]\n')
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def check_unused_lanes(nodes: np.ndarray) -> None:
    """Each unused lane is child -1 and count 0 with a NaN box, as the kernel's mask of unused
    lanes (kernels/bvh.h, node_children) and the host's readers of boxes take it."""
    unused = nodes["child"] < 0
    assert np.all(nodes["child"][unused] == -1)
    assert np.all(nodes["count"][unused] == 0)
    for side in ("lo", "hi"):
        for axis in "xyz":
            assert np.all(np.isnan(nodes[f"{side}_{axis}"][unused]))
