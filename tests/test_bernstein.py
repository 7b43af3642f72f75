"""Bernstein basis: partition of unity, degree elevation, exact derivatives, C0 pieces."""
import numpy as np
import pytest
from math import comb

from vfcli.model.loads.bernstein import (bernstein, bernstein_derivative, degree_elevation_matrix, evaluate_tensor,
                             piecewise_bernstein, tensor_basis)

T = np.linspace(-0.2, 1.2, 57)


@pytest.mark.parametrize("n", range(0, 9))
def test_partition_of_unity_and_end_interpolation(n):
    b = bernstein(n, T)
    assert b.shape == (T.size, n + 1)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    ends = bernstein(n, [0.0, 1.0])
    np.testing.assert_array_equal(ends[0], np.eye(n + 1)[0])
    np.testing.assert_array_equal(ends[1], np.eye(n + 1)[n])


def test_matches_binomial_formula():
    t = 0.3
    n = 5
    expected = [comb(n, i) * t ** i * (1 - t) ** (n - i) for i in range(n + 1)]
    np.testing.assert_allclose(bernstein(n, [t])[0], expected, rtol=1e-14)


@pytest.mark.parametrize("n", range(0, 8))
def test_degree_elevation_identity(n):
    e = degree_elevation_matrix(n)
    np.testing.assert_allclose(bernstein(n + 1, T) @ e.T, bernstein(n, T), atol=1e-13)
    # control values of the elevated curve reproduce the same curve
    c = np.random.default_rng(n).normal(size=n + 1)
    np.testing.assert_allclose(bernstein(n + 1, T) @ (e.T @ c), bernstein(n, T) @ c, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 4, 7])
@pytest.mark.parametrize("order", [1, 2])
def test_derivative_matches_central_differences(n, order):
    h = 1e-4
    t = np.linspace(0.05, 0.95, 19)
    if order == 1:
        fd = (bernstein(n, t + h) - bernstein(n, t - h)) / (2 * h)
    else:
        fd = (bernstein(n, t + h) - 2 * bernstein(n, t) + bernstein(n, t - h)) / h ** 2
    exact = bernstein_derivative(n, t, order)
    np.testing.assert_allclose(exact, fd, atol=1e-6 * max(1.0, np.abs(exact).max()) * (1e3 if order == 2 else 1))


def test_derivative_beyond_degree_is_zero():
    assert not np.any(bernstein_derivative(2, T, 3))


def test_piecewise_is_continuous_with_a_kink_at_the_split():
    n = 3
    c = np.random.default_rng(1).normal(size=2 * n + 1)
    eps = 1e-9
    left, right = piecewise_bernstein(n, [0.5 - eps, 0.5 + eps]) @ c
    assert abs(left - right) < 1e-7
    np.testing.assert_allclose(piecewise_bernstein(n, T).sum(axis=1), 1.0, atol=1e-12)
    dl, dr = piecewise_bernstein(n, [0.5 - eps, 0.5 + eps], order=1) @ c
    assert abs(dl - dr) > 1e-3  # generic control values: derivative jumps
    # each half is a Bernstein patch in its local parameter
    t = np.array([0.1, 0.3, 0.5])
    np.testing.assert_allclose(piecewise_bernstein(n, t)[:, : n + 1], bernstein(n, 2 * t), atol=1e-14)
    t = np.array([0.6, 0.9, 1.0])
    np.testing.assert_allclose(piecewise_bernstein(n, t)[:, n:], bernstein(n, 2 * t - 1), atol=1e-14)


def test_piecewise_derivative_matches_central_differences():
    n, h = 2, 1e-5
    t = np.array([0.1, 0.3, 0.45, 0.55, 0.8])
    fd = (piecewise_bernstein(n, t + h) - piecewise_bernstein(n, t - h)) / (2 * h)
    np.testing.assert_allclose(piecewise_bernstein(n, t, order=1), fd, atol=1e-6)


def test_tensor_product_is_the_product_of_1d_bases():
    rng = np.random.default_rng(2)
    u, v, t = rng.uniform(size=(3, 11))
    ctrl = rng.normal(size=(3, 4, 5))
    direct = np.zeros(11)
    for i in range(3):
        for j in range(4):
            for k in range(5):
                direct += ctrl[i, j, k] * bernstein(2, u)[:, i] * bernstein(3, v)[:, j] * bernstein(4, t)[:, k]
    np.testing.assert_allclose(evaluate_tensor(ctrl, (2, 3, 4), [u, v, t]), direct, rtol=1e-12)
    np.testing.assert_allclose(tensor_basis([bernstein(2, u), bernstein(3, v)]).sum(axis=1), 1.0, atol=1e-12)


def test_bad_degree_is_a_value_error():
    with pytest.raises(ValueError):
        bernstein(-1, T)
    with pytest.raises(ValueError):
        piecewise_bernstein(2, T, split=1.0)
