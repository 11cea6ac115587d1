"""Passes (AOVs): depth and normal against closed forms for a sphere and a plane under the
pinhole and the orthographic camera, in the float and double builds; albedo against the
material colour and a checker texture; the object, material and instance indices against the
float64 reference's closest hits (clray.reference), with instances; means over samples; the
settings' checks; and the command line's --aov files (PFMs, EXR layers, previews) and errors."""

from __future__ import annotations

import importlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from PIL import Image

from clray import cli
from clray.device.context import has_fp64
from clray.errors import EXIT_USAGE, SettingsError
from clray.image_io import read_pfm, to_png_samples
from clray.knobs import Tuning
from clray.passes import PASS_NAMES, preview
from clray.reference import camera_rays
from clray.reference.bvh import intersect_scene
from clray.reference.sampling import sample_positions
from clray.render import RenderResult, RenderSettings, render
from clray.scene import model as M

W, H = 40, 30
GREY = M.Material("grey", (0.6, 0.5, 0.4))
RED = M.Material("red", (0.9, 0.2, 0.1))
CHECKER = M.Material("checker", (0.8, 0.8, 0.2),
                     texture=M.Texture("checker", size=0.7, color2=(0.1, 0.3, 0.9), blend=0.75))
LIGHT = M.PointLight((-4.0, 6.0, 5.0), (0.8, 0.8, 0.8), (1.0, 0.0, 0.0))
CENTRE, RADIUS = np.array([0.3, 1.0, -0.5]), 1.2
SPHERE = M.Sphere(tuple(CENTRE), RADIUS, 1)
# A tilted plane, so that depth varies along both image axes.
PLANE_POINT = np.array([0.0, -0.2, 0.0])
PLANE_NORMAL = np.array([0.1, 1.0, 0.2]) / np.linalg.norm([0.1, 1.0, 0.2])
PLANE = M.Plane(tuple(PLANE_POINT), tuple(PLANE_NORMAL), 2)
EYE, LOOK = (0.5, 3.0, 7.0), (0.0, 0.6, 0.0)
CAMERAS = {
    "pinhole": M.Camera(EYE, LOOK, vfov=40),
    "orthographic": M.Camera(EYE, LOOK, vfov=None, type="orthographic", height=6.0),
}
ALL = PASS_NAMES


def _scene(camera: M.Camera, spp: int = 1, objects: tuple = (PLANE, SPHERE),
           materials: tuple = (GREY, RED, CHECKER)) -> M.Scene:
    return M.Scene(None, M.RenderOptions(W, H, spp, 2, (0.2, 0.3, 0.4)), camera, materials,
                   (LIGHT,), objects)


def _closed_forms(scene: M.Scene) -> dict[str, np.ndarray]:
    """Per pixel (one sample, its centre), in float64: the nearer of the sphere's and the
    plane's hits, its t, point, outward normal and object (0 plane, 1 sphere)."""
    o, d, _ = camera_rays(scene)
    oc = o - CENTRE
    b = np.einsum("ij,ij->i", oc, d)
    disc = b * b - (np.einsum("ij,ij->i", oc, oc) - RADIUS ** 2)
    root = np.sqrt(np.maximum(disc, 0.0))
    near, far = -b - root, -b + root
    t_sphere = np.where(disc < 0, np.inf, np.where(near > 0, near, np.where(far > 0, far, np.inf)))
    along = d @ PLANE_NORMAL
    with np.errstate(divide="ignore"):
        t_plane = ((PLANE_POINT - o) @ PLANE_NORMAL) / along
    t_plane = np.where(t_plane > 0, t_plane, np.inf)
    sphere = t_sphere < t_plane
    t = np.minimum(t_sphere, t_plane)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    normal = np.where(sphere[:, None], (p - CENTRE) / RADIUS, PLANE_NORMAL)
    # How squarely each ray meets its surface: depth's condition number is 1 / cos.
    cos = np.abs(np.einsum("ij,ij->i", normal, d))
    obj = np.where(np.isfinite(t), sphere.astype(int), -1)
    return {name: value.reshape(H, W, *value.shape[1:]) for name, value in
            (("t", t), ("p", p), ("normal", normal), ("cos", cos), ("object", obj))}


