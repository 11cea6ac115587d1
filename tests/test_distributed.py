"""Rendering on a real Dask cluster (a LocalCluster of 2 worker processes): tiles assembled bit
for bit as the single-process render, frames as tasks, a killed worker survived, an unreachable
scheduler refused in time. Dask itself is optional (clray[dask]); without it only the tests of
the missing-Dask message run."""

from __future__ import annotations

import contextlib
import importlib.metadata
import importlib.util
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import ClassVar

import pytest
from conftest import shared_packing_scene

from clray import cli
from clray.errors import EXIT_RUNTIME, EXIT_SCENE
from clray.image_io import read_pfm
from clray.render import RenderSettings, render
from clray.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent
SPHERES = ROOT / "scenes" / "spheres.toml"

needs_dask = pytest.mark.skipif(
    importlib.util.find_spec("distributed") is None,
    reason="Dask distributed is not installed (pip install 'clray[dask]')")


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def test_core_imports_no_dask():
    done = _run("import sys, clray, clray.cli, clray.sequence, clray.render\n"
                "print(sorted(m for m in sys.modules if m.split('.')[0] in "
                "('dask', 'distributed')))")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_without_dask_says_how_to_install(tmp_path):
    # `distributed` made unimportable as it is where the extra is not installed.
    done = _run("import sys; sys.modules['distributed'] = None\n"
                "from clray.cli import main\n"
                f"sys.exit(main(['render', {str(SPHERES)!r}, '--dask', "
                f"'-o', {str(tmp_path / 'x.png')!r}]))")
    assert done.returncode == EXIT_RUNTIME
    assert done.stderr == ("clray: error: --dask needs Dask distributed, which is not "
                           "installed: pip install 'clray[dask]'\n")
    assert not (tmp_path / "x.png").exists()


@pytest.fixture(scope="module")
def client():
    if needs_dask.args[0]:
        pytest.skip(needs_dask.kwargs["reason"])
    from clray.distributed import connect

    with connect(None, workers=2) as c:
        yield c


def small(spp: int = 2) -> RenderSettings:
    return RenderSettings(width=96, height=64, spp=spp, device=os.environ["CLRAY_DEVICE"])


@needs_dask
def test_tiles_assemble_bit_identical(cl_device, client):
    from clray.distributed import render_still

    scene = load_scene(SPHERES)
    local = render(scene, small())
    for tile_rows in (5, None):  # uneven fixed tiles; tiles sized by the measured rate
        result = render_still(client, scene, small(), tile_rows=tile_rows)
        assert result.image.tobytes() == local.image.tobytes()
        assert result.stats["rays"] == local.stats["rays"]
    fixed = render_still(client, scene, small(), tile_rows=5)
    # The knobs and walk that rendered, as docs/cli.md's --stats-json promises.
    assert (fixed.stats["tuning"], fixed.stats["traversal"]) == (local.stats["tuning"],
                                                                 local.stats["traversal"])
    dask = fixed.stats["dask"]
    assert dask["tiles"] == 13 and dask["tile_rows"] == [4, 5]
    assert dask["workers"] == 2
    assert dask["bytes_sent"] == 2 * dask["scene_bytes"] > 0
    assert dask["result_bytes"] == local.image.nbytes


def test_workers_that_rendered_with_other_knobs_are_each_named() -> None:
    from clray.distributed import _merge

    def tile(worker: str, tuning: dict, traversal: str) -> dict:
        stats = {"rays": dict.fromkeys(("primary", "secondary", "shadow", "total"), 1),
                 "kernel_s": 1.0, "build_s": 0.0, "launches": 1, "device_bytes": 8}
        return {"worker": worker, "device": "cpu", "device_s": 0.0, "bvh_s": 0.0, "pack_s": 0.0,
                "stats": stats, "tuning": tuning, "traversal": traversal}

    default, tuned = {"source": "default"}, {"source": "tuning file t.json"}
    small_cpu = RenderSettings(width=8, height=6)
    same = _merge([tile("a", default, "single"), tile("b", default, "single")], {}, small_cpu)
    assert (same["tuning"], same["traversal"]) == (default, "single")
    apart = _merge([tile("b", tuned, "sample_packet"), tile("a", default, "single"),
                    tile("b", tuned, "sample_packet")], {}, small_cpu)
    assert apart["tuning"] == {"a": default, "b": tuned}
    assert apart["traversal"] == {"a": "single", "b": "sample_packet"}


