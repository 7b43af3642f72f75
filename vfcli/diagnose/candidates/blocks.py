"""Screening of a fitted run from the Gauss-Newton blocks of E (no dense Jacobian, no refit).

A run's measurement has millions of rows and hundreds of load parameters: the dense projection of
:mod:`vfcli.diagnose.candidates.screening` does not fit in memory.  Here everything is in the units
of the objective E (:mod:`vfcli.inverse.problem`), read as ``-log p = kappa E`` with the
scale kappa of the fit's Laplace posterior (:func:`vfcli.inverse.uncertainty.posterior`: the
residual's own variance, deflated by its correlation area and time):

* ``H_LL``, ``g_L``: the Gauss-Newton Hessian (ridge included) and gradient of E in the load
  parameters (:func:`vfcli.inverse.linearization.gauss_newton_model`);
* ``g_c = dE/dtheta = <dE/dU, dU/dtheta>`` and the cross and own blocks ``H_Lc``, ``H_cc`` from the
  change of ``dE/dU`` along each candidate column (central differences; exact for the motion term,
  which is quadratic in U with the frozen raster);
* efficient score and information ``g = g_c - H_Lc^T H_LL^-1 g_L,data``, ``I = H_cc - H_Lc^T H_LL^-1 H_Lc``;
  statistic ``kappa g^T I^+ g ~ chi2(rank I)`` under the null, one-step estimate ``-I^+ g`` with
  covariance ``(kappa I)^+``.

``g_L,data`` is the data terms' part of the load gradient: the prior terms' (the ridge's) part is left
out of the score.  At a fitted baseline the two parts balance (``g_L = 0``), and with the full ``g_L``
the score would be ``g_c`` alone: a candidate correlated with the loads would take over what the ridge
holds back, a pull of first order in the ridge whether or not the term is present (on blind-panel
recording 2004, truth 0: asymmetry 0.0312 +- 0.037, of which 0.0306 was that pull).  Without it the
score is ``A^T Omega r`` over the efficient columns, the bootstrap calibration's
(:mod:`vfcli.diagnose.calibrate_run`), up to the gap rows' majoriser.

kappa is estimated per candidate from the residual *after* the joint one-step fit of the loads and
the candidate (its motion term, its correlation area and time, ``n_eff - dof - p`` degrees of
freedom): a present effect would otherwise count as noise, inflate the noise estimate and hide
itself.  Under the null the two estimates agree.

The normalised identifiability share is formed from these normal-equation blocks, so its round-off
floor is near sqrt(machine epsilon) times the conditioning, not machine epsilon: a share below
:data:`GRAM_ABSORBED` is "not identifiable with this load model".
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from vfcli.diagnose.candidates.identifiability import Identifiability
from vfcli.diagnose.candidates.screening import ScoreTest

#: absorbed-share threshold of the normal-equation form
GRAM_ABSORBED = 1e-6


class _GramIdentifiability(Identifiability):
    @property
    def identifiable(self) -> bool:
        return bool(self.residual_fraction > GRAM_ABSORBED)


def _grad_disp(problem, x: np.ndarray, disp: np.ndarray, frames) -> tuple[np.ndarray, np.ndarray]:
    """(dE/dU (F + 1, N, 3), dE/dx from the prior terms (n,)) at displacements ``disp``, frozen frames."""
    from vfcli.inverse.terms import Evaluation

    ev = Evaluation(problem, x, disp, frames, np.zeros_like(disp), np.zeros(len(x)))
    for term in problem.terms:
        term.value(ev)
    return ev.grad_disp, ev.grad_x


def candidate_blocks(baseline, dudp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(g_c (p,), H_Lc (n, p), H_cc (p, p)) of E at the baseline for columns dudp (F + 1, N, 3, p)."""
    p = baseline.problem
    x, u0 = baseline.x, baseline.displacements
    gd0, _ = _grad_disp(p, x, u0, baseline.frames)
    n_c = dudp.shape[-1]
    g_c = np.array([np.sum(gd0 * dudp[..., j]) for j in range(n_c)])
    h_lc = np.zeros((p.n_params, n_c))
    h_cc = np.zeros((n_c, n_c))
    size = max(float(np.abs(u0).max()), 1e-12)
    for j in range(n_c):
        col = dudp[..., j]
        eps = 1e-3 * size / max(float(np.abs(col).max()), 1e-300)
        hi, _ = _grad_disp(p, x, u0 + eps * col, baseline.frames)
        lo, _ = _grad_disp(p, x, u0 - eps * col, baseline.frames)
        d = (hi - lo) / (2 * eps)                                    # d(dE/dU)/dtheta_j
        h_lc[:, j] = p.response.adjoint(d, p.sim_times, x)
        h_cc[:, j] = [np.sum(d * dudp[..., k]) for k in range(n_c)]
    return g_c, h_lc, 0.5 * (h_cc + h_cc.T)