@pytest.mark.parametrize("precision", ["float", "double"])
@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_depth_and_normal_match_the_closed_forms(camera: str, precision: str,
                                                 cl_device: cl.Device) -> None:
    if precision == "double" and not has_fp64(cl_device):
        pytest.skip("the device has no cl_khr_fp64")
    scene = _scene(CAMERAS[camera])
    result = render(scene, RenderSettings(precision=precision, aovs=ALL))
    want = _closed_forms(scene)
    aovs = result.aovs
    assert aovs["depth"].dtype == np.float32 and aovs["depth"].shape == (H, W)
    assert aovs["object"].dtype == np.int32 and aovs["normal"].shape == (H, W, 3)
    assert np.array_equal(aovs["object"], want["object"])
    hit = want["object"] >= 0
    assert hit.mean() > 0.5 and (want["object"] == 1).sum() > 50
    assert np.all(np.isinf(aovs["depth"][~hit])) and np.all(aovs["normal"][~hit] == 0)
    # Depth within float32 rounding: the camera ray and the hit are float32 arithmetic (the
    # camera is packed in float32 in both builds), whose relative error in t grows as the ray
    # meets the surface obliquely (condition number 1 / cos).
    error = np.abs(aovs["depth"][hit] - want["t"][hit]) / want["t"][hit]
    assert np.all(error <= 32 * np.finfo(np.float32).eps / want["cos"][hit])
    normal_error = np.abs(aovs["normal"][hit] - want["normal"][hit]).max(axis=-1)
    assert normal_error.max() <= 1e-5
    assert np.allclose(np.linalg.norm(aovs["normal"][hit], axis=-1), 1.0, atol=1e-6)
    scale = np.abs(want["p"][hit]).max()
    assert np.abs(aovs["position"][hit] - want["p"][hit]).max() <= 1e-5 * max(scale, 1.0)


