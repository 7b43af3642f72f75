"""Covariance of a fit that holds when the residuals are not white noise: the sandwich.

The Laplace posterior of :mod:`vfcli.inverse.uncertainty` reads E as a negative
log-likelihood of independent residuals and scales it by the residuals' size.  On real
recordings (and phantoms) the residual of the velocity fields is mostly model and
measurement error that is smooth over the whole image and correlated over frames, so the
scale of the uncertainty follows the residual's total size, not how much of it the fitted
loads actually feel.  The estimator x_hat minimises ``E(x) = sum_f e_f(x) + ridge(x)``
(e_f: the data terms of frame f), and for such an M-estimator (Huber 1967; White 1982)

    Cov(x_hat) = H^-1 S H^-1,     S = Var(sum_f g_f),     g_f = grad e_f(x_hat)

with H the Gauss-Newton Hessian of E (ridge included).  S is measured from the recording
itself: the per-frame scores g_f are the units of replication (the whole image of a frame
is one unit, so no spatial independence is assumed), and their correlation over frames is
taken into account by the long-run covariance (:func:`long_run_covariance`: autocovariances
up to the first zero of the scores' own autocorrelation, as in Newey and West 1987 but with a flat
kernel and a projection onto the positive semi-definite matrices).  Model
error enters in exactly the share the loads respond to.

The sandwich is the covariance of the regularised estimate around its own expectation; it
ignores the ridge's bias ``-H^-1 Lambda x`` (``Lambda = 2 ridge_weight Omega / n``), which
is largest exactly where the data say nothing (there the estimate is pulled to 0 and its
sandwich variance is 0).  Its expected square under the ridge's own prior,
``x ~ N(0, tau^2 Omega^-1)``, is ``H^-1 Lambda tau^2 Omega^-1 Lambda H^-1``, with the prior
scale tau^2 measured on the fit (:func:`prior_scale`: the size of the penalised control
values per penalised degree of freedom the data determine, the empirical-Bayes moment
estimate).  The stated covariance is the mean squared error

    MSE = H^-1 (S + tau^2 Lambda Omega^-1 Lambda) H^-1.

For a linear Gaussian model whose ridge is its true prior (``Lambda = sigma^2 / tau^2
Omega``, S the noise's ``sigma^2 H_data``) this is the exact posterior covariance
``sigma^2 (H_data + Lambda)^-1``; a direction the data do not determine gets the prior's
variance tau^2 (the static offset of a load's free correction, which the velocities do not
see, is such a direction).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.linearization import QuadraticModel
from vfcli.inverse.terms import Evaluation
from vfcli.model.response.base import Linearization


def linearization_adjoint(lin: Linearization, grad_disp: np.ndarray) -> np.ndarray:
    """``(dU/dx)^T grad_disp``: a gradient with respect to the displacements taken to the control values.

    lin : dU/dx, ``dU(t) = sum_j R_j dC B_j(t)`` (T times).  grad_disp : (T, N, 3) per mm.
    Returns (n_spatial * n_time,) with x = C.ravel() (spatial index major).
    """
    g = np.asarray(grad_disp, dtype=float).reshape(grad_disp.shape[0], -1)           # (T, 3N)
    rows = np.flatnonzero(np.any(g != 0.0, axis=1))                                   # a frame's score: 2 times
    out = np.zeros((lin.n_spatial, lin.n_time))
    for t in lin.terms:
        out += (g[rows] @ t.spatial.reshape(-1, lin.n_spatial)).T @ t.temporal[rows]   # (S, n_time)
    return out.ravel()


def _only_frame(frames: list, f: int) -> list:
    """The frozen frames with every frame but ``f`` emptied (nothing compared, no silhouette)."""
    out = []
    for k, fr in enumerate(frames):
        if k == f:
            out.append(fr)
            continue
        out.append(fr.emptied())
    return out


def frame_scores(problem, x: np.ndarray, frames: list, disp: np.ndarray, lin: Linearization) -> np.ndarray:
    """(F, n_params) gradient of each frame's data terms (motion, gap) at ``x``, per unit x.

    problem : :class:`vfcli.inverse.problem.Problem`.  frames, disp : frozen at x.
    lin : the response's linearisation at x and ``problem.sim_times`` (exact for a linear response).
    Their sum plus the prior terms' gradient is the frozen gradient of E.
    """
    x = np.asarray(x, dtype=float)
    data_terms = [t for t in problem.terms if t.data]
    out = np.zeros((len(frames), problem.n_params))
    for f in range(len(frames)):
        ev = Evaluation(problem, x, disp, _only_frame(frames, f), np.zeros_like(disp), np.zeros(len(x)))
        for term in data_terms:
            term.value(ev)
        out[f] = linearization_adjoint(lin, ev.grad_disp)
    return out


@dataclass(frozen=True)
class LongRunCovariance:
    """covariance : (n, n) Var(sum_f g_f) of the scores.  lag : autocovariances used (frames).
    n_frames : scores behind it."""

    covariance: np.ndarray
    lag: int
    n_frames: int


def long_run_covariance(scores: np.ndarray) -> LongRunCovariance:
    """Var(sum_f g_f) of (F, n) per-frame scores correlated over frames.

    The scores are centred (their mean is the ridge's pull, a bias, not scatter).  With the
    normalised autocorrelation ``rho_k = sum_f g_f . g_{f+k} / sum_f |g_f|^2``, the lag L is the
    last before its first zero (the same truncation as the residuals' correlation time in
    :func:`vfcli.inverse.uncertainty.effective_sample_size`), and

        S = F (Gamma_0 + sum_{k=1}^{L} (Gamma_k + Gamma_k^T)),   Gamma_k = sum_f g_f g_{f+k}^T / F,

    projected onto the positive semi-definite matrices (negative eigenvalues set to 0).
    """
    g = np.asarray(scores, dtype=float)
    n_f = g.shape[0]
    if n_f < 2:
        raise ValueError("the long-run covariance needs at least 2 frames' scores")
    g = g - g.mean(axis=0)
    total = float(np.sum(g * g))
    s = g.T @ g
    lag = 0
    for k in range(1, n_f // 2 + 1):
        if total <= 0 or float(np.sum(g[k:] * g[:-k])) <= 0:
            break
        gk = g[k:].T @ g[:-k]
        s += gk + gk.T
        lag = k
    if lag:
        w, v = np.linalg.eigh(s)
        s = (v * np.maximum(w, 0.0)) @ v.T
    return LongRunCovariance(s, lag, n_f)


def prior_scale(x: np.ndarray, penalty: sp.spmatrix, hessian: BlockMatrix, data_hessian: BlockMatrix) -> float:
    """Empirical-Bayes scale tau^2 of the ridge's prior ``x ~ N(0, tau^2 Omega^-1)``.

    ``tau^2 = x^T Omega x / d``, d the penalised degrees of freedom the data determine:
    ``sum_i w_i (H^-1 H_data)_ii`` with ``w_i = Omega_ii / max Omega_ii`` (1 for a penalised,
    about 0 for an unpenalised control value).  (x units)^2; 0 when nothing is penalised.
    """
    omega = sp.csr_matrix(penalty)
    diag = omega.diagonal()
    if not diag.size or diag.max() <= 0:
        return 0.0
    w = diag / diag.max()
    d = 0.0
    for idx, hb, db in zip(hessian.indices, hessian.blocks, data_hessian.blocks):
        d += float(np.sum(w[idx] * np.diag(np.linalg.lstsq(hb, db, rcond=None)[0])))
    x = np.asarray(x, dtype=float)
    return float(x @ (omega @ x)) / max(d, 1.0)


#: A ridge share this far below Omega's largest diagonal entry is a device that keeps the problem well posed, not a
#: prior on the values it weighs (the pressure gains' 1e-6,
#: :meth:`vfcli.model.loads.pressure.PressureLoad.penalty_operator`).
DEVICE_SHARE = 1e-3


def prior_part(penalty: sp.spmatrix) -> sp.csr_matrix:
    """Omega with the rows and columns of its device entries (diagonal below :data:`DEVICE_SHARE` of the largest)
    set to 0: the part of the ridge that is a prior.

    The ridge's expected bias ``tau^2 Lambda Omega^-1 Lambda`` reads Omega as the prior ``N(0, tau^2 Omega^-1)``;
    for a device entry that prior has a variance of tau^2 / share, which nothing measured, and the expected bias
    follows the share (up to 96 % of the inferior surface's stated vertical sd came from the gains' 1e-6 until
    session 74; docs/optimize.md, "What the stated uncertainty rests on"). A device entry's own bias,
    ``c share x``, is negligible by design; what its values leave open is stated by the splits of
    :mod:`vfcli.inverse.uncertainty` instead.
    """
    omega = sp.csr_matrix(penalty)
    diag = omega.diagonal()
    if not diag.size or diag.max() <= 0:
        return omega
    keep = sp.diags((diag >= DEVICE_SHARE * diag.max()).astype(float))
    return sp.csr_matrix(keep @ omega @ keep)


@dataclass(frozen=True)
class Sandwich:
    """covariance : (n, n) :class:`BlockMatrix` MSE of the control values, (x units)^2.
    scatter : its H^-1 S H^-1 part.  tau2 : the prior scale.  lag : frames of score correlation."""

    covariance: BlockMatrix
    scatter: BlockMatrix
    tau2: float
    lag: int


def _pinv_and_null(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pseudo-inverse, null-space variance) of a symmetric PSD block: the null space (eigenvalues below
    1e-12 of the largest, directions the fit does not determine) gets 1e12 x the largest variance's
    scale, i.e. 'not determined', as :func:`vfcli.inverse.uncertainty.posterior` does."""
    w, v = np.linalg.eigh(0.5 * (a + a.T))
    top = max(float(w.max()), 1e-300)
    keep = w > 1e-12 * top
    pinv = (v[:, keep] / w[keep]) @ v[:, keep].T
    null = (v[:, ~keep] * (1e12 / top)) @ v[:, ~keep].T
    return pinv, null


def mse_covariance(hessian: BlockMatrix, score_cov: np.ndarray,
                   bias_cov: sp.spmatrix | np.ndarray | None = None) -> tuple[BlockMatrix, BlockMatrix]:
    """(MSE, scatter) = ``H^-1 (S + B) H^-1`` and ``H^-1 S H^-1``, per block of H.

    hessian : H (ridge included).  A singular block is pseudo-inverted, and its null space (what
        neither the data nor the ridge determine) gets a huge variance in the MSE, none in the scatter.
    score_cov : (n, n) S.
    bias_cov : (n, n) B, the expected ``(Lambda x)(Lambda x)^T`` of the ridge's bias
    (``tau^2 Lambda Omega^-1 Lambda``), or None.
    """
    b = sp.csr_matrix(bias_cov) if bias_cov is not None else None
    mse, scatter = [], []
    for idx, hb in zip(hessian.indices, hessian.blocks):
        hinv, null = _pinv_and_null(hb)
        part = hinv @ score_cov[np.ix_(idx, idx)] @ hinv
        scatter.append(part)
        mse.append(part + null if b is None else part + null + hinv @ b[idx][:, idx].toarray() @ hinv)
    return (BlockMatrix(hessian.n, hessian.indices, tuple(mse)),
            BlockMatrix(hessian.n, hessian.indices, tuple(scatter)))


def sandwich(problem, x: np.ndarray, model: QuadraticModel, frames: list, disp: np.ndarray) -> Sandwich:
    """The MSE covariance of the fit at ``x`` (module docstring).

    model : :func:`vfcli.inverse.linearization.gauss_newton_model` at x (its ``linearization``
    and Hessians); frames, disp : frozen at x.
    """
    if model.linearization is None:
        raise ValueError("the sandwich needs the model's linearization")
    scores = frame_scores(problem, x, frames, disp, model.linearization)
    lr = long_run_covariance(scores)
    c = 2.0 * float(problem.settings.ridge_weight) / problem.n_params      # Lambda = c Omega
    tau2, bias = 0.0, None
    if c > 0:
        tau2 = prior_scale(x, problem.penalty, model.hessian, model.data_hessian)
        bias = (tau2 * c * c) * prior_part(problem.penalty)                  # tau^2 Lambda Omega^-1 Lambda
    mse, scatter = mse_covariance(model.hessian, lr.covariance, bias)
    return Sandwich(mse, scatter, tau2, lr.lag)
