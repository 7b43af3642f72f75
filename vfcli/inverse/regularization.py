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

The weights scanned are ``lam_ref * 10**k`` for k in [-6, 10] (``n_points`` values, two per
decade), ``lam_ref = trace(H) / trace(2 Omega / n)`` being the weight at which penalty and data
curvature are equal on average; the corner is searched among the interior points.  The scan has to
reach the curve's horizontal branch (the misfit rising as the penalty stops falling): with the
pressure load model the data hardly resist shrinking the free correction, so the misfit stays within
a few per cent while the penalty falls by 15 decades, and the corner sits 5-6 decades above lam_ref
on the widened phantoms (docs/benchmarks.md, session 12).  The former scan to k = 2 stopped on the
vertical branch, whose curvature is round-off, and its "corner" wandered by decades between fits of
similar data (null seed 2016: 9e-10 against 1e-4..4e-3 on the other nulls).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.linearization import QuadraticModel

log = logging.getLogger(__name__)

#: The share of the corner's curvature that bounds its width (:meth:`LCurve.corner_width`): half the maximum, the
#: usual width of a peak.
CORNER_LEVEL = 0.5


@dataclass(frozen=True)
class LCurve:
    """weights : (K,) lam, 1/Pa^2.  misfit : (K,) predicted E_data.  penalty : (K,) x^T Omega x, Pa^2.
    curvature : (K,) signed curvature of (log misfit, log penalty).  chosen : lam at the corner.
    reference : ``lam_ref``, the weight at which the penalty's curvature equals the data's on average, 1/Pa^2."""

    weights: np.ndarray
    misfit: np.ndarray
    penalty: np.ndarray
    curvature: np.ndarray
    chosen: float
    reference: float = float("nan")

    @property
    def unbounded(self) -> bool:
        """The corner lies below ``reference``: the data outweigh the penalty in every direction, so the bound
        hardly holds the loads anywhere.  With the ``pressure`` loads the corner lies 5-6 decades above it on 32 widened
        stores (the blind panel's nulls and its damping, contact and asymmetry phantoms, eight fresh nulls, eight
        proof-panel phantoms) and 1-5 decades below it on the panel's three inertia phantoms, whose quasi-static model
        the tied loads cannot fit (docs/benchmarks.md, "Session 55")."""
        return bool(self.chosen < self.reference)

    def corner_width(self, level: float = CORNER_LEVEL) -> tuple[float, float]:
        """(weaker, stronger): the weights on either side of the corner where the curvature has fallen to ``level``
        of the corner's, interpolated in log weight, 1/Pa^2.

        The corner is a maximum of curvature; how sharply it stands out says how well the L-curve fixes the weight,
        so the fits across this width are equally good readings of the curve (the stated uncertainty's
        regularisation split, :func:`vfcli.inverse.uncertainty.corner_fits`).  Where the curvature stays above
        ``level`` to the end of the scan, that end; a corner of no positive curvature has the scanned neighbours.
        """
        w, k = np.asarray(self.weights, float), np.asarray(self.curvature, float)
        i = int(np.argmin(np.abs(np.log(w / self.chosen))))
        if k[i] <= 0:
            return float(w[max(i - 1, 0)]), float(w[min(i + 1, len(w) - 1)])
        half = level * k[i]
        out = []
        for step in (-1, 1):
            j = i + step
            if not 0 <= j < len(w):
                out.append(float(w[i]))
                continue
            while 0 <= j + step < len(w) and k[j] >= half:
                j += step
            if k[j] >= half:                               # the scan's end
                out.append(float(w[j]))
                continue
            frac = (half - k[j]) / (k[j - step] - k[j])    # from w[j] (below) towards w[j - step] (above)
            out.append(float(np.exp(np.log(w[j]) + frac * (np.log(w[j - step]) - np.log(w[j])))))
        return out[0], out[1]


def lcurve(model: QuadraticModel, x0: np.ndarray, omega: sp.spmatrix, n_points: int = 33,
           decades: tuple[float, float] = (-6.0, 10.0)) -> LCurve:
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
    best = inner[np.argmax(curvature[inner])]
    if best in (inner[0], inner[-1]):
        log.warning("L-curve: the corner is at the end of the scanned weights (%.3g 1/Pa^2 of %.3g..%.3g); the "
                    "ridge weight may be too %s; set optimize.ridge_weight to choose it", weights[best], weights[0],
                    weights[-1], "weak" if best == inner[0] else "strong")
    chosen = float(weights[best])
    return LCurve(weights, misfit, penalty, curvature, chosen, lam_ref)