@needs_dask
def test_scene_sent_and_packed_once_per_worker(cl_device, client):
    """Tasks refer to the scattered scene: while tiles render, each worker holds one copy, and
    each worker packs it once for all its tiles."""
    from clray.distributed import render_still

    scene = load_scene(SPHERES)
    copies: list[int] = []

    def count_scene_copies(done: int, submitted: int) -> None:
        copies.append(sum(len(workers) for key, workers in client.who_has().items()
                          if str(key).startswith("Scene-")))

    result = render_still(client, scene, small(), tile_rows=8, on_tile=count_scene_copies)
    # Never more than one copy a worker (the scene is not sent with each tile). Dask may drop a
    # replica of an idle worker mid-render (seen once on Intel's runtime: 2, 2, 1, 1, ...), so
    # the count is not pinned at 2; a worker that then needed the scene again would pack it
    # again, which the packs check below would catch.
    assert len(copies) == 8 and all(1 <= c <= 2 for c in copies), copies
    dask = result.stats["dask"]
    assert dask["packs"] == len(dask["tiles_by_worker"]) <= 2
    # Forgotten once rendered. The cancel goes on the client's batched stream, up to its
    # interval (10 ms) behind a tile released just before it, and who_has on a connection of
    # its own may overtake it: asked until the scene is gone (or the wait is absurd).
    deadline = time.monotonic() + 60
    while any(str(k).startswith("Scene-") for k in client.who_has()):
        assert time.monotonic() < deadline, "the scene is still held on the workers"
        time.sleep(0.05)


@needs_dask
def test_settings_that_are_not_render_settings_are_refused_before_any_work():
    from clray.distributed import render_sequence, render_still
    from clray.errors import SettingsError

    # No client: the settings are refused before it is asked for anything.
    with pytest.raises(SettingsError, match=r"expected a clray\.RenderSettings or None, got dict"):
        render_still(None, load_scene(SPHERES), {"width": 4})
    with pytest.raises(SettingsError, match=r"expected a clray\.RenderSettings or None, got dict"):
        render_sequence(None, None, [0], {"width": 4}, lambda frame, result: None)


@needs_dask
def test_deep_glass_without_min_weight_is_warned_about(cl_device, client):
    from clray.distributed import render_still

    glass = load_scene(ROOT / "scenes" / "glass.toml")
    # Just over the depth that warns, on a few pixels: the tree stays small enough to render.
    settings = RenderSettings(width=16, height=12, spp=1, max_depth=21)
    with pytest.warns(UserWarning, match="set min_weight"):
        render_still(client, glass, settings)


@needs_dask
def test_killed_worker_loses_no_tile(cl_device, client):
    from clray.distributed import render_still

    scene = load_scene(SPHERES)
    settings = RenderSettings(width=160, height=96, spp=24, device=os.environ["CLRAY_DEVICE"])
    local = render(scene, settings)
    pids = client.run(os.getpid)
    killed: list[int] = []

    def kill_a_busy_worker(done: int, submitted: int) -> None:
        if killed:
            return
        busy = [w for w, keys in client.processing().items() if keys]
        assert busy, "no tile left in flight to lose: make the render longer"
        killed.append(pids[busy[0]])
        os.kill(pids[busy[0]], signal.SIGKILL)

    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    result = render_still(client, scene, settings, tile_rows=4, on_tile=kill_a_busy_worker)
    assert killed
    assert result.image.tobytes() == local.image.tobytes()
    assert result.stats["dask"]["tiles"] == 24
    # The nanny restarts the worker; the next tests get two again.
    client.wait_for_workers(2, timeout=60)


