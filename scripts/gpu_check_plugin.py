"""pytest plugin of scripts/gpu_check.py's kernel-test step, loaded with `-p gpu_check_plugin`
(scripts/ on PYTHONPATH).

- GPU_CHECK_DEVICE_ONLY=1 keeps only the tests that run on an OpenCL device: those that
  tests/conftest.py parametrises by its `cl_device` fixture (directly or through `cl_ctx`).
  The device itself is chosen as the suite chooses it (`--cl-device ID`).
- GPU_CHECK_FIRST=a.py,b.py runs those test files first, in that order (pytest orders the
  files of a folder by name, whatever order the command line gives them in).
- GPU_CHECK_RESULTS=FILE appends one JSON line per test phase that decides an outcome, as it
  finishes, so a run stopped at the step's time limit still tells what ran and how.
"""

from __future__ import annotations

import json
import os

import pytest

DEVICE_ONLY_ENV = "GPU_CHECK_DEVICE_ONLY"
FIRST_ENV = "GPU_CHECK_FIRST"
RESULTS_ENV = "GPU_CHECK_RESULTS"
MESSAGE_CHARS = 600

_config: pytest.Config | None = None


def pytest_configure(config: pytest.Config) -> None:
    global _config
    _config = config


def first_files_first(items: list[pytest.Item], first: list[str]) -> list[pytest.Item]:
    """`items` with those of the files named in `first` ahead, in that order (stable)."""
    rank = {name: i for i, name in enumerate(first)}
    return sorted(items, key=lambda item: rank.get(item.path.name, len(first)))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get(DEVICE_ONLY_ENV) == "1":
        keep = [item for item in items if "cl_device" in getattr(item, "fixturenames", ())]
        dropped = [item for item in items
                   if "cl_device" not in getattr(item, "fixturenames", ())]
        if dropped:
            config.hook.pytest_deselected(items=dropped)
            items[:] = keep
    first = [name for name in os.environ.get(FIRST_ENV, "").split(",") if name]
    if first:
        items[:] = first_files_first(items, first)


def pytest_collection_finish(session: pytest.Session) -> None:
    path = os.environ.get(RESULTS_ENV)
    # Under pytest-xdist every worker collects the same tests: the first one says how many.
    worker = getattr(session.config, "workerinput", {}).get("workerid")
    if path and worker in (None, "gw0"):
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps({"collected": len(session.items)}) + "\n")


def result_line(report: pytest.TestReport) -> dict | None:
    """The JSON record of one phase's report, or None for a phase that decides nothing (a
    passed setup or teardown)."""
    if report.when != "call" and report.outcome == "passed":
        return None
    if report.when == "call":
        outcome = report.outcome
    else:  # a setup or teardown that failed or skipped
        outcome = "skipped" if report.outcome == "skipped" else "error"
    message = ""
    if report.outcome != "passed":
        message = str(report.longrepr)
        if len(message) > MESSAGE_CHARS:
            message = "..." + message[-MESSAGE_CHARS:]
    return {"nodeid": report.nodeid, "when": report.when, "outcome": outcome,
            "duration_s": round(report.duration, 4), "message": message}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    path = os.environ.get(RESULTS_ENV)
    # Under pytest-xdist a worker's reports reach the controller too: only it writes.
    if not path or (_config is not None and hasattr(_config, "workerinput")):
        return
    line = result_line(report)
    if line is not None:
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps(line) + "\n")
