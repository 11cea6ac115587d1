"""Rendering on a Dask cluster (`clray render --dask`): a still in bands of rows, or an animation
one frame a task. Only this module imports Dask, and only when called: `pip install
'clray[dask]'`.

Data movement: the scene (or the animation's scene data) goes to every worker once, with
`client.scatter(..., broadcast=True)`, and again, once, if every worker holding it is lost
(_Tasks); a task carries only its row range and settings. Each
worker selects its own OpenCL device (`--device`, else as default_device does with its own
environment: clray.device.context.DEFAULT_DEVICE_ORDER), packs the scene once for all its
tiles, or an animation's frame 0 objects once for its frames where they share a packing
(clray.sequence.Sequence.packed_objects), and keeps compiled programs cached
(clray.device.program caches per process).
Per-pixel sampling depends on the seed and the pixel's index only, so the assembled image is
bit for bit the single-process render's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib.metadata
import logging
import math
import os
import pickle
import socket
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

import numpy as np
import pyopencl as cl

from clray import __version__
from clray.device.context import describe, select_device
from clray.device.launch import render_packed
from clray.device.pack import PackedScene
from clray.errors import ClrayError, SceneError, SettingsError, one_line
from clray.render import (
    RenderResult,
    RenderSettings,
    pack_for,
    plan_for,
    png_encoding,
    render,
    resolved_settings,
    settings_or_default,
    tuning_stats,
    warn_deep_tree,
)
from clray.scene.check import check_scene
from clray.scene.load import load_scene
from clray.scene.model import Scene
from clray.sequence import Sequence
from clray.study import scene_line, study_scene, variant_line

if TYPE_CHECKING:
    from distributed import Client

INSTALL_HINT = "pip install 'clray[dask]'"
CONNECT_TIMEOUT_S = 10.0
LOCAL_WORKERS = 2
# A tile is sized to take about this long on a worker's device: long enough that the
# scheduler's per-task cost (milliseconds) is a small share, short enough to spread an image
# over many workers and lose little when one dies.
TILE_SECONDS = 1.0
# The first tile of each worker measures its device's rate: about this many pixel-samples.
PROBE_PIXEL_SAMPLES = 1 << 18


def import_distributed() -> Any:
    """The `distributed` module, or a one-line ClrayError saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise ClrayError(f"--dask needs Dask distributed, which is not installed: "
                         f"{INSTALL_HINT}") from None
    return distributed


@contextlib.contextmanager
def connect(address: str | None, workers: int = LOCAL_WORKERS,
            timeout: float = CONNECT_TIMEOUT_S) -> Iterator[Client]:
    """A client of the scheduler at `address` (`tcp://host:8786`), or of a LocalCluster of
    `workers` worker processes (one thread each: one task at a time per device) when None.
    An unreachable scheduler is a ClrayError after `timeout` seconds, an address this client
    cannot use (malformed, or tls:// without Dask's TLS configuration) one at once; the client
    waits as long for a worker to send the scene to again (_Tasks)."""
    distributed = import_distributed()
    if address is None:
        # CRITICAL, not ERROR: a task that raises is logged by its worker ("Compute Failed",
        # a block of lines with the traceback) as well as raised here, where the command
        # reports it in one line. A worker that dies is restarted by its nanny and its tasks
        # run again; tasks that keep killing workers reach here as KilledWorker.
        with contextlib.ExitStack() as stack:
            try:
                cluster = stack.enter_context(distributed.LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=":0", silence_logs=logging.CRITICAL))
            except (OSError, RuntimeError) as err:
                # Dask's RuntimeError("Cluster failed to start: ...") wraps what stopped it (a
                # temporary folder it cannot make, a port it cannot bind): say that alone.
                reason = str(err.__cause__ or err).strip() or type(err).__name__
                raise ClrayError(f"cannot start a local Dask cluster: "
                                 f"{one_line(reason.splitlines()[0])}") from None
            yield stack.enter_context(distributed.Client(cluster, timeout=timeout))
        return
    # As the local cluster's silence_logs: Dask's client logs a lost scheduler at ERROR
    # ("Failed to reconnect to scheduler", also as it closes) before the command says so in
    # one line. Its handlers' levels come back once the client is closed.
    with _dask_logs_silenced():
        yield from _remote(distributed, address, timeout)