@needs_dask
def test_the_only_worker_killed_sends_the_scene_again_once(cl_device):
    """With every worker holding the scene gone, the scheduler forgets it and cancels the tiles
    that need it (they came back as FutureCancelledError, a traceback): the scene is sent again
    and those tiles rendered, once; lost a second time, the render is one ClrayError."""
    from clray.distributed import connect, render_still
    from clray.errors import ClrayError

    scene = load_scene(SPHERES)
    settings = RenderSettings(width=64, height=48, spp=4, device=os.environ["CLRAY_DEVICE"])
    local = render(scene, settings)
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    with connect(None, workers=1) as one:

        def kill_the_worker(times: int) -> Callable[[int, int], None]:
            killed: list[int] = []

            def on_tile(done: int, submitted: int) -> None:
                if len(killed) < times:
                    [pid] = one.run(os.getpid).values()  # the nanny's restarted one after a kill
                    killed.append(pid)
                    os.kill(pid, signal.SIGKILL)

            return on_tile

        result = render_still(one, scene, settings, tile_rows=4, on_tile=kill_the_worker(1))
        assert result.image.tobytes() == local.image.tobytes()
        dask = result.stats["dask"]
        assert dask["tiles"] == 12 and dask["bytes_sent"] == 2 * dask["scene_bytes"]
        one.wait_for_workers(1, timeout=60)
        with pytest.raises(ClrayError, match=r"^rows \d+ to \d+ not rendered: every Dask worker "
                           r"holding the scene was lost, again after it was sent once more$"):
            render_still(one, scene, settings, tile_rows=4, on_tile=kill_the_worker(2))


@needs_dask
def test_cli_dask_still_equals_local(cl_device, tmp_path, capsys):
    args = ["render", str(SPHERES), "-W", "80", "-H", "48", "--spp", "2"]
    assert cli.main([*args, "-o", str(tmp_path / "local.pfm"), "-q"]) == 0
    assert cli.main([*args, "-o", str(tmp_path / "dask.pfm"), "--dask", "--dask-workers",
                     "2"]) == 0
    err = capsys.readouterr().err
    assert "dask: 1 tile on 2 workers" in err or "dask: 2 tiles on 2 workers" in err, err
    assert (read_pfm(tmp_path / "dask.pfm").tobytes()
            == read_pfm(tmp_path / "local.pfm").tobytes())


@needs_dask
def test_cli_dask_frames_render_and_resume(cl_device, tmp_path, capsys):
    scene = str(ROOT / "scenes" / "orbit.toml")
    size = ["-W", "32", "-H", "18", "--spp", "1"]
    local, dask = tmp_path / "l_%02d.pfm", tmp_path / "d_%02d.pfm"
    assert cli.main(["render", scene, *size, "--frames", "0:3", "-o", str(local), "-q"]) == 0
    assert cli.main(["render", scene, *size, "--frames", "0:2", "-o", str(dask), "--dask",
                     "-q"]) == 0
    stats = tmp_path / "stats.json"
    assert cli.main(["render", scene, *size, "--frames", "0:3", "-o", str(dask), "--dask",
                     "--resume", "--stats-json", str(stats)]) == 0
    err = capsys.readouterr().err
    assert "dask: 1 frame on 2 workers" in err and "2 complete already" in err, err
    [record] = json.loads(stats.read_text())["frames"]
    assert record["frame"] == 2 and record["load_s"] >= 0  # its scene made on the worker
    for f in range(3):
        assert (read_pfm(tmp_path / f"d_{f:02d}.pfm").tobytes()
                == read_pfm(tmp_path / f"l_{f:02d}.pfm").tobytes())


