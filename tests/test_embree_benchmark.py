"""benchmarks/embree.py: the hit comparison (always), and a tiny run of the whole benchmark where
embreex (the `embree` extra, which CI does not install) is present."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from conftest import module_from_file

ROOT = Path(__file__).resolve().parent.parent
embree_benchmark = module_from_file(ROOT / "benchmarks" / "embree.py", "embree_benchmark")
compare_hits = embree_benchmark.compare_hits


def test_same_hits_agree() -> None:
    t = np.array([1.0, np.inf, 2.5, np.inf], dtype=np.float32)
    got = compare_hits(t, t.copy())
    assert got["agree"] and got["mask_mismatches"] == 0 and got["t_rel_diff_max"] == 0.0
    assert got["rays"] == 4 and got["hits_a"] == got["hits_b"] == got["both_hit"] == 2
    assert got["hit_fraction"] == 0.5


def test_a_ray_hit_by_one_side_only_is_a_mismatch() -> None:
    got = compare_hits(np.array([1.0, 2.0, np.inf]), np.array([1.0, np.inf, np.inf]))
    assert got["mask_mismatches"] == 1 and not got["agree"]
    assert got["mask_agreement"] == pytest.approx(2 / 3)


def test_t_within_and_beyond_tolerance() -> None:
    close = compare_hits(np.array([1.0 + 1e-6, 3.0]), np.array([1.0, 3.0]))
    assert close["agree"] and close["t_rel_diff_max"] == pytest.approx(1e-6)
    far = compare_hits(np.array([1.01, 3.0]), np.array([1.0, 3.0]), rtol=1e-3)
    assert not far["agree"] and far["t_beyond_rtol"] == 1 and far["mask_mismatches"] == 0


def test_nan_is_a_miss_and_lengths_must_match() -> None:
    assert compare_hits(np.array([np.nan]), np.array([np.inf]))["agree"]
    with pytest.raises(ValueError, match="length"):
        compare_hits(np.zeros(2), np.zeros(3))


def test_without_embreex_the_benchmark_says_how_to_install_it(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(embree_benchmark, "import_embreex", lambda: None)
    with pytest.raises(SystemExit) as exit_info:
        embree_benchmark.main(["--repeat", "1"])
    assert exit_info.value.code == 2
    assert "pip install embreex" in capsys.readouterr().err


def test_tiny_run_agrees_with_embree(cl_device: cl.Device, tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("embreex")
    if not cl_device.platform.name.startswith("Portable Computing Language"):
        pytest.skip("the benchmark is read on PoCL's CPU device")
    out = tmp_path / "embree.json"
    embree_benchmark.main(["--size", "64x36", "--subdivisions", "4", "--repeat", "1",
                           "--packet-spp", "4", "--json", str(out),
                           "--mesh-dir", str(tmp_path / "mesh")])
    report = json.loads(out.read_text(encoding="utf-8"))
    for key in ("device", "driver_version", "pocl_version", "compute_units", "cpu_model",
                "embreex_version", "embree_version", "embree", "clray", "ratios", "hits",
                "render_hits", "triangles", "rays"):
        assert key in report, key
    assert report["rays"] == 64 * 36 and report["triangles"] == 20 * 4**4
    assert report["traversal"] == "single"
    assert set(report["clray"]) == {"render", "render_one_core", "intersect",
                                    "intersect_one_core", "packets"}
    for side in (report["embree"], *report["clray"].values()):
        assert side["mrays_per_s"]["median"] > 0 and len(side["mrays_per_s"]["runs"]) == 1
    assert report["clray"]["render"]["rays"] == 64 * 36
    # Embree's runs' kernel time (mapping embreex's new output arrays) and page faults, which
    # its timed runs hold: a run's, not the process's, so never negative.
    for key in ("system_seconds", "page_faults"):
        runs = report["embree"][key]["runs"]
        assert len(runs) == 1 and min(runs) >= 0, key
    assert isinstance(report["embree"]["page_faults"]["runs"][0], int)
    # The one-core child renders the very render the parent does.
    assert report["clray"]["render_one_core"]["rays"] == 64 * 36
    assert report["clray"]["packets"]["rays"] == 64 * 36 * 4
    assert report["ratios"]["render"]["per_core_vs_embree_per_thread"] > 0
    hits = report["hits"]
    assert hits["agree"], hits
    assert 0.05 < hits["hit_fraction"] < 0.5
    assert report["render_hits"]["mask_mismatches"] <= 1
    # The one-core child walks the parent's very rays: the same hits, the same t.
    assert report["one_core_hits"]["mask_mismatches"] == 0
    assert report["one_core_hits"]["t_rel_diff_max"] == 0
    assert report["instructions"] is None
    # The build figures, each one thing: no full trace inside the commit.
    assert report["embree_mesh_s"] > 0 and report["embree_commit_s"] > 0
    assert report["clray_bvh_s"] > 0
    assert "embree_build_s" not in report and "embree_commit_and_first_run_s" not in report


def test_embree_commit_is_timed_without_a_trace(monkeypatch: pytest.MonkeyPatch) -> None:
    """embree_build_s held the mesh's construction, the commit and a whole first trace."""
    embree = embree_benchmark.import_embreex()
    if embree is None:
        pytest.skip("embreex is not installed")
    triangles = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]]], dtype=np.float32)
    rays = np.zeros((3, 3), dtype=np.float32)
    runs = []
    real_run = embree[0].EmbreeScene.run

    class Scene(embree[0].EmbreeScene):
        def run(self, origins: np.ndarray, directions: np.ndarray, **kwargs: object) -> dict:
            runs.append(len(origins))
            return real_run(self, origins, directions, **kwargs)

    side = embree_benchmark.EmbreeSide((type("M", (), {"EmbreeScene": Scene}), *embree[1:]),
                                       triangles, rays, rays + np.float32([0, 0, 1]))
    assert runs == [0] and side.scene.is_committed
    assert side.mesh_s > 0 and side.commit_s > 0


