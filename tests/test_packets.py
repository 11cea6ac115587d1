"""Sample packets (KernelConfig.traversal "sample_packet", kernels/packet.h) and group packets
("group_packet", kernels/group.h) against the single-ray walk they replace: every lane or
work-item must find the hit the single-ray walk finds for the same ray, and every render the
same image.

The packet walks visit nodes in another order and test each shape with the single-ray formulas,
the same operations in the same order, so hits are compared exactly: a different t or
primitive would mean a lane missed a node, tested a shape another way, or dropped a hit.
"""

from __future__ import annotations

import dataclasses
import uuid
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest
from test_intersect import mesh_gen, random_mix, random_units

from clray.device.launch import intersect_rays, render_packed
from clray.device.pack import pack_scene
from clray.device.policy import device_plan, traversal_for
from clray.device.program import KernelConfig, kernel_source
from clray.errors import SettingsError
from clray.knobs import TRAVERSALS, Tuning
from clray.render import RenderSettings, pack_for, plan_for, render
from clray.scene import model as M
from clray.scene.load import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
# 11 samples: a full packet of 8 and one of 3 on an AVX2 CPU, three packets of 4 elsewhere.
SPP = 11


def _require_exact_arithmetic(device: cl.Device) -> None:
    """The exact comparisons hold where the compiler rounds the lane-wise and the single-ray
    formulas alike. OpenCL C lets a compiler contract a * b + c into one fma where it chooses,
    and Intel's CPU runtime does so differently in vector and scalar code (t differed in the last
    bits in 13 of 3,600 lanes there); PoCL does not. Sample packets are not any device's
    default, and each device's build is checked against its own single-ray walk here only
    where the claim is exact."""
    if not device.platform.name.startswith("Portable Computing Language"):
        pytest.skip("exact packet/single-ray equality is checked on PoCL (fma contraction "
                    "may differ between vector and scalar code elsewhere)")


