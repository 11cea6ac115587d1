"""scripts/gpu_check.sh, the prepared command for a GPU machine (docs/gpu.md): its parts that
need no GPU (finding NVIDIA's OpenCL driver, the ICD vendors folder, the PTX assembler's
register figures, the wheels, the time limits), and a whole run of its --cpu mode, the same
steps on PoCL at tiny sizes, so that a first GPU run fails only for GPU reasons."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import gpu_check as G  # noqa: E402
import gpu_check_plugin as P  # noqa: E402
import gpu_check_steps as S  # noqa: E402

# --- NVIDIA's OpenCL driver ---------------------------------------------------------------


def _touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def test_the_driver_is_found_in_the_first_driver_folder_that_has_it(tmp_path: Path) -> None:
    empty, lib64, lib = tmp_path / "x86_64-linux-gnu", tmp_path / "lib64", tmp_path / "lib"
    empty.mkdir()
    found = _touch(lib64 / "libnvidia-opencl.so.1")
    _touch(lib / "libnvidia-opencl.so.1")
    path, looked = G.find_nvidia_opencl([empty, lib64, lib], listing="")
    assert path == found
    assert looked == [str(empty), str(lib64)]


def test_a_versioned_driver_library_is_found_without_its_link(tmp_path: Path) -> None:
    found = _touch(tmp_path / "lib64" / "libnvidia-opencl.so.580.159.03")
    _touch(tmp_path / "lib64" / "libnvidia-opencl.so.580.159.03.txt")
    assert G.find_nvidia_opencl([tmp_path / "lib64"], listing="")[0] == found


def test_the_driver_is_found_through_ldconfig(tmp_path: Path) -> None:
    lib = _touch(tmp_path / "elsewhere" / "libnvidia-opencl.so.1")
    listing = ("1234 libs found in cache `/etc/ld.so.cache'\n"
               "\tlibnvidia-opencl.so.1 (libc6,x86-64) => /nonexistent/libnvidia-opencl.so.1\n"
               f"\tlibnvidia-opencl.so.1 (libc6,x86-64) => {lib}\n"
               "\tlibnvidia-ml.so.1 (libc6,x86-64) => /usr/lib/libnvidia-ml.so.1\n")
    path, looked = G.find_nvidia_opencl([tmp_path / "none"], listing=listing)
    assert path == lib
    assert looked == [str(tmp_path / "none"), "ldconfig -p"]


def test_no_driver_says_where_it_looked(tmp_path: Path) -> None:
    path, looked = G.find_nvidia_opencl([tmp_path / "a", tmp_path / "b"],
                                        listing="\tlibOpenCL.so.1 (libc6,x86-64) => /x\n")
    assert path is None
    assert looked == [str(tmp_path / "a"), str(tmp_path / "b"), "ldconfig -p"]


def test_vendors_folder_names_the_driver_and_keeps_the_other_drivers(tmp_path: Path) -> None:
    lib = _touch(tmp_path / "usr" / "local" / "nvidia" / "lib64" / "libnvidia-opencl.so.1")
    system = tmp_path / "etc" / "OpenCL" / "vendors"
    system.mkdir(parents=True)
    (system / "pocl.icd").write_text("libpocl.so.2\n")
    # A driver already listed by the system is not listed twice (two NVIDIA platforms).
    (system / "nvidia-container.icd").write_text("libnvidia-opencl.so.1\n")
    (system / "README").write_text("not an icd\n")
    vendors = tmp_path / "vendors"
    written = G.write_vendors(vendors, lib, system)
    assert sorted(p.name for p in vendors.iterdir()) == ["nvidia.icd", "pocl.icd"]
    assert sorted(written) == sorted(vendors.iterdir())
    assert (vendors / "nvidia.icd").read_text() == f"{lib}\n"
    assert (vendors / "pocl.icd").read_text() == "libpocl.so.2\n"
    # Without a system folder, NVIDIA's alone.
    alone = G.write_vendors(tmp_path / "alone", lib, tmp_path / "missing")
    assert [p.name for p in alone] == ["nvidia.icd"]


def test_driver_version_is_read_from_the_library_the_link_names(tmp_path: Path) -> None:
    real = _touch(tmp_path / "libnvidia-opencl.so.580.159.03")
    link = tmp_path / "libnvidia-opencl.so.1"
    link.symlink_to(real.name)
    assert G.driver_version_from_name(link) == "580.159.03"
    assert G.driver_version_from_name(_touch(tmp_path / "other" / "libnvidia-opencl.so.1")) is None


# --- The PTX assembler's figures ----------------------------------------------------------

# NVIDIA's OpenCL build log with -cl-nv-verbose (ptxas --verbose), as recent drivers print it:
# a non-inlined helper's properties, then the kernel's, then its registers.
NV_VERBOSE_LOG = """\
ptxas info    : 0 bytes gmem
ptxas info    : Compiling entry function 'render' for 'sm_90'
ptxas info    : Function properties for trace_shadow
    32 bytes stack frame, 8 bytes spill stores, 12 bytes spill loads
ptxas info    : Function properties for render
    400 bytes stack frame, 96 bytes spill stores, 104 bytes spill loads
ptxas info    : Used 255 registers, used 0 barriers, 400 bytes cumulative stack size, \
596 bytes cmem[0], 24 bytes cmem[2]
ptxas info    : Compile time = 4321.250 ms
ptxas info    : Compiling entry function 'intersect_rays' for 'sm_90'
ptxas info    : Function properties for intersect_rays
    0 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads
