"""The sandwich covariance with the ridge's expected bias (vfcli/inverse/sandwich.py): exact on a
linear Gaussian model, calibrated when its noise and prior scale are measured from the data,
and the per-frame scores are the frozen gradient split by frame."""
import numpy as np
import scipy.sparse as sp

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.sandwich import frame_scores, long_run_covariance, mse_covariance, prior_scale, sandwich

try:
    from _forward_case import forward_case
except ModuleNotFoundError:
    from tests._forward_case import forward_case


def _ridge_problem(rng, m=240, n=24, n_free=16):
    """y = A x + noise; the last n - n_free control values unpenalised (like the pressure model's gains)."""
    a = rng.normal(size=(m, n)) * np.geomspace(0.002, 1.5, n)
    omega = np.diag(np.r_[np.ones(n_free), np.full(n - n_free, 1e-6)])
    return a, omega


def test_sandwich_plus_expected_bias_is_the_exact_posterior_of_a_linear_gaussian_model():
    """Prior x ~ N(0, tau^2 Omega^-1), noise sigma^2, E = w (|A x - y|^2 + sigma^2 / tau^2 x^T Omega x):
    the exact posterior covariance is sigma^2 (A^T A + sigma^2 / tau^2 Omega)^-1. The sandwich with the
    noise's score covariance S = (2 w)^2 sigma^2 A^T A and the bias B = tau^2 Lambda Omega^-1 Lambda gives it;
    without B it is smaller (the ridge's bias ignored)."""
    rng = np.random.default_rng(5)
    a, omega = _ridge_problem(rng)
    n = a.shape[1]
    sigma, tau, w = 0.3, 2.0, 7.0
    lam = 2 * w * sigma ** 2 / tau ** 2 * omega                          # Hessian of the ridge term
    h = BlockMatrix(n, (np.arange(n),), (2 * w * a.T @ a + lam,))
    s = (2 * w) ** 2 * sigma ** 2 * a.T @ a
    bias = tau ** 2 * lam @ np.linalg.inv(omega) @ lam
    mse, scatter = mse_covariance(h, s, bias)
    exact = sigma ** 2 * np.linalg.inv(a.T @ a + sigma ** 2 / tau ** 2 * omega)
    np.testing.assert_allclose(mse.dense(), exact, rtol=1e-8, atol=1e-12 * np.abs(exact).max())
    # the free (penalised) values the data barely see: the scatter alone understates them
    free = np.arange(16)
    assert np.all(np.diag(scatter.dense())[free] < np.diag(exact)[free])
    assert np.diag(scatter.dense())[free][:4].mean() < 0.5 * np.diag(exact)[free][:4].mean()


def test_measured_noise_and_prior_scale_give_calibrated_intervals_and_the_scatter_alone_does_not():
    """The same model with sigma and tau unknown: S from per-block scores (the frames of a recording),
    tau^2 from the fit (prior_scale). Over 60 draws of truth and noise the 90 % intervals of the
    control values cover 85-95 %; without the bias term they cover far less."""
    rng = np.random.default_rng(6)
    a, omega = _ridge_problem(rng)
    m, n = a.shape
    sigma, tau, w = 0.3, 2.0, 1.0
    lam_w = sigma ** 2 / tau ** 2               # ridge weight per E's scale
    blocks = np.array_split(np.arange(m), 60)   # 60 "frames" of 4 residuals
    hits, hits_scatter = [], []
    for _ in range(60):
        x_true = np.linalg.cholesky(tau ** 2 * np.linalg.inv(omega)) @ rng.normal(size=n)
        y = a @ x_true + sigma * rng.normal(size=m)
        lam = 2 * w * lam_w * omega
        hd = 2 * w * a.T @ a
        x_hat = np.linalg.solve(hd + lam, 2 * w * a.T @ y)
        r = a @ x_hat - y
        scores = np.array([2 * w * a[b].T @ r[b] for b in blocks])
        s = long_run_covariance(scores)
        tau2 = prior_scale(x_hat, sp.csr_matrix(omega), BlockMatrix(n, (np.arange(n),), (hd + lam,)),
                           BlockMatrix(n, (np.arange(n),), (hd,)))
        mse, scatter = mse_covariance(BlockMatrix(n, (np.arange(n),), (hd + lam,)), s.covariance,
                                      tau2 * lam @ np.linalg.inv(omega) @ lam)
        hits.append(np.abs(x_hat - x_true) <= 1.645 * np.sqrt(np.diag(mse.dense())))
        hits_scatter.append(np.abs(x_hat - x_true) <= 1.645 * np.sqrt(np.diag(scatter.dense())))
    coverage, coverage_scatter = float(np.mean(hits)), float(np.mean(hits_scatter))
    print(f"coverage {100 * coverage:.1f} %, scatter alone {100 * coverage_scatter:.1f} %")
    assert 0.85 <= coverage <= 0.95
    assert coverage_scatter < 0.8


