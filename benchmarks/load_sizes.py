"""Does loading a model take time in proportion to its file? Each format clray reads, at sizes 4x
apart, loaded as `clray render MODEL` loads it.

    python benchmarks/load_sizes.py [--sides 64,128,256,512] [--formats obj,ply_binary,...]
                                    [--repeat 3] [--json benchmarks/results/load_sizes.json]

The model: a side x side grid of vertices, a gentle wave in z, two triangles a cell
(2 (side - 1)^2 triangles), written as
- `obj`: ASCII OBJ, `v` and `f a b c` lines;
- `ply_binary`: binary little-endian PLY, `element face` of uchar-counted int lists;
- `ply_mixed`: the same with triangles and quads alternating (each quad is two of the cells'
  triangles), whose list lengths change from record to record;
- `ply_ascii`: ASCII PLY;
- `ply_tristrips`: binary PLY, `element tristrips`, one strip a row of cells, -1 between them;
- `glb`: binary glTF, positions and uint32 indices in the one binary chunk;
- `gltf`: JSON glTF with its buffer as a base64 `data:` URI.
Each load runs in a fresh process (`clray.model_scene.load_model_scene`, the reader, the mesh
checks and the scene around it; Python's and clray's imports are not timed), in turns over the
sizes and formats, `--repeat` rounds; the median of each is reported in seconds of wall time and
of the process's CPU time (which holds better while other work shares the cores), with
microseconds a triangle and the ratio of the largest size's CPU time a triangle to the smallest's
(the sizes sorted, whatever the order of --sides)
(1 when the load is linear in the file; the smallest carries the fixed costs of a scene, so
the ratio of a linear loader is below 1).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from benchmarks.common import (  # noqa: E402
    RESULTS,
    check_outputs,
    names_of,
    positive_int,
    positive_ints,
)
from tests.gltf_files import Builder  # noqa: E402

FORMATS = ("obj", "ply_binary", "ply_mixed", "ply_ascii", "ply_tristrips", "glb", "gltf")

_LOAD = """
import json, sys, time
from pathlib import Path
from clray.model_scene import _meshes, load_model_scene
wall, cpu = time.perf_counter(), time.process_time()
scene = load_model_scene(Path(sys.argv[1]))
out = {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu}
out["triangles"] = sum(len(mesh.faces) for mesh in _meshes(scene))
print(json.dumps(out))
"""


def grid(side: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (side^2, 3), faces int64 (2 (side - 1)^2, 3)), cell by cell, the
    two triangles of a cell next to each other."""
    y, x = np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side), indexing="ij")
    vertices = np.stack([x, y, np.sin(6 * x) * 0.1], -1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(side - 1), np.arange(side - 1), indexing="ij")
    a = (i * side + j).reshape(-1)
    faces = np.stack([np.stack([a, a + 1, a + side], -1),
                      np.stack([a + 1, a + side + 1, a + side], -1)], 1).reshape(-1, 3)
    return vertices, faces


def _ply_header(fmt: str, n_vertices: int, faces: str) -> bytes:
    return (f"ply\nformat {fmt} 1.0\nelement vertex {n_vertices}\nproperty float x\n"
            f"property float y\nproperty float z\n{faces}end_header\n").encode()


def _binary_lists(lists: list[np.ndarray]) -> bytes:
    """Records of a uchar count and int32 indices, lists of any lengths."""
    out = bytearray()
    for indices in lists:
        out += np.uint8(len(indices)).tobytes() + indices.astype("<i4").tobytes()
    return bytes(out)


