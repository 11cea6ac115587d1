"""The knob table (clray.knobs): every knob acts where the table says, the defaults are
the table's, tuned renders give the default's image, and per-device tuning files are picked up,
or ignored with a warning when invalid or stale (clray.device.tuning_files)."""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import re
import uuid
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from clray import __version__, cli
from clray.accel import bvh as bvh_module
from clray.accel import wide as wide_module
from clray.device import tuning_files as store
from clray.device.context import context_for
from clray.device.pack import pack_scene
from clray.device.policy import bvh_width_for, packet_lanes_for, traversal_for
from clray.device.program import (
    ALLOWED_BUILD_OPTIONS,
    KernelConfig,
    device_build_options,
    kernel_source,
)
from clray.errors import SettingsError
from clray.knobs import BUILD_KNOBS, IMAGE_KNOBS, build_option
from clray.render import RenderSettings, pack_for, render
from clray.scene.load import load_scene
from clray.study import compare
from clray.tuning import DEFAULT_TUNING, KNOB_TABLE, KNOBS, Tuning, TuningError

ROOT = Path(__file__).resolve().parent.parent
SPHERES = ROOT / "scenes" / "spheres.toml"
SMALL = {"width": 48, "height": 27}
launch_module = importlib.import_module("clray.device.launch")


@pytest.fixture(scope="module")
def spheres():
    return load_scene(SPHERES)


@pytest.fixture(scope="module")
def crowd(tmp_path_factory):
    """300 small spheres at random: a BVH of many nodes, which every host knob reshapes."""
    rng = np.random.default_rng(7)
    centers = rng.uniform(-3, 3, (300, 3)).round(3)
    radii = rng.uniform(0.05, 0.2, 300).round(3)
    path = tmp_path_factory.mktemp("crowd") / "crowd.toml"
    path.write_text(f"""
[camera]
position = [0, 0, 9]
look_at = [0, 0, 0]
[materials.a]
color = [0.9, 0.3, 0.2]
[[lights]]
type = "point"
position = [4, 6, 5]
[[objects]]
type = "spheres"
centers = {centers.tolist()}
radii = {radii.tolist()}
materials = ["a"]
material_index = {[0] * 300}
""")
    return load_scene(path)


def packed_with(scene, **knobs):
    r = scene.render
    tuning = Tuning(**knobs)
    return pack_scene(scene, width=48, height=27, spp=r.spp, max_depth=r.max_depth, seed=0,
                      bvh_width=tuning.bvh_width or 8, tuning=tuning)


def test_every_knob_is_a_tuning_field_with_a_legal_default_among_its_tried_values() -> None:
    assert [k.name for k in KNOB_TABLE] == [f.name for f in dataclasses.fields(Tuning)]
    for knob in KNOB_TABLE:
        assert knob.legal(knob.default), knob.name
        assert knob.default in knob.tried, knob.name
        assert all(knob.legal(v) for v in knob.tried), knob.name
        assert knob.acts in ("host", "host+kernel", "kernel", "build", "launch")


def test_the_constants_at_their_sites_are_the_table_defaults() -> None:
    assert bvh_module.TRAVERSAL_COST == KNOBS["traversal_cost"].default
    assert bvh_module.SAH_MAX_LEAF == KNOBS["largest_leaf"].default
    assert bvh_module.MAX_LEAF_SIZE == KNOBS["max_leaf_size"].default
    assert wide_module.FOLD_PACKETS == KNOBS["fold_packets"].default
    assert RenderSettings().tuning is None  # a render takes the table's (or a tuning file's)
    # The traversal knob's None is the device's own (traversal_for); a build names one.
    assert KNOBS["traversal"].default is None and KernelConfig().traversal == "single"
    assert KernelConfig().packet_min_lanes == KNOBS["packet_min_lanes"].default
    # The study variants are off by default: the default build is the exact one.
    assert all(KNOBS[name].default is False for name in IMAGE_KNOBS)
    assert {"cl_mad_enable", "cl_unsafe_math_optimizations", "cl_fast_relaxed_math",
            "sphere_textbook", "triangle_moller_trumbore", "fresnel_schlick"} == set(IMAGE_KNOBS)
    assert all(build_option(name) in ALLOWED_BUILD_OPTIONS for name in BUILD_KNOBS)