def _checker(p: np.ndarray, n_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """docs/rendering.md's 3D checker at p moved a quarter cell against n_f: (second colour,
    distance of the moved point from the nearest cell wall, in cells)."""
    size = CHECKER.texture.size
    q = (p - 0.25 * size * n_f) / size
    second = np.floor(q).sum(axis=-1) % 2 == 1
    wall = np.abs(q - np.rint(q)).min(axis=-1)
    return second, wall


@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_albedo_is_the_material_colour_times_the_texture(camera: str, cl_device: cl.Device) -> None:
    scene = _scene(CAMERAS[camera])
    result = render(scene, RenderSettings(aovs=("albedo", "object")))
    want = _closed_forms(scene)
    albedo = result.aovs["albedo"]
    assert albedo.shape == (H, W, 3) and albedo.dtype == np.float32
    sphere, plane = want["object"] == 1, want["object"] == 0
    assert np.array_equal(albedo[sphere], np.broadcast_to(np.float32(RED.color), albedo[sphere]
                                                          .shape))
    assert np.all(albedo[want["object"] < 0] == 0)
    # The plane's checker: blend * texel + (1 - blend) * colour, the cells by the closed form
    # away from their walls (where float32 and float64 points may fall on either side).
    n_f = np.where((want["p"] - np.asarray(EYE)) @ PLANE_NORMAL < 0, 1, -1)[..., None]
    second, wall = _checker(want["p"], n_f * PLANE_NORMAL)
    texture = CHECKER.texture
    base = np.asarray(CHECKER.color)
    colour = np.where(second[..., None], texture.blend * np.asarray(texture.color2)
                      + (1 - texture.blend) * base, base)
    clear = plane & (wall > 1e-3)
    assert second[clear].any() and (~second[clear]).any()
    assert np.abs(albedo[clear] - colour[clear]).max() <= 1e-6


# Objects of every packing: a plane, a sphere, a Spheres array, a box, a mesh, and two
# instances of one group (one with its own material): each pixel's object, material and
# instance against the float64 reference's closest hit.
GROUP = M.Group("pair", (M.Sphere((0.0, 0.0, 0.0), 0.5, 1), M.Box((0.6, -0.3, -0.3),
                                                                  (1.2, 0.3, 0.3), 0)))


def _index_scene(camera: M.Camera, spp: int) -> M.Scene:
    mesh = M.Mesh(np.array([[-3.0, 0.0, -3.0], [-1.5, 0.0, -3.0], [-2.2, 2.0, -3.0],
                            [-1.5, 2.0, -3.0]]), np.array([[0, 1, 2], [1, 3, 2]]), 3)
    spheres = M.Spheres(np.array([[2.0, 0.4, 0.5], [2.6, 0.4, 1.5]]), np.array([0.4, 0.35]),
                        np.array([2, 1]))
    shift = np.array([[1.0, 0.0, 0.0, -1.5], [0.0, 1.0, 0.0, 0.5], [0.0, 0.0, 1.0, 1.5]])
    scaled = np.array([[0.8, 0.0, 0.0, 1.0], [0.0, 0.8, 0.0, 2.3], [0.0, 0.0, 0.8, -1.0]])
    objects = (PLANE, SPHERE, spheres, M.Box((-0.5, -0.2, 1.5), (0.3, 0.5, 2.5), 3), mesh,
               M.Instance(GROUP, shift), M.Instance(GROUP, scaled, material=2))
    materials = (GREY, RED, CHECKER, M.Material("green", (0.1, 0.8, 0.2)))
    return _scene(camera, spp, objects, materials)


@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_indices_follow_the_scene_order(camera: str, cl_device: cl.Device) -> None:
    scene = _index_scene(CAMERAS[camera], 1)
    result = render(scene, RenderSettings(aovs=("object", "material", "instance", "depth")))
    o, d, _ = camera_rays(scene)
    ref = intersect_scene(scene, o, d)
    want_object = ref.obj.reshape(H, W)
    aovs = result.aovs
    assert {0, 1, 2, 3, 4, 5, 6} <= set(np.unique(want_object))
    # Pixels whose nearest two surfaces are within float32 rounding may differ: none here.
    assert np.array_equal(aovs["object"], want_object)
    assert np.array_equal(aovs["material"], ref.material.reshape(H, W))
    # Instances count from 0 in scene order: objects 5 and 6 are instances 0 and 1.
    want_instance = np.where(want_object >= 5, want_object - 5, -1)
    assert np.array_equal(aovs["instance"], want_instance)
    assert all(aovs[name].dtype == np.int32 for name in ("object", "material", "instance"))


# The thin lens too: each sample's ray leaves its own point of the lens.
SAMPLED_CAMERAS = {**CAMERAS, "thin_lens": M.Camera(EYE, LOOK, vfov=40, aperture=0.4)}


def _nearest_samples(scene: M.Scene) -> np.ndarray:
    """(H, W): which of each pixel's samples lies nearest its centre, the first of equally
    near ones, from the render's own sample positions (docs/passes.md)."""
    spp = scene.render.spp
    sx, sy, pixel = sample_positions(W, H, spp, scene.render.seed)
    away = (sx - (pixel % W + 0.5)) ** 2 + (sy - (pixel // W + 0.5)) ** 2
    return away.reshape(H, W, spp).argmin(axis=-1)  # argmin: the first of equal minima


@pytest.mark.parametrize("spp", [4, 9])
@pytest.mark.parametrize("camera", sorted(SAMPLED_CAMERAS))
def test_many_samples_give_the_mean_and_the_nearest_samples_indices(
        camera: str, spp: int, cl_device: cl.Device) -> None:
    # depth, position and normal are the means over the samples that hit (the normal
    # renormalised), albedo the mean over all, the indices the sample's nearest the pixel
    # centre, all over the render's own sample positions. At 9 spp (a 3 x 3 grid) that is
    # mostly the centre cell's sample, but not always; at 4 (2 x 2) no cell holds the centre.
    # Without the floor, so that pixels on the objects' edges mix hits and misses.
    full = _index_scene(SAMPLED_CAMERAS[camera], spp)
    scene = replace(full, objects=full.objects[1:])
    result = render(scene, RenderSettings(aovs=ALL))
    o, d, _ = camera_rays(scene)
    ref = intersect_scene(scene, o, d)
    hit = (ref.obj >= 0).reshape(H, W, spp)
    t = np.where(hit, ref.t.reshape(H, W, spp), 0.0)
    count = hit.sum(axis=-1)
    some = count > 0
    mixed = some & (count < spp)
    assert mixed.sum() > 20
    want_depth = np.where(some, t.sum(axis=-1) / np.maximum(count, 1), np.inf)
    aovs = result.aovs
    assert np.all(np.isinf(aovs["depth"][~some]))
    # Bounds at 4x the largest errors measured on PoCL over the three cameras (float32 kernel,
    # float64 reference): depth 2.9e-6 relative (a grazing sample, orthographic), position
    # 3.8e-5, albedo 7.7e-8.
    assert np.all(np.abs(aovs["depth"][some] - want_depth[some]) <= 1.2e-5 * want_depth[some])
    p = o + np.where(hit.reshape(-1), ref.t, 0.0)[:, None] * d
    want_p = (p.reshape(H, W, spp, 3) * hit[..., None]).sum(axis=2) / np.maximum(count, 1)[
        ..., None]
    assert np.abs(aovs["position"][some] - want_p[some]).max() <= 1.5e-4
    normals = aovs["normal"][some]
    assert np.allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-6)
    nearest = _nearest_samples(scene)[..., None]
    samples_object = ref.obj.reshape(H, W, spp)
    want_object = np.take_along_axis(samples_object, nearest, axis=-1)[..., 0]
    if spp == 4:  # no fixed sample stands in for the nearest (each differs on 30 to 55
        # pixels here, measured on PoCL and Intel's CPU runtime over the three cameras); at
        # 9 spp, the centre cell's sample 4 gives the same objects here
        assert all((want_object != samples_object[..., k]).sum() >= 30 for k in range(spp))
    assert np.array_equal(aovs["object"], want_object)
    want_material = np.take_along_axis(ref.material.reshape(H, W, spp), nearest, axis=-1)
    assert np.array_equal(aovs["material"], want_material[..., 0])
    assert np.array_equal(aovs["instance"] >= 0, (aovs["object"] >= 4))
    want_albedo = np.zeros((H * W * spp, 3))
    colours = np.array([m.color for m in scene.materials])
    solid = (ref.obj >= 0) & (ref.material != 2)
    want_albedo[solid] = colours[ref.material[solid]]
    want_albedo = want_albedo.reshape(H, W, spp, 3).mean(axis=2)
    plain = ~(ref.material.reshape(H, W, spp) == 2).any(axis=-1)
    assert plain.sum() > 1000
    assert np.abs(aovs["albedo"][plain] - want_albedo[plain]).max() <= 3e-7


def test_passes_leave_the_image_alone(cl_device: cl.Device) -> None:
    # The passes build adds a kernel: the image the render kernel makes in it is the same.
    scene = _index_scene(CAMERAS["pinhole"], 4)
    plain = render(scene)
    with_passes = render(scene, RenderSettings(aovs=("depth",)))
    assert plain.aovs == {} and list(with_passes.aovs) == ["depth"]
    assert np.array_equal(plain.image, with_passes.image)


def test_progress_ends_when_the_passes_launches_end(cl_device: cl.Device,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    # Bands of 3 rows for both kernels: the image's reports rise to half the total, the
    # passes' launches the other half; the total is reached by the passes' last band, not
    # before their kernel runs.
    render_module = importlib.import_module("clray.render")  # also the function's name
    events: list[object] = []
    launch_passes = render_module.render_passes_packed

    def passes_packed(*args: object, **kwargs: object) -> object:
        events.append("passes")
        return launch_passes(*args, **kwargs)

    monkeypatch.setattr(render_module, "render_passes_packed", passes_packed)
    scene = _index_scene(CAMERAS["pinhole"], 4)
    rows = Tuning(first_launch_pixel_samples=W * 4 * 3, max_launch_pixel_samples=W * 4 * 3)
    result = render(scene, RenderSettings(aovs=("depth",), tuning=rows,
                                          progress=lambda done, total: events.append(
                                              (done, total))))
    total = 2 * W * H * 4
    reports = [e for e in events if e != "passes"]
    assert {t for _, t in reports} == {total}
    done = [d for d, _ in reports]
    assert done == sorted(done) and done[0] == 0 and done[-1] == total
    assert done.count(total) == 1
    passes_at = events.index("passes")
    assert max(d for d, _ in events[:passes_at]) == total // 2
    assert result.stats["launches"] == result.stats["passes_launches"] == 10
    assert len(reports) == 2 * (10 + 1)


@pytest.mark.parametrize(("aovs", "denoise", "suffix"), [
    (("depth",), False, ".png"), (("object",), False, ".pfm"),
    (("depth", "normal", "albedo"), False, ".png"), (ALL, False, ".pfm"), (ALL, False, ".exr"),
    ((), True, ".png"), (("depth", "normal", "albedo"), True, ".exr")])
def test_passes_host_bytes_bound_a_render_and_its_write(aovs: tuple[str, ...], denoise: bool,
                                                        suffix: str, cl_device: cl.Device,
                                                        tmp_path: Path) -> None:
    # What `clray render` announces for a large image (the image's bytes and the passes') bounds
    # tracemalloc's peak of a render and its write, and is within 1.5 times of it: the image's
    # figure alone (30 bytes a pixel for a PNG) was under a third of the peak with every pass.
    import tracemalloc

    from clray.image_io import image_host_bytes
    from clray.passes import passes_host_bytes

    if denoise:
        pytest.importorskip("pyoidn")
    if suffix == ".exr":
        pytest.importorskip("OpenEXR")
    width, height = 480, 360
    scene = replace(_index_scene(CAMERAS["pinhole"], 1),
                    render=M.RenderOptions(width, height, 1, 2, (0.2, 0.3, 0.4)))
    settings = RenderSettings(aovs=aovs, denoise=denoise)
    render(scene, settings).save(tmp_path / f"warm{suffix}")  # builds, the PNG table
    tracemalloc.start()
    try:
        result = render(scene, settings)
        result.save(tmp_path / f"out{suffix}")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = (image_host_bytes(width, height, suffix)
                + width * height * passes_host_bytes(aovs, denoise, suffix))
    assert peak <= estimate <= 1.5 * peak, (peak / (width * height), estimate / (width * height))


@pytest.mark.parametrize("aovs, words", [
    (("depth", "shadow"), "unknown pass 'shadow'; expected some of depth, normal"),
    (("depth", "depth"), "named twice"),
    ("depth", "expected a tuple of pass names"),
    ((1,), "expected a tuple of pass names"),
])
def test_bad_pass_names_are_refused_on_creation(aovs: object, words: str) -> None:
    with pytest.raises(SettingsError, match=r"RenderSettings\.aovs: ") as err:
        RenderSettings(aovs=aovs)
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name", PASS_NAMES)
def test_previews_are_pictures_in_the_unit_range(name: str) -> None:
    rng = np.random.default_rng(1)
    if name == "depth":
        values = rng.uniform(1, 5, (6, 5)).astype(np.float32)
        values[0, 0] = np.inf
    elif name in ("object", "material", "instance"):
        values = rng.integers(-1, 9, (6, 5)).astype(np.int32)
    else:
        values = rng.uniform(-3, 3, (6, 5, 3)).astype(np.float32)
    picture = preview(name, values)
    assert picture.shape == (6, 5, 3) and picture.dtype == np.float32
    assert np.all((picture >= 0) & (picture <= 1))
    if name == "depth":
        assert np.all(picture[0, 0] == 0) and picture[1:].max() == 1.0


def test_position_preview_is_black_on_a_miss_and_spans_the_hits() -> None:
    # The misses' (0, 0, 0) stretched the range and showed white where the hits' coordinates
    # are all negative.
    values = np.zeros((3, 4, 3), np.float32)
    values[1:, 1:] = np.random.default_rng(3).uniform(-6, -5, (2, 3, 3))
    picture = preview("position", values)
    assert np.all(picture[0] == 0) and np.all(picture[:, 0] == 0)
    hits = picture[1:, 1:].reshape(-1, 3)
    assert np.all(hits.min(axis=0) == 0) and np.all(hits.max(axis=0) == 1)
    assert np.all(preview("position", np.zeros((2, 2, 3), np.float32)) == 0)  # nothing hit


def png_chunk_types(data: bytes) -> list[bytes]:
    """The types of a PNG file's chunks, in order."""
    types, at = [], 8
    while at < len(data):
        length = int.from_bytes(data[at:at + 4], "big")
        types.append(data[at + 4:at + 8])
        at += 12 + length
    return types


def test_previews_are_tagged_srgb_and_albedo_is_srgb_encoded(tmp_path: Path) -> None:
    # The previews' codes are what to show, but were tagged gAMA 1.0 (linear): a colour-managed
    # viewer showed them washed out. Albedo, linear reflectance, is sRGB-encoded as the image is.
    rng = np.random.default_rng(5)
    aovs = {name: (rng.integers(-1, 9, (4, 5)).astype(np.int32)
                   if name in ("object", "material", "instance")
                   else rng.uniform(1, 5, (4, 5)).astype(np.float32) if name == "depth"
                   else rng.uniform(-1, 1, (4, 5, 3)).astype(np.float32))
            for name in PASS_NAMES}
    RenderResult(np.zeros((4, 5, 3), np.float32), {}, aovs=aovs).save(tmp_path / "out.png",
                                                                       previews=True)
    for name, values in aovs.items():
        data = (tmp_path / f"out.{name}.png").read_bytes()
        types = png_chunk_types(data)
        assert b"sRGB" in types and b"gAMA" not in types, name
        codes = np.asarray(Image.open(tmp_path / f"out.{name}.png"))
        shown = preview(name, values)
        expected = (to_png_samples(shown) if name == "albedo"
                    else np.rint(shown.astype(np.float64) * 255).astype(np.uint8))
        assert np.array_equal(codes, expected), name


# --- the command line: --aov, --aov-preview, the files they write -----------------------------

SCENE_FILE = """
[render]
width = 32
height = 24
spp = 4
[camera]
position = [0, 1, 6]
look_at = [0, 0.5, 0]
[materials.red]
color = [0.9, 0.2, 0.1]
[materials.floor]
color = [0.7, 0.7, 0.7]
[[lights]]
type = "point"
position = [3, 5, 4]
[[objects]]
type = "plane"
point = [0, 0, 0]
normal = [0, 1, 0]
material = "floor"
[[objects]]
type = "sphere"
center = [0, 1, 0]
radius = 1
material = "red"
"""


@pytest.fixture
def scene_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "scene.toml"
    path.write_text(SCENE_FILE)
    return path


def _cli(capsys: pytest.CaptureFixture, *argv: str | Path) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_writes_one_pfm_a_pass_beside_the_image_and_previews(
        capsys: pytest.CaptureFixture, scene_file: Path, tmp_path: Path,
        cl_device: cl.Device) -> None:
    code, _, err = _cli(capsys, "render", scene_file, "-o", "out.png", "--aov",
                        "depth,normal,object", "--aov-preview", "-q")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "out.depth.pfm", "out.depth.png", "out.normal.pfm", "out.normal.png", "out.object.pfm",
        "out.object.png", "out.png", "scene.toml"]
    want = render(scene_file, RenderSettings(aovs=("depth", "normal", "object"))).aovs
    assert np.array_equal(read_pfm(tmp_path / "out.depth.pfm"), want["depth"])
    assert np.array_equal(read_pfm(tmp_path / "out.normal.pfm"), want["normal"])
    assert np.array_equal(read_pfm(tmp_path / "out.object.pfm"),
                          want["object"].astype(np.float32))
    assert set(np.unique(want["object"])) == {-1, 0, 1}
    with Image.open(tmp_path / "out.depth.png") as picture:
        assert picture.size == (32, 24) and picture.mode == "RGB"


def test_cli_writes_the_passes_as_layers_of_one_exr(
        capsys: pytest.CaptureFixture, scene_file: Path, tmp_path: Path,
        cl_device: cl.Device) -> None:
    exr = pytest.importorskip("OpenEXR")
    code, _, err = _cli(capsys, "render", scene_file, "-o", "out.exr", "--aov",
                        "albedo,depth,instance")
    assert code == 0, err
    assert "wrote passes albedo,depth,instance: layers of out.exr" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr", "scene.toml"]
    result = render(scene_file, RenderSettings(aovs=("albedo", "depth", "instance")))
    channels = {name: c.pixels for name, c in
                exr.File(str(tmp_path / "out.exr"), separate_channels=True).channels().items()}
    assert sorted(channels) == ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z",
                                "instance.id"]
    assert np.array_equal(np.stack([channels[c] for c in "RGB"], axis=-1), result.image)
    assert np.array_equal(channels["depth.Z"], result.aovs["depth"])
    albedo = np.stack([channels[f"albedo.{c}"] for c in "RGB"], axis=-1)
    assert np.array_equal(albedo, result.aovs["albedo"])
    assert np.all(channels["instance.id"] == -1)


def test_cli_frames_get_their_passes_beside_each(capsys: pytest.CaptureFixture,
                                                  tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  cl_device: cl.Device) -> None:
    monkeypatch.chdir(tmp_path)
    orbit = Path(__file__).resolve().parent.parent / "scenes" / "orbit.toml"
    code, _, err = _cli(capsys, "render", orbit, "--frames", "0:2", "-W", "16", "-H", "12",
                        "-o", "out/f_%04d.png", "--aov", "depth,object", "--aov-preview", "-q")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        f"f_{frame:04d}{part}" for frame in (0, 1)
        for part in (".png", ".depth.pfm", ".object.pfm", ".depth.png", ".object.png"))
    depths = [read_pfm(tmp_path / "out" / f"f_{frame:04d}.depth.pfm") for frame in (0, 1)]
    assert depths[0].shape == (12, 16) and not np.array_equal(depths[0], depths[1])


