"""Shared fixtures: the OpenCL device and context (skipped, never silently passed, when no
platform exists) and a helper that writes scene files."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pyopencl as cl
import pytest

from clray.device.context import context_for, select_device
from clray.errors import DeviceError


@pytest.fixture(scope="session")
def cl_device() -> cl.Device:
    """The device clray would pick by default (CLRAY_DEVICE / PYOPENCL_CTX honoured)."""
    try:
        return select_device()
    except DeviceError as err:
        pytest.skip(str(err))


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