@needs_dask
def test_dask_frames_that_share_a_packing_are_the_local_frames(cl_device, tmp_path, capsys):
    """Each worker packs frame 0's objects once and moves them to its frames' eyes and
    instances' places (the client's packing is not sent): frames split between workers,
    whichever frames each gets, are the single-process frames bit for bit."""
    scene = str(shared_packing_scene(tmp_path, "turntable"))
    size = ["-W", "32", "-H", "18", "--spp", "1"]
    local, dask = tmp_path / "l_%02d.pfm", tmp_path / "d_%02d.pfm"
    assert cli.main(["render", scene, *size, "--frames", "0:5", "-o", str(local), "-q"]) == 0
    assert cli.main(["render", scene, *size, "--frames", "1:5", "-o", str(dask), "--dask",
                     "-q"]) == 0
    for f in range(1, 5):
        assert (read_pfm(tmp_path / f"d_{f:02d}.pfm").tobytes()
                == read_pfm(tmp_path / f"l_{f:02d}.pfm").tobytes())


@needs_dask
def test_a_frame_failing_on_a_local_cluster_is_one_line(cl_device, tmp_path):
    """The workers log a failed task (distributed.worker's "Compute Failed", with its
    traceback) at ERROR; the client reports it as one line, so they must say nothing."""
    scene = tmp_path / "overshoot.toml"
    # A Catmull-Rom track through 0, 1, 1, 0 overshoots past 1 between its middle keys: frame 3
    # has reflect 1.125, which loading that frame refuses.
    scene.write_text((ROOT / "scenes" / "orbit.toml").read_text().replace(
        'key = "materials.red.reflect"\nframes = [0, 47]\nvalues = [0.0, 0.6]',
        'key = "materials.red.reflect"\ninterpolation = "catmull-rom"\n'
        'frames = [0, 2, 4, 6]\nvalues = [0.0, 1.0, 1.0, 0.0]'))
    done = subprocess.run([sys.executable, "-m", "clray", "render", str(scene), "-W", "4", "-H",
                           "4", "--spp", "1", "--frames", "0:6", "-o",
                           str(tmp_path / "f_%02d.png"), "--dask", "--dask-workers", "1"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == EXIT_SCENE
    assert done.stderr.splitlines() == [
        f"clray: error: {scene}: materials.red.reflect: must be <= 1, got 1.125 "
        "(animated, frame 3)"], done.stderr


@needs_dask
def test_unreachable_scheduler_is_one_line_in_time(tmp_path):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "clray", "render", str(SPHERES), "-o",
                           str(tmp_path / "x.png"), "--dask", f"tcp://127.0.0.1:{port}",
                           "--dask-timeout", "2"], capture_output=True, text=True, timeout=60)
    assert time.monotonic() - started < 30
    assert done.returncode == EXIT_RUNTIME
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"clray: error: cannot connect to the Dask scheduler at "
                               f"tcp://127.0.0.1:{port}")


@needs_dask
@pytest.mark.parametrize("scheme", ["tls", "ucx"])
def test_an_address_of_a_scheme_this_client_cannot_use_is_one_line(tmp_path, scheme):
    # tls:// without Dask's TLS configuration and ucx:// without its backend: Dask raises
    # TypeError (ImportError in older releases), not OSError.
    done = subprocess.run([sys.executable, "-m", "clray", "render", str(SPHERES), "-o",
                           str(tmp_path / "x.png"), "--dask", f"{scheme}://127.0.0.1:1",
                           "--dask-timeout", "2"], capture_output=True, text=True, timeout=60,
                          cwd=ROOT)
    assert done.returncode == EXIT_RUNTIME
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"clray: error: cannot connect to the Dask scheduler at "
                               f"{scheme}://127.0.0.1:1: ")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(("err", "reason"), [
    (TimeoutError(), "no answer within 2 s"),
    (OSError(), "the connection failed"),
    (OSError("Timed out trying to connect\nafter 2 s"), "Timed out trying to connect"),
])
def test_a_failed_connection_says_why_without_a_class_name(monkeypatch, err, reason):
    from clray import distributed as module
    from clray.errors import ClrayError

    def refuse(address, timeout):
        raise err

    monkeypatch.setattr(module, "import_distributed", lambda: SimpleNamespace(Client=refuse))
    with pytest.raises(ClrayError) as info, module.connect("tcp://10.0.0.1:8786", timeout=2):
        pass
    assert str(info.value) == ("cannot connect to the Dask scheduler at tcp://10.0.0.1:8786: "
                               f"{reason}")