@pytest.mark.parametrize(("values", "words"), [
    ({"work_group_width": 48}, "work_group_width: expected a power of two"),
    ({"bvh_width": 16}, "bvh_width: expected 4, 8, or None"),
    ({"bvh_width": 4.0}, "bvh_width: expected 4, 8, or None"),  # was legal: 4.0 == 4
    ({"traversal_cost": 0}, "traversal_cost: expected a number over 0"),
    ({"max_leaf_size": 8, "largest_leaf": 4}, "largest_leaf 4 is below max_leaf_size 8"),
    ({"first_launch_pixel_samples": 100, "max_launch_pixel_samples": 10},
     "max_launch_pixel_samples 10 is below"),
    ({"launch_growth": True}, "launch_growth: expected an integer"),
    ({"traversal": "packet"}, "traversal: expected single, sample_packet, group_packet, or None"),
    ({"traversal": "sample_packet", "packet_lanes": 12}, "packet_lanes: expected 4, 8, 16"),
    ({"traversal": "sample_packet", "packet_lanes": 4, "packet_min_lanes": 4},
     "packet_min_lanes 4 is not below packet_lanes 4"),
    ({"traversal": "single", "packet_lanes": 16},
     "packet_lanes 16 acts only with traversal sample_packet"),
    ({"traversal": "single", "packet_min_lanes": 0},
     "packet_min_lanes 0 acts only with traversal sample_packet"),
    ({"traversal": "group_packet", "packet_lanes": 8},
     "packet_lanes 8 acts only with traversal sample_packet"),
    ({"traversal": "group_packet", "group_side": 6}, "group_side: expected 4 or 8"),
    ({"traversal": "sample_packet", "group_side": 8},
     "group_side 8 acts only with traversal group_packet"),
    ({"cl_mad_enable": 1}, "cl_mad_enable: expected True or False"),
    ({"traversal": "sample_packet", "implicit_vectorization": True},
     "implicit_vectorization True does not build with traversal sample_packet"),
])
def test_illegal_knobs_and_broken_restrictions_are_refused(values, words) -> None:
    # A SettingsError, as another bad render setting: one line on the command line.
    with pytest.raises(SettingsError, match=words) as refused:
        Tuning(**values)
    assert isinstance(refused.value, TuningError) and isinstance(refused.value, ValueError)
    with pytest.raises(TuningError, match=r"^1 unknown knob: work_group_size$"):
        Tuning.from_values({"work_group_size": 64})
    with pytest.raises(TuningError, match=r"^2 unknown knobs: lanes, work_group_size$"):
        Tuning.from_values({"work_group_size": 64, "lanes": 8})


def test_no_knob_takes_a_float_or_a_bool_for_an_integer() -> None:
    # A tuning file's "bvh_width": 4.0 passed the check (4.0 == 4) and failed every render in
    # the wide BVH's build with a traceback.
    for knob in KNOB_TABLE:
        counts = [v for v in knob.tried if isinstance(v, int) and not isinstance(v, bool)]
        assert not any(knob.legal(float(v)) for v in counts), knob.name
        if not isinstance(knob.default, bool):
            assert not knob.legal(True) and not knob.legal(False), knob.name


def test_numpy_numbers_are_knob_values_as_pythons_own() -> None:
    # As RenderSettings takes them: a knob from an array (a sweep's np.int64) is the number it
    # holds, and the tuning's values serialise.
    tuning = Tuning(work_group_width=np.int64(32), launch_seconds=np.float32(0.5),
                    launch_growth=np.uint8(2))
    assert tuning == Tuning(work_group_width=32, launch_seconds=0.5, launch_growth=2)
    assert type(tuning.work_group_width) is int and type(tuning.launch_seconds) is float
    assert json.loads(json.dumps(tuning.values()))["work_group_width"] == 32
    with pytest.raises(TuningError, match="work_group_width: expected a power of two"):
        Tuning(work_group_width=np.float64(32.0))  # a float is no count, numpy's or not


