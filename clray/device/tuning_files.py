"""Per-device tuning files: where `clray tune` leaves its winner, and where renders pick it up.

One JSON file per device under the user's cache directory ($XDG_CACHE_HOME/clray/tuning, else
~/.cache/clray/tuning), named by the device's platform and name, and holding the driver version,
the clray version and a digest of the kernels and the knob table it was tuned with: a file
written under another driver, clray, kernel source or knob table is stale,
and like a file that does not parse or names an illegal knob it is ignored with a one-line
warning. The knobs change the speed, not the image, so a stale file is never an error.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import warnings
from pathlib import Path

import pyopencl as cl

from clray.device.program import kernel_source, source_digest
from clray.errors import utf8_problem
from clray.knobs import DEFAULT_TUNING, KNOB_TABLE, Tuning, TuningError
from clray.output import write_bytes_atomically
from clray.scene.files import UnreadableFile, read_regular

FORMAT = 1
# What `clray tune` writes is the knobs and a summary of a few kB a scene tuned on (at most
# 2 x MAX_CONFIRM_ROUNDS render times each): 1 MiB holds hundreds of scenes' worth. A larger
# file was not written by it, and reading it whole could take the memory a render needs.
MAX_TUNING_FILE_BYTES = 2**20


def cache_dir() -> Path:
    """clray's folder in the user's cache directory (XDG base directories)."""
    base = os.environ.get("XDG_CACHE_HOME") or ""
    root = Path(base) if os.path.isabs(base) else Path.home() / ".cache"
    return root / "clray"


def _clray_version() -> str:
    # As clray.__version__ reads it (importing clray here would make an import loop).
    try:
        return importlib.metadata.version("clray")
    except importlib.metadata.PackageNotFoundError:
        return "0+unknown"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "-", text.strip()).strip("-")[:80] or "device"


def _kernels_digest() -> str:
    """The kernels' source and the knob table a winner is timed against. The package version
    stays the same across commits, so without this a winner measured with older kernels, or
    with knobs that meant something else, would be applied to new ones."""
    knobs = repr([(k.name, k.acts, k.default, k.legal_text) for k in KNOB_TABLE])
    return source_digest(f"{kernel_source()}\n{knobs}")


def device_key(device: cl.Device) -> dict[str, str]:
    """What a tuning file is valid for: the device, its driver, the clray version, and the
    kernels and knobs (_kernels_digest)."""
    platform, name = _names(device)
    return {"platform": platform, "device": name,
            "driver_version": device.driver_version.strip(), "clray_version": _clray_version(),
            "kernels": _kernels_digest()}


def _names(device: cl.Device) -> tuple[str, str]:
    """The platform's and the device's names, as tuning files and their names give them."""
    return device.platform.name.strip(), device.name.strip()


def tuning_path(device: cl.Device) -> Path:
    # From the names alone: device_key's digest reads and hashes the kernels' source (9 ms),
    # which every render would pay to find that there is no tuning file.
    platform, name = _names(device)
    return cache_dir() / "tuning" / f"{_slug(platform)}--{_slug(name)}.json"


def _problem(record: object, key: dict[str, str]) -> str | None:
    """Why a parsed tuning file does not apply to the device of `key`, or None."""
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        return f"expected a clray tuning file of format {FORMAT}"
    for name in key:
        if record.get(name) != key[name]:
            return (f"stale: tuned for {name} {record.get(name)!r}, this is {key[name]!r}; "
                    "run clray tune again")
    if not isinstance(record.get("tuning"), dict):
        return "expected a 'tuning' table of knob values"
    return None


def load_tuning(device: cl.Device) -> tuple[Tuning, Path] | None:
    """The device's stored tuning and its file, or None where there is none that applies (with
    a warning naming the file where one exists but is invalid or stale)."""
    path = tuning_path(device)
    try:
        os.stat(path)  # through a link, as the read goes
    except FileNotFoundError:
        # Never tuned, or a link whose target no tune has written yet (save_tuning writes
        # through it): the defaults, silently.
        return None
    except OSError:
        pass  # there but not to be looked at: read_regular's reason is the warning
    try:
        # Only a regular file, opened without blocking: a FIFO there would hang every render,
        # and a link to /dev/zero would be read until the memory runs out.
        raw = read_regular(path, MAX_TUNING_FILE_BYTES)
    except UnreadableFile as err:
        warnings.warn(f"ignoring tuning file {path}: {err}", stacklevel=2)
        return None
    try:
        record = json.loads(raw.decode("utf-8"))
        problem = _problem(record, device_key(device))
        if problem is None:
            return Tuning.from_values(record["tuning"]), path
    except UnicodeDecodeError as err:
        problem = utf8_problem(raw, err)
    except json.JSONDecodeError as err:
        problem = f"not JSON ({err})"
    except (TuningError, TypeError) as err:
        problem = str(err)
    except RecursionError:  # json.loads recurses once per nested array or object
        problem = "not JSON (nested too deeply)"
    warnings.warn(f"ignoring tuning file {path}: {problem}", stacklevel=2)
    return None


def chosen_tuning(device: cl.Device, stored: bool = True) -> tuple[Tuning, str]:
    """The knobs a render on `device` uses and where they come from: the device's tuning file
    (when `stored`), else the table's defaults."""
    found = load_tuning(device) if stored else None
    if found is None:
        return DEFAULT_TUNING, "default"
    return found[0], f"tuning file {found[1]}"


def save_tuning(device: cl.Device, tuning: Tuning, summary: dict) -> Path:
    """Store `tuning` as the device's winner (whole or not at all), with `summary` (what was
    tuned, and the times) beside it for people reading the file."""
    path = tuning_path(device)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"format": FORMAT, **device_key(device), "tuning": tuning.values(),
              "summary": summary}
    write_bytes_atomically(path, (json.dumps(record, indent=2) + "\n").encode("utf-8"))
    return path