@needs_dask
def test_study_keeps_each_scene_on_one_worker(cl_device, client, tmp_path):
    import functools

    from clray.distributed import study_scenes
    from clray.study import DEFAULT, REFERENCE, run_study

    scenes = [SPHERES, ROOT / "scenes" / "glass.toml"]
    records = run_study(scenes, tmp_path, repeat=1, width=24, height=16,
                        device=os.environ["CLRAY_DEVICE"], variants=(REFERENCE, DEFAULT),
                        run_scenes=functools.partial(study_scenes, client))
    assert [(r["scene"], r["variant"]) for r in records] == [
        (s.stem, v.name) for s in scenes for v in (REFERENCE, DEFAULT)]
    for stem in ("spheres", "glass"):
        assert len({r["worker"] for r in records if r["scene"] == stem}) == 1
    # The same numbers as a study in this process: the double build is its own reference.
    assert all(r["rmse"] == 0 for r in records if r["variant"] == REFERENCE.name)
    report = (tmp_path / "report.md").read_text()
    assert "each scene's variants all on one worker" in report
    assert f"on worker {records[0]['worker']}" in report


@needs_dask
def test_cli_study_on_a_local_cluster(cl_device, tmp_path):
    import json

    assert cli.main(["study", str(SPHERES), "--out", str(tmp_path), "--repeat", "1", "-W", "16",
                     "-H", "12", "--dask", "-q"]) == 0
    records = json.loads((tmp_path / "results.json").read_text())["records"]
    assert len(records) > 2
    assert len({r["worker"] for r in records}) == 1
    assert cli.main(["study", str(SPHERES), "--out", str(tmp_path), "--dask",
                     "tcp://127.0.0.1:1", "--dask-workers", "2"]) == 2


@needs_dask
def test_a_tasks_warnings_go_back_to_the_client_and_compiler_output_nowhere(monkeypatch):
    # A worker printed them raw on its own stderr, which a local cluster shares with the
    # command: Intel's runtime's compiler output broke the one error line of a failed frame.
    import pyopencl as cl

    from clray import distributed

    def warning_render(scene: object, settings: object, geometry_for: object) -> str:
        warnings.warn("the scene's own warning", stacklevel=1)
        warnings.warn("build output", cl.CompilerWarning, stacklevel=1)
        return "rendered"

    monkeypatch.setattr(distributed, "render", warning_render)
    frames = SimpleNamespace(scene=lambda frame: frame, frame_geometry=lambda: None)
    with warnings.catch_warnings(record=True) as escaped:
        warnings.simplefilter("always")
        out = distributed._render_frame(frames, 3, RenderSettings())  # type: ignore[arg-type]
    assert out["result"] == "rendered" and escaped == []
    assert out["warnings"] == ["the scene's own warning"]
    with pytest.warns(UserWarning, match="^the scene's own warning$"):
        distributed._tell(out["warnings"])