def test_host_knobs_change_the_packed_bvh(crowd) -> None:
    base = packed_with(crowd)
    assert base.tuning == DEFAULT_TUNING
    four = packed_with(crowd, bvh_width=4)
    assert (base.config.bvh_width, four.config.bvh_width) == (8, 4)
    assert "-DBVH_WIDTH=4" in four.config.options() and "-DBVH_WIDTH=8" in base.config.options()
    assert len(four.nodes) > len(base.nodes)
    deep = {"traversal_cost": 0.25}  # a deeper tree, whose bottom folding can shrink
    for before, knobs in (({}, {"traversal_cost": 0.25}),
                          ({}, {"max_leaf_size": 1, "largest_leaf": 1}),
                          ({}, {"largest_leaf": 4}),
                          ({**deep, "fold_packets": 0}, {**deep, "fold_packets": 8})):
        one, other = packed_with(crowd, **before), packed_with(crowd, **knobs)
        assert other.tuning == Tuning(**knobs)
        assert (other.nodes.tobytes(), other.prim_refs.tobytes()) != (
            one.nodes.tobytes(), one.prim_refs.tobytes()), knobs


def options_with(cl_device, scene, tuning: Tuning, **settings) -> list[str]:
    # Sixteen samples a pixel: with one the single-ray build renders whatever the traversal,
    # and a device's own sample packets need a pixel's samples to fill a packet (4 to 16 lanes).
    settings = {"spp": 16, **settings}
    return pack_for(scene, RenderSettings(**SMALL, tuning=tuning, **settings),
                    cl_device).config.options()


def test_kernel_and_build_knobs_change_the_kernel_build(cl_device, spheres) -> None:
    own = traversal_for(cl_device)
    assert f"-DTRAVERSAL=TRAVERSAL_{own.upper()}" in options_with(cl_device, spheres,
                                                                 DEFAULT_TUNING)
    # The other knobs against the single-ray build (the device's own traversal or not).
    default = options_with(cl_device, spheres, Tuning(traversal="single"))
    assert "-DTRAVERSAL=TRAVERSAL_SINGLE" in default
    assert not any(o.startswith(("-DPACKET_", "-cl-")) for o in default)
    packets = Tuning(traversal="sample_packet")
    auto = packet_lanes_for(cl_device, spp=16)
    assert set(options_with(cl_device, spheres, packets)) - set(default) == {
        "-DTRAVERSAL=TRAVERSAL_SAMPLE_PACKET", f"-DPACKET_LANES={auto}",
        f"-DPACKET_MIN_LANES={KNOBS['packet_min_lanes'].default}"}
    for knobs, option in (({"packet_lanes": 16}, "-DPACKET_LANES=16"),
                          ({"packet_lanes": 4}, "-DPACKET_LANES=4"),
                          ({"packet_min_lanes": 0}, "-DPACKET_MIN_LANES=0"),
                          ({"packet_lanes": 16, "packet_min_lanes": 9}, "-DPACKET_MIN_LANES=9")):
        if knobs.get("packet_lanes") == auto and len(knobs) == 1:
            continue  # the device's own width: the same build as the default's
        changed = set(options_with(cl_device, spheres, Tuning(traversal="sample_packet", **knobs)))
        assert option in changed and option not in options_with(cl_device, spheres, packets)
    # RenderSettings.traversal overrides the knob, and then the packet knobs do not act.
    forced = options_with(cl_device, spheres, Tuning(traversal="sample_packet", packet_lanes=16),
                          traversal="single")
    assert forced == default
    for name in IMAGE_KNOBS:
        option = (build_option(name) if name in BUILD_KNOBS else f"-D{name.upper()}=1")
        changed = options_with(cl_device, spheres, Tuning(traversal="single", **{name: True}))
        assert option in changed and option not in default, name
        assert len(set(changed) - set(default)) == 1, name


def test_implicit_vectorization_is_a_kernel_switch_that_keeps_the_image(cl_device,
                                                                        spheres) -> None:
    default = options_with(cl_device, spheres, Tuning(traversal="single"))
    packed = options_with(cl_device, spheres, Tuning(traversal="single",
                                                     implicit_vectorization=True))
    assert "-DIMPLICIT_VECTORIZATION=0" in default
    assert set(packed) - set(default) == {"-DIMPLICIT_VECTORIZATION=1"}
    # Never with sample packets (the CPU drivers' own walk at 16 spp): the default's build.
    assert options_with(cl_device, spheres, Tuning(implicit_vectorization=True),
                        traversal="sample_packet") == options_with(
        cl_device, spheres, DEFAULT_TUNING, traversal="sample_packet")
    one = render(spheres, RenderSettings(**SMALL))
    lanes = render(spheres, RenderSettings(**SMALL, tuning=Tuning(implicit_vectorization=True)))
    assert lanes.stats["rays"] == one.stats["rays"]
    assert compare(lanes.image, one.image)["status"] == "pass"


