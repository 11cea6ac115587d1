"""A bounded run of the fuzzing harness (tests/fuzz.py) in the normal suite.

Hypothesis draws the random choices of each strategy (so a failure shrinks to a small case);
every case must load or fail cleanly. A few cases of each are rendered on an 8x6 image, which
needs a device. The long run is `python -m tests.fuzz --cases N --seed S`.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests import fuzz

FAST = settings(max_examples=30, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz")
    fuzz.make_workdir(folder)
    return folder


def check(case: fuzz.Case, work: Path, render: bool = False) -> fuzz.Outcome:
    outcome = fuzz.run_case(case, work, render)
    assert outcome.kind != "bug", f"{case.strategy}: {outcome.detail}\nfiles: {case.files}"
    return outcome


@pytest.mark.parametrize("strategy", ["scene", "bytes", "obj", "mtl", "ply", "texture"])
@FAST
@given(rng=st.randoms(use_true_random=False))
def test_loading_never_crashes(work, strategy, rng):
    check(fuzz.generate(strategy, rng), work)


@settings(max_examples=8, deadline=None, derandomize=True)
@given(rng=st.randoms(use_true_random=False), strategy=st.sampled_from(fuzz.STRATEGIES))
def test_the_command_never_crashes(cl_device, work, rng, strategy):
    check(fuzz.generate(strategy, rng), work, render=True)


def test_the_base_scene_renders(cl_device, work):
    data = fuzz.base_scene(random.Random(1))
    outcome = check(fuzz._with_data(fuzz.Case("scene", {}), data), work, render=True)
    assert outcome.rendered


@pytest.mark.parametrize(("message", "why"), [
    ("s.toml: objects[0].radius: must be > 0, got 0", None),
    ('s.toml: materials."a\\nb".x: unknown key', None),
    ("m.obj: line 3: f: bad vertex reference '1/'", None),
    ("s.toml: invalid TOML: Expected '=' (at line 2, column 3)", None),
    ("s.toml: cannot read scene file: not a regular file", None),
    # A PLY element's name is a word of any characters (the fuzzer's "verte,x").
    ("c.ply: element verte,x: 99 records cannot fit in a file of 470 bytes", None),
    ("c.ply: element vertex, line 12: x must be a number", None),
    ("c.ply: element vertex bad", "message names neither a key nor a line"),
    ("s.toml: something went wrong", "message names neither a key nor a line"),
    ("s.toml: objects[0]: two\nlines", "message spans lines"),
])
def test_scene_error_messages_are_checked(message, why):
    assert fuzz._check_scene_error(message) == why


def test_a_traceback_is_a_bug_and_is_saved(work, tmp_path, monkeypatch):
    def broken(_path):
        raise OverflowError("int too large to convert to float")

    monkeypatch.setattr(fuzz, "load_scene", broken)
    data = fuzz.base_scene(random.Random(2))
    case = fuzz._with_data(fuzz.Case("scene", {}), data)
    outcome = fuzz.run_case(case, work, render=False)
    assert outcome.kind == "bug"
    assert "OverflowError" in outcome.detail
    small = fuzz.shrink(case, work, False, outcome)
    assert small.data == {}  # nothing in the scene is needed for this bug
    saved = fuzz.save_bug(small, outcome, tmp_path, 1, False)
    assert sorted(p.name for p in saved.iterdir()) == ["case.toml", "report.txt"]


def test_cli_outcomes_are_classified(work, monkeypatch):
    def noisy(_argv):
        print("RuntimeWarning: overflow", file=__import__("sys").stderr)
        return 0

    monkeypatch.setattr(fuzz.cli, "main", noisy)
    outcome = fuzz.run_case(fuzz.Case("flags", {}, argv=["render", "scene.toml"]), work, False)
    assert outcome.kind == "bug" and "stray stderr line" in outcome.detail
    monkeypatch.setattr(fuzz.cli, "main", lambda _argv: 1)
    outcome = fuzz.run_case(fuzz.Case("flags", {}, argv=["render", "scene.toml"]), work, False)
    assert outcome.kind == "bug" and outcome.detail.startswith("exit 1")


def test_raw_output_on_file_descriptor_2_is_a_bug(work, monkeypatch, capfd):
    # What libtiff does from inside Pillow: it bypasses sys.stderr.
    def printing(_path):
        os.write(2, b"More samples per pixel than can be decoded: 224\n")

    monkeypatch.setattr(fuzz, "load_scene", printing)
    case = fuzz._with_data(fuzz.Case("scene", {}), fuzz.base_scene(random.Random(3)))
    outcome = fuzz.run_case(case, work, render=False)
    assert outcome.kind == "bug" and outcome.detail.startswith("raw output on stderr: b'More")