def test_white_and_correlated_scores_have_their_long_run_variance():
    """White scores: Var(sum) = F sigma^2 I. AR(1) scores with coefficient phi: F sigma^2 (1 + phi) / (1 - phi)."""
    rng = np.random.default_rng(7)
    f, n = 4000, 3
    white = rng.normal(size=(f, n))
    lr = long_run_covariance(white)
    np.testing.assert_allclose(np.diag(lr.covariance) / f, 1.0, rtol=0.15)
    phi = 0.6
    g = np.empty((f, n))
    g[0] = rng.normal(size=n)
    for k in range(1, f):
        g[k] = phi * g[k - 1] + np.sqrt(1 - phi ** 2) * rng.normal(size=n)
    lr = long_run_covariance(g)
    np.testing.assert_allclose(np.diag(lr.covariance) / f, (1 + phi) / (1 - phi), rtol=0.25)
    assert np.all(np.linalg.eigvalsh(lr.covariance) >= -1e-9 * f)


def test_frame_scores_sum_to_the_frozen_gradient_of_the_data_terms():
    """Motion and gap terms, two-sided force field with a ridge: the per-frame scores plus the ridge's
    gradient are the exact frozen gradient of E (checked against Problem.frozen_value_and_grad)."""
    case = forward_case(resolution=(2, 2, 4), sides=("inferior", "superior"), n_frames=8)
    p = case.problem.with_weights(ridge_weight=1e-6)
    rng = np.random.default_rng(8)
    x = case.x_true * (1 + 0.2 * rng.normal(size=case.x_true.shape))
    u = p.displacements(x)
    frames = p.freeze(x, u)
    _, grad = p.frozen_value_and_grad(x, frames)
    model = gauss_newton_model(p, x, frames, u)
    scores = frame_scores(p, x, frames, u, model.linearization)
    assert scores.shape == (8, p.n_params)
    ridge = (2 * 1e-6 / p.n_params) * (p.penalty @ x)
    np.testing.assert_allclose(scores.sum(axis=0) + ridge, grad, rtol=1e-9, atol=1e-12 * np.abs(grad).max())
    assert np.count_nonzero(np.abs(scores).max(axis=1)) == 8
    sw = sandwich(p, x, model, frames, u)
    assert sw.tau2 > 0 and np.all(np.diag(sw.covariance.dense()) >= np.diag(sw.scatter.dense()) - 1e-15)


def test_what_nothing_determines_is_stated_as_not_determined():
    """A control value no data and no ridge touch (H singular there): the MSE gives it a huge variance
    (as the Laplace posterior does), the determined ones their sandwich variance."""
    rng = np.random.default_rng(9)
    a = rng.normal(size=(50, 4))
    a[:, 3] = 0.0
    h = 2 * a.T @ a
    s = 4 * 0.1 ** 2 * a.T @ a
    mse, scatter = mse_covariance(BlockMatrix(4, (np.arange(4),), (h,)), s)
    d = np.diag(mse.dense())
    assert d[3] > 1e6 * d[:3].max() and np.diag(scatter.dense())[3] == 0.0
    np.testing.assert_allclose(mse.dense()[:3, :3], 0.1 ** 2 * np.linalg.inv(a[:, :3].T @ a[:, :3]), rtol=1e-8)


def test_the_expected_bias_leaves_out_the_ridges_device_entries():
    """A ridge share far below Omega's largest entry (the pressure gains' 1e-6) keeps the problem well posed and
    is no prior: its row and column leave the expected bias, the prior's entries stay as they are; an Omega whose
    entries are all priors (the regularised force field's identity plus differences) is kept whole."""
    from vfcli.inverse.sandwich import DEVICE_SHARE, prior_part

    omega = sp.diags([1.0, 1e-6, 0.5, 2.0 * DEVICE_SHARE]).tocsr()
    np.testing.assert_array_equal(prior_part(omega).toarray(), np.diag([1.0, 0.0, 0.5, 2.0 * DEVICE_SHARE]))
    d = sp.diags([-1.0, 1.0], [0, 1], shape=(4, 5))
    whole = (sp.identity(5) + d.T @ d).tocsr()
    np.testing.assert_array_equal(prior_part(whole).toarray(), whole.toarray())
