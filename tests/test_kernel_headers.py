"""Every kernel header is self-contained: it builds on its own, with every build switch off and
with every scene switch on (under each traversal scheme: the sample packets' and the group's
code is in a header's build only with its scheme), so it includes what it uses and no file's
include order matters."""

from __future__ import annotations

import dataclasses
from importlib.resources import files

import pyopencl as cl
import pytest

from clray.device.program import KERNEL_PACKAGE, KernelConfig, kernel_source

HEADERS = sorted(p.name for p in files(KERNEL_PACKAGE).iterdir() if p.name.endswith(".h"))
_EVERY_SWITCH = KernelConfig(max_depth=4, count_tests=True, **{
    f.name: True for f in dataclasses.fields(KernelConfig) if f.name.startswith("has_")})
_CONFIGS = {"off": KernelConfig(), "on": _EVERY_SWITCH,
            **{f"on-{traversal}": dataclasses.replace(_EVERY_SWITCH, traversal=traversal)
               for traversal in ("sample_packet", "group_packet")}}


def test_the_headers_are_found() -> None:
    assert {"clray_types.h", "scene.h", "hit.h", "bvh.h", "shading.h"} <= set(HEADERS)


@pytest.mark.parametrize("config", list(_CONFIGS.values()), ids=list(_CONFIGS))
@pytest.mark.parametrize("header", HEADERS)
def test_header_builds_alone(cl_ctx: cl.Context, header: str, config: KernelConfig) -> None:
    source = kernel_source(header) + "\n__kernel void probe(void) {}\n"
    cl.Program(cl_ctx, source).build(options=config.options())
