"""Batched Gauss-Newton fit of a spline phase to periodic records (used by vfcli.sync.phase).

Model of row n (samples s, strided)::

    y[n, s] = sum_p x[n, p] C_p(phi[n, s]) + sum_d beta[n, d] L_d(s),   phi = theta @ B^T

with periodic *columns* C_p of the phase (see :func:`model_columns`), a polynomial baseline
L and a B-spline basis B. For a given phase the linear coefficients (x, beta) are solved
exactly (variable projection); the phase coefficients theta take Gauss-Newton steps on the
full Jacobian ``[a * B, C, L]`` with ``a = sum_p x_p dC_p/dphi``, with per-row backtracking.

Column sets (``mode``):

* ``"template"``: one column, the unit-RMS template W(phi): the record's phase is the
  template's (all harmonics weighted by the fit); x is the gain.
* ``"fundamental"``: cos(2 pi phi) and cos / sin(2 pi h phi) for h = 2..H: the waveform's
  harmonics h >= 2 are free per record, the fundamental's phase is pinned to phi (its sine
  is absent), so phase 0 is the record's own fundamental maximum. Its harmonics still carry
  the phase's drift (they follow h phi(t)); only their phase *offsets* are free, so a record
  whose waveform shape differs from the template's is not biased.
"""
from __future__ import annotations

import logging

import numpy as np
from scipy.interpolate import BSpline

log = logging.getLogger(__name__)

#: Rows per Gauss-Newton chunk (memory: CHUNK * S * n_params * 8 bytes).
CHUNK = 32
MODES = ("template", "fundamental")