@needs_dask
def test_a_device_error_from_pyopencl_reaches_the_client_as_itself(monkeypatch):
    # Dask pickles a failed task's exception with its cause (tblib), and pyopencl's errors
    # hold an _ErrorRecord, which cannot be pickled: the client got Exception(repr(err)), a
    # traceback and exit 1, where the same render in one process says one line, exit 4.
    import pyopencl as cl
    from distributed.core import error_message
    from distributed.protocol import pickle

    from clray import distributed
    from clray.errors import DeviceError

    def no_platform(scene: object, settings: object, geometry_for: object) -> None:
        record = cl._cl._ErrorRecord(msg="clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR",
                                     code=-1001, routine="clGetPlatformIDs")
        try:
            raise cl.LogicError(record)
        except cl.Error as err:
            raise DeviceError("no OpenCL platform found") from err

    monkeypatch.setattr(distributed, "render", no_platform)
    frames = SimpleNamespace(scene=lambda frame: frame, frame_geometry=lambda: None)
    with pytest.raises(DeviceError) as info:
        distributed._render_frame(frames, 0, RenderSettings())  # type: ignore[arg-type]
    # What the worker sends, as the client unpickles it.
    sent = pickle.loads(error_message(info.value)["exception"].data)
    # Said on the client, where it would read as this machine's: the worker's name first.
    assert type(sent) is DeviceError
    assert str(sent) == (f"Dask worker {socket.gethostname()}:{os.getpid()}: no OpenCL platform "
                         "found")


@needs_dask
@pytest.mark.parametrize("tile_rows", [0, -1, 2.5, True])
def test_tile_rows_not_a_positive_int_is_refused_before_any_work(tile_rows):
    from clray.distributed import render_still
    from clray.errors import SettingsError

    # No client: refused before the scene is sent (0 was a ZeroDivisionError, -1 a ValueError).
    with pytest.raises(SettingsError, match=r"^tile_rows: must be a positive integer, got "):
        render_still(None, load_scene(SPHERES), RenderSettings(width=8, height=6),
                     tile_rows=tile_rows)


@needs_dask
def test_progress_lines_count_the_tile_just_done(cl_device, client, capsys):
    from clray.distributed import render_still

    lines = cli._ProgressLines()
    settings = RenderSettings(width=96, height=64, spp=2, device=os.environ["CLRAY_DEVICE"],
                              progress=lines)
    render_still(client, load_scene(SPHERES), settings, tile_rows=32, on_tile=lines.note_tiles)
    last = capsys.readouterr().err.splitlines()[-1]
    assert last.startswith("clray: rendering: 100% ") and ", 2 of 2 tiles, " in last, last


def test_load_s_with_dask_is_the_loading_alone(cl_device, monkeypatch, tmp_path):
    # Importing Dask takes about a second; it is not the scene's loading.
    monkeypatch.setattr(cli, "import_distributed", lambda: time.sleep(1))
    monkeypatch.setattr(cli, "_cluster", lambda args: contextlib.nullcontext())
    monkeypatch.setattr(cli, "render_still",
                        lambda client, scene, settings, on_tile: render(scene, settings))
    stats = tmp_path / "stats.json"
    assert cli.main(["render", str(SPHERES), "-W", "8", "-H", "6", "--spp", "1", "-o",
                     str(tmp_path / "x.png"), "--dask", "--stats-json", str(stats), "-q"]) == 0
    assert json.loads(stats.read_text())["load_s"] < 0.5


class _FakeClient:
    """A client of a remote scheduler whose workers report `versions` (clray's, or the error
    importlib.metadata.version raised there)."""

    versions: ClassVar[dict] = {}

    def __init__(self, address: str, timeout: float) -> None:
        pass

    def __enter__(self) -> _FakeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def wait_for_workers(self, n: int, timeout: float) -> None:
        pass

    def run(self, function: Callable, *args: object, on_error: str) -> dict:
        return self.versions