def test_clray_side_runs_without_embreex(cl_device: cl.Device, tmp_path: Path) -> None:
    # The clray half of the benchmark uses the launch module's internals, which CI's runs
    # without embreex would otherwise never import: its walk and its render must see the same
    # hits on the same rays.
    from clray.scene.load import load_scene

    scene_file = embree_benchmark.write_scene(tmp_path / "mesh", 48, 27, 3)
    scene = load_scene(scene_file)
    origins, directions = embree_benchmark.primary_rays(scene, 48, 27)
    side = embree_benchmark.ClraySide(scene, cl_device, origins, directions, 0)
    walked = side.intersect()
    rendered = side.render()
    assert rendered["rays"] == 48 * 27
    hit = np.isfinite(walked["t"]) & (walked["t"] > 0)
    assert 0 < hit.sum() < hit.size
    assert np.count_nonzero(hit != rendered["hit"]) <= 1


def test_instruction_count_calls_the_counter_as_it_is_written(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # --instructions had called benchmarks/instructions.py's _render without the size it
    # came to take, a TypeError after every timed round; its arguments are bound to the real
    # signature here (valgrind itself is not in CI).
    import inspect

    real = embree_benchmark._module("instructions")
    calls = []

    def render(*args: object, **kwargs: object) -> dict:
        bound = inspect.signature(real._render).bind(*args, **kwargs)
        calls.append(bound.arguments)
        return {"instructions": 2_000, "rays": {"primary": 10}}

    monkeypatch.setattr(embree_benchmark, "_module",
                        lambda name: type("Counter", (), {"_render": staticmethod(render)}))
    counted = embree_benchmark.count_instructions(Path("scene.toml"))
    assert counted["instructions_per_ray"] == 200
    assert [call["valgrind"] for call in calls] == [False, True]
    assert all(call["size"] == (0, 0) for call in calls)


def test_a_timed_embree_run_reuses_the_arrays_of_an_untimed_one() -> None:
    """embreex allocates its output arrays at every run; the memory the previous round freed
    had gone to clray's arrays, so the timed run's page faults were timed as Embree's."""
    calls = []

    class Scene:
        is_committed = True

        def run(self, origins: np.ndarray, directions: np.ndarray, output: int) -> dict:
            calls.append(len(origins))
            n = len(origins)
            return {"geomID": np.full(n, embree_benchmark.EMBREE_MISS), "tfar": np.ones(n)}

    modules = (type("S", (), {"EmbreeScene": Scene}),
               type("M", (), {"TriangleMesh": staticmethod(lambda scene, triangles: None)}),
               "fake")
    rays = np.zeros((5, 3), dtype=np.float32)
    side = embree_benchmark.EmbreeSide(modules, np.zeros((1, 3, 3), np.float32), rays, rays)
    calls.clear()  # the commit's run on no rays
    done = side.run()
    assert calls == [5, 5]  # an untimed run, then the timed one
    assert done["page_faults"] >= 0 and done["system_s"] >= 0
    assert np.all(np.isinf(done["t"]))
