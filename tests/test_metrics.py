import math

import numpy as np
import pytest

from clray.metrics import count_over, max_abs, nonfinite_count, psnr, rmse


def test_rmse_and_psnr_against_hand_computed_values() -> None:
    a = np.zeros((1, 2, 3))
    b = np.zeros((1, 2, 3))
    b[0, 0, 0] = 0.6  # one channel of six off by 0.6: mse = 0.36 / 6 = 0.06
    assert rmse(a, b) == pytest.approx(math.sqrt(0.06))
    assert psnr(a, b) == pytest.approx(20 * math.log10(1 / math.sqrt(0.06)))
    assert psnr(a, b, max_value=255.0) == pytest.approx(20 * math.log10(255 / math.sqrt(0.06)))


def test_identical_images() -> None:
    a = np.full((3, 4, 3), 0.25, dtype=np.float32)
    assert rmse(a, a) == 0.0
    assert psnr(a, a) == math.inf
    assert max_abs(a, a) == 0.0
    assert count_over(a, a, 0.0) == 0


def test_computed_in_float64() -> None:
    a = np.zeros((2, 2, 3), dtype=np.float32)
    b = np.full((2, 2, 3), 1e20, dtype=np.float32)  # (1e20)**2 overflows float32
    assert rmse(a, b) == pytest.approx(float(np.float32(1e20)), rel=1e-12)
    assert count_over(a, b, 1e19) == 4


def test_max_abs_and_count_over_per_pixel() -> None:
    a = np.zeros((2, 2, 3))
    b = a.copy()
    b[0, 0] = [0.1, 0.0, 0.0]
    b[0, 1] = [0.0, -0.3, 0.2]  # two channels over in one pixel count once
    b[1, 1, 2] = 0.05
    assert max_abs(a, b) == pytest.approx(0.3)
    assert count_over(a, b, 0.08) == 2
    assert count_over(a, b, 0.04) == 3
    assert count_over(a, b, 0.3) == 0  # "more than" the threshold


def test_nonfinite_values() -> None:
    a = np.zeros((2, 2, 3))
    b = a.copy()
    b[0, 0, 1] = np.nan
    b[1, 0] = [np.inf, -np.inf, np.nan]
    assert nonfinite_count(b) == 2
    assert nonfinite_count(a) == 0
    assert math.isnan(rmse(a, b))
    assert count_over(a, b, 1e9) == 2
    assert count_over(b, b, 0.0) == 2  # NaN never matches; the equal infinities alone would


def test_two_dimensional_images_count_elements() -> None:
    a = np.zeros((2, 3))
    b = np.array([[0.0, 0.5, np.nan], [0.0, 0.0, 0.0]])
    assert count_over(a, b, 0.1) == 2
    assert nonfinite_count(b) == 1


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="shape"):
        rmse(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))


@pytest.mark.parametrize("shape", [(0, 4, 3), (4, 0), (2, 2, 0)])
@pytest.mark.parametrize(
    "compare",
    [rmse, psnr, max_abs, lambda a, b: count_over(a, b, 0.0)],
    ids=["rmse", "psnr", "max_abs", "count_over"],
)
def test_empty_images_are_an_error_in_every_comparison(shape, compare) -> None:
    # Before: rmse NaN with RuntimeWarnings, max_abs numpy's own ValueError, count_over 0 (a
    # match, to a caller that counts the pixels off).
    empty = np.zeros(shape)
    with pytest.raises(ValueError, match=rf"^images are empty: shape \({shape[0]}, "):
        compare(empty, empty)