@needs_dask
@pytest.mark.parametrize(("version", "says"), [
    ("0.0.9", "Dask worker tcp://10.0.0.2:4000 has clray 0.0.9, this client clray {}: "
              "install the same version on every worker"),
    (importlib.metadata.PackageNotFoundError("clray"),
     "Dask worker tcp://10.0.0.2:4000 has no clray installed, this client clray {}: "
     "install the same version on every worker"),
])
def test_a_worker_without_this_clray_is_refused_on_connecting(monkeypatch, version, says):
    import distributed

    from clray import __version__
    from clray.distributed import connect
    from clray.errors import ClrayError

    monkeypatch.setattr(distributed, "Client", _FakeClient)
    monkeypatch.setattr(_FakeClient, "versions",
                        {"tcp://10.0.0.1:4000": __version__, "tcp://10.0.0.2:4000": version})
    with pytest.raises(ClrayError) as info, connect("tcp://10.0.0.9:8786"):
        pass
    assert str(info.value) == says.format(__version__)


@needs_dask
def test_a_remote_clients_dask_logs_are_silent_while_it_is_open():
    # Dask's client logged "Failed to reconnect to scheduler" at ERROR when the scheduler went,
    # a line before clray's own error line saying so. Dask's log handler writes to the stderr
    # it found when imported: a process of its own shows what a user would see.
    done = _run("import logging, distributed\n"
                "from clray import __version__\n"
                "from clray.distributed import connect\n"
                "class Client:\n"
                "    def __init__(self, address, timeout): pass\n"
                "    def __enter__(self): return self\n"
                "    def __exit__(self, *exc): pass\n"
                "    def wait_for_workers(self, n, timeout): pass\n"
                "    def run(self, *args, on_error):\n"
                "        return {'tcp://10.0.0.1:4000': __version__}\n"
                "distributed.Client = Client\n"
                "log = logging.getLogger('distributed.client')\n"
                "with connect('tcp://10.0.0.9:8786'):\n"
                "    log.error('Failed to reconnect to scheduler')\n"
                "log.error('after')\n")  # as Dask had it, once the client is closed
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].endswith("distributed.client - ERROR - after"), lines


@needs_dask
def test_a_worker_without_clray_is_one_line(tmp_path):
    """A worker that joined with no clray importable (its package's metadata still there, so
    that the version check passes): the scene cannot be sent, which is one line, exit 1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    worker = tmp_path / "worker.py"
    worker.write_text("import sys\nsys.modules['clray'] = None\n"
                      "from distributed.cli.dask_worker import main\n"
                      f"sys.argv = ['dask-worker', 'tcp://127.0.0.1:{port}', '--nthreads', '1', "
                      "'--no-nanny']\nmain()\n")
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    started = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                                 "--host", "127.0.0.1", "--port", str(port),
                                 "--dashboard-address", ":0"], **quiet)]
    try:
        started.append(subprocess.Popen([sys.executable, str(worker)], **quiet))
        done = subprocess.run([sys.executable, "-m", "clray", "render", str(SPHERES), "-W", "8",
                               "-H", "6", "-o", str(tmp_path / "x.png"), "--dask",
                               f"tcp://127.0.0.1:{port}", "--dask-timeout", "30"],
                              capture_output=True, text=True, timeout=90, cwd=ROOT)
    finally:
        for process in started:
            process.kill()
            process.wait()
    assert done.returncode == EXIT_RUNTIME
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("clray: error: cannot send the scene to the Dask workers: "
                               "ModuleNotFoundError"), lines[0]
    assert not (tmp_path / "x.png").exists()


@needs_dask
def test_a_local_cluster_that_cannot_start_is_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-m", "clray", "render", str(SPHERES), "-W", "8",
                           "-H", "6", "-o", str(tmp_path / "x.png"), "--dask"],
                          capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, "DASK_TEMPORARY_DIRECTORY": "/proc/nope"})
    assert done.returncode == EXIT_RUNTIME
    assert done.stderr.splitlines() == [
        "clray: error: cannot start a local Dask cluster: [Errno 2] No such file or directory: "
        "'/proc/nope'"], done.stderr
