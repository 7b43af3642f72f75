"""The L-curve picks a Tikhonov weight that bounds an ill-posed problem without a noise level."""
import numpy as np
import pytest
import scipy.sparse as sp

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.linearization import QuadraticModel
from vfcli.inverse.terms import Terms
from vfcli.inverse.regularization import lcurve


def _ill_posed(seed: int, noise: float):
    """A Gaussian blur operator (severely ill-conditioned) on a smooth signal, with white noise."""
    rng = np.random.default_rng(seed)
    n, m = 60, 200
    s = np.linspace(0, 1, n)
    t = np.linspace(0, 1, m)
    a = np.exp(-((t[:, None] - s[None, :]) / 0.06) ** 2) / n
    x_true = np.sin(2 * np.pi * s) + 0.5 * np.cos(5 * np.pi * s)
    y = a @ x_true
    y = y + noise * np.abs(y).max() * rng.normal(size=m)
    # E_data(x) = |A x - y|^2: at x0 = 0, value |y|^2, gradient -2 A^T y, Hessian 2 A^T A
    h = BlockMatrix(n, (np.arange(n),), (2 * a.T @ a,))
    model = QuadraticModel(Terms(float(y @ y), float(y @ y), 0.0), -2 * a.T @ y, h, h, m)
    return model, a, y, x_true


@pytest.mark.parametrize("seed,noise", [(0, 0.01), (1, 0.03), (2, 0.003)])
def test_lcurve_corner_recovers_the_signal_where_no_regularisation_fails(seed, noise):
    """The corner lies within a few grid steps of the best weight (the L-curve is known to smooth a
    little less than optimal); its error stays under 10 % of the signal, the unregularised one is huge."""
    model, a, y, x_true = _ill_posed(seed, noise)
    n = len(x_true)
    omega = sp.identity(n)
    curve = lcurve(model, np.zeros(n), omega, n_points=33, decades=(-10, 2))

    def solution(lam):
        return np.linalg.solve(2 * a.T @ a + 2 * lam / n * np.eye(n), 2 * a.T @ y)

    errors = np.array([np.linalg.norm(solution(w) - x_true) for w in curve.weights])
    err_chosen = np.linalg.norm(solution(curve.chosen) - x_true)
    err_none = np.linalg.norm(np.linalg.lstsq(a, y, rcond=None)[0] - x_true)
    assert err_chosen < 0.1 * np.linalg.norm(x_true)
    assert err_chosen < 1e-2 * err_none
    assert abs(np.argmin(errors) - np.argmin(np.abs(curve.weights - curve.chosen))) <= 6   # 6 steps: 2.25 decades
    # the predicted misfit and penalty are those of the exact regularised solutions (where these are
    # well conditioned: from the corner on)
    k = int(np.argmin(np.abs(curve.weights - curve.chosen)))
    assert len(curve.weights[k::3]) >= 3
    for w, rho, eta in zip(curve.weights[k::3], curve.misfit[k::3], curve.penalty[k::3]):
        z = solution(w)
        assert rho == pytest.approx(np.sum((a @ z - y) ** 2), rel=1e-6, abs=1e-10 * float(y @ y))
        assert eta == pytest.approx(z @ z, rel=1e-8)
    assert np.all(np.diff(curve.misfit) >= -1e-12 * curve.misfit.max())   # misfit grows with the weight
    assert np.all(np.diff(curve.penalty) <= 1e-12 * curve.penalty.max())  # and the penalty falls
