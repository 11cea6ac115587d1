"""benchmarks/povray.py without POV-Ray: the sampling options it passes and what it reads back
from POV-Ray's statistics (the logs below are excerpts of POV-Ray 3.7.0.10's own output)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import module_from_file

ROOT = Path(__file__).resolve().parent.parent
povray = module_from_file(ROOT / "benchmarks" / "povray.py", "povray")

# A 32x18 render of spheres.pov with +AM1 +A0.0 +R4 (the figures as POV-Ray printed them).
LOG_16 = """\
Persistence of Vision(tm) Ray Tracer Version 3.7.0.10.unofficial (g++ @
Parser Time
  Parse Time:       0 hours  0 minutes  0 seconds (0.001 seconds)
              using 1 thread(s) with 0.001 CPU-seconds total
  Bounding Time:    0 hours  0 minutes  0 seconds (0.000 seconds)
              using 1 thread(s) with 0.000 CPU-seconds total
Render Statistics
Image Resolution 32 x 18
Pixels:              626   Samples:            9216   Smpls/Pxl: 14.72
Rays:              23690   Saved:                 0   Max Level: 5/5
Shadow Ray Tests:             24032   Succeeded:                  3068
Shadow Cache Hits:             2055
Reflected Rays:               13848
Render Time:
  Photon Time:      No photons
  Radiosity Time:   No radiosity
  Trace Time:       0 hours  0 minutes  0 seconds (0.038 seconds)
              using 1 thread(s) with 0.025 CPU-seconds total
"""


@pytest.mark.parametrize(("samples", "options"), [
    (1, ["-A"]),
    (4, ["+AM1", "+A0.0", "+R2"]),
    (16, ["+AM1", "+A0.0", "+R4"]),
    (81, ["+AM1", "+A0.0", "+R9"]),
])
def test_antialias_options_sample_a_square_grid(samples: int, options: list[str]) -> None:
    assert povray.antialias_options(samples) == options


@pytest.mark.parametrize("samples", [0, -4, 2, 15, 17, 100])
def test_antialias_options_refuse_counts_povray_cannot_sample(samples: int) -> None:
    with pytest.raises(ValueError, match=f"got {samples}"):
        povray.antialias_options(samples)


def test_statistics_count_samples_over_the_images_pixels() -> None:
    # POV-Ray's own Smpls/Pxl (14.72) divides by its 626 pixels, more than the image's 576.
    stats = povray.read_statistics(LOG_16, 32 * 18, "spheres.pov")
    assert stats["samples_per_pixel"] == 9216 / 576 == 16.0
    assert stats["version"] == "3.7.0.10.unofficial"
    assert (stats["parse_s"], stats["parse_cpu_s"]) == (0.001, 0.001)
    assert (stats["trace_s"], stats["trace_cpu_s"]) == (0.038, 0.025)
    assert stats["rays"] == {"traced": 23690, "reflected": 13848, "shadow_tests": 24032}


def test_statistics_without_antialiasing_or_reflection() -> None:
    log = (LOG_16.replace("Samples:            9216", "Samples:               0")
           .replace("Reflected Rays:               13848\n", ""))
    stats = povray.read_statistics(log, 32 * 18, "bumpy.pov")
    assert stats["samples_per_pixel"] == 1.0
    assert stats["rays"]["reflected"] == 0


def test_statistics_without_a_trace_time_name_the_file() -> None:
    log = LOG_16.replace("Trace Time", "Trace Tme")
    with pytest.raises(RuntimeError, match=re.escape("'Trace Time' for bumpy.pov")):
        povray.read_statistics(log, 32 * 18, "bumpy.pov")