def test_a_stored_implicit_vectorization_leaves_sample_packets_image_alone(cl_device) -> None:
    # A 1-spp tune builds only the single-ray walk, so it may store implicit_vectorization;
    # a 16-spp render then builds sample packets, which Intel's CPU runtime renders wrongly
    # with work-items packed on top (645 of 768 pixels of glass.toml off): left off there.
    glass = load_scene(ROOT / "scenes" / "glass.toml")
    store.save_tuning(cl_device, Tuning(implicit_vectorization=True), {"note": "test"})
    settings = {"width": 32, "height": 24, "spp": 16}
    stored = render(glass, RenderSettings(**settings))
    plain = render(glass, RenderSettings(**settings, stored_tuning=False))
    assert stored.stats["tuning"]["source"].startswith("tuning file ")
    assert "implicit_vectorization=True" in stored.stats["tuning"]["label"]
    assert stored.stats["tuning"]["implicit_vectorization"] is False  # as built
    np.testing.assert_array_equal(stored.image, plain.image)


def test_vector_width_is_the_preferred_or_the_native_one() -> None:
    # Intel's CPU runtime prefers 1 float (it would pack work-items) over AVX2's native 8; a
    # GPU has 1 of each; PoCL on AVX2 prefers 8 floats and 4 doubles, on AVX-512 16 and 8.
    def device(preferred_float, native_float, preferred_double, native_double):
        return SimpleNamespace(preferred_vector_width_float=preferred_float,
                               native_vector_width_float=native_float,
                               preferred_vector_width_double=preferred_double,
                               native_vector_width_double=native_double)

    intel, gpu = device(1, 8, 1, 4), device(1, 1, 1, 1)
    avx2, avx512 = device(8, 8, 4, 4), device(16, 16, 8, 8)
    assert [bvh_width_for(d) for d in (intel, gpu, avx2, avx512)] == [8, 4, 8, 8]
    assert [bvh_width_for(d, "double") for d in (intel, gpu, avx2, avx512)] == [4, 4, 4, 8]
    assert [packet_lanes_for(d) for d in (intel, gpu, avx2, avx512)] == [8, 4, 8, 16]
    assert [packet_lanes_for(d, "double") for d in (intel, gpu, avx2, avx512)] == [4, 4, 4, 8]
    # Where a pixel's samples fill them, 16 lanes on a device 8 wide too (two vectors a test).
    assert [packet_lanes_for(d, spp=16) for d in (intel, gpu, avx2, avx512)] == [16, 4, 16, 16]
    assert [packet_lanes_for(d, spp=15) for d in (intel, gpu, avx2, avx512)] == [8, 4, 8, 16]
    assert [packet_lanes_for(d, "double", 16) for d in (intel, gpu, avx2, avx512)] == [4, 4, 4, 16]


def test_each_device_has_its_own_traversal() -> None:
    # Sample packets where they measured faster (the CPU devices of PoCL and Intel's CPU
    # runtime), the single-ray walk on GPUs and on anything else.
    def device(platform: str, kind: int) -> SimpleNamespace:
        return SimpleNamespace(platform=SimpleNamespace(name=platform), type=kind)

    assert traversal_for(device("Intel(R) OpenCL", cl.device_type.CPU)) == "sample_packet"
    assert traversal_for(device("Intel(R) OpenCL Graphics", cl.device_type.GPU)) == "single"
    assert traversal_for(device("Portable Computing Language", cl.device_type.CPU)) == (
        "sample_packet")
    assert traversal_for(device("NVIDIA CUDA", cl.device_type.GPU)) == "single"


def _vectorizer_report(device: cl.Device, config: KernelConfig) -> str:
    # A source of its own: a program pyopencl reloads from its binary cache has no compiler log.
    source = kernel_source() + f"\n// {uuid.uuid4()}\n"
    options = [*config.options(), *device_build_options(device)]
    program = cl.Program(context_for(device), source).build(options=options)
    log = program.get_build_info(device, cl.program_build_info.LOG)
    return " ".join(line for line in log.splitlines() if 'Kernel "render"' in line)


def test_intels_runtime_packs_work_items_only_when_the_switch_lets_it(cl_device,
                                                                      spheres) -> None:
    # Intel's CPU compiler says in its build log whether it packed the kernel's work-items
    # into a vector's lanes; the default build must ask it not to (the intel_vec_len_hint).
    if "Intel" not in cl_device.platform.name:
        pytest.skip("only Intel's CPU runtime packs work-items into vector lanes")
    config = pack_for(spheres, RenderSettings(**SMALL), cl_device).config
    assert "was not vectorized" in _vectorizer_report(cl_device, config)
    packed = dataclasses.replace(config, implicit_vectorization=True)
    assert "was successfully vectorized" in _vectorizer_report(cl_device, packed)


