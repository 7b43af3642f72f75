"""Bernstein polynomials and their tensor products (paper, section 3.3).

``B_i^n(t) = C(n, i) t^i (1 - t)^(n - i)`` for ``i = 0 .. n`` on ``t`` in [0, 1]
(values outside [0, 1] are the same polynomials, extrapolated).  A tensor-product
field is built as the row-wise (Khatri-Rao) product of 1-D bases::

    f(u, v, t) = sum_ijk f_ijk B_i^l(u) B_j^m(v) B_k^n(t)
              = (tensor_basis([B^l(u), B^m(v), B^n(t)]) @ f.ravel())

with ``f`` of shape ``(l + 1, m + 1, n + 1)`` in C order.

:func:`piecewise_bernstein` joins two Bernstein patches at a break point with C0
continuity (they share the control value on the break), the building block of
the split force fields of :mod:`vfcli.model.loads.force_field`.

Examples
--------
>>> import numpy as np
>>> b = bernstein(3, np.array([0.0, 0.5, 1.0]))
>>> b.sum(axis=1).tolist()
[1.0, 1.0, 1.0]
"""
from __future__ import annotations

from math import comb

import numpy as np



def _check_degree(n: int) -> int:
    if int(n) != n or n < 0:
        raise ValueError(f"Bernstein degree must be an integer >= 0, got {n!r}")
    return int(n)


def bernstein(n: int, t: np.ndarray) -> np.ndarray:
    """Values of the n + 1 Bernstein polynomials of degree n.

    Parameters
    ----------
    n : degree (>= 0).
    t : (P,) parameter values (any real; [0, 1] is the patch).

    Returns
    -------
    (P, n + 1) float64, column i is B_i^n(t).
    """
    n = _check_degree(n)
    t = np.asarray(t, dtype=float).ravel()[:, None]
    i = np.arange(n + 1)[None, :]
    coef = np.array([comb(n, k) for k in range(n + 1)], dtype=float)[None, :]
    return coef * t ** i * (1.0 - t) ** (n - i)


def bernstein_derivative(n: int, t: np.ndarray, order: int = 1) -> np.ndarray:
    """Derivatives d^k/dt^k of the degree-n Bernstein polynomials.

    Uses ``d/dt B_i^n = n (B_{i-1}^{n-1} - B_i^{n-1})`` recursively.

    Parameters
    ----------
    n : degree.
    t : (P,) parameter values.
    order : derivative order k >= 0.

    Returns
    -------
    (P, n + 1) float64.
    """
    n = _check_degree(n)
    if order < 0:
        raise ValueError(f"derivative order must be >= 0, got {order!r}")
    t = np.asarray(t, dtype=float).ravel()
    if order == 0:
        return bernstein(n, t)
    if order > n:
        return np.zeros((t.size, n + 1))
    low = bernstein_derivative(n - 1, t, order - 1)  # (P, n)
    out = np.zeros((t.size, n + 1))
    out[:, 1:] += low
    out[:, :-1] -= low
    return n * out


def degree_elevation_matrix(n: int) -> np.ndarray:
    """(n + 1, n + 2) matrix E with ``bernstein(n, t) = bernstein(n + 1, t) @ E.T``.

    ``B_i^n = (n + 1 - i) / (n + 1) B_i^{n+1} + (i + 1) / (n + 1) B_{i+1}^{n+1}``;
    equivalently control values ``c`` of degree n become ``E.T @ c`` of degree n + 1.
    """
    n = _check_degree(n)
    e = np.zeros((n + 1, n + 2))
    i = np.arange(n + 1)
    e[i, i] = (n + 1 - i) / (n + 1)
    e[i, i + 1] = (i + 1) / (n + 1)
    return e


def piecewise_bernstein(n: int, t: np.ndarray, split: float = 0.5, order: int = 0) -> np.ndarray:
    """Two degree-n Bernstein patches on [0, split] and [split, 1], joined C0.

    Each patch is a Bernstein basis in its local parameter (``t / split`` and
    ``(t - split) / (1 - split)``); the last control value of the first patch and
    the first of the second are the same (column n), so every field in this
    basis is continuous at ``split`` while its derivative may jump there.
    Points exactly at ``split`` belong to the first patch (the value is the same).

    Parameters
    ----------
    n : degree of each patch (n + 1 control values per patch).
    t : (P,) parameter values in [0, 1] (outside: the end patches extrapolated).
    split : break point in (0, 1).
    order : derivative order (d^k/dt^k, chain rule included).

    Returns
    -------
    (P, 2 n + 1) float64.
    """
    n = _check_degree(n)
    if not 0.0 < split < 1.0:
        raise ValueError(f"split must be in (0, 1), got {split!r}")
    t = np.asarray(t, dtype=float).ravel()
    first = t <= split
    out = np.zeros((t.size, 2 * n + 1))
    out[first, : n + 1] = bernstein_derivative(n, t[first] / split, order) / split ** order
    w = 1.0 - split
    out[~first, n:] = bernstein_derivative(n, (t[~first] - split) / w, order) / w ** order
    return out


def tensor_basis(bases: list[np.ndarray]) -> np.ndarray:
    """Row-wise tensor (Khatri-Rao) product of 1-D bases evaluated at the same points.

    Parameters
    ----------
    bases : list of (P, n_a) arrays (e.g. ``[bernstein(l, u), bernstein(m, v)]``).

    Returns
    -------
    (P, prod n_a) float64; column ``(i, j, ...)`` in C order is
    ``bases[0][:, i] * bases[1][:, j] * ...``.
    """
    if not bases:
        raise ValueError("tensor_basis needs at least one basis")
    out = np.asarray(bases[0], dtype=float)
    for b in bases[1:]:
        b = np.asarray(b, dtype=float)
        if b.shape[0] != out.shape[0]:
            raise ValueError(f"tensor_basis: bases evaluated at {out.shape[0]} and {b.shape[0]} points")
        out = (out[:, :, None] * b[:, None, :]).reshape(out.shape[0], -1)
    return out


def evaluate_tensor(control: np.ndarray, degrees: tuple[int, ...], coords: list[np.ndarray]) -> np.ndarray:
    """Evaluate ``sum f_ij.. B_i(c0) B_j(c1) ...`` at points.

    control : (l + 1, m + 1, ...) control values.  degrees : (l, m, ...).
    coords : list of (P,) parameter arrays, one per dimension.  Returns (P,).
    """
    c = np.asarray(control, dtype=float)
    if c.shape != tuple(d + 1 for d in degrees) or len(coords) != len(degrees):
        raise ValueError(f"control shape {c.shape} does not match degrees {degrees}")
    return tensor_basis([bernstein(d, x) for d, x in zip(degrees, coords)]) @ c.ravel()
