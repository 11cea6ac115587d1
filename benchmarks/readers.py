"""What benchmarks/ply_readers.py and benchmarks/gltf_readers.py share: each reader in its own
process (peak RSS is per process), interleaved over --repeat rounds, medians, each reader's
message for the file cut to three quarters, and the JSON they write. Each script brings its
readers and the generator of its file; the result's keys are the same for both but "file",
which names what the generator counted.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from statistics import median

# A reader: (import, read). The import is timed apart, as clray's own import is outside the
# reader; the read sets n to the number of faces it read.
Readers = Mapping[str, tuple[str, str]]

_RUN = """
import json, resource, sys, time
from pathlib import Path
P = Path(sys.argv[1])
t = time.perf_counter()
{head}
out = {{"import_s": time.perf_counter() - t}}
t = time.perf_counter()
try:
{body}
    out.update(seconds=time.perf_counter() - t, faces=n)
except Exception as exc:
    out["error"] = (type(exc).__name__ + ": " + str(exc))[:300]
out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def run(readers: Readers, reader: str, path: Path) -> dict:
    """One read of path by readers[reader] in a fresh process: its times, faces and peak RSS, or
    its error."""
    head, read = readers[reader]
    body = "\n".join("    " + line for line in read.splitlines())
    done = subprocess.run([sys.executable, "-c", _RUN.format(head=head, body=body), str(path)],
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(doc: str, readers: Readers, file_name: str,
            write_file: Callable[[Path, int], dict[str, int]]) -> None:
    """Parse the scripts' common arguments (--side, --repeat, --out), write the file with
    write_file(path, side), which gives the counts that head the result's "file", time every
    reader on it and write the result to --out (and print it)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--side", type=int, default=1000, help="vertices per side (V = side^2)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / file_name
        counts = write_file(path, args.side)
        truncated = Path(tmp) / ("truncated" + path.suffix)
        truncated.write_bytes(path.read_bytes()[:path.stat().st_size * 3 // 4])
        runs: dict[str, list[dict]] = {name: [] for name in readers}
        for _ in range(args.repeat):
            for name in readers:  # interleaved, so drifting load hits all alike
                runs[name].append(run(readers, name, path))
        result = {
            "machine": {"cpu": platform.processor() or platform.machine(),
                        "python": platform.python_version()},
            "file": {**counts, "bytes": path.stat().st_size},
            "readers": {name: {
                "median_s": median(r["seconds"] for r in rs),
                "median_import_s": median(r["import_s"] for r in rs),
                "median_peak_rss_mib": median(r["peak_rss_mib"] for r in rs),
                "faces": rs[0]["faces"],
                "truncated_file": run(readers, name, truncated).get("error", "(no error)"),
            } for name, rs in runs.items()},
        }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