def test_packet_min_lanes_must_be_below_the_devices_own_lanes(cl_device, spheres,
                                                              lane_width) -> None:
    # At 8 spp the device's lanes are its vector width: 8 on AVX2, 16 on AVX-512.
    auto = packet_lanes_for(cl_device, spp=8)
    assert auto == lane_width
    below = options_with(cl_device, spheres, Tuning(traversal="sample_packet",
                                                    packet_min_lanes=auto - 1), spp=8)
    assert f"-DPACKET_MIN_LANES={auto - 1}" in below
    # 8 lanes: the device's lanes refuse 8. 16 lanes: the knob's own range (0 to 15) answers.
    refusal = (f"tuning: packet_min_lanes {auto} is not below the {auto}" if auto < 16
               else "packet_min_lanes: expected an integer, 0 to 15")
    with pytest.raises(SettingsError if auto < 16 else TuningError, match=refusal):
        options_with(cl_device, spheres, Tuning(traversal="sample_packet",
                                                packet_min_lanes=auto), spp=8)


def test_a_tuning_file_that_does_not_fit_a_double_render_is_ignored_for_it(
        cl_device, capsys, tmp_path) -> None:
    # packet_min_lanes tuned below a float render's lanes (16 on AVX-512) need not be below a
    # double render's (8): that render takes the defaults, with one warning line.
    lanes = packet_lanes_for(cl_device, "double", spp=8)
    path = store.save_tuning(cl_device, Tuning(packet_min_lanes=lanes), {"note": "test"})
    stats = tmp_path / "stats.json"
    code = cli.main(["render", str(SPHERES), "-W", "16", "-H", "12", "--spp", "8",
                     "--traversal", "sample_packet", "--precision", "double",
                     "-o", str(tmp_path / "out.png"), "--stats-json", str(stats)])
    warned = [line for line in capsys.readouterr().err.splitlines()
              if line.startswith("clray: warning: ")]
    assert code == 0
    assert warned == [f"clray: warning: ignoring tuning file {path} for this render: "
                      f"packet_min_lanes {lanes} is not below the {lanes} packet lanes of "
                      f"{cl_device.name.strip()!r} in double"]
    assert json.loads(stats.read_text())["tuning"]["source"] == "default"


def test_traversal_cost_reaches_the_sah() -> None:
    rng = np.random.default_rng(1)
    lo = rng.uniform(0, 10, (500, 3))
    hi = lo + rng.uniform(0.1, 1, (500, 3))
    cheap = bvh_module.build_bvh(lo, hi, traversal_cost=0.5).nodes
    dear = bvh_module.build_bvh(lo, hi, traversal_cost=4.0).nodes
    # A dearer node visit makes fewer, bigger leaves.
    assert len(dear) < len(cheap)
    assert (dear["count"].max()) > (cheap["count"].max())


def test_work_group_width_is_the_launch_local_size(cl_device, spheres, monkeypatch) -> None:
    seen = []
    enqueue = cl.enqueue_nd_range_kernel

    def recording(queue, kernel, global_size, local_size, *args, **kwargs):
        seen.append(local_size)
        return enqueue(queue, kernel, global_size, local_size, *args, **kwargs)

    monkeypatch.setattr(cl, "enqueue_nd_range_kernel", recording)
    # A GPU takes whole warps (clray.device.launch.gpu_group_width: 16 became 32 on an H100),
    # so there the knob is a width it keeps.
    width = 64 if cl_device.type & cl.device_type.GPU else 16
    render(spheres, RenderSettings(**SMALL, tuning=Tuning(work_group_width=width)))
    assert seen and {s[0] for s in seen} == {width}


def test_default_knobs_render_the_untuned_image_bit_for_bit(cl_device, spheres) -> None:
    untuned = render(spheres, RenderSettings(**SMALL))
    assert untuned.stats["tuning"]["source"] == "default"
    assert untuned.stats["tuning"]["label"] == "default"
    # Every knob given, each at the table's value: the same image, bit for bit.
    given = render(spheres, RenderSettings(**SMALL, tuning=Tuning(**{
        k.name: k.default for k in KNOB_TABLE})))
    np.testing.assert_array_equal(untuned.image, given.image)
    assert given.stats["tuning"]["source"] == "given"