ptxas info    : Used 72 registers, used 0 barriers, 412 bytes cmem[0]
"""

# Older drivers' one-line form.
NV_VERBOSE_ONE_LINE = """\
ptxas info    : Compiling entry function 'render' for 'sm_80'
ptxas info    : Used 64 registers, 0 bytes spill stores, 0 bytes spill loads, 16384 bytes smem
"""


def test_registers_and_spills_are_read_per_kernel() -> None:
    figures = S.parse_ptxas_log(NV_VERBOSE_LOG)
    assert figures["render"] == {
        "entry": True, "registers": 255, "barriers": 0, "stack_frame_bytes": 400,
        "spill_stores_bytes": 96, "spill_loads_bytes": 104, "constant0_bytes": 596,
        "compile_ms": 4321.25}
    assert figures["intersect_rays"] == {
        "entry": True, "registers": 72, "barriers": 0, "stack_frame_bytes": 0,
        "spill_stores_bytes": 0, "spill_loads_bytes": 0, "constant0_bytes": 412}
    assert figures["trace_shadow"] == {"stack_frame_bytes": 32, "spill_stores_bytes": 8,
                                       "spill_loads_bytes": 12}


def test_the_one_line_form_is_read_too() -> None:
    assert S.parse_ptxas_log(NV_VERBOSE_ONE_LINE) == {"render": {
        "entry": True, "registers": 64, "spill_stores_bytes": 0, "spill_loads_bytes": 0,
        "shared_bytes": 16384}}


def test_a_log_without_ptxas_lines_gives_nothing() -> None:
    assert S.parse_ptxas_log("") == {}
    assert S.parse_ptxas_log("warning: something about -Wpsabi\n") == {}


# --- Wheels, the package, output limits ---------------------------------------------------


def test_wheels_unpack_as_pip_installs_them(tmp_path: Path) -> None:
    wheel = tmp_path / "demo-1.0-cp312-cp312-manylinux_2_28_x86_64.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        z.writestr("demo/__init__.py", "X = 1\n")
        z.writestr("demo/.libs/libdemo.so.1", b"\x7fELF")
        z.writestr("demo-1.0.dist-info/METADATA", "Name: demo\n")
        z.writestr("demo-1.0.data/platlib/demo_ext.py", "Y = 2\n")
        z.writestr("demo-1.0.data/scripts/demo-tool", "#!/bin/sh\n")
    site = tmp_path / "site"
    G.unzip_wheels([wheel], site)
    assert (site / "demo" / "__init__.py").read_text() == "X = 1\n"
    assert (site / "demo" / ".libs" / "libdemo.so.1").exists()
    assert (site / "demo-1.0.dist-info" / "METADATA").exists()
    assert (site / "demo_ext.py").read_text() == "Y = 2\n"
    assert not any("demo-tool" in p.name for p in site.rglob("*"))


def test_the_wheels_python_is_read_from_their_abi_tags() -> None:
    names = ["pyopencl-2026.1.4-cp312-cp312-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl",
             "attrs-26.1.0-py3-none-any.whl", "cryptography-46.0-cp311-abi3-manylinux_2_28.whl",
             "siphash24-1.9-cp312-cp312-manylinux2014_x86_64.whl", "broken.whl"]
    assert G.wheel_pythons(Path(name) for name in names) == {"3.12"}
    assert G.wheel_pythons([Path("x-1-cp39-cp39-linux_x86_64.whl")]) == {"3.9"}


def test_setup_stops_in_one_line_where_the_wheels_are_for_another_python(
        tmp_path: Path) -> None:
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    (wheels / "pyopencl-2026.1.4-cp39-cp39-manylinux_2_28_x86_64.whl").write_bytes(b"")
    (wheels / "attrs-26.1.0-py3-none-any.whl").write_bytes(b"")
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=wheels, python=sys.executable,
                    work=tmp_path / "work")
    have = f"{sys.version_info[0]}.{sys.version_info[1]}"
    with pytest.raises(G.StepError) as caught:
        check.step_setup(60)
    message = str(caught.value)
    assert "\n" not in message
    assert "for Python 3.9" in message and f"is Python {have}" in message
    assert f"GPU_PYTHON={have}" in message


def test_the_package_is_assembled_as_its_wheel_lays_it_out(tmp_path: Path) -> None:
    package = G.assemble_package(ROOT, tmp_path)
    assert (package / "__init__.py").exists()
    assert (package / "kernels" / "render.cl").exists()
    assert (package / "kernels" / "__init__.py").exists()
    assert (tmp_path / "tests" / "reference_check.py").exists()
    assert not list(package.rglob("__pycache__"))


def test_long_logs_are_cut_to_their_head_and_tail(tmp_path: Path) -> None:
    log = tmp_path / "a.log"
    log.write_bytes(b"head" + b"x" * 10_000 + b"tail")
    assert not G.cap_file(log, 20_000)
    assert G.cap_file(log, 4096)
    text = log.read_bytes()
    assert len(text) <= 4096 and text.startswith(b"head") and text.endswith(b"tail")
    lines = "\n".join(str(i) for i in range(500))
    cut = G.head_and_tail(lines, 3, 2)
    assert cut.splitlines() == ["0", "1", "2", "[... 495 lines ...]", "498", "499"]


# --- Time limits --------------------------------------------------------------------------


@pytest.mark.parametrize("mode", [G.GPU_MODE, G.CPU_MODE], ids=lambda m: m.name)
def test_every_step_has_a_limit_and_the_run_fits_its_time(mode: G.Mode) -> None:
    assert set(mode.limits) == set(G.STEP_ORDER)
    assert sum(limit.min_s for limit in mode.limits.values()) < mode.deadline_s / 2
    # The GPU machine gives a run 8 minutes; the shell's last-resort limit is inside them.
    assert mode.deadline_s + 25 <= 480
    tune = mode.limits["tune"]
    assert mode.tune_budget(tune.cap_s) + mode.tune_overhead_s <= tune.cap_s
    # Squeezed to its minimum, the tune step still has its least search and its report.
    assert tune.min_s >= mode.tune_needs_s()
    assert mode.tune_budget(tune.min_s) + mode.tune_overhead_s <= tune.min_s


def test_the_tune_step_does_not_start_without_the_time_it_needs(tmp_path: Path) -> None:
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path / "work")
    check.target = "0:0"

    def child(*args: object, **kwargs: object) -> None:
        raise AssertionError("clray tune started")

    check.child = child
    outcome = check.step_tune(G.GPU_MODE.tune_needs_s() - 1)
    assert outcome.status == "timeout" and "not started" in outcome.note


def test_the_packet_profiles_come_before_the_larger_sizes(tmp_path: Path) -> None:
    """A profiles step at its limit leaves out its last runs: those at 3840x2160 with the
    default walk, not the packets' measurements that issue 41 asks a GPU for."""
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path / "work")
    check.mesh_scene = tmp_path / "mesh.toml"
    runs = [(scene, size, spp, traversal) for scene, _, size, spp, traversal
            in check.profile_runs()]
    first, second = G.GPU_MODE.sizes
    most = max(G.GPU_MODE.spps)
    assert runs == [
        *[(scene, first, spp, None) for scene in ("spheres", "mesh") for spp in G.GPU_MODE.spps],
        *[(scene, first, most, traversal) for traversal in G.PACKET_TRAVERSALS
          for scene in ("spheres", "mesh")],
        *[(scene, second, spp, None) for scene in ("spheres", "mesh")
          for spp in G.GPU_MODE.spps]]


