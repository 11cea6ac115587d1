"""The benchmarks' scene arguments (compare.py, stages.py): the named benchmark scenes and scene
files."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import module_from_file

ROOT = Path(__file__).resolve().parent.parent
compare = module_from_file(ROOT / "benchmarks" / "compare.py", "compare")
stages = module_from_file(ROOT / "benchmarks" / "stages.py", "stages")


def test_scene_names_and_files(tmp_path: Path) -> None:
    scene = tmp_path / "lights.toml"
    scene.write_text("", encoding="utf-8")
    paths = compare.scene_paths(["spheres", str(scene)], tmp_path)
    assert paths == {"spheres": ROOT / "scenes" / "spheres.toml", str(scene): scene.resolve()}


@pytest.mark.parametrize("script", ["compare", "stages"])
def test_unknown_scene_is_a_usage_error(script: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "missing.toml"
    args = {"compare": ["HEAD"], "stages": []}[script]
    with pytest.raises(SystemExit) as exit_info:
        {"compare": compare, "stages": stages}[script].main([*args, "--scenes",
                                                             f"spheres,{missing}"])
    assert exit_info.value.code == 2
    assert str(missing) in capsys.readouterr().err
