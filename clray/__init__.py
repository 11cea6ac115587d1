"""clray: a Whitted ray tracer whose rendering runs as OpenCL kernels, driven from Python.

    import clray
    scene = clray.load_scene("scenes/spheres.toml")
    result = clray.render(scene, clray.RenderSettings(width=320, height=240, spp=4))
    result.image  # (H, W, 3) float32 linear
    result.save("out.png")  # sRGB-encoded unless RenderSettings(linear=True); .pfm, .exr linear

Imported directly rather than lazily: `clray.render` names both the function and its module, and
only an import here keeps the attribute bound to the function.
"""

import importlib.metadata
import sys
from pathlib import Path


def _started_as_command() -> bool:
    """Whether this process is the `clray` command (the console script or `python -m clray`)
    rather than a program importing the library."""
    argv = getattr(sys, "orig_argv", sys.argv)
    as_module = any(a == "-mclray" or (a == "-m" and b == "clray")
                    for a, b in zip(argv, [*argv[1:], ""], strict=True))
    return as_module or Path(sys.argv[0]).name == "clray"


try:
    from clray.device.context import list_devices
    from clray.render import RenderResult, RenderSettings, render
    from clray.scene.load import load_scene, scene_from_dict
except KeyboardInterrupt:
    # Ctrl-C while numpy and pyopencl load (the first fraction of a second of every run): the
    # command exits as it does when interrupted later, with one line and status 130, instead
    # of a traceback. A program importing clray gets its KeyboardInterrupt.
    if not _started_as_command():
        raise
    sys.stderr.write("clray: error: interrupted\n")
    raise SystemExit(130) from None

__all__ = ["RenderResult", "RenderSettings", "list_devices", "load_scene", "render",
           "scene_from_dict"]

# One source for the version: pyproject.toml, through the installed package's metadata.
try:
    __version__ = importlib.metadata.version("clray")
except importlib.metadata.PackageNotFoundError:
    # Imported from a source tree that was never installed: no metadata to read.
    __version__ = "0+unknown"
