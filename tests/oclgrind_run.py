"""Run every kernel on tiny inputs on the current default device and save what they return:
tests/test_oclgrind.py runs this under Oclgrind (CLRAY_DEVICE=oclgrind) and on PoCL, and
compares. Usage: python tests/oclgrind_run.py OUT.npz DEVICE PARTS (PARTS: renders,
intersections,bvh,bvh_float)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.characterize

from clray.device.bvh_builder import build_bvh_on
from clray.device.context import queue_for, select_device
from clray.device.launch import intersect_rays
from clray.device.pack import pack_scene
from clray.device.program import built_as_for_a_gpu
from clray.knobs import Tuning
from clray.reference import camera_rays
from clray.render import RenderSettings, render
from clray.scene.load import load_scene

SCENES = Path(__file__).resolve().parent.parent / "scenes"
# The shipped scenes between them switch on every feature of KernelConfig but the study
# variants (tests/test_oclgrind.py checks); a few pixels of each, every pixel a sample or two.
WIDTH, HEIGHT, SPP = 6, 4, 2
PACKET_SPP = 5
# Every study variant at once (and the counting and stage-profiling builds), on the scene with
# the most primitive kinds.
VARIANTS = (("sphere_textbook", True), ("offset_fixed_eps", True),
            ("triangle_no_fp64_fallback", True), ("triangle_moller_trumbore", True),
            ("fresnel_schlick", True), ("fp64_spheres", True), ("count_tests", True),
            ("stage_profile", True), ("implicit_vectorization", True))
VARIANT_SCENES = ("primitives.toml", "fresnel.toml")
# Every pass, on the scene with the most primitive kinds: the passes build (KernelConfig.passes),
# which the scenes alone do not switch on; likewise intersections() runs the intersection build
# (KernelConfig.intersect_rays, which clray.device.launch.intersect_rays asks for).
PASSES = ("depth", "normal", "albedo", "position", "object", "material", "instance")
PASS_SCENE = "primitives.toml"
RUN_SWITCHES = ("passes", "intersect_rays")


def nv_compute_capability_if_nvidia(device: cl.Device) -> tuple[int, int] | None:
    """pyopencl's nv_compute_capability, asked only of a device that has the NVIDIA query.
    pyopencl asks every device for CL_DEVICE_COMPUTE_CAPABILITY_MAJOR_NV (building a program,
    creating a kernel) and takes the refusal as "not NVIDIA"; Oclgrind reports the refused
    query as an API error, which would hide any of clray's own among them."""
    if "cl_nv_device_attribute_query" not in device.extensions.split():
        return None
    return (device.compute_capability_major_nv, device.compute_capability_minor_nv)


def renders(device: str | None) -> dict[str, np.ndarray]:
    out = {}
    for path in sorted(SCENES.glob("*.toml")):
        scene = load_scene(path)
        print(f"oclgrind_run: {path.name}", file=sys.stderr, flush=True)
        for precision in ("float", "double"):
            settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=SPP, device=device,
                                      precision=precision)
            out[f"{path.stem}/{precision}"] = render(scene, settings).image
        # As a GPU builds it: a pixel a work-item, the group's work-items side by side (no
        # row segments), where --data-races sees what they share.
        with built_as_for_a_gpu():
            settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=SPP, device=device)
            out[f"{path.stem}/gpu_build"] = render(scene, settings).image
        # The sample-packet walk with more samples than the hybrid's threshold, so that packets
        # (not only lanes gone on ray by ray) run.
        settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=PACKET_SPP, device=device,
                                  traversal="sample_packet")
        out[f"{path.stem}/sample_packet"] = render(scene, settings).image
        # Group packets in 4 x 4 tiles: the image's 6 columns leave two of the second tile's
        # work-items outside it, riding along in the group's walks.
        settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=SPP, device=device,
                                  traversal="group_packet", tuning=Tuning(group_side=4),
                                  stored_tuning=False)
        out[f"{path.stem}/group_packet"] = render(scene, settings).image
        if path.name == PASS_SCENE:
            settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=SPP, device=device,
                                      aovs=PASSES)
            result = render(scene, settings)
            out[f"{path.stem}/passes"] = result.image
            out.update({f"{path.stem}/pass_{name}": a for name, a in result.aovs.items()})
        if path.name in VARIANT_SCENES:
            settings = RenderSettings(width=WIDTH, height=HEIGHT, spp=SPP, device=device,
                                      variants=VARIANTS)
            out[f"{path.stem}/variants"] = render(scene, settings).image
    return out


def intersections(device: str | None) -> dict[str, np.ndarray]:
    """intersect_rays on the camera rays of the scene with every primitive kind."""
    scene = load_scene(SCENES / "primitives.toml")
    packed = pack_scene(scene, width=WIDTH, height=HEIGHT, spp=1, max_depth=0, seed=0)
    o, d, _ = camera_rays(scene, WIDTH, HEIGHT, 1, 0)
    eye = np.asarray(scene.camera.position)
    t, n, ref = intersect_rays(packed, select_device(device), o - eye, d)
    out = {"intersect/t": t, "intersect/n": n, "intersect/ref": ref}
    # The rays as group packets of 16 (the last padded).
    packed = pack_scene(scene, width=WIDTH, height=HEIGHT, spp=1, max_depth=0, seed=0,
                        traversal="group_packet", tuning=Tuning(group_side=4))
    t, n, ref = intersect_rays(packed, select_device(device), o - eye, d)
    out.update({"intersect/group_t": t, "intersect/group_n": n, "intersect/group_ref": ref})
    return out


def bvh(device: str | None) -> dict[str, np.ndarray]:
    """The device BVH build over 300 random boxes (the packer uses it from 20000 on)."""
    lo, hi = _boxes()
    tree = build_bvh_on(queue_for(select_device(device)), lo, hi, 2)
    return {"bvh/nodes": tree.nodes.view(np.uint8), "bvh/order": tree.order}


def bvh_float(device: str | None) -> dict[str, np.ndarray]:
    """The same from float32 bounds (a mesh's: the build's float path). A run of its own:
    under Oclgrind a second build in one process reads the first one's buffers' memory as
    uninitialised (so it did before float bounds, for two float64 builds)."""
    lo, hi = _boxes()
    tree = build_bvh_on(queue_for(select_device(device)), lo.astype(np.float32),
                        hi.astype(np.float32), 2)
    return {"bvh/float_nodes": tree.nodes.view(np.uint8), "bvh/float_order": tree.order}


def _boxes() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    lo = rng.uniform(-10, 10, (300, 3))
    return lo, lo + rng.uniform(0.01, 2, (300, 3))


PARTS = {"renders": renders, "intersections": intersections, "bvh": bvh,
         "bvh_float": bvh_float}


def main(out: str, device: str, parts: str) -> None:
    pyopencl.characterize.nv_compute_capability = nv_compute_capability_if_nvidia
    results: dict[str, np.ndarray] = {}
    for part in parts.split(","):
        results.update(PARTS[part](device))
    np.savez(out, **results)


if __name__ == "__main__":
    main(*sys.argv[1:4])
