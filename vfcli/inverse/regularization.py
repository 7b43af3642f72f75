"""Choosing the Tikhonov weight of bounded load models from the data: the L-curve.

The regularised objective is ``E_data(x) + lam * x^T Omega x / n`` (Omega the load
model's :meth:`penalty_operator`, :mod:`vfcli.inverse.problem`).  On the Gauss-Newton
model of E_data at a point x0 (:func:`vfcli.inverse.linearization.gauss_newton_model`, no
ridge) the minimiser for each weight is one linear solve::

    (H + 2 lam Omega / n) x_lam = H x0 - g

and the L-curve is the parametric curve ``(log rho(lam), log eta(lam))`` of the
predicted data misfit ``rho`` and the penalty ``eta = x_lam^T Omega x_lam``.  Its
corner, the point of maximum curvature, balances fitting the data against the size
and roughness of the loads (Hansen, "Analysis of discrete ill-posed problems by means
of the L-curve", SIAM Review 1992).  It needs no noise level, which the superior
surface data of one recording do not give independently of the model: the residual
of the velocity field is spatially correlated and contains model error.

The weights scanned are ``lam_ref * 10**k`` for k in [-6, 2] (``n_points`` values),
``lam_ref = trace(H) / trace(2 Omega / n)`` being the weight at which penalty and data
curvature are equal on average; the corner is searched among the interior points.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.linearization import QuadraticModel


@dataclass(frozen=True)
class LCurve:
    """weights : (K,) lam, 1/Pa^2.  misfit : (K,) predicted E_data.  penalty : (K,) x^T Omega x, Pa^2.
    curvature : (K,) signed curvature of (log misfit, log penalty).  chosen : lam at the corner."""

    weights: np.ndarray
    misfit: np.ndarray
    penalty: np.ndarray
    curvature: np.ndarray
    chosen: float


def lcurve(model: QuadraticModel, x0: np.ndarray, omega: sp.spmatrix, n_points: int = 17,
           decades: tuple[float, float] = (-6.0, 2.0)) -> LCurve:
    """The L-curve of the regularised problem around ``x0`` and its corner.

    Parameters
    ----------
    model : Gauss-Newton model of the data terms at ``x0`` (built with ridge weight 0).
    x0 : (n,) control values of the linearisation.
    omega : (n, n) sparse PSD penalty matrix.
    n_points : weights scanned (>= 5).
    decades : range of ``log10(lam / lam_ref)``.
    """
    if n_points < 5:
        raise ValueError("the L-curve needs at least 5 points")
    x0 = np.asarray(x0, dtype=float)
    n = len(x0)
    h = model.data_hessian
    omega = sp.csr_matrix(omega)
    rhs = h @ x0 - model.grad
    lam_ref = float(np.sum(h.diagonal())) / float(2.0 * omega.diagonal().sum() / n)
    weights = lam_ref * 10.0 ** np.linspace(decades[0], decades[1], n_points)
    e0 = model.terms.motion + model.terms.gap
    misfit, penalty = np.empty(n_points), np.empty(n_points)
    for k, lam in enumerate(weights):
        z = h.plus(omega, 2.0 * lam / n).solve(rhs)
        dz = z - x0
        misfit[k] = e0 + model.grad @ dz + 0.5 * dz @ (h @ dz)
        penalty[k] = z @ (omega @ z)
    t = np.log(weights)
    a = np.log(np.maximum(misfit, 1e-300))
    b = np.log(np.maximum(penalty, 1e-300))
    a1, b1 = np.gradient(a, t), np.gradient(b, t)
    a2, b2 = np.gradient(a1, t), np.gradient(b1, t)
    curvature = (a1 * b2 - a2 * b1) / np.maximum((a1 ** 2 + b1 ** 2) ** 1.5, 1e-300)
    inner = np.arange(1, n_points - 1)
    chosen = float(weights[inner[np.argmax(curvature[inner])]])
    return LCurve(weights, misfit, penalty, curvature, chosen)
