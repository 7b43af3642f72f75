"""Screening: a score test per candidate at the baseline fit, from the Gauss-Newton blocks, no refit.

With whitened Jacobians J_c (m, p) of the candidate, J_L (m, q) of the loads, and the whitened
residual r (measured minus predicted) of the baseline fit, the linearised model
``r = J_L dx + J_c theta + e``, e ~ N(0, I), gives the efficient score and information

    U = J_c^T (I - P_L) r,        I = J_c^T (I - P_L) J_c,        S = U^T I^+ U ~ chi2(rank I)

under the null (theta = 0, the term absent), exactly for a linear model with known noise
(tests/test_candidates_screening.py checks the false-alarm rate at alpha = 0.05 both ways and the
power).  ``I^+ U`` is the one-step estimate of theta, with covariance ``I^+``.  At the baseline's
optimum ``J_L^T r = 0`` and U is simply ``J_c^T r``; the projection keeps it right when the fit
stopped early or carries a ridge.

The run's noise is not known: :func:`screen_baseline` whitens with a standard deviation per
row kind (motion, gap) estimated from the baseline residual, inflated by the residual's
correlation area and time (:func:`vfcli.inverse.uncertainty.effective_sample_size`), so that
correlated rows are not counted as independent.  Bootstrap calibration in whole cycles and the
family-wise control over candidates are :mod:`vfcli.diagnose.calibrate` (docs/diagnose.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from vfcli.diagnose.candidates.identifiability import Identifiability, identifiability, load_basis, project_out


@dataclass(frozen=True)
class ScoreTest:
    """statistic : U^T I^+ U.  dof : rank of I.  p_value : chi2 survival of the statistic.
    estimate : (p,) one-step theta.  std : (p,) its standard deviation.  identifiability : of the term."""

    statistic: float
    dof: int
    p_value: float
    estimate: np.ndarray
    std: np.ndarray
    identifiability: Identifiability


def score_test(jc: np.ndarray, r: np.ndarray, jl: np.ndarray | None = None, q: np.ndarray | None = None,
               rtol: float = 1e-10) -> ScoreTest:
    """Score test of one candidate (module docstring).

    Parameters
    ----------
    jc : (m, p) whitened candidate Jacobian.
    r : (m,) whitened residual, measured minus predicted.
    jl : (m, q) whitened load Jacobian, or ``q`` its orthonormal basis (:func:`load_basis`).
    rtol : eigenvalues of I below ``rtol`` times the largest are not information (not counted in dof).
    """
    jc = np.asarray(jc, dtype=float).reshape(len(jc), -1)
    q = load_basis(jl) if q is None else q
    ident = identifiability(jc, q=q)
    u = project_out(jc, q).T @ np.asarray(r, dtype=float)
    w, v = np.linalg.eigh(ident.information)
    keep = w > rtol * max(float(w.max(initial=0.0)), 1e-300)
    if not ident.identifiable or not keep.any():
        nan = np.full(jc.shape[1], np.nan)
        return ScoreTest(0.0, 0, 1.0, nan, nan, ident)
    inv = (v[:, keep] / w[keep]) @ v[:, keep].T
    stat = float(u @ inv @ u)
    dof = int(keep.sum())
    return ScoreTest(stat, dof, float(stats.chi2.sf(stat, dof)), inv @ u, np.sqrt(np.maximum(np.diag(inv), 0.0)),
                     ident)


def load_jacobian(baseline) -> np.ndarray:
    """(n_rows, n_params) Jacobian of the predicted measurement with respect to the baseline's
    control values (rows of :meth:`vfcli.diagnose.candidate.Baseline.measure_linear`)."""
    p = baseline.problem
    lin = p.response.linearize(baseline.x, p.sim_times)
    eye = np.eye(p.n_params)
    dudp = np.stack([lin.apply(eye[j]) for j in range(p.n_params)], axis=-1)     # (F + 1, N, 3, n)
    return baseline.measure_linear(dudp)


def row_noise(baseline, residual: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
    """(n_rows,) noise standard deviation of each measurement row, estimated from the baseline.

    Per row kind (motion mm/s, gap mm): the RMS residual, inflated by the square root of the
    motion residual's correlation area times correlation time
    (:func:`vfcli.inverse.uncertainty.effective_sample_size`; the gap rows by the correlation time
    only), so that n correlated rows weigh as the n_eff independent ones they are worth.
    """
    from vfcli.inverse.uncertainty import effective_sample_size

    n_motion = baseline.n_motion_rows
    r = np.asarray(residual, dtype=float)
    corr = effective_sample_size(baseline.problem.motion_residuals(baseline.x, baseline.frames),
                                 pixel_stride=baseline.problem.meas.pixel_stride)
    out = np.empty(len(r))
    for rows, inflate in ((slice(0, n_motion), corr.area_px * corr.tau_frames),
                          (slice(n_motion, len(r)), corr.tau_frames)):
        part = r[rows]
        if part.size:
            out[rows] = np.sqrt(max(float(np.mean(part ** 2)), 1e-300) * inflate)
    return out


def screen_baseline(candidates, baseline) -> list[ScoreTest]:
    """Score test of every candidate at ``baseline`` (a :class:`vfcli.diagnose.candidate.Baseline`),
    whitened by :func:`row_noise`; in the order given."""
    r = baseline.residual_vector()
    sigma = row_noise(baseline, r)
    q = load_basis(load_jacobian(baseline) / sigma[:, None])
    return [score_test(c.jacobian(baseline) / sigma[:, None], r / sigma, q=q) for c in candidates]


#: family-wise false-alarm rate over all candidates (the calibrated decision's, :mod:`vfcli.diagnose.decide`)
FAMILY_ALPHA = 0.05


def words(candidate, test: ScoreTest, n_candidates: int, alpha: float = FAMILY_ALPHA) -> str:
    """One plain line: not acting / not identifiable / the one-step estimate and the uncalibrated p-value (the
    decision is the calibrated one, :mod:`vfcli.diagnose.decide`)."""
    if not np.any(test.identifiability.own_information):
        # a zero column: the term changes nothing at this baseline (contact whose folds never touch)
        return f"{candidate.name}: no evidence (the term does not act on this fit)"
    if not test.identifiability.identifiable:
        return f"{candidate.name}: not identifiable with this load model (the loads can absorb it)"
    est = ", ".join(f"{n} = {e:.3g} +- {1.96 * s:.2g}"
                    for n, e, s in zip(candidate.parameter_names, test.estimate, test.std))
    return (f"{candidate.name}: one-step estimate {est}; uncalibrated score test p = {test.p_value:.2g} (white-noise "
            "chi2 reference, not a decision: see the calibrated decision below)")