@pytest.mark.parametrize("argv, words", [
    (["--aov", "depth,shadow"], "unknown pass 'shadow'; expected some of depth, normal"),
    (["--aov", ""], "unknown pass ''"),
    (["--aov", "depth,depth"], "a pass is named twice"),
    (["--aov-preview"], "--aov-preview applies to --aov"),
    (["--aov", "depth", "-o", "-"], "not with -o -"),
    (["--aov", "depth", "--dask"], "a still rendered in tiles on Dask has no passes"),
    (["--aov", "depth", "-o", "out.png", "--stats-json", "out.depth.pfm"],
     "--stats-json and the out.depth.pfm pass file"),
])
def test_cli_pass_usage_errors_exit_2_in_one_line(capsys: pytest.CaptureFixture,
                                                  scene_file: Path, tmp_path: Path,
                                                  argv: list[str], words: str) -> None:
    code, out, err = _cli(capsys, "render", scene_file, *argv)
    assert code == EXIT_USAGE and out == ""
    assert len(err.splitlines()) == 1 and err.startswith("clray: error: ") and words in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


def test_cli_takes_every_pass_at_once() -> None:
    # A list over 40 characters was refused as "expected a tuple of pass names": the flag's
    # parser left text that long unconverted, as it must for a number's.
    every = ",".join(ALL)
    assert len(every) > 40
    assert cli._parse(["render", "scene.toml", "--aov", every]).aov == ALL