@contextlib.contextmanager
def _dask_logs_silenced() -> Iterator[None]:
    """Dask's log handlers (on the `distributed` logger) at CRITICAL, their levels restored
    after: what LocalCluster(silence_logs=logging.CRITICAL) does."""
    handlers = [h for h in logging.getLogger("distributed").handlers
                if isinstance(h, logging.StreamHandler)]
    levels = [h.level for h in handlers]
    for handler in handlers:
        handler.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for handler, level in zip(handlers, levels, strict=True):
            handler.setLevel(level)


def _remote(distributed: Any, address: str, timeout: float) -> Iterator[Client]:
    """connect()'s client of the scheduler at `address`, once a worker with this clray is
    there."""
    try:
        client = distributed.Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError, TypeError, ImportError, RuntimeError) as err:
        # What Dask's comm layer raises for an address it cannot use: unreachable (OSError,
        # TimeoutError), malformed or of an unknown scheme (ValueError), or of a scheme this
        # client is not set up for: tls:// without Dask's TLS configuration and ucx:// without
        # its backend (TypeError), ucx:// without ucx-py in older Dask (ImportError), a plain
        # address where Dask's configuration requires encryption (RuntimeError). Each is the
        # address's fault, not clray's; anything else Client() raises is a bug to show whole.
        # An exception without a message says nothing but its type, which is no reason a user
        # can act on: say what the type means instead.
        reason = (str(err).strip().splitlines()[0] if str(err).strip() else
                  f"no answer within {timeout:g} s" if isinstance(err, TimeoutError) else
                  "the connection failed")
        raise ClrayError(f"cannot connect to the Dask scheduler at {address}: {reason}"
                         ) from None
    with client:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise ClrayError(f"the Dask scheduler at {address} has no workers (waited "
                             f"{timeout:g} s)") from None
        _check_versions(client)
        yield client


def _check_versions(client: Client) -> None:
    """A ClrayError naming the first worker whose clray is missing or not this one's: tasks name
    clray's functions and pickle its classes, which such a worker cannot run or unpickle, and
    it said so in a traceback. Asked through the standard library, which every worker has.
    (A local cluster's workers run this Python, so they are not asked.)"""
    versions = client.run(importlib.metadata.version, "clray", on_error="return")
    for worker, version in sorted(versions.items()):
        if isinstance(version, importlib.metadata.PackageNotFoundError):
            has = "no clray installed"
        elif isinstance(version, Exception):
            has = f"a clray whose version cannot be read ({one_line(str(version))})"
        elif version != __version__:
            has = f"clray {version}"
        else:
            continue
        raise ClrayError(f"Dask worker {worker} has {has}, this client clray {__version__}: "
                         "install the same version on every worker")


# -- on the workers ----------------------------------------------------------------------

# One packed scene per worker process, for the scene it is rendering now (with its knobs'
# stats, tuning_stats): the tiles of one image share it, and a long-lived worker does not keep
# every scene it was ever sent.
_packed: dict[tuple, tuple[PackedScene, dict]] = {}
# A worker started with several threads would run tiles at once on one device, sharing its
# queue and program cache; the device is busy either way, so they take turns.
_device_lock = threading.Lock()


@contextlib.contextmanager
def _kept_warnings() -> Iterator[list[str]]:
    """The warnings of a task, kept for its result: the client tells them as the render in one
    process does (`clray: warning:` lines), where a worker would print them raw on its own
    stderr, which a local cluster shares with the command's. Compiler output is noise here as
    there (cli._warnings_as_lines): Intel's runtime reports some at every build."""
    kept: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        warnings.simplefilter("ignore", cl.CompilerWarning)
        try:
            yield kept
        finally:
            kept.extend(str(w.message) for w in caught)


def _tell(messages: Iterable[str]) -> None:
    """A task's kept warnings, warned again here, in the client."""
    for message in messages:
        warnings.warn(message, stacklevel=3)


_P = ParamSpec("_P")
_R = TypeVar("_R")


