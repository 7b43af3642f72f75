"""The L-curve picks a Tikhonov weight that bounds an ill-posed problem without a noise level."""
import numpy as np
import pytest
import scipy.sparse as sp

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.linearization import QuadraticModel
from vfcli.inverse.terms import Terms
from vfcli.inverse.regularization import LCurve, lcurve


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


def _gains_and_correction(seed: int = 0):
    """A pressure-model-like problem: 3 gains that explain the data (penalty weight 1e-6, as
    PressureLoad.penalty_operator gives them) and 60 free correction values the data hardly see
    (column scales 1 .. 1e-4) that can only fit the noise."""
    rng = np.random.default_rng(seed)
    m, ng, nf = 400, 3, 60
    a = np.hstack([10 * rng.normal(size=(m, ng)), rng.normal(size=(m, nf)) @ np.diag(np.logspace(0, -4, nf))])
    g_true = np.array([1.0, -0.5, 0.3])
    y = a[:, :ng] @ g_true + 0.05 * rng.normal(size=m)
    n = ng + nf
    h = BlockMatrix(n, (np.arange(n),), (2 * a.T @ a,))
    model = QuadraticModel(Terms(float(y @ y), float(y @ y), 0.0), -2 * a.T @ y, h, h, m)
    omega = sp.diags(np.r_[np.full(ng, 1e-6), np.ones(nf)])
    return model, a, y, omega, g_true


def test_the_default_scan_reaches_the_corner_where_the_free_correction_gives_way(caplog):
    """The misfit of such a problem rises by about 10 % over the 8 decades of the former scan (-6 .. 2 about
    lam_ref) while the penalty falls: that scan's largest curvature was its last interior weight (its
    "corner" a point of the vertical branch, with a warning now).  The default scan reaches the real
    corner: an interior maximum of the curvature far above the rest, where the correction has shrunk to
    the noise's share and the gains are those of the data."""
    model, a, y, omega, g_true = _gains_and_correction()
    n = a.shape[1]

    def solution(lam):
        return np.linalg.solve(2 * a.T @ a + 2 * lam / n * omega.toarray(), 2 * a.T @ y)

    with caplog.at_level("WARNING", logger="vfcli.inverse.regularization"):
        narrow = lcurve(model, np.zeros(n), omega, n_points=17, decades=(-6.0, 2.0))
    assert narrow.chosen == narrow.weights[-2] and "the corner is at the end of the scanned weights" in caplog.text
    assert np.ptp(np.log(narrow.misfit)) < 0.15                             # measured 0.10
    caplog.clear()
    with caplog.at_level("WARNING", logger="vfcli.inverse.regularization"):
        curve = lcurve(model, np.zeros(n), omega)
    assert not caplog.text
    k = int(np.flatnonzero(curve.weights == curve.chosen)[0])
    assert 2 <= k <= len(curve.weights) - 3
    assert curve.curvature[k] > 100 * np.median(np.abs(curve.curvature))       # measured: 2e4 against 0.01
    free = lambda lam: np.linalg.norm(solution(lam)[3:])                        # noqa: E731
    assert free(curve.chosen) < 1e-3 * free(curve.weights[0])
    np.testing.assert_allclose(solution(curve.chosen)[:3], g_true, atol=2e-3)   # measured 3e-4


def _curve_with_curvature(curvature: np.ndarray, chosen_index: int) -> LCurve:
    """An L-curve of 33 weights two per decade whose curvature is given (misfit and penalty do not enter)."""
    weights = 10.0 ** np.linspace(-6.0, 10.0, 33)
    ones = np.ones_like(weights)
    return LCurve(weights, ones, ones, np.asarray(curvature, float), float(weights[chosen_index]))


def test_the_corner_width_is_where_the_curvature_falls_to_half_its_peak():
    """A corner whose curvature is a Gaussian in log10 weight, narrower on the weaker side (sd 0.4 decade) than on
    the stronger (0.9 decade): the half-maximum lies sqrt(2 ln 2) sd from the peak on each side, read by linear
    interpolation between the scanned weights (two per decade; measured 0.010 and 0.008 decade off). A curvature
    that stays above half its peak to the scan's end gives that end; a corner of no positive curvature, its
    neighbours."""
    weights = 10.0 ** np.linspace(-6.0, 10.0, 33)
    t = np.log10(weights)
    peak = 20
    sd = np.where(t < t[peak], 0.4, 0.9)
    curve = _curve_with_curvature(3.0 * np.exp(-0.5 * ((t - t[peak]) / sd) ** 2), peak)
    weaker, stronger = curve.corner_width()
    half = np.sqrt(2.0 * np.log(2.0))
    assert np.log10(weaker) == pytest.approx(t[peak] - half * 0.4, abs=0.02)
    assert np.log10(stronger) == pytest.approx(t[peak] + half * 0.9, abs=0.02)
    assert weaker < curve.chosen < stronger
    plateau = _curve_with_curvature(np.where(t >= t[peak], 1.0, 0.1), peak)
    assert plateau.corner_width()[1] == weights[-1]
    assert plateau.corner_width()[0] == pytest.approx(10 ** (t[peak] - 0.5 * 5 / 9), rel=1e-9)  # 1 -> 0.1 over a step
    flat = _curve_with_curvature(-np.ones_like(t), peak)
    assert flat.corner_width() == (weights[peak - 1], weights[peak + 1])