def _kappa_after(baseline, model, dof: float, u: np.ndarray, n_extra: int) -> float:
    """kappa of the fit with displacements u (F + 1, N, 3): (n_eff - dof - n_extra) / (2 E_motion)."""
    from vfcli.inverse.terms import Evaluation
    from vfcli.inverse.terms.motion import frame_residual
    from vfcli.inverse.uncertainty import effective_sample_size

    p = baseline.problem
    h, w = p.camera.shape
    images = np.full((p.n_frames, h * w, 3), np.nan)
    for f, fr in enumerate(baseline.frames):
        images[f, fr.pix_both] = frame_residual(fr, p.frame_velocity(u, f), u[f])
        images[f, fr.pix_only] = -p.meas.velocity[f].reshape(-1, 3)[fr.pix_only]
    corr = effective_sample_size(images.reshape(p.n_frames, h, w, 3), pixel_stride=p.meas.pixel_stride)
    motion = next(t for t in p.terms if t.name == "motion")
    e_motion = motion.value(Evaluation(p, baseline.x, u, baseline.frames))
    return max(corr.n_eff - dof - n_extra, 1.0) / (2.0 * max(float(e_motion), 1e-300))


def screen_run(candidates, baseline, rtol: float = 1e-10) -> list[ScoreTest]:
    """Score test of every candidate (each a :class:`vfcli.diagnose.candidates.base.DisplacementTerm`)
    at a fitted run's baseline, from the Gauss-Newton blocks (module docstring)."""
    return screen_run_columns(candidates, baseline, rtol)[0]


def screen_run_columns(candidates, baseline, rtol: float = 1e-10):
    """(tests, columns, model): :func:`screen_run`'s score tests, and per candidate its efficient displacement
    columns ``dU_c - dU/dx H_LL^-1 H_Lc`` (F + 1, N, 3, p_c) (what the candidate moves that a Gauss-Newton
    refit of the loads, ridge included, cannot make; the bootstrap calibration's score directions,
    :mod:`vfcli.diagnose.calibrate_run`), and the Gauss-Newton model of E at the baseline."""
    from vfcli.inverse.linearization import gauss_newton_model
    from vfcli.inverse.uncertainty import effective_sample_size, posterior

    p = baseline.problem
    model = gauss_newton_model(p, baseline.x, baseline.frames, baseline.displacements)
    corr = effective_sample_size(p.motion_residuals(baseline.x, baseline.frames), pixel_stride=p.meas.pixel_stride)
    dof = posterior(model, corr).dof
    g_l = model.grad
    g_data = g_l - _grad_disp(p, baseline.x, baseline.displacements, baseline.frames)[1]    # the ridge left out
    lin = model.linearization
    out, columns = [], []
    for cand in candidates:
        dudp = cand.displacement_jacobian(baseline)
        g_c, h_lc, h_cc = candidate_blocks(baseline, dudp)
        solved = model.hessian.solve(np.column_stack([g_data, h_lc]))
        g = g_c - h_lc.T @ solved[:, 0]
        info = h_cc - h_lc.T @ solved[:, 1:]
        info = 0.5 * (info + info.T)
        columns.append(dudp - np.moveaxis(np.stack([lin.apply(solved[:, 1 + j]) for j in range(dudp.shape[-1])]),
                                          0, -1))
        d = np.sqrt(np.maximum(np.diag(h_cc), 1e-300))
        frac = float(np.linalg.eigvalsh(info / np.outer(d, d)).min())
        ident = _GramIdentifiability(max(frac, 0.0), info, h_cc)
        w, v = np.linalg.eigh(info)
        keep = w > rtol * max(float(w.max(initial=0.0)), 1e-300)
        if not ident.identifiable or not keep.any():
            nan = np.full(len(g_c), np.nan)
            out.append(ScoreTest(0.0, 0, 1.0, nan, nan, ident))
            continue
        inv = (v[:, keep] / w[keep]) @ v[:, keep].T
        theta = -inv @ g
        dx = -model.hessian.solve(g_l + h_lc @ theta)
        u = baseline.displacements + lin.apply(dx) + dudp @ theta
        kappa = _kappa_after(baseline, model, dof, u, len(theta))
        stat = float(kappa * g @ inv @ g)
        out.append(ScoreTest(stat, int(keep.sum()), float(stats.chi2.sf(stat, int(keep.sum()))), theta,
                             np.sqrt(np.maximum(np.diag(inv), 0.0) / kappa), ident))
    return out, columns, model
