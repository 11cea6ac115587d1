"""The sRGB transfer function against values worked out by hand from IEC 61966-2-1.

Inputs straddle the linear segment's end (0.0031308 in linear light) and lie between it and
0.04045, the *encoded* value at which the decoding direction switches: a threshold mixed up
between the two directions changes every value in that gap.
"""

from __future__ import annotations

import numpy as np
import pytest

from clray.image_io import to_png_samples
from clray.scene.colour import srgb_decode, srgb_encode

# linear -> encoded, by hand: 12.92 x on the linear segment, 1.055 x^(1/2.4) - 0.055 above it.
HAND_VALUES = [
    (0.0, 0.0),
    (0.001, 0.01292),  # 12.92 * 0.001
    (0.003, 0.038760),  # 12.92 * 0.003, just below the linear segment's end
    (0.0031308, 0.0404499),  # the segment's end: both branches meet near 0.04045
    (0.004, 0.0507087),  # 1.055 * 0.004^(1/2.4) - 0.055: above the end
    (0.01, 0.0998528),  # between 0.0031308 and 0.04045: the power branch
    (0.03, 0.1897483),
    (0.5, 0.7353570),
    (1.0, 1.0),
]


def test_srgb_encode_matches_hand_computed_values() -> None:
    linear = np.array([x for x, _ in HAND_VALUES])
    want = np.array([y for _, y in HAND_VALUES])
    np.testing.assert_allclose(srgb_encode(linear), want, rtol=0, atol=5e-7)


def test_png_bytes_in_the_linear_segment() -> None:
    # round(255 * 12.92 x): 0.0005 -> 1.65 -> 2, 0.002 -> 6.59 -> 7, 0.003 -> 9.88 -> 10; and
    # 0.01 on the power branch -> 255 * 0.09985 = 25.46 -> 25.
    image = np.array([[[0.0005, 0.002, 0.003], [0.01, 0.0, 1.0]]])
    assert to_png_samples(image).tolist() == [[[2, 7, 10], [25, 0, 255]]]


def test_srgb_decode_matches_hand_computed_values() -> None:
    encoded = np.array([y for _, y in HAND_VALUES])
    want = np.array([x for x, _ in HAND_VALUES])
    # The decode's threshold is 0.04045 (encoded): 0.0404499 lies just below it, on the linear
    # segment, and the values between 0.0031308 and 0.04045 show a swapped threshold.
    np.testing.assert_allclose(srgb_decode(encoded), want, rtol=0, atol=2e-7)


def test_srgb_decode_of_every_8bit_code_encodes_back_to_it() -> None:
    codes = np.arange(256)
    back = np.rint(srgb_encode(srgb_decode(codes / 255.0)) * 255)
    np.testing.assert_array_equal(back, codes)
    assert srgb_decode(np.array([128 / 255]))[0] == pytest.approx(0.2158605, abs=1e-7)