def _task(function: Callable[_P, _R]) -> Callable[_P, _R]:
    """A function run as a task on the workers, whose ClrayError reaches the client as itself:
    Dask pickles a failed task's exception with its cause and context (tblib), and where one of
    them cannot be pickled (a pyopencl error's _ErrorRecord, the cause of a DeviceError) it sends
    Exception(repr(err)) instead, which the command cannot tell from a bug. The message alone
    says what a user needs, with the worker's name first where it is about the worker's machine
    (its OpenCL platform, its files): the command says it where it would read as its own."""

    @functools.wraps(function)
    def task(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        try:
            return function(*args, **kwargs)
        except ClrayError as err:
            err.__cause__ = err.__context__ = None
            err.__suppress_context__ = True
            if not isinstance(err, SceneError):  # the scene's fault, wherever it is made
                err.args = (f"Dask worker {_worker_name()}: {err}",)
            raise

    return task


def _worker_name() -> str:
    """This worker as its tasks' results and errors name it: its machine and process."""
    return f"{socket.gethostname()}:{os.getpid()}"


@_task
def _render_tile(scene: Scene, scene_key: str, settings: RenderSettings, start: int,
                 stop: int) -> dict:
    started = time.perf_counter()
    with _device_lock, _kept_warnings() as kept:
        device_started = time.perf_counter()
        device = select_device(settings.device)
        key = (scene_key, settings, describe(device))
        packs = key not in _packed
        if packs:
            _packed.clear()
            plan = plan_for(scene, settings, device)
            pack_started = time.perf_counter()
            fresh = pack_for(scene, settings, device, plan)
            _packed[key] = fresh, tuning_stats(plan, fresh)
            pack_s = time.perf_counter() - pack_started
        device_s = pack_started - device_started if packs else 0.0
        packed, tuning = _packed[key]
        image, stats = render_packed(packed, device, rows=(start, stop))
    return {"start": start, "rows": stop - start, "image": image, "stats": stats,
            "tuning": tuning, "traversal": packed.config.traversal,
            "packed": packs, "device_s": device_s, "pack_s": pack_s if packs else 0.0,
            "bvh_s": packed.bvh_s if packs else 0.0, "device": describe(device),
            "worker": _worker_name(), "warnings": kept,
            "task_s": time.perf_counter() - started}


@_task
def _render_frame(sequence: Sequence, frame: int, settings: RenderSettings) -> dict:
    started = time.perf_counter()
    with _device_lock, _kept_warnings() as kept:
        scene = sequence.scene(frame)
        load_s = time.perf_counter() - started
        result = render(scene, settings, geometry_for=sequence.frame_geometry())
    return {"frame": frame, "result": result, "worker": _worker_name(), "warnings": kept,
            "task_s": time.perf_counter() - started, "load_s": load_s}


# -- on the client -----------------------------------------------------------------------


def _lost(err: BaseException, what: str) -> ClrayError | None:
    """The one-line error for a task lost with the cluster (a worker that died each time it ran
    it, the scheduler's connection, a cancellation clray did not ask for), naming `what` the
    task was rendering; None for any other exception: the task's own ClrayError, or a bug."""
    distributed = import_distributed()
    if isinstance(err, distributed.KilledWorker):
        return ClrayError(f"{what} not rendered: each Dask worker that ran it died (killed, or "
                          "out of memory)")
    if isinstance(err, distributed.comm.CommClosedError) or (
            isinstance(err, distributed.client.FutureCancelledError)
            and err.reason == "scheduler-connection-lost"):
        return ClrayError(f"{what} not rendered: the connection to the Dask scheduler was lost")
    if isinstance(err, distributed.client.FutureCancelledError):
        return _Cancelled(f"{what} not rendered: cancelled by the Dask scheduler ({err.reason})")
    return None


class _Cancelled(ClrayError):
    """A task cancelled by the scheduler, not by clray: the data it needs was lost with the
    workers that held it (_Tasks sends it again)."""


def _result(task: Any, what: str) -> Any:
    """task.result(), where the task was lost with the cluster a one-line ClrayError (_lost)."""
    try:
        return task.result()
    except Exception as err:
        lost = _lost(err, what)
        if lost is None:
            raise
        raise lost from None


class _Tasks:
    """Tasks that each take one value sent to every worker (a scene, a sequence), and their
    results as they arrive. The value is sent once (`client.scatter(..., broadcast=True)`) and
    each task refers to it. Where every worker holding it is lost (the one worker, killed), the
    scheduler forgets it and cancels the tasks that need it: then the value is sent again and
    those tasks submitted again, once; a second loss is a one-line ClrayError naming a task's
    `what`, as a task lost otherwise is (_lost)."""

    def __init__(self, client: Client, value: object,
                 submit: Callable[[Any, tuple], Any], what: Callable[[tuple], str]) -> None:
        """`submit(future, args)`: the task of `args` on the value's future; `what(args)`: what
        that task renders, for an error."""
        self.client, self.value, self._submit, self.what = client, value, submit, what
        self.nbytes = len(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        self.copies = 0  # sent, to this many workers in all
        self.future = self._scatter()
        self.workers = self.copies  # workers connected when it was first sent
        self.resent = False
        # The tasks not done yet, by key: the value's future each was submitted with, and
        # its arguments.
        self.pending: dict[Any, tuple[Any, tuple]] = {}
        self.done = import_distributed().as_completed()

    def _scatter(self) -> Any:
        try:
            [future] = self.client.scatter([self.value], broadcast=True, hash=False)
        except TimeoutError:
            raise  # no worker to send it to: the caller says what was not rendered
        except Exception as err:
            # A worker that cannot unpickle it (no clray there, or another version, having
            # joined after connect() checked) fails the scatter with Exception(repr of its
            # error).
            reason = str(err).strip() or type(err).__name__
            raise ClrayError(f"cannot send the scene to the Dask workers: "
                             f"{one_line(reason.splitlines()[0])} (each needs clray "
                             f"{__version__})") from None
        # The workers it went to, counted after: sent again, it waits for a worker first.
        self.copies += len(self.client.who_has([future])[future.key])
        return future

    def submit(self, *args: Any) -> None:
        task = self._submit(self.future, args)
        self.pending[task.key] = self.future, args
        self.done.add(task)

    def results(self) -> Iterator[Any]:
        """Each task's result as it arrives, until every task submitted (before the iteration
        or during it) is done; the value is forgotten after. Each result is fetched on its own:
        as_completed(with_results=True) fetches them concurrently through the client's batched
        gathers, and there a 12-frame animation once waited for ever on its last frame's
        result, which the scheduler held in memory (distributed 2026.8.0)."""
        try:
            for task in self.done:
                sent, args = self.pending.pop(task.key)
                try:
                    result = _result(task, self.what(args))
                except _Cancelled:
                    self._again(sent, args)
                    continue
                yield result
        finally:
            self.client.cancel([self.future])

    def _again(self, sent: Any, args: tuple) -> None:
        """A task cancelled because the value it took was lost, submitted again: with the value
        sent again where it took the value sent last, which is then lost too."""
        what = self.what(args)
        if sent is self.future:
            if self.resent:
                raise ClrayError(f"{what} not rendered: every Dask worker holding the scene was "
                                 "lost, again after it was sent once more")
            self.resent = True
            try:
                self.future = self._scatter()
            except TimeoutError:
                raise ClrayError(f"{what} not rendered: every Dask worker holding the scene was "
                                 "lost, and no worker came to take it again") from None
        self.submit(*args)


def tile_rows_for(rate_rows_per_s: float, rows_left: int, workers: int) -> int:
    """Rows of a tile that takes about TILE_SECONDS at the measured rate, but no more than an
    even share of what is left, so that every worker gets some."""
    by_time = math.ceil(rate_rows_per_s * TILE_SECONDS) if rate_rows_per_s > 0 else rows_left
    return max(1, min(by_time, math.ceil(rows_left / max(workers, 1))))


def render_still(client: Client, scene: Scene, settings: RenderSettings | None = None,
                 tile_rows: int | None = None,
                 on_tile: Callable[[int, int], None] | None = None) -> RenderResult:
    """Render `scene` on the cluster in bands of rows, assembled here: the same image, bit for
    bit, as render(scene, settings) on the workers' device. `tile_rows` fixes the band height
    (default: sized by the first tiles' rate to about TILE_SECONDS each). settings.progress
    hears pixel-samples as tiles arrive; on_tile(tiles done, tiles submitted) after each."""
    import_distributed()
    settings = settings_or_default(settings)
    _check_tiled_settings(settings, tile_rows)
    started = time.perf_counter()
    scene = check_scene(scene)
    encoding = png_encoding(scene, settings)
    resolved = resolved_settings(scene, settings)
    warn_deep_tree(scene, resolved)
    width, height, spp = (int(resolved[k]) for k in ("width", "height", "spp"))
    task_settings = dataclasses.replace(settings, progress=None)
    tasks = _Tasks(client, scene,
                   lambda scene, rows: client.submit(_render_tile, scene, scene.key,
                                                     task_settings, *rows, pure=False),
                   lambda rows: f"rows {rows[0]} to {rows[1] - 1}")
    image = np.empty((height, width, 3), dtype=np.float32)
    tiles = _assemble_tiles(tasks, image, spp, tile_rows, settings, on_tile)
    stats = _merge(tiles, resolved, settings)
    stats["dask"] = _tile_stats(client, tasks, tiles, image)
    stats["total_s"] = time.perf_counter() - started
    return RenderResult(image, stats, encoding)


def _check_tiled_settings(settings: RenderSettings, tile_rows: int | None) -> None:
    """SettingsError for what a still rendered in tiles cannot do, or a band height that is
    not a positive integer."""
    if tile_rows is not None and (isinstance(tile_rows, bool) or not isinstance(tile_rows, int)
                                  or tile_rows < 1):
        # Checked before the scene is sent: 0 divided by zero, and -1 cut no tiles, only then.
        raise SettingsError(f"tile_rows: must be a positive integer, got {tile_rows!r}")
    if settings.denoise:
        # The denoiser needs the whole image's albedo and normal passes, which tiles lack.
        raise SettingsError("--denoise (RenderSettings.denoise): a still rendered in tiles on "
                            "Dask cannot be denoised; render it without --dask")
    if settings.aovs:
        # Tiles render the image only (render_packed); their passes would be lost unasked.
        raise SettingsError("RenderSettings.aovs: a still rendered in tiles on Dask has no "
                            "passes; render it without Dask")


def _assemble_tiles(tasks: _Tasks, image: np.ndarray, spp: int, tile_rows: int | None,
                    settings: RenderSettings,
                    on_tile: Callable[[int, int], None] | None) -> list[dict]:
    """Submit `image`'s bands of rows as tiles (`tile_rows` each, or probes first that size
    the rest) and copy each tile into it as it arrives: the tiles' records in that order,
    their warnings told, settings.progress and on_tile heard after each."""
    height, width = image.shape[:2]
    workers = tasks.workers
    row_samples = width * spp
    tiles: list[dict] = []
    next_row = 0
    submitted = 0

    def submit(rows: int) -> None:
        nonlocal next_row, submitted
        start, next_row = next_row, min(height, next_row + rows)
        tasks.submit(start, next_row)
        submitted += 1

    if settings.progress is not None:
        settings.progress(0, height * row_samples)
    if tile_rows is not None:
        for _ in range(math.ceil(height / tile_rows)):
            submit(tile_rows)
    else:
        probe = max(1, PROBE_PIXEL_SAMPLES // row_samples)
        for _ in range(workers):
            if next_row < height:
                submit(probe)
    rows_done = 0
    for tile in tasks.results():
        image[tile["start"]:tile["start"] + tile["rows"]] = tile.pop("image")
        _tell(tile.pop("warnings"))
        tiles.append(tile)
        rows_done += tile["rows"]
        if tile_rows is None and len(tiles) == 1 and next_row < height:
            # The first probe sizes the remaining tiles by its device's rate; waiting for the
            # other probes would leave their workers idle for a round trip.
            kernel_s = tile["stats"]["kernel_s"]
            size = tile_rows_for(tile["rows"] / kernel_s if kernel_s > 0 else 0.0,
                                 height - next_row, workers)
            for _ in range(math.ceil((height - next_row) / size)):
                submit(size)
        # The tiles first: a progress line says the count as it is with this tile.
        if on_tile is not None:
            on_tile(len(tiles), submitted)
        if settings.progress is not None:
            settings.progress(rows_done * row_samples, height * row_samples)
    return tiles


def _tile_stats(client: Client, tasks: _Tasks, tiles: list[dict], image: np.ndarray) -> dict:
    """The still's stats["dask"]: the cluster, its tiles and what was sent and returned."""
    by_worker: dict[str, int] = {}
    for t in tiles:
        by_worker[t["worker"]] = by_worker.get(t["worker"], 0) + 1
    return {
        "scheduler": client.scheduler.address,
        "workers": tasks.workers,
        "tiles": len(tiles),
        "tile_rows": sorted({t["rows"] for t in tiles}),
        "scene_bytes": tasks.nbytes,
        "bytes_sent": tasks.nbytes * tasks.copies,
        "result_bytes": image.nbytes,
        "task_s": sum(t["task_s"] for t in tiles),
        "tiles_by_worker": by_worker,
        # Tiles that packed the scene (BVH, buffers): one a worker, the rest reuse it.
        "packs": sum(t["packed"] for t in tiles),
    }


def _merge(tiles: list[dict], resolved: dict, settings: RenderSettings) -> dict:
    """The stats of render() from those of the tiles: counts and device times summed, packing
    as the slowest worker did it."""
    rays = {k: sum(t["stats"]["rays"][k] for t in tiles)
            for k in ("primary", "secondary", "shadow", "total")}
    kernel_s = sum(t["stats"]["kernel_s"] for t in tiles)
    stats = {
        **resolved,
        "device": ", ".join(sorted({t["device"] for t in tiles})),
        "precision": settings.precision,
        "device_s": max(t["device_s"] for t in tiles),
        "bvh_s": max(t["bvh_s"] for t in tiles),
        "pack_s": max(t["pack_s"] - t["bvh_s"] for t in tiles),
        "build_s": max(t["stats"]["build_s"] for t in tiles),
        "kernel_s": kernel_s,
        "launches": sum(t["stats"]["launches"] for t in tiles),
        "rays": rays,
        "mrays_per_s": rays["total"] / kernel_s * 1e-6 if kernel_s > 0 else None,
        "device_bytes": tiles[0]["stats"]["device_bytes"],
    }
    # Which knobs and walk rendered, as render()'s stats say: each worker's own tuning file
    # may differ, and then each worker's, by its name.
    for name in ("tuning", "traversal"):
        by_worker = {t["worker"]: t[name] for t in tiles}
        values = list(by_worker.values())
        stats[name] = (values[0] if all(v == values[0] for v in values)
                       else dict(sorted(by_worker.items())))
    if "tests" in tiles[0]["stats"]:
        stats["tests"] = {k: sum(t["stats"]["tests"][k] for t in tiles)
                          for k in tiles[0]["stats"]["tests"]}
    return stats


def render_sequence(client: Client, sequence: Sequence, frames: Iterable[int],
                    settings: RenderSettings | None,
                    done: Callable[[int, RenderResult], None]) -> dict:
    """Render frames on the cluster, one task each, `done(frame, result)` here as each
    arrives (in any order); returns what was moved and where it ran."""
    settings = dataclasses.replace(settings_or_default(settings), progress=None)
    frames = [sequence.check_frame(f) for f in frames]  # each, before any is sent
    tasks = _Tasks(client, sequence,
                   lambda sequence, frame: client.submit(_render_frame, sequence, *frame,
                                                         settings, pure=False),
                   lambda frame: f"frame {frame[0]}")
    for frame in frames:
        tasks.submit(frame)
    by_worker: dict[str, int] = {}
    result_bytes = 0
    task_s = 0.0
    for out in tasks.results():
        _tell(out["warnings"])
        by_worker[out["worker"]] = by_worker.get(out["worker"], 0) + 1
        result_bytes += out["result"].image.nbytes
        task_s += out["task_s"]
        out["result"].stats["load_s"] = out["load_s"]  # as render_frames' stats have it
        done(out["frame"], out["result"])
    return {"scheduler": client.scheduler.address, "workers": tasks.workers,
            "frames": sum(by_worker.values()),
            "scene_bytes": tasks.nbytes, "bytes_sent": tasks.nbytes * tasks.copies,
            "result_bytes": result_bytes, "task_s": task_s, "frames_by_worker": by_worker}


@_task
def _study_scene(scene: Scene, path: str, variants: tuple, repeat: int,
                 base: RenderSettings) -> list[dict]:
    with _device_lock, warnings.catch_warnings():
        warnings.simplefilter("ignore", cl.CompilerWarning)
        records = study_scene(Path(path), variants, repeat, base, scene=scene)
    worker = _worker_name()
    device = describe(select_device(base.device))
    return [{**r, "worker": worker, "device": device} for r in records]


def study_scenes(client: Client, paths: Iterable[Path], variants: Iterable, repeat: int,
                 base: RenderSettings, say: Callable[[str], None] = lambda _: None
                 ) -> list[dict]:
    """clray study's renders on the cluster, one task a scene: all the variants of a scene run
    on one worker, in interleaved rounds, so that their times compare (times from different
    workers do not). The scenes are loaded here and sent with their tasks; the records come
    back in the order of `paths`, each naming its worker and device."""
    paths = list(paths)
    variants = tuple(variants)
    tasks = [client.submit(_study_scene, load_scene(p), str(p), variants, repeat, base,
                           pure=False) for p in paths]
    by_path: dict[int, list[dict]] = {}
    index = {t.key: i for i, t in enumerate(tasks)}
    for task in import_distributed().as_completed(tasks):
        i = index[task.key]
        by_path[i] = records = _result(task, f"scene {paths[i]}")
        if records:
            say(scene_line(records[0]))
        for r in records:
            say(f"{variant_line(r)} (on {r['worker']})")
    return [r for i in range(len(paths)) for r in by_path[i]]
