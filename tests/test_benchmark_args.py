"""The benchmarks' argument checks: a bad argument is one usage line (exit status 2) before any
work, not a traceback, a half-written result, or a run that measured or checked nothing.
Each script's work is replaced by a function that fails, so a check that came too late fails
here at once instead of rendering."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from conftest import module_from_file

ROOT = Path(__file__).resolve().parent.parent
image_hashes = module_from_file(ROOT / "benchmarks" / "image_hashes.py", "image_hashes")


def _no_work(*args: object, **kwargs: object) -> None:
    raise AssertionError("the benchmark started work on bad arguments")


def _usage_error(main, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """main(argv)'s usage message; fails unless it exits with status 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    return capsys.readouterr().err


@pytest.fixture
def hashes(monkeypatch: pytest.MonkeyPatch):
    for name in ("render", "select_device"):
        monkeypatch.setattr(image_hashes, name, _no_work)
    return image_hashes


def _baseline(path: Path, size: list[int], keys: list[str]) -> Path:
    renders = {key: {"sha256": "0" * 64, "mean": 0.0, "seconds": 0.0} for key in keys}
    path.write_text(json.dumps({"device": "x", "size": size, "renders": renders}),
                    encoding="utf-8")
    return path


@pytest.mark.parametrize(("argv", "says"), [
    (["--only", "spherse"], "spherse"),  # was 0 renders, and --against passed on nothing
    (["--size", "8"], "--size"),  # was a ValueError traceback
    (["--size", "0x54"], "--size"),
])
def test_image_hashes_refuses_bad_arguments(hashes, argv: list[str], says: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "after.json"
    assert says in _usage_error(hashes.main, [*argv, "--json", str(out)], capsys)
    assert not out.exists()


def test_image_hashes_reads_against_before_rendering(hashes, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = ["--json", str(tmp_path / "after.json"), "--only", "spheres"]
    # A missing baseline was noticed after every render.
    missing = tmp_path / "missing.json"
    assert "missing.json" in _usage_error(hashes.main, [*out, "--against", str(missing)], capsys)
    # A baseline of another size reported every render as differing.
    other = _baseline(tmp_path / "big.json", [192, 108], hashes.render_keys(["spheres"]))
    assert "192x108" in _usage_error(hashes.main, [*out, "--against", str(other)], capsys)
    # A baseline with no render of this run's: nothing would be compared, yet it passed.
    unrelated = _baseline(tmp_path / "glass.json", [96, 54], hashes.render_keys(["glass"]))
    assert "nothing would be compared" in _usage_error(
        hashes.main, [*out, "--against", str(unrelated)], capsys)


def test_image_hashes_counts_in_the_readme() -> None:
    """Every DOUBLE name is a scene or a hard case (a stale name renders nothing in double), and
    benchmarks/README.md gives the number of renders and of scenes in double that the script
    makes."""
    names = image_hashes.scene_runs()
    assert image_hashes.DOUBLE <= set(names), image_hashes.DOUBLE - set(names)
    text = (ROOT / "benchmarks" / "README.md").read_text(encoding="utf-8")
    section = text.split("## `image_hashes.py`")[1].split("\n## ")[0]
    words = {"six": 6, "seven": 7, "eight": 8, "nine": 9, "ten": 10}
    doubles = re.search(r"for (\w+)\s+scenes \(`DOUBLE`\)", section)
    assert doubles and words.get(doubles.group(1)) == len(image_hashes.DOUBLE)
    renders = re.search(r"(\d+) renders", section)
    assert renders and int(renders.group(1)) == len(image_hashes.render_keys())