def evaluate_template(coeffs: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Template W(phi) and dW/dphi (per cycle) for a harmonic series; same shape as phi."""
    e1 = np.exp(2j * np.pi * phi)
    eh = np.ones_like(e1)
    w = np.zeros(phi.shape)
    dw = np.zeros(phi.shape)
    for h, c in enumerate(np.asarray(coeffs), start=1):
        eh = eh * e1
        ce = c * eh
        w += ce.real
        dw -= (2.0 * np.pi * h) * ce.imag
    return w, dw


def model_columns(mode: str, coeffs: np.ndarray, phi: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Periodic columns and their phase derivatives: phi (n, S) -> (n, P, S) twice."""
    if mode == "template":
        w, dw = evaluate_template(coeffs, phi)
        return w[:, None, :], dw[:, None, :]
    n_h = coeffs.size
    n, s = phi.shape
    cols = np.empty((n, 2 * n_h - 1, s))
    dcols = np.empty_like(cols)
    e1 = np.exp(2j * np.pi * phi)
    eh = e1.copy()
    cols[:, 0], dcols[:, 0] = eh.real, -2.0 * np.pi * eh.imag
    for h in range(2, n_h + 1):
        eh = eh * e1
        j = 2 * h - 3
        cols[:, j], cols[:, j + 1] = eh.real, eh.imag
        dcols[:, j], dcols[:, j + 1] = -2.0 * np.pi * h * eh.imag, 2.0 * np.pi * h * eh.real
    return cols, dcols


def gram(a: np.ndarray) -> np.ndarray:
    """a^T a for a (S, D), via a contiguous copy (non-contiguous GEMMs are slow in OpenBLAS)."""
    return np.ascontiguousarray(a.T) @ a


def linear_part(y: np.ndarray, cols: np.ndarray, base: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares column and baseline coefficients: y (n,S), cols (n,P,S), base (S,D).

    Returns x (n, P), beta (n, D), residual (n, S).
    """
    n_rows, n_p, _ = cols.shape
    d = base.shape[1]
    m = n_p + d
    ata = np.empty((n_rows, m, m))
    ata[:, :n_p, :n_p] = np.matmul(cols, cols.transpose(0, 2, 1))
    cl = cols @ base
    ata[:, :n_p, n_p:] = cl
    ata[:, n_p:, :n_p] = cl.transpose(0, 2, 1)
    ata[:, n_p:, n_p:] = gram(base)
    aty = np.concatenate([np.matmul(cols, y[:, :, None])[..., 0], y @ base], axis=1)
    ata += 1e-12 * np.trace(ata, axis1=1, axis2=2)[:, None, None] * np.eye(m)
    x = np.linalg.solve(ata, aty[..., None])[..., 0]
    resid = (y - np.matmul(x[:, None, :n_p], cols)[:, 0]
             - x[:, n_p:] @ np.ascontiguousarray(base.T))
    return x[:, :n_p], x[:, n_p:], resid


class BandedBasis:
    """A B-spline design matrix (S, K) stored by its non-zero band.

    Row s has at most ``width`` non-zeros (degree + 1), in columns from ``span[s]`` on;
    rows are sorted in time, so equal spans form contiguous segments. Products
    ``sum_s f[s] B[s, j] B[s, k]`` then need no GEMM (small GEMMs suffer from BLAS
    threading on a loaded machine), only per-segment sums (``np.add.reduceat``).
    """

    def __init__(self, basis: np.ndarray) -> None:
        n_s, n_k = basis.shape
        nz = basis != 0.0
        width = max(1, int(nz.sum(axis=1).max()))
        first = np.argmax(nz, axis=1)
        self.span = np.minimum(first, n_k - width)
        self.local = basis[np.arange(n_s)[:, None], self.span[:, None] + np.arange(width)]
        self.starts = np.flatnonzero(np.r_[True, np.diff(self.span) != 0])
        self.seg_span = self.span[self.starts]
        self.width = width
        self.n_k = n_k

    def weighted_gram(self, f: np.ndarray) -> np.ndarray:
        """sum_s f[n, s] B[s, j] B[s, k] -> (n, K, K), for f (n, S)."""
        out = np.zeros((f.shape[0], self.n_k, self.n_k))
        for u in range(self.width):
            for v in range(u, self.width):
                vals = np.add.reduceat(f * (self.local[:, u] * self.local[:, v]), self.starts,
                                       axis=1)
                out[:, self.seg_span + u, self.seg_span + v] += vals
                if u != v:
                    out[:, self.seg_span + v, self.seg_span + u] += vals
        return out

    def project(self, f: np.ndarray) -> np.ndarray:
        """sum_s f[..., s] B[s, k] -> (..., K), for f (..., S)."""
        out = np.zeros(f.shape[:-1] + (self.n_k,))
        for u in range(self.width):
            out[..., self.seg_span + u] += np.add.reduceat(f * self.local[:, u], self.starts,
                                                          axis=-1)
        return out


def _normal_equations(a: np.ndarray, cols: np.ndarray, r: np.ndarray, base: np.ndarray,
                      weighted_gram, project) -> tuple[np.ndarray, np.ndarray]:
    """J^T J and J^T r for J = [a * B, cols, base], with B given by two operations:
    ``weighted_gram(f) = sum_s f[n, s] B[s, j] B[s, k]`` and ``project(f) = f @ B``."""
    n_rows = a.shape[0]
    n_p, d = cols.shape[1], base.shape[1]
    g = weighted_gram(a * a)
    k = g.shape[1]
    m = k + n_p + d
    jtj = np.empty((n_rows, m, m))
    jtj[:, :k, :k] = g
    acb = project(a[:, None, :] * cols)                                       # (n, P, K)
    jtj[:, k:k + n_p, :k] = acb
    jtj[:, :k, k:k + n_p] = acb.transpose(0, 2, 1)
    alb = project(a[:, None, :] * base.T[None])                               # (n, D, K)
    jtj[:, k + n_p:, :k] = alb
    jtj[:, :k, k + n_p:] = alb.transpose(0, 2, 1)
    jtj[:, k:k + n_p, k:k + n_p] = np.matmul(cols, cols.transpose(0, 2, 1))
    cl = cols @ base
    jtj[:, k:k + n_p, k + n_p:] = cl
    jtj[:, k + n_p:, k:k + n_p] = cl.transpose(0, 2, 1)
    jtj[:, k + n_p:, k + n_p:] = gram(base)
    jtr = np.concatenate([project(a * r), np.matmul(cols, r[:, :, None])[..., 0], r @ base], axis=1)
    return jtj, jtr


def normal_equations_banded(a: np.ndarray, cols: np.ndarray, r: np.ndarray,
                            band: BandedBasis, base: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`normal_equations`, with the spline basis given by its band."""
    return _normal_equations(a, cols, r, base, band.weighted_gram, band.project)


def normal_equations(a: np.ndarray, cols: np.ndarray, r: np.ndarray, basis: np.ndarray,
                     base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T J and J^T r for J = [a * basis, cols, base] (all rows), using GEMMs.

    a, r : (n, S); cols : (n, P, S); basis : (S, K); base : (S, D)
    -> (n, M, M), (n, M) with M = K + P + D.
    """
    n_s = a.shape[1]

    def weighted_gram(f: np.ndarray) -> np.ndarray:
        fb = f[:, None, :] * basis.T[None]                                     # (n, K, S)
        return (fb.reshape(-1, n_s) @ basis).reshape(f.shape[0], basis.shape[1], basis.shape[1])

    return _normal_equations(a, cols, r, base, weighted_gram, lambda f: f @ basis)


def curvature_penalty(knots: np.ndarray, degree: int) -> np.ndarray:
    """Penalty matrix P (K, K): theta^T P theta ~ integral of the squared third derivative.

    Zero for phases up to quadratic in time (constant f0 drift rate); normalised to unit
    mean diagonal. Zeros when the spline has degree < 3.
    """
    n_k = knots.size - degree - 1
    if degree < 3:
        return np.zeros((n_k, n_k))
    inner = np.unique(knots)
    mids = 0.5 * (inner[:-1] + inner[1:])
    widths = np.diff(inner)
    d3 = np.stack([BSpline(knots, np.eye(n_k)[j], degree).derivative(3)(mids)
                   for j in range(n_k)], axis=1)                       # (n_int, K)
    pen = d3.T @ (widths[:, None] * d3)
    mean_diag = np.mean(np.diag(pen))
    return pen / mean_diag if mean_diag > 0 else pen


def gauss_newton(
    y: np.ndarray, basis: np.ndarray, base: np.ndarray, coeffs: np.ndarray,
    theta: np.ndarray, *, mode: str = "template", n_iter: int = 8, tol: float = 1e-4,
    smooth: float = 0.0, pen: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit the phase coefficients of N rows (in chunks of ``CHUNK``).

    Parameters
    ----------
    y : (N, S) float
        Records (strided samples).
    basis : (S, K) float
        Phase B-spline basis at the samples.
    base : (S, D) float
        Baseline basis.
    coeffs : (H,) complex
        Template harmonics (``mode="template"``) or, for ``"fundamental"``, only its size
        H matters.
    theta : (N, K) float
        Starting phase coefficients, cycles (within ~0.1 cycle of the solution).
    mode : {"template", "fundamental"}
        Column set (module docstring).
    n_iter, tol : int, float
        Iterations at most; stop when every row's step is below ``tol`` cycles.
    smooth, pen : float, (K, K)
        Penalty ``lambda theta^T pen theta`` with ``lambda = smooth * mean diagonal of the
        phase block of J^T J`` per row (``pen`` from :func:`curvature_penalty`).

    Returns
    -------
    theta : (N, K)
    x : (N, P)
        Column coefficients (the gain, or the fundamental's cosine amplitude first).
    beta : (N, D)
        Baseline coefficients.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    n_rows, n_k = theta.shape
    if pen is None:
        pen = np.zeros((n_k, n_k))
    theta = theta.copy()
    basis_t = np.ascontiguousarray(basis.T)
    band = BandedBasis(basis)
    n_p = 1 if mode == "template" else 2 * coeffs.size - 1
    x_out = np.zeros((n_rows, n_p))
    beta = np.zeros((n_rows, base.shape[1]))

    def evaluate(yc, th, lam):
        cols, dcols = model_columns(mode, coeffs, th @ basis_t)
        x, b, r = linear_part(yc, cols, base)
        cost = np.einsum("ns,ns->n", r, r) + lam * np.einsum("nk,kl,nl->n", th, pen, th)
        return cols, dcols, x, b, r, cost

    for lo in range(0, n_rows, CHUNK):
        sl = slice(lo, min(lo + CHUNK, n_rows))
        yc, th = y[sl], theta[sl]
        lam = np.zeros(len(th))
        cols, dcols, x, b, r, cost = evaluate(yc, th, lam)
        for it in range(n_iter):
            a = np.einsum("np,nps->ns", x, dcols)
            jtj, jtr = normal_equations_banded(a, cols, r, band, base)
            diag = np.einsum("nii->ni", jtj)
            if it == 0:
                lam = smooth * diag[:, :n_k].mean(axis=1)
                cost = cost + lam * np.einsum("nk,kl,nl->n", th, pen, th)
            jtj[:, :n_k, :n_k] += lam[:, None, None] * pen
            jtr[:, :n_k] -= lam[:, None] * (th @ pen)
            jtj += 1e-10 * diag.max(axis=1)[:, None, None] * np.eye(jtj.shape[1])
            step = np.linalg.solve(jtj, jtr[..., None])[..., 0][:, :n_k]
            # per-row backtracking: halve the step until the cost does not increase
            scale = np.ones(len(th))
            accepted = np.zeros(len(th), dtype=bool)
            state = [th.copy(), cols.copy(), dcols.copy(), x.copy(), b.copy(), r.copy(),
                     cost.copy()]
            for _ in range(5):
                todo = np.flatnonzero(~accepted)
                if todo.size == 0:
                    break
                cand = th[todo] + scale[todo, None] * step[todo]
                c_cols, c_dcols, c_x, c_b, c_r, c_cost = evaluate(yc[todo], cand, lam[todo])
                good = c_cost <= cost[todo] * (1.0 + 1e-12)
                idx = todo[good]
                for arr, new in zip(state, (cand, c_cols, c_dcols, c_x, c_b, c_r, c_cost)):
                    arr[idx] = new[good]
                accepted[idx] = True
                scale[~accepted] *= 0.5
            th, cols, dcols, x, b, r, cost = state
            moved = np.max(np.abs(scale[:, None] * step) * accepted[:, None], axis=1)
            log.debug("GN chunk %d: max step %.3g cycles", lo, moved.max())
            if np.all(moved < tol):
                break
        theta[sl], x_out[sl], beta[sl] = th, x, b
    return theta, x_out, beta