def test_tuned_render_gives_the_default_image_within_tolerance(cl_device, spheres) -> None:
    default = render(spheres, RenderSettings(**SMALL))
    tuned_knobs = Tuning(work_group_width=16, bvh_width=4, traversal_cost=1.0, max_leaf_size=2,
                         largest_leaf=8, fold_packets=0, first_launch_pixel_samples=48 * 5,
                         launch_growth=2)
    tuned = render(spheres, RenderSettings(**SMALL, tuning=tuned_knobs))
    assert tuned.stats["launches"] > default.stats["launches"]
    assert tuned.stats["tuning"]["bvh_width"] == 4
    assert compare(tuned.image, default.image)["status"] == "pass"
    assert tuned.stats["rays"]["primary"] == default.stats["rays"]["primary"]


def _write_file(device: cl.Device, knobs: Tuning, changes: dict) -> Path:
    path = store.save_tuning(device, knobs, {"note": "test"})
    record = json.loads(path.read_text())
    record.update(changes)
    path.write_text(json.dumps(record))
    return path


def test_render_uses_the_stored_winner_unless_told_not_to(cl_device, spheres) -> None:
    winner = Tuning(work_group_width=16, fold_packets=2)
    path = store.save_tuning(cl_device, winner, {"note": "test"})
    assert path.is_relative_to(store.cache_dir())
    with warnings.catch_warnings():
        # No warning about the tuning file; a driver's build log (Intel's runtime writes one
        # wherever the kernel is not in pyopencl's cache yet) is no concern of this test's.
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", cl.CompilerWarning)
        stored = render(spheres, RenderSettings(**SMALL))
    assert stored.stats["tuning"]["source"] == f"tuning file {path}"
    assert stored.stats["tuning"]["work_group_width"] == 16
    assert stored.stats["tuning"]["label"] == "work_group_width=16, fold_packets=2"
    plain = render(spheres, RenderSettings(**SMALL, stored_tuning=False))
    assert plain.stats["tuning"]["source"] == "default"
    assert compare(stored.image, plain.image)["status"] == "pass"


@pytest.mark.parametrize(("changes", "words"), [
    ({"driver_version": "0.0-elsewhere"}, "stale: tuned for driver_version '0.0-elsewhere'"),
    ({"clray_version": "0.0.1"}, "stale: tuned for clray_version '0.0.1'"),
    ({"tuning": {"work_group_width": 48}}, "work_group_width: expected a power of two"),
    ({"format": 99}, "expected a clray tuning file of format 1"),
])
def test_invalid_or_stale_tuning_files_are_ignored_with_a_warning(cl_device, changes,
                                                                  words) -> None:
    path = _write_file(cl_device, Tuning(work_group_width=16), changes)
    with pytest.warns(UserWarning, match=f"ignoring tuning file {path}: {words}"):
        tuning, source = store.chosen_tuning(cl_device)
    assert (tuning, source) == (DEFAULT_TUNING, "default")


@pytest.mark.parametrize("change", ["kernels", "knobs"])
def test_a_tuning_file_measured_with_other_kernels_is_stale(cl_device, monkeypatch,
                                                            change) -> None:
    # The package version is the same for every commit: a winner timed against older kernels
    # (or a knob table whose values meant something else) is not this build's winner.
    path = store.save_tuning(cl_device, Tuning(work_group_width=16), {"note": "test"})
    assert store.load_tuning(cl_device) == (Tuning(work_group_width=16), path)
    if change == "kernels":
        source = store.kernel_source()
        monkeypatch.setattr(store, "kernel_source", lambda: source + "\n// changed")
    else:
        table = store.KNOB_TABLE
        monkeypatch.setattr(store, "KNOB_TABLE", table[:-1])
    with pytest.warns(UserWarning, match=f"ignoring tuning file {path}: stale: tuned for "
                                         "kernels '[0-9a-f]{64}', this is '[0-9a-f]{64}'"):
        assert store.load_tuning(cl_device) is None