def test_a_step_gets_its_cap_or_what_later_steps_leave(tmp_path: Path) -> None:
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path / "work")
    check.deadline = time.monotonic() + 1000
    assert check.limit_for("setup") == pytest.approx(60)
    reserve_after_profiles = sum(G.GPU_MODE.limits[s].min_s
                                 for s in ("builds", "cpu_beside", "tune"))
    check.deadline = time.monotonic() + 100
    assert check.limit_for("profiles") == pytest.approx(100 - reserve_after_profiles, abs=1)
    check.deadline = time.monotonic() - 5
    assert check.limit_for("tune") == 0


def _running(pid: int) -> bool:
    """Whether process `pid` runs (a zombie its new parent has not read yet does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rfind(")") + 2] not in "ZX"


def _wait_for_lines(path: Path, count: int, seconds: float = 20.0) -> list[int]:
    give_up = time.monotonic() + seconds
    while time.monotonic() < give_up:
        if path.exists() and len(lines := path.read_text().split()) >= count:
            return [int(pid) for pid in lines]
        time.sleep(0.05)
    raise AssertionError(f"{path} never held {count} process ids")


def _family(pids: Path, last: str = "sleep 33") -> str:
    """A shell command whose two children outlive it unless stopped: one takes SIGTERM, the
    other ignores it (only SIGKILL ends it, once the shell itself has ended)."""
    return (f"sleep 31 & echo $! >> {pids}; (trap '' TERM; exec sleep 32) & "
            f"echo $! >> {pids}; {last}")


needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


@needs_proc
def test_a_child_past_its_limit_is_stopped_with_its_children(tmp_path: Path) -> None:
    pids = tmp_path / "pids"
    start = time.monotonic()
    result = G.run_child(["bash", "-c", _family(pids, "sleep 33; echo never")], 1.0,
                         env=dict(os.environ), cwd=tmp_path, output=tmp_path / "out.txt")
    assert result.timed_out and not result.ok
    assert time.monotonic() - start < 15
    assert "never" not in result.output
    grandchildren = _wait_for_lines(pids, 2)
    assert not [pid for pid in grandchildren if _running(pid)]


@needs_proc
def test_children_a_child_leaves_behind_are_stopped(tmp_path: Path) -> None:
    pids = tmp_path / "pids"
    result = G.run_child(["bash", "-c", _family(pids, "exit 0")], 20.0,
                         env=dict(os.environ), cwd=tmp_path, output=tmp_path / "out.txt")
    assert result.ok
    assert not [pid for pid in _wait_for_lines(pids, 2) if _running(pid)]


# A run of the driver whose icd step starts processes that take their time (those of
# _family), stopped by SIGTERM (twice: the second one during the clean-up) while they run.
STOPPED_RUN = """
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import gpu_check as G
out, work, pids, command = Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4], sys.argv[5]

class Check(G.Check):
    def step_setup(self, limit):
        return G.StepOutcome("ok", "nothing to set up")

    def step_icd(self, limit):
        self.child("icd", ["bash", "-c", command], limit, cwd=self.work)
        raise G.StepError("not stopped")