@pytest.mark.parametrize(("aovs", "message"), [
    ({"shadow": np.zeros((2, 3))}, "aovs: unknown pass 'shadow'; expected some of depth"),
    ({"depth": np.zeros((3, 2))}, "aovs['depth']: expected shape (2, 3) (the image's size), "
                                  "got (3, 2)"),
    ({"normal": np.zeros((2, 3))}, "aovs['normal']: expected shape (2, 3, 3)"),
    ({"depth": np.full((2, 3), "a")}, "aovs['depth']: expected an (H, W) or (H, W, 3) array"),
    ([np.zeros((2, 3))], "aovs: expected a dict of pass arrays by name, got list"),
])
@pytest.mark.parametrize("suffix", [".png", ".exr"])
def test_bad_passes_are_refused_before_any_file(tmp_path: Path, aovs: object, message: str,
                                                suffix: str) -> None:
    # The passes' files were written before the image; a bad one failed half way (KeyError
    # or IndexError in the EXR's channels), leaving the passes before it.
    result = RenderResult(np.zeros((2, 3, 3), np.float32), {},
                          aovs={"albedo": np.zeros((2, 3, 3)), **aovs}
                          if isinstance(aovs, dict) else aovs)  # type: ignore[arg-type]
    with pytest.raises(SettingsError) as info:
        result.save(tmp_path / f"out{suffix}", previews=True)
    assert str(info.value).startswith(message)
    assert list(tmp_path.iterdir()) == []


