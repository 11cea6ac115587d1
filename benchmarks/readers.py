"""What benchmarks/ply_readers.py and benchmarks/gltf_readers.py share: each reader in its own
process (its peak resident memory, VmHWM, is its own), interleaved over --repeat rounds,
medians, each reader's message for the file cut to three quarters, and the JSON they write
(--out, by default under benchmarks/results/). A reader whose package is not installed is
recorded as "not installed" and the others go on. Each script brings its readers and the
generator of its file; the result's keys are the same for both but "file", which names what the
generator counted.
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

from benchmarks.common import PEAK_SOURCE, RESULTS, check_outputs, positive_int

# A reader: (import, read). The import is timed apart, as clray's own import is outside the
# reader; the read sets n to the number of faces it read.
Readers = Mapping[str, tuple[str, str]]

# The peak is VmHWM (PEAK_SOURCE): ru_maxrss survives fork and exec, so a reader that stays
# below the benchmark's own peak (the generated file's arrays) reported the parent's.
_RUN = PEAK_SOURCE.replace("{", "{{").replace("}", "}}") + """
import json, sys, time
from pathlib import Path
P = Path(sys.argv[1])
t = time.perf_counter()
try:
{head}
except ImportError as exc:
    print(json.dumps({{"not_installed": str(exc)}}))
    sys.exit(0)
out = {{"import_s": time.perf_counter() - t}}
t = time.perf_counter()
try:
{body}
    out.update(seconds=time.perf_counter() - t, faces=n)
except Exception as exc:
    out["error"] = (type(exc).__name__ + ": " + str(exc))[:300]
out["peak_rss_mib"] = peak() / 1024 / 1024
print(json.dumps(out))
"""


def run(readers: Readers, reader: str, path: Path) -> dict:
    """One read of path by readers[reader] in a fresh process: its times, faces and peak (VmHWM), or
    its error."""
    head, read = readers[reader]
    indent = "\n".join("    " + line for line in head.splitlines())
    body = "\n".join("    " + line for line in read.splitlines())
    done = subprocess.run([sys.executable, "-c", _RUN.format(head=indent, body=body), str(path)],
                          capture_output=True, text=True)
    if done.returncode != 0:  # the reader's crash is its row, not the end of the benchmark
        last = done.stderr.strip().splitlines()[-1:] or [f"exit status {done.returncode}"]
        return {"error": last[0][:300]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _summary(runs: list[dict], truncated: dict) -> dict | str:
    """A reader's medians over its runs; "not installed" where its import failed."""
    if "not_installed" in runs[0]:
        return "not installed"
    done = [r for r in runs if "seconds" in r]
    if not done:
        return {"error": runs[0].get("error", "no run")}
    return {
        "median_s": median(r["seconds"] for r in done),
        "median_import_s": median(r["import_s"] for r in done),
        "median_peak_rss_mib": median(r["peak_rss_mib"] for r in done),
        "faces": done[0]["faces"],
        "truncated_file": truncated.get("error", "(no error)"),
    }


def compare(doc: str, readers: Readers, file_name: str,
            write_file: Callable[[Path, int], dict[str, int]], result_name: str,
            argv: list[str] | None = None) -> None:
    """Parse the scripts' common arguments (--side, --repeat, --out), write the file with
    write_file(path, side), which gives the counts that head the result's "file", time every
    reader on it and write the result to --out (and print it)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--side", type=positive_int, default=1000,
                        help="vertices per side (V = side^2)")
    parser.add_argument("--repeat", type=positive_int, default=3)
    parser.add_argument("--out", type=Path, default=RESULTS / result_name,
                        help=f"where to write the result (default: benchmarks/results/"
                        f"{result_name})")
    args = parser.parse_args(argv)
    if args.side < 2:
        parser.error("--side: a side of 1 vertex makes no face")
    check_outputs(parser, out=args.out)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / file_name
        counts = write_file(path, args.side)
        truncated = Path(tmp) / ("truncated" + path.suffix)
        truncated.write_bytes(path.read_bytes()[:path.stat().st_size * 3 // 4])
        runs: dict[str, list[dict]] = {name: [] for name in readers}
        for _ in range(args.repeat):
            for name in readers:  # interleaved, so drifting load hits all alike
                if runs[name] and "not_installed" in runs[name][0]:
                    continue
                runs[name].append(run(readers, name, path))
        result = {
            "machine": {"cpu": platform.processor() or platform.machine(),
                        "python": platform.python_version()},
            "file": {**counts, "bytes": path.stat().st_size},
            "readers": {name: _summary(rs, {} if "not_installed" in rs[0]
                                        else run(readers, name, truncated))
                        for name, rs in runs.items()},
        }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print(f"wrote {args.out}")
