"""params.npz's values are checked finite in one pass when they are (a finite sum proves it), and
counted exactly when they are not, or when the sum overflows."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.pstudio.reader import non_finite_count


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_non_finite_values_are_counted_exactly(dtype):
    values = np.random.default_rng(0).normal(size=(6, 500, 3)).astype(dtype)
    assert non_finite_count(values) == 0
    values[1, 7, 0], values[4, 99, 2], values[5, 0, 1] = np.nan, np.inf, -np.inf
    assert non_finite_count(values) == 3
    values[1, 7, 0] = 0.0
    values[2, 3, 1] = np.inf  # +inf and -inf: a NaN sum
    assert non_finite_count(values) == 3


def test_a_sum_that_overflows_is_not_a_non_finite_value():
    """Finite values whose float sum overflows: none is counted (the sum alone would say inf)."""
    values = np.full((4, 3), np.finfo(np.float32).max, np.float32)
    with np.errstate(over="ignore"):
        assert not np.isfinite(np.add.reduce(values, axis=None))
    assert non_finite_count(values) == 0
    assert non_finite_count(np.zeros((0, 3), np.float32)) == 0