out.mkdir()
work.mkdir()
sys.exit(Check(out, G.CPU_MODE, wheels=None, python=sys.executable, work=work).run())
"""


@needs_proc
def test_a_run_stopped_by_sigterm_stops_its_step_and_writes_what_it_has(tmp_path: Path) -> None:
    out, pids = tmp_path / "out", tmp_path / "pids"
    driver = subprocess.Popen([sys.executable, "-c", STOPPED_RUN, str(ROOT / "scripts"),
                               str(out), str(tmp_path / "work"), str(pids), _family(pids)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        grandchildren = _wait_for_lines(pids, 2)
        start = time.monotonic()
        driver.send_signal(signal.SIGTERM)
        time.sleep(0.2)
        driver.send_signal(signal.SIGTERM)
        output, _ = driver.communicate(timeout=30)
    finally:
        driver.kill()
    # The shell's `timeout -k` leaves it this long before SIGKILL.
    assert time.monotonic() - start < 10, output
    assert driver.returncode == 128 + signal.SIGTERM, output
    assert not [pid for pid in grandchildren if _running(pid)]
    data = json.loads((out / "gpu_check.json").read_text())
    steps = data["steps"]
    assert list(steps) == list(G.STEP_ORDER)
    assert steps["setup"]["status"] == "ok"
    assert steps["icd"]["status"] == "killed" and "SIGTERM" in steps["icd"]["note"]
    assert all(steps[name]["status"] == "skipped" and "SIGTERM" in steps[name]["note"]
               for name in G.STEP_ORDER[2:])
    assert data["result"]["exit_status"] == 128 + signal.SIGTERM
    assert data["result"]["not_ok"] == {"icd": "killed"}
    assert data["finished_utc"] and "gpu_check.json" in data["outputs"]
    log = (out / "gpu_check.log").read_text()
    assert "summary:" in log and "exit 143: stopped by SIGTERM" in log


def test_the_shell_stops_the_driver_with_sigterm_and_gives_it_time(tmp_path: Path) -> None:
    # PYTHON stands for the driver: it says when SIGTERM came and takes a second to end.
    fake = tmp_path / "python"
    fake.write_text("#!/usr/bin/env bash\n"
                    "trap 'echo got SIGTERM; sleep 1; echo ended; exit 143' TERM\n"
                    "sleep 60 & wait\n")
    fake.chmod(0o755)
    env = dict(os.environ, PYTHON=str(fake), GPU_CHECK_LIMIT="1")
    start = time.monotonic()
    done = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), str(tmp_path / "o")],
                          capture_output=True, text=True, env=env, timeout=60, check=False)
    assert done.returncode == 124
    assert "got SIGTERM" in done.stdout and "ended" in done.stdout
    assert time.monotonic() - start < 15
    # The time between SIGTERM and SIGKILL covers the driver's stop of its step's group.
    script = (ROOT / "scripts" / "gpu_check.sh").read_text()
    grace = int(re.search(r"^grace=(\d+)$", script, re.MULTILINE).group(1))
    assert grace >= sum(G.STOP_WAITS_ON_SIGNAL_S) + 3
    assert '-k "$grace"' in script
    assert G.GPU_MODE.deadline_s + 20 + grace <= 480


@needs_proc
def test_the_shell_kills_the_steps_group_of_a_driver_killed_by_sigkill(tmp_path: Path) -> None:
    # PYTHON stands for the driver: it starts a step's process in a session of its own, notes
    # its group where gpu_check.py does, and is SIGKILLed (timeout -k, the kernel's OOM killer).
    pids = tmp_path / "pids"
    fake = tmp_path / "python"
    # The id is noted once the step's session exists, as gpu_check.py's Popen (setsid before
    # exec, which Popen waits for) notes it: noted at once, a loaded machine's shell ran its
    # kill before setsid had made the group, and the sleep outlived the test. Its output goes
    # elsewhere, so that a group left alive fails the assertions, not the pipe's timeout.
    fake.write_text("#!/usr/bin/env bash\n"
                    "setsid sleep 61 >/dev/null 2>&1 & step=$!\n"
                    "until [ \"$(cut -d' ' -f5 /proc/$step/stat 2>/dev/null)\" = $step ]; do "
                    "sleep 0.01; done\n"
                    "echo $step > \"$GPU_CHECK_GROUP_FILE\"\n"
                    f"echo $step > {pids}\n"
                    "kill -KILL $$\n")
    fake.chmod(0o755)
    env = dict(os.environ, PYTHON=str(fake))
    env.pop(G.GROUP_FILE_ENV, None)
    done = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), str(tmp_path / "o")],
                          capture_output=True, text=True, env=env, timeout=60, check=False)
    step = _wait_for_lines(pids, 1)[0]
    try:
        assert done.returncode == 137, done.stderr
        assert f"killed the running step's processes (group {step})" in done.stderr
        give_up = time.monotonic() + 5
        while _running(step) and time.monotonic() < give_up:
            time.sleep(0.05)
        assert not _running(step)
    finally:
        if _running(step):
            os.kill(step, signal.SIGKILL)


def test_the_running_childs_group_is_noted_for_the_shell(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    noted = tmp_path / "group"
    monkeypatch.setenv(G.GROUP_FILE_ENV, str(noted))
    # The child may run before the driver has written the file: it waits for it.
    wait = f"for i in $(seq 200); do [ -s {noted} ] && break; sleep 0.05; done"
    result = G.run_child(["bash", "-c", f"{wait}; cat {noted}; echo pid $$"], 30,
                         env=dict(os.environ), cwd=tmp_path, output=tmp_path / "out.txt")
    group, pid = result.output.split("pid")
    assert group.strip() == pid.strip()
    assert noted.read_text() == ""  # the group has ended
    # The steps' children do not write it: only the driver's own children are noted.
    check = G.Check(tmp_path / "o", G.CPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path)
    assert G.GROUP_FILE_ENV not in check.env


def _scripted_check(tmp_path: Path, outcomes: dict[str, object]) -> G.Check:
    """A Check whose steps do nothing but end as `outcomes` says (a StepOutcome, or an
    exception to raise); the others pass."""
    (tmp_path / "out").mkdir()
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path)

    def step(name: str):
        def body(limit: float) -> G.StepOutcome:
            outcome = outcomes.get(name, G.StepOutcome("ok"))
            if isinstance(outcome, BaseException):
                raise outcome
            return outcome
        return body

    for name in G.STEP_ORDER:
        setattr(check, f"step_{name}", step(name))
    return check


def test_the_run_exits_0_when_steps_are_skipped_for_their_reasons(tmp_path: Path) -> None:
    # The GPU machine has no CPU device: cpu_beside is skipped there, every time.
    check = _scripted_check(tmp_path, {
        "cpu_beside": G.Skip("no CPU device beside the target")})
    assert check.run() == 0
    result = json.loads(check.json_path.read_text())["result"]
    assert result["exit_status"] == 0 and result["not_ok"] == {}
    assert result["skipped"] == {"cpu_beside": "no CPU device beside the target"}
    assert "exit 0" in check.log_path.read_text()
    assert "skipped: cpu_beside" in check.log_path.read_text()


@pytest.mark.parametrize("outcome", [
    G.StepError("pytest exit 1: 3 failed"), G.StepOutcome("timeout", "stopped at 90 s"),
    ValueError("a bug in the step")], ids=["failed", "timeout", "error"])
def test_the_run_exits_1_when_a_step_failed_or_ran_out_of_time(tmp_path: Path,
                                                               outcome: object) -> None:
    check = _scripted_check(tmp_path, {"scenes": outcome,
                                       "cpu_beside": G.Skip("no CPU device")})
    assert check.run() == 1
    data = json.loads(check.json_path.read_text())
    assert list(data["result"]["not_ok"]) == ["scenes"]
    assert data["steps"]["tune"]["status"] == "ok"  # the later steps ran


# --- The kernel tests' results ------------------------------------------------------------


def test_test_results_are_counted_from_the_plugins_lines(tmp_path: Path) -> None:
    lines = tmp_path / "results.jsonl"
    records = [
        {"collected": 4},
        {"nodeid": "t.py::a[nvidia-gpu]", "when": "call", "outcome": "passed",
         "duration_s": 1.5, "message": ""},
        {"nodeid": "t.py::b[nvidia-gpu]", "when": "call", "outcome": "failed",
         "duration_s": 0.5, "message": "assert 3 <= 2"},
        {"nodeid": "t.py::b[nvidia-gpu]", "when": "teardown", "outcome": "error",
         "duration_s": 0.1, "message": "teardown broke"},
        {"nodeid": "t.py::c[nvidia-gpu]", "when": "setup", "outcome": "skipped",
         "duration_s": 0.0, "message": "no fp64"},
    ]
    lines.write_text("".join(json.dumps(r) + "\n" for r in records) + '{"nodeid": "t.py::d')
    summary = G.summarise_test_results(lines)
    assert summary["collected"] == 4
    assert summary["counts"] == {"passed": 1, "failed": 1, "error": 0, "skipped": 1}
    assert summary["failures"] == {"t.py::b[nvidia-gpu]": "assert 3 <= 2"}
    assert summary["slowest"][0] == {"nodeid": "t.py::a[nvidia-gpu]", "seconds": 1.5}
    assert G.summarise_test_results(tmp_path / "none.jsonl")["counts"]["passed"] == 0


def test_the_plugin_records_outcomes_not_passing_set_ups() -> None:
    def report(when: str, outcome: str, longrepr: object = None) -> pytest.TestReport:
        return pytest.TestReport("t.py::a", ("t.py", 1, "a"), {}, outcome, longrepr, when)

    assert P.result_line(report("setup", "passed")) is None
    assert P.result_line(report("teardown", "passed")) is None
    assert P.result_line(report("call", "passed"))["outcome"] == "passed"
    assert P.result_line(report("setup", "skipped", ("t.py", 1, "Skipped: no fp64")))[
        "outcome"] == "skipped"
    failed = P.result_line(report("setup", "failed", "x" * 5000))
    assert failed["outcome"] == "error"
    assert len(failed["message"]) <= P.MESSAGE_CHARS + 3


def test_the_named_test_files_run_first_in_their_order() -> None:
    items = [SimpleNamespace(path=Path("tests") / name, n=i) for i, name in enumerate(
        ["test_a.py", "test_b.py", "test_render.py", "test_b.py", "test_layout.py"])]
    ordered = P.first_files_first(items, ["test_layout.py", "test_render.py", "missing.py"])
    assert [item.n for item in ordered] == [4, 2, 0, 1, 3]


def test_pytest_summary_line_is_found() -> None:
    output = "....F\n=== short test summary info ===\nFAILED t.py::b\n1 failed, 4 passed in 2s\n"
    assert G.last_summary_line(output) == "1 failed, 4 passed in 2s"
    assert G.last_summary_line("") is None


def test_a_test_past_its_limit_leaves_every_threads_stack_in_the_log(tmp_path: Path) -> None:
    """pytest-timeout's thread method writes its dump to the terminal, which an xdist worker
    has not: the log said only "worker 'gw0' crashed". pytest's faulthandler dumps the stacks
    to the worker's stderr before the limit. Where this Python lacks pytest-timeout or
    pytest-xdist, the dump alone is checked (the test then ends by itself)."""
    import importlib.util

    has = {name: importlib.util.find_spec(name) is not None
           for name in ("pytest_timeout", "xdist")}
    args = G.kernel_test_limit_args(4)
    stacks_at = float(next(a for a in args if a.startswith("faulthandler_timeout="))
                      .partition("=")[2])
    assert 0 < stacks_at < 4
    assert G.kernel_test_limit_args(60)[-1] == "faulthandler_timeout=55"
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_hang.py").write_text(
        "import time\n\n"
        "def waiting_in_the_driver():\n"
        f"    time.sleep({60 if has['pytest_timeout'] else 6})\n\n"
        "def test_hangs():\n"
        "    waiting_in_the_driver()\n")
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           "--rootdir", str(tmp_path)]
    if has["pytest_timeout"]:
        cmd += args
    else:
        cmd += args[-2:]
    if has["xdist"]:
        cmd += ["-n", "1"]
    log = tmp_path / "kernel_tests.log"
    with open(log, "wb") as out:  # stdout and stderr to one file, as run_child writes them
        subprocess.run([*cmd, "test_hang.py"], cwd=tmp_path, stdout=out, stderr=out,
                       stdin=subprocess.DEVNULL, timeout=60, check=False)
    text = log.read_text(errors="replace")
    assert "in waiting_in_the_driver" in text, text
    if has["pytest_timeout"] and has["xdist"]:
        assert "worker 'gw0' crashed" in text


# --- The scene comparison's images --------------------------------------------------------


def test_difference_image_marks_pixels_over_the_threshold() -> None:
    a = np.zeros((2, 3, 3), np.float32)
    b = a.copy()
    b[0, 0] = 1 / 255  # under 2/255: grey
    b[0, 1, 2] = 0.5  # over: red
    b[1, 2] = np.nan  # not finite: magenta
    diff = S.difference_image(a, b)
    assert diff.shape == (2, 3, 3) and np.isfinite(diff).all()
    assert np.allclose(diff[0, 0], (1 / 8,) * 3)
    assert tuple(diff[0, 1]) == (1.0, 0.0, 0.0)
    assert tuple(diff[1, 2]) == (1.0, 0.0, 1.0)
    assert tuple(diff[1, 0]) == (0.0, 0.0, 0.0)


def test_the_worst_scene_is_the_failing_one_then_the_most_pixels_off() -> None:
    ok = {"status": "pass", "nonfinite": 0, "over_2_255": 3, "rmse": 0.01}
    results = {"a": ok, "b": {**ok, "over_2_255": 5}, "c": {"status": "error"}}
    assert S.worst_scene(results) == "b"
    results["d"] = {**ok, "status": "FAIL", "over_2_255": 1}
    assert S.worst_scene(results) == "d"
    assert S.worst_scene({"c": {"status": "error"}}) is None


# --- The builds step -----------------------------------------------------------------------


def test_a_process_starts_only_with_time_left_and_its_failure_is_said(tmp_path: Path) -> None:
    now = time.monotonic()
    assert S.in_new_process(["echo", "hi"], now + 30) == "hi\n"
    with pytest.raises(S.OutOfTime):
        S.in_new_process(["echo", "hi"], now + S.MIN_PROCESS_S / 2)
    with pytest.raises(S.OutOfTime):
        S.in_new_process(["echo", "hi"], now + 30, start_by=now)
    with pytest.raises(ValueError, match="exit 3: the error"):
        S.in_new_process(["bash", "-c", "echo the error >&2; exit 3"], now + 30)
    with pytest.raises(ValueError, match="no result within 1 s"):
        S.in_new_process(["sleep", "5"], now + 30, most_s=1)


class _DeviceWithoutSomeQueries:
    """A GPU whose driver answers some of clray's device queries with an error."""

    def __init__(self) -> None:
        import pyopencl as cl

        self.type = cl.device_type.GPU
        self.platform = SimpleNamespace(name="NVIDIA CUDA ", version="OpenCL 3.0 CUDA 13.0")
        self.name, self.vendor = "Fake GPU ", "NVIDIA Corporation"
        self.version, self.driver_version = "OpenCL 3.0 CUDA", "580.159.04"
        self.opencl_c_version = "OpenCL C 1.2 "
        self.max_compute_units, self.max_clock_frequency = 132, 1980
        self.global_mem_size, self.local_mem_size = 80 * 2**30, 48 * 2**10
        self.max_mem_alloc_size, self.max_work_group_size = 20 * 2**30, 1024
        self.preferred_vector_width_float = self.native_vector_width_float = 1
        self.extensions = "cl_khr_fp64 cl_nv_compiler_options cl_nv_device_attribute_query"
        self.double_fp_config = int(cl.device_fp_config.FMA)
        self.compute_capability_major_nv, self.compute_capability_minor_nv = 9, 0

    @property
    def host_unified_memory(self) -> bool:
        import pyopencl as cl

        raise cl.LogicError("clGetDeviceInfo failed: INVALID_VALUE")

    @property
    def single_fp_config(self) -> int:
        import pyopencl as cl

        raise cl.LogicError("clGetDeviceInfo failed: INVALID_VALUE")