def _packets(rng: np.random.Generator, n: int, lanes: int, spread: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """n packets of `lanes` rays: one origin each (jittered by spread / 10) and directions
    within about `spread` radians of a random one: a pixel's samples for small spreads, rays
    that share nothing for spread 1."""
    origins = np.repeat(rng.uniform(-12, 12, (n, 3)), lanes, axis=0)
    origins += rng.normal(scale=spread / 10, size=origins.shape)
    axes = np.repeat(random_units(rng, n), lanes, axis=0)
    directions = axes + rng.normal(scale=spread, size=axes.shape)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins.astype(np.float32), directions.astype(np.float32)


def _hits(device: cl.Device, scene: M.Scene, o: np.ndarray, d: np.ndarray, precision: str,
          **switches: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    packed = pack_scene(scene, width=4, height=4, spp=1, max_depth=0, seed=0,
                        precision=precision, **switches)
    return intersect_rays(packed, device, o - np.asarray(scene.camera.position), d)


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize(("lanes", "precision"),
                         [(8, "float"), (16, "float"), (8, "double")])
def test_packet_lanes_find_the_single_ray_hits(cl_device, lanes, precision):
    _require_exact_arithmetic(cl_device)
    if precision == "double" and "cl_khr_fp64" not in cl_device.extensions:
        pytest.skip("no fp64")
    rng = np.random.default_rng(21)
    scene = random_mix(rng, (0.0, 0.0, 0.0))
    parts = [_packets(rng, 150, lanes, spread) for spread in (1e-3, 3e-2, 1.0)]
    o = np.concatenate([p[0] for p in parts])
    d = np.concatenate([p[1] for p in parts])
    t1, n1, r1 = _hits(cl_device, scene, o, d, precision, traversal="single")
    t2, n2, r2 = _hits(cl_device, scene, o, d, precision, traversal="sample_packet",
                       packet_lanes=lanes)
    assert (r1 >= 0).mean() > 0.3
    assert np.array_equal(r1, r2), f"{np.sum(r1 != r2)} of {len(r1)} lanes hit another shape"
    assert np.array_equal(t1, t2), f"t differs in {np.sum(t1 != t2)} lanes"
    assert np.array_equal(n1, n2)


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize("min_lanes", [0, 16])
def test_mesh_packets_find_the_single_ray_hits(cl_device, min_lanes):
    _require_exact_arithmetic(cl_device)
    """A bumpy mesh seen by pixel-sized packets from outside and from inside it; min_lanes 16
    walks every subtree ray by ray below the root, 0 never does."""
    rng = np.random.default_rng(5)
    vertices, faces, _ = mesh_gen.bumpy_mesh(4, (0.0, 0.0, -6.0), 2.0)
    scene = M.Scene(None, M.RenderOptions(),
                    M.Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0)),
                    (M.Material("m"),), (), (M.Mesh(vertices=vertices, faces=faces, material=0),))
    n, lanes = 300, 8
    centre = np.array([0.0, 0.0, -6.0])
    outside = np.tile([0.0, 0.0, 0.0], (n * lanes, 1))
    aim = np.repeat(rng.uniform(-2.2, 2.2, (n, 3)) + centre, lanes, axis=0)
    aim += rng.normal(scale=2e-3, size=aim.shape)
    inside_o, inside_d = _packets(rng, n, lanes, 1e-2)
    inside_o = np.repeat(rng.uniform(-0.5, 0.5, (n, 3)) + centre, lanes, axis=0)
    o = np.concatenate([outside, inside_o]).astype(np.float32)
    d = np.concatenate([aim / np.linalg.norm(aim, axis=1, keepdims=True), inside_d])
    d = d.astype(np.float32)
    t1, _, r1 = _hits(cl_device, scene, o, d, "float", traversal="single")
    t2, _, r2 = _hits(cl_device, scene, o, d, "float", traversal="sample_packet",
                      packet_lanes=lanes, packet_min_lanes=min_lanes)
    assert (r1 >= 0).mean() > 0.5
    assert np.array_equal(r1, r2), f"{np.sum(r1 != r2)} of {len(r1)} lanes hit another shape"
    assert np.array_equal(t1, t2)


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize("side", [4, 8])
def test_group_packets_find_the_single_ray_hits(cl_device, side):
    """Random mixes of every shape, rays in groups from nearly parallel to unrelated, and a
    mesh seen from outside and from inside, walked by work-groups of side * side rays."""
    _require_exact_arithmetic(cl_device)
    rng = np.random.default_rng(22)
    group = side * side
    scene = random_mix(rng, (0.0, 0.0, 0.0))
    parts = [_packets(rng, 20, group, spread) for spread in (1e-3, 3e-2, 1.0)]
    vertices, faces, _ = mesh_gen.bumpy_mesh(4, (0.0, 0.0, -6.0), 2.0)
    mesh = M.Scene(None, M.RenderOptions(),
                   M.Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0)),
                   (M.Material("m"),), (), (M.Mesh(vertices=vertices, faces=faces, material=0),))
    _, inside_d = _packets(rng, 20, group, 1e-2)
    centres = rng.uniform(-0.5, 0.5, (20, 3)) + np.array([0.0, 0.0, -6.0])
    inside_o = np.repeat(centres, group, axis=0).astype(np.float32)
    for world, (o, d) in ((scene, [np.concatenate(x) for x in zip(*parts, strict=True)]),
                          (mesh, (inside_o, inside_d))):
        # One ray fewer than whole groups: the last group is padded.
        o, d = o[:-1], d[:-1]
        t1, _, r1 = _hits(cl_device, world, o, d, "float", traversal="single")
        t2, _, r2 = _hits(cl_device, world, o, d, "float", traversal="group_packet",
                          tuning=Tuning(group_side=side))
        assert (r1 >= 0).mean() > 0.3
        assert np.array_equal(r1, r2), f"{np.sum(r1 != r2)} of {len(r1)} rays hit another shape"
        assert np.array_equal(t1, t2), f"t differs in {np.sum(t1 != t2)} rays"


def _render_both(scene: M.Scene | Path, traversal: str, tuning: Tuning,
                 **size: int) -> tuple[np.ndarray, np.ndarray]:
    """The single-ray walk's image and the packet traversal's. Sizes that are not whole tiles
    leave some of a group packet's work-items outside the image."""
    images = [render(scene, RenderSettings(spp=SPP, traversal=name, tuning=knobs,
                                           stored_tuning=False, **size)).image
              for name, knobs in (("single", Tuning()), (traversal, tuning))]
    return images[0], images[1]


