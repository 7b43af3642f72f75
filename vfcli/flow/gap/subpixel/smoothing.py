"""Smoothing of sub-pixel edges along the glottis (and in time), with robustness weights.

Edges are (n_rays,) or (n_frames, n_rays) arrays of lateral px, NaN on closed rays; the
smoothing is a tricube-weighted local fit over neighbouring open rays (and frames).
"""
from __future__ import annotations

import numpy as np

#: Smallest robustness scale of the edge smoothing (median absolute residual), px: edges
#: that agree with their neighbours to a hundredth of a pixel are never outliers.
ROBUST_FLOOR_PX = 0.01


def _tricube(d: np.ndarray, h: int) -> np.ndarray:
    return (1.0 - (np.abs(d) / (h + 1.0)) ** 3) ** 3


def _run_labels(ok: np.ndarray) -> np.ndarray:
    """Label of each run of equal values of a (n,) bool array (consecutive rays)."""
    return np.cumsum(np.concatenate([[1], (ok[1:] != ok[:-1]).astype(int)]))


def smooth_edges(
    edges: np.ndarray,
    half_window: float,
    *,
    centre: int | None = None,
    half_window_frames: int = 0,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Smooth one frame's edge along the glottis and, optionally, over neighbouring frames.

    The edge of ray c in the centre frame is replaced by the value at (c, centre) of a
    surface fitted by weighted least squares to the edges of rays ``c - h .. c + h`` in
    frames ``centre - h_t .. centre + h_t``: quadratic along the glottis, linear in time
    (``1, dc, dc^2, dt, dc dt``; LOESS, Cleveland & Devlin 1988). Weights are tricube in
    both distances times ``weights`` (robustness, see :func:`robustness_weights`); only
    rays of the same run of open rays as c in the centre frame enter (a closed ray
    separates two openings). Where a window holds too few rays the degree drops.

    Parameters
    ----------
    edges : (n_rays,) or (k, n_rays) float
        Edge per ray of one frame or of k consecutive frames, lateral px; NaN on closed rays.
    half_window : float
        Half-width h of the window along the glottis, rays (px); below 1 with
        ``half_window_frames = 0`` returns the centre frame's edges unchanged.
    centre : int, optional
        Index of the output frame in the stack (default: the middle one).
    half_window_frames : int
        Half-width h_t of the window in time, frames (0: this frame only).
    weights : same shape as ``edges``, optional
        Per-ray weights in [0, 1] (default 1).

    Returns
    -------
    (n_rays,) float
        Smoothed edges of the centre frame; NaN where its edge is NaN.
    """
    e = np.asarray(edges, dtype=float)
    if e.ndim == 1:
        e = e[None]
    k, n = e.shape
    j0 = k // 2 if centre is None else int(centre)
    rob = np.ones_like(e) if weights is None else np.asarray(weights, dtype=float).reshape(e.shape)
    h = int(np.floor(half_window))
    ht = int(half_window_frames)
    own = e[j0]
    ok0 = np.isfinite(own)
    if (h < 1 and ht < 1) or not ok0.any():
        return own.copy()
    frames = np.arange(max(0, j0 - ht), min(k, j0 + ht + 1))
    offs = np.arange(-h, h + 1)
    col = np.arange(n)[:, None] + offs[None, :]                    # (n, 2h+1)
    inside = (col >= 0) & (col < n)
    col = np.clip(col, 0, n - 1)
    run = _run_labels(ok0)
    same = inside & ok0[col] & (run[col] == run[:, None])           # same open run in the centre frame
    dt = (frames - j0).astype(float)
    vals = e[frames][:, col]                                        # (f, n, 2h+1)
    wts = rob[frames][:, col] * np.isfinite(vals) * same[None]
    wts = wts * _tricube(offs, h)[None, None, :] * _tricube(dt, ht)[:, None, None]
    vals = np.where(wts > 0, vals, 0.0)
    dc = np.broadcast_to(offs / (h + 1.0), wts.shape)  # scaled to about [-1, 1]: a well-conditioned basis
    dtt = np.broadcast_to(dt[:, None, None] / (ht + 1.0), wts.shape)
    basis = [np.ones_like(dc), dc, dc * dc]
    if len(frames) > 1:
        basis += [dtt, dc * dtt]
    p_all = len(basis)
    b = np.stack(basis, axis=-1).transpose(1, 0, 2, 3).reshape(n, -1, p_all)  # (n, f (2h+1), p)
    wb = b * wts.transpose(1, 0, 2).reshape(n, -1)[..., None]
    lhs = wb.transpose(0, 2, 1) @ b
    rhs = (wb.transpose(0, 2, 1) @ vals.transpose(1, 0, 2).reshape(n, -1, 1))[..., 0]
    count = (wts > 0).sum(axis=(0, 2))
    out = np.full(n, np.nan)
    # fall back to fewer terms where the window cannot support them
    for p in sorted({p_all, 3, 2, 1}, reverse=True):
        sub = lhs[:, :p, :p]
        scale = np.maximum(np.einsum("nii->n", sub), 1e-300) ** p
        good = np.isnan(out) & ok0 & (count > p) & (np.abs(np.linalg.det(sub)) > 1e-10 * scale)
        if p == 1:
            good = np.isnan(out) & ok0 & (lhs[:, 0, 0] > 0)
        if good.any():
            out[good] = np.linalg.solve(sub[good], rhs[good, :p, None])[:, 0, 0]
    return np.where(ok0 & np.isfinite(out), out, own)


def robustness_weights(edge: np.ndarray, half_window: float, iterations: int = 2) -> np.ndarray:
    """Bisquare robustness weights of one frame's edge against its own smooth curve.

    The edge is smoothed along the glottis (:func:`smooth_edges`, this frame only); rays
    whose residual is large get a small weight, ``(1 - (r / 6 MAD)^2)^2`` (Cleveland
    1979: LOWESS robustness), e.g. where a dark mark next to the gap pulled the edge out.
    Repeated ``iterations`` times with the weights found.

    Parameters
    ----------
    edge : (n_rays,) float
        Edge per ray, lateral px; NaN on closed rays.
    half_window : float
        Half-width of the window along the glottis, rays.
    iterations : int

    Returns
    -------
    (n_rays,) float in [0, 1]; 0 on closed rays.
    """
    e = np.asarray(edge, dtype=float)
    ok = np.isfinite(e)
    w = ok.astype(float)
    for _ in range(iterations):
        resid = np.abs(e - smooth_edges(e, half_window, weights=w))
        # residuals below a hundredth of a pixel are never outliers (and keep the scale off zero)
        scale = 6.0 * max(float(np.median(resid[ok])), ROBUST_FLOOR_PX) if ok.any() else 0.0
        if not scale > 0:
            break
        u = np.clip(np.nan_to_num(resid / scale), 0.0, 1.0)
        w = np.where(ok, (1.0 - u * u) ** 2, 0.0)
    return w
