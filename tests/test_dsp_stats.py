"""dsp.stats.median against numpy's own median, the counterpart it stands in for."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar.dsp.stats import median


@pytest.mark.parametrize("shape, axis", [((1,), None), ((2,), None), ((7,), None),
                                         ((8,), 0), ((5, 6), 0), ((5, 6), 1),
                                         ((6, 5), 1), ((4, 3), None)])
def test_median_is_numpys_bit_for_bit(shape, axis):
    rng = np.random.default_rng(sum(shape))
    a = rng.standard_normal(shape) * 10.0 ** rng.integers(-5, 5, shape)
    assert np.array_equal(np.asarray(median(a, axis=axis)), np.asarray(np.median(a, axis=axis)))


def test_median_is_nan_where_numpys_is():
    a = np.arange(12.0).reshape(3, 4)
    a[1, 2] = np.nan
    assert np.array_equal(median(a, axis=1), np.median(a, axis=1), equal_nan=True)
    assert np.isnan(median(a)) and np.isnan(np.median(a))
    assert median(np.array([3, 1, 2])) == 2 and median(np.array([4, 1, 2, 3])) == 2.5
