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


@pytest.mark.parametrize("t", [0.0, 0.3, 1.0, 3.0, 12.0, 250.0, 1e4])
def test_t_tail_is_the_closed_form_at_one_and_two_degrees_of_freedom(t):
    """Cauchy (1 degree): 1/2 - atan(t)/pi; 2 degrees: (1 - t/sqrt(2 + t^2))/2, written
    here in the tail's own form so that it keeps its digits far out."""
    import math

    from bladesonar.dsp.stats import t_tail
    cauchy = math.atan2(1.0, t) / math.pi
    two = 1.0 / (math.sqrt(2.0 + t * t) * (math.sqrt(2.0 + t * t) + t))
    assert t_tail(t, 1) == pytest.approx(cauchy, rel=1e-12)
    assert t_tail(t, 2) == pytest.approx(two, rel=1e-12)
    assert t_tail(-t, 1) == pytest.approx(1.0 - cauchy, rel=1e-12)


@pytest.mark.parametrize("z", [0.0, 0.5, 2.0, 3.0, 6.0, 20.0, 37.0])
def test_the_normal_tail_inverse_undoes_erfc(z):
    import math

    from bladesonar.dsp.stats import normal_tail_inverse
    assert normal_tail_inverse(0.5 * math.erfc(z / math.sqrt(2.0))) == pytest.approx(
        z, abs=1e-9, rel=1e-10)
    if z <= 6.0:                # (further out 1 - p rounds to 1)
        assert normal_tail_inverse(1.0 - 0.5 * math.erfc(z / math.sqrt(2.0))) == \
            pytest.approx(-z, abs=1e-6)


def test_a_t_reads_as_the_z_of_its_tail():
    """Student's t with many degrees of freedom is a normal z; with five it is heavy-tailed:
    t 3 has the tail of z 2.17 (P 0.015; tables: t(5) 0.975 quantile 2.571 is z 1.960)."""
    from bladesonar.dsp.stats import t_as_z
    assert t_as_z(3.0, 10 ** 7) == pytest.approx(3.0, abs=1e-4)
    assert t_as_z(2.570582, 5) == pytest.approx(1.959964, abs=1e-5)
    assert t_as_z(-2.570582, 5) == pytest.approx(-1.959964, abs=1e-5)
    assert t_as_z(4.032143, 5) == pytest.approx(2.575829, abs=1e-5)   # the 0.995 quantile
    assert t_as_z(float("inf"), 5) == float("inf") and t_as_z(0.0, 5) == 0.0