def test_an_untuned_device_is_found_untuned_without_reading_the_kernels(cl_device,
                                                                        monkeypatch) -> None:
    # Every render looks for a tuning file: finding none must not cost the kernels' digest
    # (reading and hashing their source, 9 ms a render), only a file that exists needs it.
    store.tuning_path(cl_device).unlink(missing_ok=True)

    def no_reading() -> str:
        raise AssertionError("the kernels' source was read to find the tuning file")

    monkeypatch.setattr(store, "kernel_source", no_reading)
    assert store.load_tuning(cl_device) is None


def test_a_tuning_file_that_is_not_json_is_ignored(cl_device) -> None:
    path = store.tuning_path(cl_device)
    path.parent.mkdir(parents=True)
    path.write_text("{half a file")
    with pytest.warns(UserWarning, match="not JSON"):
        assert store.load_tuning(cl_device) is None


def test_a_tuning_file_that_is_not_utf8_is_ignored_with_its_line_and_column(cl_device) -> None:
    path = store.tuning_path(cl_device)
    path.parent.mkdir(parents=True)
    path.write_bytes(b'{\n  "format": 1\xff\n}')
    with pytest.warns(UserWarning) as caught:
        assert store.load_tuning(cl_device) is None
    assert [str(w.message) for w in caught] == [
        f"ignoring tuning file {path}: line 2, column 14: not valid UTF-8 (byte 0xff)"]


@pytest.mark.parametrize(("make", "words"), [
    (lambda path: path.write_text("[" * 200_000 + "]" * 200_000), "not JSON (nested too deeply)"),
    (lambda path: os.mkfifo(path), "not a regular file"),  # reading it would wait for a writer
    (lambda path: path.symlink_to("/dev/zero"), "not a regular file"),  # would never end
    (lambda path: path.write_bytes(b" " * (store.MAX_TUNING_FILE_BYTES + 1)),
     f"{store.MAX_TUNING_FILE_BYTES + 1} bytes is over the limit"),
], ids=["deep", "fifo", "dev-zero", "huge"])
def test_a_tuning_file_that_cannot_be_read_safely_is_ignored(cl_device, make, words) -> None:
    path = store.tuning_path(cl_device)
    path.parent.mkdir(parents=True)
    make(path)
    with pytest.warns(UserWarning, match=re.escape(f"ignoring tuning file {path}: {words}")):
        assert store.chosen_tuning(cl_device) == (DEFAULT_TUNING, "default")


def test_devices_command_calls_an_unreadable_tuning_file_invalid(cl_device, capsys) -> None:
    path = store.tuning_path(cl_device)
    path.parent.mkdir(parents=True)
    os.mkfifo(path)
    assert cli.main(["devices"]) == 0
    assert "tuning file stale or invalid" in capsys.readouterr().out


def test_cache_directory_follows_xdg(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert store.cache_dir() == tmp_path / "clray"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/ignored")
    assert store.cache_dir() == Path.home() / ".cache" / "clray"


def test_next_band_rows_reads_the_band_knobs() -> None:
    rows = launch_module.next_band_rows
    assert rows(100, 0, 0.0, 10_000) == (1 << 16) // 100
    assert rows(100, 0, 0.0, 10_000, Tuning(first_launch_pixel_samples=500)) == 5
    assert rows(100, 10, 0.1, 10_000, Tuning(launch_seconds=0.5)) == 40  # at most 4x
    assert rows(100, 10, 0.1, 10_000, Tuning(launch_seconds=0.5, launch_growth=8)) == 50


@pytest.mark.parametrize(("changes", "why"), [
    ({"clray_version": "0.0.1"},
     f"stale: tuned for clray_version '0.0.1', this is '{__version__}'; run clray tune again"),
    # A float width was taken as legal, and every render failed with a traceback.
    ({"tuning": {"bvh_width": 4.0}},
     f"bvh_width: expected {KNOBS['bvh_width'].legal_text}, got 4.0"),
])
def test_render_command_warns_once_of_a_bad_file_and_renders(cl_device, capsys, tmp_path,
                                                             changes, why) -> None:
    path = _write_file(cl_device, Tuning(work_group_width=16), changes)
    stats = tmp_path / "stats.json"
    code = cli.main(["render", str(SPHERES), "-W", "32", "-H", "18", "-o",
                     str(tmp_path / "out.png"), "--stats-json", str(stats)])
    err = capsys.readouterr().err.splitlines()
    assert code == 0
    warned = [line for line in err if line.startswith("clray: warning: ")]
    assert warned == [f"clray: warning: ignoring tuning file {path}: {why}"]
    assert json.loads(stats.read_text())["tuning"]["source"] == "default"