# Each packet traversal, group packets in the default 4 x 4 tiles for the example scenes and
# in 8 x 8 tiles for the hard cases.
PACKETS = [("sample_packet", Tuning()), ("group_packet", Tuning())]
HARD_PACKETS = [("sample_packet", Tuning()), ("group_packet", Tuning(group_side=8))]


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize(("traversal", "tuning"), PACKETS, ids=[p for p, _ in PACKETS])
@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_example_scene_renders_the_same_with_packets(cl_device, path, traversal, tuning):
    _require_exact_arithmetic(cl_device)
    single, packets = _render_both(path, traversal, tuning, width=40, height=30)
    assert np.array_equal(single, packets, equal_nan=True), (
        f"{np.sum(np.any(single != packets, axis=2))} pixels differ")


def _hard_cases() -> list:
    import sys
    sys.path.insert(0, str(ROOT / "tests" / "hard_cases"))
    from cases import CASES
    return [c for c in CASES if not c.slow]


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize(("traversal", "tuning"), HARD_PACKETS,
                         ids=[p for p, _ in HARD_PACKETS])
@pytest.mark.parametrize("case", _hard_cases(), ids=lambda c: c.name)
def test_hard_case_renders_the_same_with_packets(cl_device, case, traversal, tuning):
    _require_exact_arithmetic(cl_device)
    single, packets = _render_both(scene_from_dict(case.scene), traversal, tuning, width=38,
                                   height=30)
    assert np.array_equal(single, packets, equal_nan=True), (
        f"{np.sum(np.any(single != packets, axis=2))} pixels differ")


def _lane_wise_scene(shininess: float, light: list[float]) -> M.Scene:
    """Two shiny spheres on a plane under one point light, seen by the pinhole camera: every
    lane-wise set-up of a sample packet (camera rays, the point light's shadow rays and terms,
    planes) has work to do."""
    shiny = {"color": [0.9, 0.6, 0.3], "ambient": 0.1, "diffuse": 0.6, "specular": 0.8,
             "shininess": shininess, "reflect": 0.3}
    return scene_from_dict({
        "render": {"width": 40, "height": 30, "max_depth": 2, "ambient": [1.0, 1.0, 1.0]},
        "camera": {"position": [0, 2, 6], "look_at": [0, 0.5, 0], "vfov": 45},
        "materials": {"shiny": shiny},
        "lights": [{"type": "point", "position": light, "color": [1.0, 1.0, 1.0]}],
        "objects": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0],
                     "material": "shiny"},
                    {"type": "sphere", "center": [-0.8, 0.7, 0], "radius": 0.7,
                     "material": "shiny"},
                    {"type": "sphere", "center": [0.9, 0.5, -0.5], "radius": 0.5,
                     "material": "shiny"}]})


# A whole specular exponent and a near light take the lane-wise paths; a fractional exponent
# (phong_power's exp2 and log2) and a light so far that its squared distance overflows float
# (where length() scales and sqrt(d . d) is infinite) must go lane by lane, and still give the
# single-ray image. Each fallback removed, its case fails.
LANE_WISE = {"lane_wise": (32.0, [3.0, 5.0, 4.0]),
             "fractional_shininess": (12.5, [3.0, 5.0, 4.0]),
             "light_beyond_2^64": (32.0, [3e19, 5e19, 4e19])}


@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")
@pytest.mark.parametrize("case", list(LANE_WISE))
def test_lane_wise_set_ups_render_the_single_ray_image(cl_device, case):
    _require_exact_arithmetic(cl_device)
    scene = _lane_wise_scene(*LANE_WISE[case])
    single, packets = _render_both(scene, "sample_packet", Tuning(), width=40, height=30)
    assert np.mean(single[..., 0] > 0.2) > 0.2, "the scene should be mostly lit"
    assert np.array_equal(single, packets, equal_nan=True), (
        f"{np.sum(np.any(single != packets, axis=2))} pixels differ")


def test_traversal_setting_is_checked():
    with pytest.raises(SettingsError, match="traversal"):
        RenderSettings(traversal="packets")


def test_default_traversal_is_reported(cl_device):
    want = traversal_for(cl_device)
    assert want in TRAVERSALS
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    assert RenderSettings().traversal is None
    # 16 samples fill a packet of any width (4 to 16 lanes).
    assert render(scene, RenderSettings(width=8, height=6, spp=16)).stats["traversal"] == want
    chosen = render(scene, RenderSettings(width=8, height=6, spp=2, traversal="sample_packet"))
    assert chosen.stats["traversal"] == "sample_packet"


