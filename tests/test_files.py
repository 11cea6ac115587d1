"""Reading the files a scene names (clray.scene.files): a small file costs its own size in
memory, not its kind's limit, and a file over the limit is still refused."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from clray.model_scene import model_scene_data
from clray.scene import files
from clray.scene.files import UnreadableFile, open_regular, read_at_most, read_regular
from tests.gltf_files import CUBE_FACES, CUBE_VERTICES, Builder

# Far below the limits (256 MiB for an OBJ file, 1 GiB for the others), far above what a
# cube's scene takes.
SMALL_PEAK = 16 << 20


def cube_file(path: Path) -> Path:
    """A unit cube (12 triangles) in the file `path`, of the kind its suffix names."""
    vertices, faces = np.asarray(CUBE_VERTICES, np.float32), np.asarray(CUBE_FACES, np.int32)
    if path.suffix == ".obj":
        path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
                        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    elif path.suffix == ".ply":
        path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\n"
                        "property float x\nproperty float y\nproperty float z\n"
                        f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
                        "end_header\n" + "".join(f"{x} {y} {z}\n" for x, y, z in vertices)
                        + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces))
    elif path.suffix == ".npz":
        np.savez(path, vertices=vertices, faces=faces)
    else:
        builder = Builder()
        builder.node(mesh=builder.mesh(vertices, faces))
        builder.save(path)
    return path


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".npz", ".glb"])
def test_a_small_mesh_file_takes_little_memory_to_load(tmp_path: Path, suffix: str) -> None:
    path = cube_file(tmp_path / f"cube{suffix}")
    model_scene_data(path)  # modules imported and caches filled before the count
    tracemalloc.start()
    try:
        model_scene_data(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < SMALL_PEAK


def test_a_file_over_the_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "big.bin"
    path.write_bytes(b"x" * 101)
    with pytest.raises(UnreadableFile, match="101 bytes is over the limit of 100 bytes"):
        read_regular(path, 100)
    assert read_regular(path, 101) == b"x" * 101


@pytest.mark.parametrize("grown", [1, 3 * 7 + 1])
def test_a_file_that_grew_past_the_limit_after_it_was_opened_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, grown: int) -> None:
    monkeypatch.setattr(files, "_GROWN_READ", 7)  # the growth read in several parts
    path = tmp_path / "growing.bin"
    path.write_bytes(b"x" * 50)
    stream, _ = open_regular(path, 50 + grown - 1)
    with stream:
        with path.open("ab") as more:
            more.write(b"y" * grown)
        with pytest.raises(UnreadableFile, match=f"over the limit of {50 + grown - 1} bytes"):
            read_at_most(stream, 50 + grown - 1)


def test_a_file_that_grew_within_the_limit_is_read_whole(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(files, "_GROWN_READ", 7)
    path = tmp_path / "growing.bin"
    path.write_bytes(b"x" * 50)
    stream, _ = open_regular(path, 100)
    with stream:
        with path.open("ab") as more:
            more.write(b"y" * 30)
        assert read_at_most(stream, 100) == b"x" * 50 + b"y" * 30