def test_a_device_query_that_fails_loses_only_its_own_figure() -> None:
    record = S.device_record("0:0", _DeviceWithoutSomeQueries())
    assert record["host_unified_memory"] is None
    assert record["single_fp_config"] is None
    # clray's own build options take an unanswered single_fp_config as no correctly rounded
    # division (clray.device.program), so the GPU's options are there all the same.
    from clray.device.program import GPU_BUILD_OPTIONS

    assert record["device_build_options"] == list(GPU_BUILD_OPTIONS)
    assert set(record["query_errors"]) == {"host_unified_memory", "single_fp_config"}
    assert "INVALID_VALUE" in record["query_errors"]["host_unified_memory"]
    assert record["name"] == "Fake GPU" and record["type"] == "GPU"
    assert record["double_fp_config"] == ["FMA"] and record["fp64"] is True
    assert record["compute_capability_major_nv"] == 9
    assert record["registers_per_block_nv"] is None


def test_a_failed_device_listing_still_gives_the_later_steps_its_device(
        tmp_path: Path) -> None:
    check = G.Check(tmp_path / "out", G.GPU_MODE, wheels=None, python=sys.executable,
                    work=tmp_path / "work")
    check.out.mkdir()
    check.work.mkdir()
    target = {"spec": "0:0", "test_id": "nvidia-gpu", "name": "Fake GPU",
              "platform": "NVIDIA CUDA", "driver_version": "580", "version": "OpenCL 3.0"}

    def child(name: str, cmd: list, limit_s: float, **kwargs: object) -> G.ChildResult:
        if "device-info" in map(str, cmd):
            path = Path(cmd[list(map(str, cmd)).index("--json") + 1])
            path.write_text(json.dumps({"devices": [target], "target": target}))
            return G.ChildResult(list(cmd), 1, 0.1, False, "Traceback: LogicError")
        return G.ChildResult(list(cmd), 0, 0.1, False, "0:0 GPU Fake GPU\n")

    check.child = child
    with pytest.raises(G.StepError, match="the steps run on 0:0"):
        check.step_devices(45)
    assert check.need_device() == "0:0"
    assert check.test_device == "nvidia-gpu"
    assert check.env["CLRAY_DEVICE"] == "0:0"


