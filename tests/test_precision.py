"""Stored precision of /fields/velocity: rounding float32 to fewer mantissa bits, checked against
numpy's own float arithmetic (frexp) and against what gzip gains."""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.store.precision import round_mantissa


@pytest.mark.parametrize("bits", [4, 10, 12, 22])
def test_the_relative_error_is_at_most_half_an_ulp_of_the_kept_bits_and_no_better_rounding_exists(bits):
    rng = np.random.default_rng(bits)
    x = (rng.standard_normal(20000) * 10.0 ** rng.uniform(-6, 6, 20000)).astype(np.float32)
    r = round_mantissa(x, bits)
    rel = np.abs(r.astype(np.float64) - x) / np.abs(x.astype(np.float64))
    assert rel.max() <= 2.0 ** -(bits + 1)
    assert rel.max() > 2.0 ** -(bits + 1) * 0.9  # the bound is reached, not a looser rounding
    # r has at most `bits` stored mantissa bits: scaled to [0.5, 1) by frexp, times 2**(bits + 1), an integer
    m, _ = np.frexp(r.astype(np.float64))
    scaled = m * 2.0 ** (bits + 1)
    np.testing.assert_array_equal(scaled, np.round(scaled))
    # and it is the nearest such value (the neighbours one kept-bit step away are not closer)
    step = np.ldexp(1.0, np.frexp(r.astype(np.float64))[1] - (bits + 1))
    for other in (r + step, r - step):
        assert np.all(np.abs(r.astype(np.float64) - x) <= np.abs(other - x.astype(np.float64)) + 1e-300)


def test_values_with_few_bits_nan_and_infinity_are_kept_exactly():
    x = np.array([0.0, -0.0, 1.5, -0.75, 1024.0, np.nan, np.inf, -np.inf, np.finfo(np.float32).max], np.float32)
    r = round_mantissa(x, 3)
    np.testing.assert_array_equal(r[:5], x[:5])
    assert np.signbit(r[1]) and np.isnan(r[5]) and r[6] == np.inf and r[7] == -np.inf
    assert r[8] == x[8]  # would round past the largest float32: kept
    assert r.dtype == np.float32


def test_twenty_three_bits_is_the_identity_and_bad_arguments_are_refused():
    x = np.random.default_rng(0).random(100).astype(np.float32)
    np.testing.assert_array_equal(round_mantissa(x, 23), x)
    with pytest.raises(ValueError, match="float32"):
        round_mantissa(x.astype(np.float64), 12)
    with pytest.raises(ValueError, match="bits"):
        round_mantissa(x, 0)
