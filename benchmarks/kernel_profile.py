"""Where a render's kernel time goes: rays by kind, Mrays/s by kind, tests per ray.

The render kernel does everything in one launch, so its time is split by rendering the same
packed scene three ways and differencing the medians:

- `primary`: max depth 0 and no lights: eye rays, closest hits and ambient shading only;
- `primary_shadow`: max depth 0 with the lights: adds the shadow rays from primary hits;
- `full`: the scene as given: adds reflected and refracted rays and their shadow rays.

Box and primitive tests come from the instrumented build (KernelConfig.count_tests), rendered
once and untimed: its counters cost time of their own.
"""

from __future__ import annotations

import dataclasses
import statistics

import pyopencl as cl

from clray.device.launch import render_packed
from clray.device.pack import PackedScene


def _variant(packed: PackedScene, *, depth0: bool, lights: bool) -> PackedScene:
    config = packed.config
    params = packed.params.copy()
    if depth0:
        config = dataclasses.replace(config, max_depth=0)
        params[0]["max_depth"] = 0
    if not lights:
        params[0]["n_lights"] = 0
    return dataclasses.replace(packed, config=config, params=params)


def time_split(packed: PackedScene, device: cl.Device, repeat: int) -> dict:
    """Kernel seconds and Mrays/s per kind of ray, from the three variants above."""
    variants = {"primary": _variant(packed, depth0=True, lights=False),
                "primary_shadow": _variant(packed, depth0=True, lights=True),
                "full": packed}
    # Interleave the variants' runs so load changes spread over all three.
    runs: dict[str, list[float]] = {name: [] for name in variants}
    rays: dict[str, dict] = {}
    for variant in variants.values():
        render_packed(variant, device)  # build and warm-up
    for _ in range(repeat):
        for name, variant in variants.items():
            _, stats = render_packed(variant, device)
            runs[name].append(stats["kernel_s"])
            rays[name] = stats["rays"]
    t = {name: statistics.median(r) for name, r in runs.items()}
    primary_shadow_rays = rays["primary_shadow"]["shadow"]
    later_rays = rays["full"]["total"] - rays["primary_shadow"]["total"]
    parts = {
        "primary": (t["primary"], rays["full"]["primary"]),
        "shadow_of_primary": (t["primary_shadow"] - t["primary"], primary_shadow_rays),
        "secondary_and_their_shadow": (t["full"] - t["primary_shadow"], later_rays),
    }
    return {
        "variant_kernel_s": t,
        "parts": {
            name: {"kernel_s": s, "rays": n,
                   "mrays_per_s": n / s * 1e-6 if s > 0 and n > 0 else None}
            for name, (s, n) in parts.items()
        },
    }


def tests_per_ray(packed: PackedScene, device: cl.Device) -> dict:
    """Box and primitive tests per closest-hit ray (primary and secondary) and per shadow ray."""
    counted = dataclasses.replace(packed, config=dataclasses.replace(packed.config,
                                                                     count_tests=True))
    _, stats = render_packed(counted, device)
    tests, rays = stats["tests"], stats["rays"]
    closest = rays["primary"] + rays["secondary"]
    shadow = rays["shadow"]

    def per(n: int, d: int) -> float | None:
        return n / d if d else None

    return {
        "closest_boxes_per_ray": per(tests["closest_boxes"], closest),
        "closest_prims_per_ray": per(tests["closest_prims"], closest),
        "shadow_boxes_per_ray": per(tests["shadow_boxes"], shadow),
        "shadow_prims_per_ray": per(tests["shadow_prims"], shadow),
        "totals": tests,
    }
