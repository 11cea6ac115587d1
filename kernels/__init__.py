"""The OpenCL C sources, installed as the package `clray.kernels` (pyproject.toml maps it here).

clray.device.program reads them with importlib.resources, so a wheel, an sdist and an editable
install all find them. This file has to exist for the editable install: setuptools' editable
finder resolves a package mapped to another folder only through its __init__.py.
"""