def test_passes_given_as_nested_lists_are_written_as_arrays_are(tmp_path: Path) -> None:
    # The image could be a nested list; a pass so given raised AttributeError (no astype).
    depth = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    result = RenderResult(np.zeros((2, 3, 3), np.float32), {},
                          aovs={"depth": depth})  # type: ignore[dict-item]
    result.save(tmp_path / "out.png", previews=True)
    assert np.array_equal(read_pfm(tmp_path / "out.depth.pfm"), np.array(depth))
    assert (tmp_path / "out.depth.png").is_file()


@pytest.mark.parametrize("folder", ["out.png", "out.object.pfm", "out.object.png"])
def test_a_folder_in_the_way_is_refused_before_any_file(tmp_path: Path, folder: str) -> None:
    # A folder at the image's name failed its write after the passes' files were written,
    # which stayed beside no image; one at a later pass's name left the earlier passes.
    (tmp_path / folder).mkdir()
    result = RenderResult(np.zeros((2, 3, 3), np.float32), {},
                          aovs={"depth": np.zeros((2, 3)), "object": np.zeros((2, 3), np.int32)})
    with pytest.raises(IsADirectoryError) as info:
        result.save(tmp_path / "out.png", previews=True)
    assert info.value.filename == str(tmp_path / folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == [folder]


def test_a_dask_still_refuses_passes_before_any_work() -> None:
    pytest.importorskip("distributed")
    from clray.distributed import render_still

    # Refused before the client is used: tiles render the image only.
    with pytest.raises(SettingsError, match="has no passes"):
        render_still(None, _scene(CAMERAS["pinhole"]), RenderSettings(aovs=("depth",)))


@pytest.mark.parametrize("traversal", ["sample_packet", "group_packet"])
def test_passes_are_the_same_in_bands_and_under_every_traversal(traversal: str,
                                                                 cl_device: cl.Device) -> None:
    # Bands of 3 rows (10 launches of render_passes, each at its row offset) in another
    # scheme's build give the passes of one launch in the single-ray build, bit for bit.
    scene = _index_scene(CAMERAS["pinhole"], 4)
    whole = render(scene, RenderSettings(aovs=ALL, traversal="single", stored_tuning=False))
    rows = Tuning(first_launch_pixel_samples=W * 4 * 3, max_launch_pixel_samples=W * 4 * 3)
    banded = render(scene, RenderSettings(aovs=ALL, traversal=traversal, tuning=rows))
    assert banded.stats["traversal"] == traversal and banded.stats["launches"] == 10
    for name in ALL:
        assert np.array_equal(banded.aovs[name], whole.aovs[name]), name


@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_normals_are_outward_not_turned_to_the_viewer(camera: str, cl_device: cl.Device) -> None:
    # From inside a sphere every ray meets its inner side: the pass holds the outward normal
    # (p - centre) / radius, which points away from the camera, not the one shading faces it.
    big = M.Sphere((0.0, 0.0, 0.0), 30.0, 0)
    scene = _scene(CAMERAS[camera], objects=(big,))
    result = render(scene, RenderSettings(aovs=("normal", "position")))
    o, d, _ = camera_rays(scene)
    oc = o - np.asarray(big.center)
    b = np.einsum("ij,ij->i", oc, d)
    t = -b + np.sqrt(b * b - (np.einsum("ij,ij->i", oc, oc) - big.radius ** 2))
    want = ((o + t[:, None] * d - np.asarray(big.center)) / big.radius).reshape(H, W, 3)
    assert np.all(np.einsum("ijk,ijk->ij", want, d.reshape(H, W, 3)) > 0)
    assert np.abs(result.aovs["normal"] - want).max() <= 1e-5