@dataclasses.dataclass
class FakeConfig:
    scene: str
    spp: int | None = None
    traversal: str = "default"
    precision: str = "float"

    def options(self) -> list[str]:
        return [f"-D{k}={v}" for k, v in dataclasses.asdict(self).items()]


def _fake_builds(monkeypatch: pytest.MonkeyPatch, calls: list[str],
                 cold_fails: set[str] = frozenset(), left: list[int] | None = None) -> None:
    """cmd_builds without a device: scenes pack to FakeConfigs (broken.toml does not); every
    new process is answered here: the sample-packet build fails to compile (as on the first
    GPU run), the group-packet one prints no JSON, the others succeed; cold builds of the
    scenes in `cold_fails` fail; after `left[0]` processes there is no time left."""
    import clray.device.context as context
    import clray.device.program as program

    def scene_config(path: Path, device: object, spp: int | None = None,
                     **settings: object) -> FakeConfig:
        if Path(path).stem == "broken":
            raise ValueError("no such material")
        return FakeConfig(Path(path).stem, spp, **settings)

    def in_new_process(cmd: list[str], end: float, env: object = None, **kwargs: object) -> str:
        if left is not None:
            if left[0] <= 0:
                raise S.OutOfTime
            left[0] -= 1
        if "nv-build" in cmd:
            config = json.loads(cmd[cmd.index("--config") + 1])
            calls.append(f"nv-build {config['scene']} {config['traversal']}")
            if config["traversal"] == "sample_packet":
                raise ValueError("exit 1: error: passing 'REAL __generic (*)[4]'")
            if config["traversal"] == "group_packet":
                return "Segmentation fault\n"
            return json.dumps({"build_s": 0.5, "verbose": True, "log": "",
                               "kernels": {"render": {"registers": 128}}}) + "\n"
        if "--build-only" in cmd:
            scene = json.loads(cmd[cmd.index("--build-only") + 1])["scene"]
            calls.append(f"build-only {scene}")
            if scene in cold_fails:
                raise ValueError("exit 1: clray: error: CL_OUT_OF_RESOURCES")
            return json.dumps({"build_s": 0.2, "context_s": 0.1}) + "\n"
        calls.append("floor")
        return "0.01\n"

    monkeypatch.setattr(S, "scene_config", scene_config)
    monkeypatch.setattr(S, "in_new_process", in_new_process)
    monkeypatch.setattr(context, "select_device", lambda spec: SimpleNamespace(
        extensions="cl_khr_fp64 cl_nv_compiler_options"))
    monkeypatch.setattr(context, "has_fp64", lambda device: True)
    monkeypatch.setattr(program, "private_stack_bytes", lambda config: {"total": 64})