def write(fmt: str, path: Path, side: int) -> int:
    """The grid as `fmt` at `path`; the triangles it holds."""
    vertices, faces = grid(side)
    n = len(vertices)
    if fmt == "obj":
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
        lines += [f"f {a} {b} {c}" for a, b, c in faces + 1]
        path.write_text("\n".join(lines) + "\n")
    elif fmt == "ply_ascii":
        head = _ply_header("ascii", n, f"element face {len(faces)}\n"
                           "property list uchar int vertex_indices\n")
        body = [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
        body += [f"3 {a} {b} {c}" for a, b, c in faces]
        path.write_bytes(head + ("\n".join(body) + "\n").encode())
    elif fmt == "ply_binary":
        counted = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
        counted["n"], counted["i"] = 3, faces
        head = _ply_header("binary_little_endian", n, f"element face {len(faces)}\n"
                           "property list uchar int vertex_indices\n")
        path.write_bytes(head + vertices.astype("<f4").tobytes() + counted.tobytes())
    elif fmt == "ply_mixed":  # even cells as their two triangles, odd ones as one quad
        lists: list[np.ndarray] = []
        for k, (first, second) in enumerate(faces.reshape(-1, 2, 3)):
            lists += [first, second] if k % 2 == 0 else [np.append(first, second[1])]
        head = _ply_header("binary_little_endian", n, f"element face {len(lists)}\n"
                           "property list uchar int vertex_indices\n")
        path.write_bytes(head + vertices.astype("<f4").tobytes() + _binary_lists(lists))
    elif fmt == "ply_tristrips":
        rows = [np.stack([r * side + np.arange(side), (r + 1) * side + np.arange(side)],
                         -1).reshape(-1) for r in range(side - 1)]
        strip = np.concatenate([np.append(row, -1) for row in rows])[:-1]
        head = _ply_header("binary_little_endian", n, "element tristrips 1\n"
                           "property list int int vertex_indices\n")
        path.write_bytes(head + vertices.astype("<f4").tobytes()
                         + np.int32(len(strip)).tobytes() + strip.astype("<i4").tobytes())
    else:
        b = Builder()
        mesh = {"POSITION": b.accessor(vertices, "VEC3")}
        b.doc["meshes"].append({"primitives": [{"attributes": mesh, "indices": b.accessor(
            faces.reshape(-1).astype(np.uint32), "SCALAR")}]})
        b.node(mesh=0)
        if fmt == "glb":
            path.write_bytes(b.glb())
        else:
            path.write_bytes(b.gltf())
    return len(faces)


def load(path: Path, triangles: int) -> dict:
    done = subprocess.run([sys.executable, "-c", _LOAD, str(path)], capture_output=True,
                          text=True, cwd=ROOT)
    if done.returncode != 0:
        raise RuntimeError(f"{path.name}: {done.stderr.strip().splitlines()[-1:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if result["triangles"] != triangles:
        raise RuntimeError(f"{path.name}: {result['triangles']} triangles loaded, "
                           f"{triangles} written")
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sides", type=positive_ints, default=[64, 128, 256, 512],
                        help="grid sides, comma-separated (512: 522,242 triangles)")
    parser.add_argument("--formats", type=names_of(FORMATS), default=list(FORMATS),
                        help=f"comma-separated, of {','.join(FORMATS)} (default: all)")
    parser.add_argument("--repeat", type=positive_int, default=3)
    parser.add_argument("--json", type=Path, default=RESULTS / "load_sizes.json")
    args = parser.parse_args(argv)
    # Sorted and once each: largest_over_smallest_a_triangle compares the last size with the
    # first, which followed the order given.
    sides = sorted(set(args.sides))
    if sides[0] < 2:
        parser.error("--sides: a grid of side 1 has no triangle")
    formats = list(dict.fromkeys(args.formats))
    check_outputs(parser, json=args.json)
    with tempfile.TemporaryDirectory() as tmp:
        files = {}
        for fmt in formats:
            for side in sides:
                suffix = {"obj": ".obj", "glb": ".glb", "gltf": ".gltf"}.get(fmt, ".ply")
                path = Path(tmp) / f"{fmt}_{side}{suffix}"
                files[fmt, side] = (path, write(fmt, path, side))
        runs: dict[tuple[str, int], list[dict]] = {key: [] for key in files}
        for _ in range(args.repeat):
            for key in files:  # in turns, so drifting load falls on every size alike
                runs[key].append(load(*files[key]))
        rows: dict[str, list[dict]] = {}
        for (fmt, side), results in runs.items():
            path, triangles = files[fmt, side]
            cpu = median(r["cpu_s"] for r in results)
            rows.setdefault(fmt, []).append({
                "side": side, "triangles": triangles, "bytes": path.stat().st_size,
                "wall_s": median(r["wall_s"] for r in results), "cpu_s": cpu,
                "cpu_us_a_triangle": cpu / triangles * 1e6})
    result = {
        "machine": {"cpu": platform.processor() or platform.machine(),
                    "python": platform.python_version()},
        "repeat": args.repeat,
        "formats": {fmt: {"sizes": sizes, "largest_over_smallest_a_triangle":
                          sizes[-1]["cpu_us_a_triangle"] / sizes[0]["cpu_us_a_triangle"]}
                    for fmt, sizes in rows.items()},
    }
    for fmt, entry in result["formats"].items():
        per = ", ".join(f"{s['triangles']:,} {s['cpu_s']:.3f} s" for s in entry["sizes"])
        print(f"{fmt:14s} {per}; largest/smallest a triangle "
              f"{entry['largest_over_smallest_a_triangle']:.2f}")
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