def test_a_devices_own_sample_packets_need_a_full_packet() -> None:
    # Intel's CPU runtime (8 float lanes on AVX2) renders with sample packets of its own accord
    # only where a pixel's samples fill one; a traversal named by the settings or the tuning
    # is used from 2 samples a pixel.
    intel = SimpleNamespace(name="CPU", platform=SimpleNamespace(name="Intel(R) OpenCL"),
                            type=cl.device_type.CPU, preferred_vector_width_float=1,
                            native_vector_width_float=8, preferred_vector_width_double=1,
                            native_vector_width_double=4)

    def traversal(spp: int, settings: RenderSettings, tuning: Tuning) -> str:
        return device_plan(intel, spp=spp, traversal=settings.traversal, tuning=tuning).traversal

    own, named = RenderSettings(), RenderSettings(traversal="sample_packet")
    assert [traversal(spp, own, Tuning()) for spp in (1, 4, 7, 8, 16)] == [
        "single", "single", "single", "sample_packet", "sample_packet"]
    assert [traversal(spp, named, Tuning()) for spp in (1, 2, 4)] == [
        "single", "sample_packet", "sample_packet"]
    tuned = Tuning(traversal="sample_packet")
    assert [traversal(spp, own, tuned) for spp in (1, 2)] == ["single", "sample_packet"]
    assert traversal(4, own, Tuning(packet_lanes=4)) == "sample_packet"


def test_one_sample_a_pixel_renders_with_the_single_ray_build(cl_device):
    # No packet is traced at 1 spp, and the packet build's code would cost every ray more.
    scene = load_scene(ROOT / "scenes" / "spheres.toml")
    one = render(scene, RenderSettings(width=8, height=6, spp=1, traversal="sample_packet"))
    assert one.stats["traversal"] == "single"


@pytest.mark.parametrize(("precision", "lanes"), [("float", 16), ("double", 8)])
def test_wide_packets_build_without_warnings(cl_ctx: cl.Context, precision: str,
                                             lanes: int) -> None:
    """Packets wider than an AVX2 target's vectors made clang warn at every function that
    passes them (-Wpsabi): 257 warnings, whose count PoCL printed at a render's first build.
    The build log must stay empty of warnings; the source carries a fresh comment, so that no
    driver or pyopencl cache answers the build without compiling."""
    config = KernelConfig(has_spheres=True, has_planes=True, has_triangles=True, max_depth=2,
                          traversal="sample_packet", packet_lanes=lanes, precision=precision)
    device = cl_ctx.devices[0]
    if precision == "double" and not device.double_fp_config:
        pytest.skip(f"{device.name.strip()} has no double precision")
    source = f"// {uuid.uuid4()}\n" + kernel_source()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", cl.CompilerWarning)
        program = cl.Program(cl_ctx, source).build(options=config.options())
    log = program.get_build_info(device, cl.program_build_info.LOG)
    assert [line for line in log.splitlines() if "warning" in line.lower()] == []


@pytest.mark.parametrize("name", ["spheres", "cornell_box"])
def test_packet_build_at_one_sample_traces_a_packet_of_one(cl_device, name):
    """With chains (no refraction) the sample-packet build holds no ray-by-ray tree (issue 42,
    kernels/packet_trace.h): launched at 1 spp, which clray's renders never do
    (test_one_sample_a_pixel_renders_with_the_single_ray_build), it traces packets of one lane,
    and must render the single-ray build's image."""
    _require_exact_arithmetic(cl_device)
    scene = load_scene(ROOT / "scenes" / f"{name}.toml")
    one = RenderSettings(width=24, height=18, spp=1, stored_tuning=False)
    packets = plan_for(scene, dataclasses.replace(one, spp=16, traversal="sample_packet"),
                       cl_device)
    assert packets.traversal == "sample_packet"
    packed = pack_for(scene, one, cl_device, packets)
    assert packed.config.traversal == "sample_packet" and not packed.config.has_refraction
    image, _ = render_packed(packed, cl_device)
    single, _ = render_packed(pack_for(scene, one, cl_device), cl_device)
    assert np.array_equal(single, image, equal_nan=True), (
        f"{np.sum(np.any(single != image, axis=2))} pixels differ")