def test_builds_record_each_failure_and_go_on_with_the_register_figures_first(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    _fake_builds(monkeypatch, calls, cold_fails={"mesh"})
    out = tmp_path / "builds.json"
    rc = S.main(["builds", "--json", str(out), "--device", "x", "--no-examples",
                 "--scene", "spheres=spheres.toml", "--scene", "mesh=mesh.toml",
                 "--scene", "broken=broken.toml", "--spp", "1", "--spp", "4"])
    assert rc == 1
    report = json.loads(out.read_text())
    status = {record["labels"][0]: record["status"] for record in report["configurations"]}
    assert status == {"spheres 1 spp": "ok", "spheres 4 spp": "ok", "mesh 1 spp": "ok",
                      "mesh 4 spp": "ok", "spheres 4 spp sample_packet": "failed",
                      "spheres 4 spp group_packet": "failed", "spheres 1 spp double": "ok",
                      "broken 1 spp": "failed", "broken 4 spp": "failed"}
    errors = {record["labels"][0]: record.get("error", "") for record in
              report["configurations"]}
    assert "__generic" in errors["spheres 4 spp sample_packet"]
    assert "JSONDecodeError" in errors["spheres 4 spp group_packet"]
    assert "no such material" in errors["broken 1 spp"]
    assert all(record["kernels"]["render"]["registers"] == 128
               for record in report["configurations"] if record["status"] == "ok")
    # The register figures before any cold or warm build.
    first_cold = calls.index("build-only spheres")
    assert all(call.startswith("nv-build") for call in calls[:first_cold])
    assert not any(call.startswith("nv-build") for call in calls[first_cold:])
    cold_warm = report["cold_warm"]
    assert set(cold_warm["spheres"]) == {"spp", "cold_s", "warm_s", "warm_again_s",
                                         "context_cold_s", "context_warm_s",
                                         "warm_without_pyopencl_cache_s", "floor_warm_s"}
    assert "CL_OUT_OF_RESOURCES" in cold_warm["mesh"]["errors"]["cold_s"]
    assert "cold_s" not in cold_warm["mesh"] and "warm_s" not in cold_warm["mesh"]
    assert cold_warm["broken"]["errors"]
    assert calls.count("build-only mesh") == 1  # nothing after its failed cold build


def test_cold_and_warm_builds_start_no_process_past_the_time_limit(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    _fake_builds(monkeypatch, calls, left=[2])
    times = S.cold_and_warm(FakeConfig("spheres", 1), "x", time.monotonic() + 60)
    assert calls == ["build-only spheres", "build-only spheres"]
    assert set(times) == {"cold_s", "context_cold_s", "warm_s", "context_warm_s", "unfinished"}
    assert times["unfinished"] == ["warm_again_s", "warm_without_pyopencl_cache_s",
                                   "floor_warm_s"]


def test_cold_and_warm_builds_get_clray_profiles_caches_all_on(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The caches `clray profile` moves for its cold build (clray.profile.cache_env), empty
    # for the cold build and shared by the rest; NVIDIA's and pyopencl's on even where this
    # environment turns them off, bar the build measured without pyopencl's.
    from clray.profile import CACHE_FOLDERS

    monkeypatch.setenv("CUDA_CACHE_DISABLE", "1")
    monkeypatch.setenv("PYOPENCL_NO_CACHE", "1")
    envs: list[tuple[str, dict[str, str], bool]] = []  # process, env, its caches all empty

    def in_new_process(cmd: list[str], end: float, env: dict[str, str] | None = None,
                       **kwargs: object) -> str:
        assert env is not None
        empty = not any(Path(env[name]).exists() for name in CACHE_FOLDERS)
        for name in CACHE_FOLDERS:  # what a build leaves in its caches
            Path(env[name]).mkdir(parents=True, exist_ok=True)
        envs.append(("build-only" if "--build-only" in cmd else "floor", env, empty))
        if "--build-only" in cmd:
            return json.dumps({"build_s": 0.2, "context_s": 0.1}) + "\n"
        return "0.01\n"

    monkeypatch.setattr(S, "in_new_process", in_new_process)
    times = S.cold_and_warm(FakeConfig("spheres", 1), "x", time.monotonic() + 60)
    assert "errors" not in times and "unfinished" not in times
    assert [(kind, empty) for kind, _, empty in envs] == [
        ("build-only", True), ("build-only", False), ("build-only", False),
        ("build-only", False), ("floor", False), ("floor", False)]
    caches = {name: envs[0][1][name] for name in CACHE_FOLDERS}
    assert all(Path(folder).parent == Path(caches["XDG_CACHE_HOME"]).parent
               for folder in caches.values())
    assert all({name: env[name] for name in CACHE_FOLDERS} == caches for _, env, _ in envs)
    assert not any("CUDA_CACHE_DISABLE" in env for _, env, _ in envs)
    assert [env.get("PYOPENCL_NO_CACHE") for _, env, _ in envs] == [None, None, None, "1",
                                                                    "1", "1"]


def test_a_configurations_build_ends_soon_after_the_cold_and_warm_builds_time_begins(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert S.config_build_limit(100.0, 200.0) == S.BUILD_TIMEOUT_S
    assert S.config_build_limit(100.0, 105.0) == pytest.approx(5 + S.BUILD_OVERRUN_S)
    # The least a build that may still start gets: MIN_PROCESS_S before the share begins.
    assert S.config_build_limit(100.0, 100.0 + S.MIN_PROCESS_S) >= S.MIN_PROCESS_S
    # cmd_builds asks each configuration's build for no more: 10 s, 4 of them kept back.
    calls: list[str] = []
    _fake_builds(monkeypatch, calls)
    limits: list[float] = []
    answer = S.in_new_process

    def in_new_process(cmd: list[str], end: float, env: object = None,
                       **kwargs: float) -> str:
        if "nv-build" in cmd:
            limits.append(kwargs["start_by"] + S.BUILD_OVERRUN_S - time.monotonic()
                          - kwargs["most_s"])
        return answer(cmd, end, env, **kwargs)

    monkeypatch.setattr(S, "in_new_process", in_new_process)
    S.main(["builds", "--json", str(tmp_path / "b.json"), "--device", "x", "--no-examples",
            "--scene", "spheres=spheres.toml", "--spp", "1", "--time-limit", "10"])
    assert limits and all(slack >= -0.5 for slack in limits)


# --- A whole --cpu run --------------------------------------------------------------------


def _has_pocl() -> bool:
    from clray.device.context import list_devices
    from clray.errors import DeviceError

    try:
        return any(d.platform == "Portable Computing Language" for d in list_devices())
    except DeviceError:
        return False


@pytest.mark.slow
def test_cpu_mode_runs_every_step_on_pocl(tmp_path: Path) -> None:
    if not _has_pocl():
        if os.environ.get("CI", "").lower() not in ("", "0", "false") or os.environ.get(
                "CLRAY_REQUIRE_DEVICE") == "1":
            pytest.fail("no PoCL device, and CI needs one")
        pytest.skip("no PoCL device")
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k not in ("CLRAY_DEVICE", "PYOPENCL_CTX")}
    env["PYTHON"] = sys.executable
    done = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), str(out), "--cpu"],
                          capture_output=True, text=True, env=env, timeout=600, check=False)
    summary = done.stdout[done.stdout.rfind("summary:"):] if "summary:" in done.stdout else ""
    assert done.returncode == 0, (summary or done.stdout[-3000:]) + done.stderr[-3000:]

    files = [p for p in out.rglob("*") if p.is_file()]
    assert 0 < len(files) <= 8
    assert all(p.stat().st_size < 16 * 2**20 for p in files)
    assert all(p.name.replace(".", "").replace("_", "").replace("-", "").isalnum()
               for p in files)
    assert (out / "gpu_check.log").stat().st_size > 0
    data = json.loads((out / "gpu_check.json").read_text())
    assert list(data["steps"]) == list(G.STEP_ORDER)
    assert {name: step["status"] for name, step in data["steps"].items()} == {
        name: "ok" for name in G.STEP_ORDER}
    assert data["device"]["platform"] == "Portable Computing Language"
    assert data["software"]["clray_file"].endswith(str(Path("root", "clray", "__init__.py")))
    assert data["kernel_tests"]["counts"]["passed"] > 0
    assert data["kernel_tests"]["counts"]["failed"] == 0
    scenes = data["scenes"]["results"]
    assert set(scenes) == {p.stem for p in (ROOT / "scenes").glob("*.toml")}
    assert all(r["status"] == "pass" for r in scenes.values())
    assert all(r["cpu_opencl_ulps_over_2_255"] >= 0 for r in scenes.values())
    assert {p.name for p in files} >= {"gpu_check.json", "gpu_check.log", *S.PNG_NAMES}
    profiles = data["profiles"]
    assert [(p["scene"], p["spp"], p["traversal"]) for p in profiles] == [
        ("spheres", 1, "default"), ("spheres", 4, "default"), ("mesh", 1, "default"),
        ("mesh", 4, "default"), ("spheres", 4, "sample_packet"), ("mesh", 4, "sample_packet"),
        ("spheres", 4, "group_packet"), ("mesh", 4, "group_packet")]
    assert [p["profile"]["traversal"] for p in profiles[4:]] == [p["traversal"]
                                                                for p in profiles[4:]]
    assert all(p["profile"]["mrays_per_s"] > 0 for p in profiles)
    assert set(data["builds"]["cold_warm"]) == {"spheres", "mesh"}
    assert all(set(times) == {"spp", "cold_s", "warm_s", "warm_again_s", "context_cold_s",
                              "context_warm_s", "warm_without_pyopencl_cache_s",
                              "floor_warm_s"}
               and min(times.values()) > 0 for times in data["builds"]["cold_warm"].values())
    beside = data["cpu_beside"]["renders"]
    assert set(beside) == {"spheres", "mesh"}
    assert all(r["default"]["device"] == r["cpu"]["device"] == data["scenes"]["device"]
               and r["cpu_over_default_kernel"] > 0 for r in beside.values())
    assert all(c["status"] == "ok" for c in data["builds"]["configurations"])
    assert data["tune"]["results"]["best"]["label"]


