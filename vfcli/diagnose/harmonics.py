"""Least-squares harmonics of f0 on a phase-locked series: amplitude and phase per harmonic.

A series y sampled at cycle phases phi (cycles) is fitted by
``y ~ c_0 + sum_k a_k cos(2 pi k phi) + b_k sin(2 pi k phi)``, k = 1..K, so that the k-th
harmonic is ``A_k cos(2 pi k phi + theta_k)`` with ``A_k = hypot(a_k, b_k)`` and
``theta_k = atan2(-b_k, a_k)`` (radians).
"""
from __future__ import annotations

import numpy as np


def design(phase: np.ndarray, n_harmonics: int) -> np.ndarray:
    """(M, 1 + 2K) columns 1, cos(2 pi k phi), sin(2 pi k phi) (k = 1..K) at phases (M,) cycles."""
    phi = np.asarray(phase, dtype=float)[:, None] * (2 * np.pi * np.arange(1, n_harmonics + 1))[None, :]
    return np.concatenate([np.ones((phi.shape[0], 1)), np.cos(phi), np.sin(phi)], axis=1)


def fit_harmonics(phase: np.ndarray, y: np.ndarray, n_harmonics: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Harmonic coefficients of the series y at ``phase``.

    Parameters
    ----------
    phase : (M,) cycles.  y : (M, ...) values; NaN rows of a column are left out of that column's fit.
    n_harmonics : K.

    Returns
    -------
    cos, sin : (K, ...) coefficients a_k, b_k (units of y); NaN where a column has fewer than 1 + 2K values.
    scale : (K, ...) mean of the diagonal entries of (X^T X)^-1 for a_k and b_k (1 / samples): the variance of
        a_k, b_k per unit variance of independent noise on y.
    """
    y = np.asarray(y, dtype=float)
    flat = y.reshape(y.shape[0], -1)
    x = design(phase, n_harmonics)
    k = n_harmonics
    cos = np.full((k, flat.shape[1]), np.nan)
    sin = np.full((k, flat.shape[1]), np.nan)
    scale = np.full((k, flat.shape[1]), np.nan)
    ok = np.isfinite(flat)
    patterns: dict[bytes, list[int]] = {}
    for j in range(flat.shape[1]):
        patterns.setdefault(ok[:, j].tobytes(), []).append(j)
    for key, cols in patterns.items():
        rows = ok[:, cols[0]]
        if rows.sum() < x.shape[1] + 1:
            continue
        xr = x[rows]
        gram_inv = np.linalg.pinv(xr.T @ xr)
        coef = gram_inv @ (xr.T @ flat[rows][:, cols])
        cos[:, cols] = coef[1:1 + k]
        sin[:, cols] = coef[1 + k:]
        d = np.diag(gram_inv)
        scale[:, cols] = (0.5 * (d[1:1 + k] + d[1 + k:]))[:, None]
    shape = (k,) + y.shape[1:]
    return cos.reshape(shape), sin.reshape(shape), scale.reshape(shape)
