"""clray: a Whitted ray tracer whose rendering runs as OpenCL kernels, driven from Python.

    import clray
    scene = clray.load_scene("scenes/spheres.toml")
    result = clray.render(scene, clray.RenderSettings(width=320, height=240, spp=4))
    result.image  # (H, W, 3) float32 linear

Imported directly rather than lazily: `clray.render` names both the function and its module, and
only an import here keeps the attribute bound to the function.
"""

import importlib.metadata

from clray.device.context import list_devices
from clray.render import RenderResult, RenderSettings, render
from clray.scene.load import load_scene

__all__ = ["RenderResult", "RenderSettings", "list_devices", "load_scene", "render"]

# One source for the version: pyproject.toml, through the installed package's metadata.
try:
    __version__ = importlib.metadata.version("clray")
except importlib.metadata.PackageNotFoundError:
    # Imported from a source tree that was never installed: no metadata to read.
    __version__ = "0+unknown"