def _processes_under(folder: Path) -> list[str]:
    """The processes whose working folder is under `folder` (the run's children work in its
    temporary folder, removed or not)."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and os.readlink(proc / "cwd").startswith(str(folder)) \
                    and _running(int(proc.name)):
                found.append((proc / "cmdline").read_bytes().replace(b"\0", b" ").decode())
        except OSError:
            continue
    return found


@pytest.mark.slow
@needs_proc
def test_cpu_mode_stopped_by_the_shells_limit_leaves_no_process_and_its_json(
        tmp_path: Path) -> None:
    # The shell stops the driver mid-step (12 s: about the profiles): SIGTERM, then the
    # driver stops that step's processes and writes its JSON and log before SIGKILL.
    if not _has_pocl():
        pytest.skip("no PoCL device")
    out, tmp = tmp_path / "out", tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("CLRAY_DEVICE", "PYOPENCL_CTX")}
    env.update(PYTHON=sys.executable, GPU_CHECK_LIMIT="12", TMPDIR=str(tmp))
    done = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), str(out), "--cpu"],
                          capture_output=True, text=True, env=env, timeout=120, check=False)
    assert done.returncode == 124, done.stdout[-3000:] + done.stderr[-3000:]
    assert not _processes_under(tmp)
    data = json.loads((out / "gpu_check.json").read_text())
    statuses = [step["status"] for step in data["steps"].values()]
    assert list(data["steps"]) == list(G.STEP_ORDER)
    assert statuses.count("killed") <= 1 and "running" not in statuses
    assert data["result"]["exit_status"] == 128 + signal.SIGTERM
    assert "summary:" in (out / "gpu_check.log").read_text()


@pytest.mark.parametrize(("status", "over", "nonfinite", "reference_nonfinite", "spread",
                          "judged"), [
    ("pass", 0, 0, 0, 0, "pass"),
    ("FAIL", 45, 0, 0, 50, "pass"),  # the first GPU run's depth_of_field, within the CPU's spread
    ("FAIL", 45, 0, 0, 44, "FAIL"),
    ("FAIL", 3, 1, 0, 50, "FAIL"),  # a non-finite pixel is never rounding
    ("FAIL", 0, 0, 1, 50, "FAIL"),  # nor one in the reference, which fails every variant
])
def test_a_scene_within_the_cpus_spread_at_opencl_accuracy_passes(
        status, over, nonfinite, reference_nonfinite, spread, judged) -> None:
    record = {"status": status, "over_2_255": over, "nonfinite": nonfinite,
              "reference_nonfinite": reference_nonfinite}
    assert S.judged(record, spread) == judged
