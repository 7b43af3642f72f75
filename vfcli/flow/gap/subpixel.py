"""Sub-pixel edges of the glottal gap: per-ray blurred-slit fits, smoothing, mask and area.

A binary mask can only be as good as the pixels it is cut from; :func:`segment_stream`
(used by ``vfcli flow`` unless ``flow.subpixel_edges`` is off) keeps the paper's
segmentation (:mod:`vfcli.flow.gap.detect`) as the detector and places the edges to a fraction of a
pixel: on every image line across the glottis (ray) it fits the blurred "tissue - gap -
tissue" profile (:func:`fit_slit_profiles`; gap level and blur measured once per recording,
:func:`estimate_edge_model`), smooths the edges along the glottis and in time
(:func:`smooth_edges`), and takes the pixels whose centres lie between them; the glottal area
is the integral of the edge distance (:func:`area_from_edges`).
"""
from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from vfcli.flow.gap.detect import gap_mask

log = logging.getLogger(__name__)


# ---- sub-pixel edges ----------------------------------------------------------------------
#
# A binary mask can only be as good as the pixels it is cut from: on a slit a few pixels wide,
# a threshold that misplaces each edge by a fraction of a pixel costs a large share of the gap.
# The image itself holds the edges to a fraction of a pixel: across the glottis (along one
# ray) it is the blurred profile of "tissue - gap - tissue". The functions below fit that
# profile per ray, smooth the edge positions along the glottis, and cut the mask at the
# sub-pixel edges (pixel centres strictly between them), the area from the edge distances.

#: Prior weight of the recording's gap level in each ray's fit, in pixels' worth of data:
#: one observation. It pins the gap level on a slit too narrow to show it (a 1 px slit
#: blurred by the optics never reaches the gap level) and is outweighed on a wide one.
GAP_LEVEL_WEIGHT = 1.0

#: Half-width of the fit window outside each edge, in PSF standard deviations. The tissue
#: model (a straight ramp) is a first-order expansion of the tissue's brightness about the
#: edge, so the window should be as short as still shows the whole blurred step: at 2 sigma
#: the step is within 2.3 % of its height (1 - Phi(2)), below the noise of a high-speed camera
#: at SNR 40 (60 counts on a 12-bit surface level of 2400) for any step the image can hold;
#: beyond, the tissue's own shading and texture, not the edge, would shape the fit.
WINDOW_SIGMAS = 2.0

#: The same for the PSF search (:func:`estimate_edge_model`): there the blur itself is
#: fitted, so the window holds the step's tails too (to 0.13 %).
PSF_WINDOW_SIGMAS = 3.0

#: Smallest robustness scale of the edge smoothing (median absolute residual), px: edges
#: that agree with their neighbours to a hundredth of a pixel are never outliers.
ROBUST_FLOOR_PX = 0.01

#: Range and resolution of the PSF search (:func:`estimate_edge_model`), px.
PSF_SIGMA_RANGE_PX = (0.2, 3.0)


@dataclass(frozen=True)
class EdgeModel:
    """What the sub-pixel edge fit needs to know about a recording's images.

    Attributes
    ----------
    gap_counts : float
        Intensity of the open gap (the channel seen through it), counts.
    psf_sigma_px : float
        Standard deviation of the Gaussian that models the blur of optics and pixel, px.
    """

    gap_counts: float
    psf_sigma_px: float


@dataclass(frozen=True)
class SlitFit:
    """Per-ray result of :func:`fit_slit_profiles` (n rays).

    Attributes
    ----------
    e0, e1 : (n,) float
        Sub-pixel edges, lateral px (pixel centres at integers): the gap is ``e0 < r < e1``.
    levels : (n, 5) float
        Linear parameters ``[G, T0, s0, T1, s1]``: gap level (counts), tissue level at
        each edge (counts) and the tissue's brightening away from the edge (counts/px).
    rms : (n,) float
        RMS residual of the fit, counts.
    cost : (n,) float
        Sum of squared residuals plus the gap-level prior term, counts^2.
    """

    e0: np.ndarray
    e1: np.ndarray
    levels: np.ndarray
    rms: np.ndarray
    cost: np.ndarray


def _phi(z: np.ndarray) -> np.ndarray:
    return np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)


def _slit_basis(rows: np.ndarray, e0: np.ndarray, e1: np.ndarray, sigma: float):
    """Basis (n, L, 5) of the blurred slit model and the normalised distances to the edges."""
    from scipy.special import ndtr

    za = (e0[:, None] - rows) / sigma
    zb = (rows - e1[:, None]) / sigma
    pa, pb = ndtr(za), ndtr(zb)
    ra = za * pa + _phi(za)
    rb = zb * pb + _phi(zb)
    basis = np.stack([1.0 - pa - pb, pa, sigma * ra, pb, sigma * rb], axis=-1)
    return basis, za, zb, pa, pb


def slit_profile_model(rows: np.ndarray, e0: float, e1: float, levels, sigma: float) -> np.ndarray:
    """Intensity of the blurred slit model at lateral positions ``rows`` (see :func:`fit_slit_profiles`).

    Parameters
    ----------
    rows : (L,) float
        Lateral positions, px.
    e0, e1 : float
        Edges, px (``e0 < e1``).
    levels : (5,) float
        ``[G, T0, s0, T1, s1]`` (counts, counts, counts/px, counts, counts/px).
    sigma : float
        PSF standard deviation, px.

    Returns
    -------
    (L,) float, counts.
    """
    basis, *_ = _slit_basis(np.asarray(rows, float)[None], np.array([e0], float), np.array([e1], float), sigma)
    return basis[0] @ np.asarray(levels, float)


def _slit_levels(data: tuple, e0: np.ndarray, e1: np.ndarray):
    """Linear levels of the slit model for fixed edges: (levels (n, 5), weighted residuals (n, L),
    cost (n,), (z0, z1, P0, P1, weighted basis (n, L, 5), normal matrix (n, 5, 5)))."""
    r, y, w, sw, sigma, gap_counts, gap_weight, ridge = data
    basis, za, zb, pa, pb = _slit_basis(r, e0, e1, sigma)
    bt = (basis * w[..., None]).transpose(0, 2, 1)
    lhs = bt @ basis
    rhs = (bt @ y[..., None])[..., 0]
    lhs[:, 0, 0] += gap_weight
    rhs[:, 0] += gap_weight * gap_counts
    lhs += (ridge * np.einsum("nii->n", lhs))[:, None, None] * np.eye(5)  # numerical safety only
    x = np.linalg.solve(lhs, rhs[..., None])[..., 0]
    res = ((basis @ x[..., None])[..., 0] - y) * sw
    cost = (res**2).sum(axis=1) + gap_weight * (x[:, 0] - gap_counts) ** 2
    return x, res, cost, (za, zb, pa, pb, basis * sw[..., None], lhs)


def fit_slit_profiles(
    profiles: np.ndarray,
    rows: np.ndarray,
    e0: np.ndarray,
    e1: np.ndarray,
    sigma: float,
    gap_counts: float,
    *,
    gap_weight: float = GAP_LEVEL_WEIGHT,
    iterations: int = 20,
    closed: bool = False,
    inner: tuple[np.ndarray, np.ndarray] | None = None,
) -> SlitFit:
    """Sub-pixel edges of the gap on many rays at once: least squares fit of a blurred slit.

    Along a ray (lateral position r, px) the scene is tissue of fold 0 up to the edge
    ``e0``, the gap (level G) up to ``e1``, then tissue of fold 1. Next to the gap the
    tissue is the fold's medial surface seen at a slant, darker than the top surface and
    brightening away from the edge, so each side is a ramp ``T + s * distance``. The
    camera blurs this with its point spread function, modelled as a Gaussian of standard
    deviation ``sigma`` (optics and pixel integration together)::

        I(r) = G (1 - P0 - P1) + T0 P0 + s0 sigma rho(z0) + T1 P1 + s1 sigma rho(z1)
        z0 = (e0 - r) / sigma, z1 = (r - e1) / sigma, P = Phi(z), rho(z) = z Phi(z) + phi(z)

    (Phi, phi: standard normal CDF and density). At a blurred step the edge is where the
    intensity is half-way between the levels on either side; the fit finds that point
    for each edge while accounting for the other edge's blur (narrow slits), the ramps and
    noise. The model is linear in ``[G, T0, s0, T1, s1]``, which are eliminated (variable
    projection); the two edges are found by Levenberg-Marquardt. G has a Gaussian prior
    at ``gap_counts`` worth ``gap_weight`` pixels.

    Parameters
    ----------
    profiles : (n, L) float
        Intensities, counts; NaN where a ray's window has no sample.
    rows : (n, L) float
        Lateral position of each sample, px.
    e0, e1 : (n,) float
        Initial edges, px (within a pixel or so of the answer).
    sigma : float
        PSF standard deviation, px.
    gap_counts : float
        Prior gap level, counts.
    gap_weight : float
        Weight of that prior, in samples.
    iterations : int
        Levenberg-Marquardt iterations.
    closed : bool
        Fit the model without a gap instead: ``e0 = e1`` (the two folds' tissue meeting
        at one line, e.g. a closed glottis's contact line), starting from ``(e0 + e1) / 2``.
    inner : ((n,) float, (n,) float), optional
        Bounds ``e0 <= inner[0]`` and ``e1 >= inner[1]``, px: positions known to lie in
        the gap (e.g. the outermost pixel centres darker than the threshold).

    Returns
    -------
    SlitFit
        Edges are kept inside the window of each ray; ``e1 <= e0`` means no gap.
    """
    y = np.asarray(profiles, dtype=float)
    r = np.asarray(rows, dtype=float)
    ok = np.isfinite(y)
    w = ok.astype(float)
    sw = np.sqrt(w)
    y = np.where(ok, y, 0.0)
    n = len(y)
    e0 = np.asarray(e0, dtype=float).copy()
    e1 = np.asarray(e1, dtype=float).copy()
    if n == 0:
        return SlitFit(e0, e1, np.zeros((0, 5)), np.zeros(0), np.zeros(0))
    if closed:
        e0 = e1 = 0.5 * (e0 + e1)
    lo = np.where(ok, r, np.inf).min(axis=1)
    hi = np.where(ok, r, -np.inf).max(axis=1)
    hi0, lo1 = hi, lo  # bounds of e0 from above and of e1 from below
    if inner is not None and not closed:
        hi0 = np.minimum(hi, np.asarray(inner[0], float))
        lo1 = np.maximum(lo, np.asarray(inner[1], float))
        e0, e1 = np.minimum(e0, hi0), np.maximum(e1, lo1)
    ridge = 1e-12

    x, res, cost, aux = _slit_levels((r, y, w, sw, sigma, gap_counts, gap_weight, ridge), e0, e1)
    aux = list(aux)
    damping = np.full(n, 1e-3)
    act = np.arange(n)  # rays still moving
    for _ in range(iterations):
        if act.size == 0:
            break
        za, zb, pa, pb, bw, lhs = (v[act] for v in aux)
        swa, xa = sw[act], x[act]
        g_lvl, t0, s0, t1, s1 = xa.T
        d0 = ((t0 - g_lvl)[:, None] * _phi(za) / sigma + s0[:, None] * pa) * swa
        d1 = (-(t1 - g_lvl)[:, None] * _phi(zb) / sigma - s1[:, None] * pb) * swa
        jac = (d0 + d1)[..., None] if closed else np.stack([d0, d1], axis=-1)
        # variable projection (Kaufman): the Jacobian of the residual with the levels re-solved
        # is the edge derivative projected off the basis (the prior on G is one more row)
        c = np.linalg.solve(lhs, bw.transpose(0, 2, 1) @ jac)          # (m, 5, k)
        jac = jac - bw @ c
        prior_row = -np.sqrt(gap_weight) * c[:, :1, :]                  # (m, 1, k)
        prior_res = (np.sqrt(gap_weight) * (xa[:, 0] - gap_counts))[:, None]
        jt = jac.transpose(0, 2, 1)
        jtj = jt @ jac + prior_row.transpose(0, 2, 1) @ prior_row
        grad = (jt @ res[act][..., None])[..., 0] + (prior_row.transpose(0, 2, 1) @ prior_res[..., None])[..., 0]
        diag = np.einsum("nii->ni", jtj) + 1e-12
        eye = np.eye(jac.shape[-1])
        damp = damping[act]
        step = -np.linalg.solve(jtj + damp[:, None, None] * (diag[:, :, None] * eye), grad[..., None])[..., 0]
        step = np.clip(step, -0.5, 0.5)
        a = np.clip(e0[act] + step[:, 0], lo[act], hi0[act])
        b = a if closed else np.clip(e1[act] + step[:, 1], lo1[act], hi[act])
        sub = (r[act], y[act], w[act], swa, sigma, gap_counts, gap_weight, ridge)
        nx, nres, ncost, naux = _slit_levels(sub, a, b)
        better = ncost < cost[act]
        damping[act] = np.where(better, damp * 0.3, damp * 10.0)
        upd = act[better]
        e0[upd], e1[upd], x[upd], res[upd], cost[upd] = a[better], b[better], nx[better], nres[better], ncost[better]
        for v, nv in zip(aux, naux):
            v[upd] = nv[better]
        done = (better & (np.abs(step).max(axis=1) < 1e-3)) | (damping[act] > 1e6)
        act = act[~done]
    rms = np.sqrt((res**2).sum(axis=1) / np.maximum(ok.sum(axis=1), 1.0))
    return SlitFit(e0, e1, x, rms, cost)


def _rays(frame: np.ndarray, lateral_axis: int) -> np.ndarray:
    """(n_lateral, n_rays) view of a frame: one column per ray."""
    if lateral_axis not in (0, 1):
        raise ValueError(f"gap: lateral_axis must be 0 (rows) or 1 (columns), got {lateral_axis}")
    a = np.asarray(frame)
    return a if lateral_axis == 0 else a.T


def ray_windows(
    frame: np.ndarray, e0: np.ndarray, e1: np.ndarray, margin_px: int, lateral_axis: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Intensity profiles across the gap, one per ray: from ``margin_px`` before ``e0`` to after ``e1``.

    Parameters
    ----------
    frame : (H, W) array of counts
    e0, e1 : (n_rays,) float
        Edges per ray, lateral px; NaN on rays without a gap (their profile is all NaN).
    margin_px : int
        Pixels taken beyond each edge.
    lateral_axis : {0, 1}

    Returns
    -------
    profiles : (n_rays, L) float, counts (NaN outside the window or the image)
    rows : (n_rays, L) float, lateral position of each sample, px
    """
    img = _rays(frame, lateral_axis)
    n_lat, n_rays = img.shape
    open_ = np.isfinite(e0) & np.isfinite(e1)
    a, b = np.nan_to_num(np.minimum(e0, e1)), np.nan_to_num(np.maximum(e0, e1))
    lo = np.where(open_, np.floor(a) - margin_px, 0).astype(int)
    hi = np.where(open_, np.ceil(b) + margin_px, -1).astype(int)
    length = int(max((hi - lo + 1).max(initial=1), 1))
    rows = lo[:, None] + np.arange(length)[None, :]
    inside = (rows <= hi[:, None]) & (rows >= 0) & (rows < n_lat)
    vals = img[np.clip(rows, 0, n_lat - 1), np.arange(n_rays)[:, None]].astype(float)
    return np.where(inside, vals, np.nan), rows.astype(float)


def runs_from_mask(mask: np.ndarray, lateral_axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Outermost silhouette of a binary gap mask per ray, lateral px (pixel edges).

    Parameters
    ----------
    mask : (H, W) bool
    lateral_axis : {0, 1}

    Returns
    -------
    e0, e1 : (n_rays,) float
        ``first gap pixel - 0.5`` and ``last gap pixel + 0.5``; NaN on rays without gap.
    """
    m = _rays(mask, lateral_axis).astype(bool)
    has = m.any(axis=0)
    first = np.argmax(m, axis=0)
    last = m.shape[0] - 1 - np.argmax(m[::-1], axis=0)
    return np.where(has, first - 0.5, np.nan), np.where(has, last + 0.5, np.nan)


def fit_ray_edges(
    frame: np.ndarray, e0: np.ndarray, e1: np.ndarray, model: EdgeModel, lateral_axis: int = 0, passes: int = 2
) -> SlitFit:
    """Sub-pixel edges of every open ray of one frame, starting from a threshold mask's edges.

    The window of each ray reaches :data:`WINDOW_SIGMAS` PSF widths beyond its edges;
    after each pass it is re-centred on the edges found. The edges are kept at or beyond
    the outermost pixel centres of the rough run: those pixels are darker than the
    threshold, which lies at most half-way between gap and tissue (as the automatic one
    does), so their centres are in the gap.

    Parameters
    ----------
    frame : (H, W) array of counts
    e0, e1 : (n_rays,) float
        Pixel boundaries of the threshold mask's run on each ray (:func:`runs_from_mask`),
        lateral px; NaN on closed rays.
    model : EdgeModel
    lateral_axis : {0, 1}
    passes : int
        Window placements.

    Returns
    -------
    SlitFit over all rays (NaN edges on rays that were NaN on input).
    """
    margin = int(np.ceil(WINDOW_SIGMAS * model.psf_sigma_px))
    e0 = np.asarray(e0, float).copy()
    e1 = np.asarray(e1, float).copy()
    sel = np.flatnonzero(np.isfinite(e0) & np.isfinite(e1))
    # the rough run's outermost pixels are darker than the threshold, which lies at most half-way
    # between gap and tissue: their centres are in the gap, so the edges lie at or beyond them
    inner = (e0[sel] + 0.5, e1[sel] - 0.5)
    levels = np.full((len(e0), 5), np.nan)
    rms = np.full(len(e0), np.nan)
    cost = np.full(len(e0), np.nan)
    for _ in range(max(1, passes)):
        prof, rows = ray_windows(frame, e0, e1, margin, lateral_axis)
        fit = fit_slit_profiles(prof[sel], rows[sel], e0[sel], e1[sel], model.psf_sigma_px, model.gap_counts,
                                inner=inner)
        e0[sel], e1[sel] = fit.e0, fit.e1
        levels[sel], rms[sel], cost[sel] = fit.levels, fit.rms, fit.cost
    return SlitFit(e0, e1, levels, rms, cost)


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


def mask_from_edges(e0: np.ndarray, e1: np.ndarray, shape: tuple[int, int], lateral_axis: int = 0) -> np.ndarray:
    """Gap mask of the pixels whose centres lie strictly between the edges of their ray.

    Parameters
    ----------
    e0, e1 : (n_rays,) float
        Edges per ray, lateral px (pixel centres at integers); NaN on closed rays.
    shape : (H, W)
    lateral_axis : {0, 1}

    Returns
    -------
    (H, W) bool
    """
    n_lat = shape[lateral_axis]
    pos = np.arange(n_lat, dtype=float)[:, None]
    ok = (np.isfinite(e0) & np.isfinite(e1))[None, :]
    m = ok & (pos > np.nan_to_num(e0, nan=np.inf)[None, :]) & (pos < np.nan_to_num(e1, nan=-np.inf)[None, :])
    return m if lateral_axis == 0 else np.ascontiguousarray(m.T)


def area_from_edges(e0: np.ndarray, e1: np.ndarray, px_per_mm: float) -> float:
    """Glottal area from sub-pixel edges, mm^2: sum over rays of the gap's width (1 px per ray).

    Parameters
    ----------
    e0, e1 : (n_rays,) float
        Edges per ray, lateral px; NaN on closed rays.
    px_per_mm : float
        Image scale, px/mm.

    Returns
    -------
    float
    """
    if px_per_mm <= 0:
        raise ValueError(f"glottal area: px_per_mm must be positive, got {px_per_mm}")
    width = np.nan_to_num(np.asarray(e1, float) - np.asarray(e0, float), nan=0.0)
    return float(np.maximum(width, 0.0).sum() / float(px_per_mm) ** 2)


def estimate_edge_model(
    frames_sample: np.ndarray, masks: np.ndarray, lateral_axis: int = 0, *, min_width_px: float = 3.0, max_rays: int = 1000
) -> EdgeModel | None:
    """Gap level and PSF width of a recording, measured on sampled frames and their rough masks.

    * Gap level: median intensity of the mask pixels whose two lateral neighbours are in
      the mask too (the gap's interior, away from the blurred edges).
    * PSF width: the sigma that minimises the pooled residual of :func:`fit_slit_profiles`
      over the rays where the rough gap is at least ``min_width_px`` wide (on narrower
      slits blur and width cannot be told apart); a log-spaced search over
      :data:`PSF_SIGMA_RANGE_PX` refined by a parabola, with a window of 3 px beyond each
      edge, widened to :data:`PSF_WINDOW_SIGMAS` sigmas if the PSF turns out wider.

    Parameters
    ----------
    frames_sample : (k, H, W) array of counts
    masks : (k, H, W) bool
        Rough gap masks of those frames (e.g. :func:`gap_mask`).
    lateral_axis : {0, 1}
    min_width_px : float
        Narrowest rough gap used for the PSF, px.
    max_rays : int
        At most this many rays (spread evenly) enter the PSF search.

    Returns
    -------
    EdgeModel, or None when the sample shows no gap at least ``min_width_px`` wide
    (nothing to measure the blur on).
    """
    frames = np.asarray(frames_sample)
    m = np.asarray(masks, dtype=bool)
    if frames.ndim == 2:
        frames, m = frames[None], m[None]
    if frames.shape != m.shape:
        raise ValueError(f"edge model: frames {frames.shape} and masks {m.shape} differ")
    if not m.any():
        return None
    lat = 1 + lateral_axis  # lateral axis of the (k, H, W) stack
    interior = m & np.roll(m, 1, axis=lat) & np.roll(m, -1, axis=lat)
    pixels = frames[interior] if interior.sum() >= 16 else frames[m]
    gap_counts = float(np.median(pixels))
    rays = []
    for f, mk in zip(frames, m):
        e0, e1 = runs_from_mask(mk, lateral_axis)
        wide = np.isfinite(e0) & (e1 - e0 >= min_width_px)
        if wide.any():
            rays.append((f, np.where(wide, e0, np.nan), np.where(wide, e1, np.nan)))
    if not rays:
        log.warning("edge model: the sampled gap is never %.0f px wide, too narrow to measure the blur on; "
                    "no sub-pixel edges", min_width_px)
        return None

    def collect(margin: int):
        windows = [ray_windows(f, e0, e1, margin, lateral_axis) + (e0, e1) for f, e0, e1 in rays]
        width = max(p.shape[1] for p, *_ in windows)
        prof, rows, a, b = [], [], [], []
        for p, r, e0, e1 in windows:
            sel = np.isfinite(e0)
            pad = ((0, 0), (0, width - p.shape[1]))
            prof.append(np.pad(p[sel], pad, constant_values=np.nan))
            rows.append(np.pad(r[sel], pad, constant_values=0.0))
            a.append(e0[sel])
            b.append(e1[sel])
        prof, rows, a, b = (np.concatenate(v) for v in (prof, rows, a, b))
        take = np.unique(np.linspace(0, len(prof) - 1, min(len(prof), max_rays)).astype(int))
        return prof[take], rows[take], a[take], b[take]

    def search(margin: int) -> float:
        prof, rows, a, b = collect(margin)

        def cost(s: float) -> float:
            fit = fit_slit_profiles(prof, rows, a, b, s, gap_counts, inner=(a + 0.5, b - 0.5))
            return float(np.sum(fit.rms**2))

        grid = np.geomspace(*PSF_SIGMA_RANGE_PX, 13)  # steps of 25 %
        k = int(np.argmin([cost(s) for s in grid]))
        fine = np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 9)  # steps of about 5 %
        values = np.array([cost(s) for s in fine])
        k = int(np.argmin(values))
        if 0 < k < len(fine) - 1:  # parabola through the three lowest points, in log sigma
            x = np.log(fine[k - 1 : k + 2])
            c = np.polyfit(x, values[k - 1 : k + 2], 2)
            if c[0] > 0:
                return float(np.exp(np.clip(-c[1] / (2 * c[0]), x[0], x[2])))
        return float(fine[k])

    sigma = search(3)
    if np.ceil(PSF_WINDOW_SIGMAS * sigma) > 3:
        sigma = search(int(np.ceil(PSF_WINDOW_SIGMAS * sigma)))
    return EdgeModel(gap_counts, sigma)


@dataclass(frozen=True)
class GapSegmentation:
    """The gap of one frame (:func:`segment_gap`, :func:`segment_stream`).

    Attributes
    ----------
    mask : (H, W) bool
        Pixels whose centres lie strictly between the sub-pixel edges of their ray.
    e0, e1 : (n_rays,) float
        Sub-pixel edges per ray, lateral px (pixel centres at integers); NaN on closed rays.
    """

    mask: np.ndarray
    e0: np.ndarray
    e1: np.ndarray

    def area_mm2(self, px_per_mm: float) -> float:
        """Glottal area from the sub-pixel edges, mm^2 (:func:`area_from_edges`)."""
        return area_from_edges(self.e0, self.e1, px_per_mm)


@dataclass(frozen=True)
class SubpixelGap:
    """Settings of the sub-pixel gap segmentation of one recording.

    Attributes
    ----------
    threshold : float
        Gap threshold, counts (:func:`gap_threshold` or ``flow.threshold``).
    model : EdgeModel or None
        Gap level and PSF (:func:`estimate_edge_model`); None: the detection mask alone.
    median_px : int
        Median window of the detection, px (odd).
    midline : float, optional
        Lateral coordinate of the glottal midline, px.
    lateral_axis : {0, 1}
    half_window_px : float
        Half-window of the edge smoothing along the glottis, px (0: none).
    half_window_frames : int
        Half-window of the edge smoothing in time, frames (0: none).
    """

    threshold: float
    model: EdgeModel | None
    median_px: int = 5
    midline: float | None = None
    lateral_axis: int = 0
    half_window_px: float = 0.0
    half_window_frames: int = 0


def raw_edges(frame: np.ndarray, gap: SubpixelGap) -> tuple[np.ndarray, np.ndarray]:
    """Detection and per-ray sub-pixel edges of one frame, before smoothing.

    1. Detection, the paper's intensity segmentation (:func:`gap_mask`): pixels darker
       than the threshold, median-filtered along the glottis (``median_along_slit``, so
       a one-pixel slit survives), dark components on the midline of at least
       ``median_px`` pixels.
    2. Sub-pixel edges on every ray the detection crosses (:func:`fit_ray_edges`); a ray
       whose fitted edges cross (width <= 0) is closed. Without a model, the detection's
       pixel boundaries.
    3. A detected component is kept only if (a) at least ``median_px`` of its rays hold a
       slit of one pixel or more: a narrower blurred dip cannot be told from a dark line
       of tissue (the contact line of a closed glottis), and a slit under a pixel wide
       holds a pixel centre only by chance; (b) its fitted gap level (median over its
       rays) is nearer the recording's gap level than the threshold: a dark patch of
       tissue below the threshold is fitted with its own, brighter level. This replaces
       the dark-core hysteresis of :func:`gap_mask`, whose core a narrow, blurred slit
       never reaches.

    Parameters
    ----------
    frame : (H, W) array of counts
    gap : SubpixelGap

    Returns
    -------
    e0, e1 : (n_rays,) float
        Lateral px; NaN on closed rays.
    """
    rough = gap_mask(frame, gap.threshold, gap.median_px, core_fraction=1.0, midline=gap.midline,
                     min_area_px=gap.median_px, lateral_axis=gap.lateral_axis, median_along_slit=True)
    e0, e1 = runs_from_mask(rough, gap.lateral_axis)
    if gap.model is None or not np.isfinite(e0).any():
        return e0, e1
    fit = fit_ray_edges(frame, e0, e1, gap.model, gap.lateral_axis)
    e0, e1 = fit.e0.copy(), fit.e1.copy()
    closed = ~(e1 > e0)
    # step 3: whole components (a) surely open somewhere and (b) at the gap's level
    component = _ray_components(rough, gap.lateral_axis)
    n_comp = int(component.max()) + 1
    wide = np.bincount(component, weights=(e1 - e0 >= 1.0) & ~closed, minlength=n_comp)
    level = np.full(n_comp, np.inf)
    for c in np.unique(component[~closed & (component > 0)]):
        level[c] = np.median(fit.levels[(component == c) & ~closed, 0])
    dark = level < 0.5 * (gap.model.gap_counts + gap.threshold)
    closed |= (component == 0) | (wide[component] < gap.median_px) | ~dark[component]
    e0[closed] = np.nan
    e1[closed] = np.nan
    return e0, e1


def _ray_components(mask: np.ndarray, lateral_axis: int) -> np.ndarray:
    """(n_rays,) int: the 8-connected component of ``mask`` met first along each ray, 0 if none."""
    import cv2

    _, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    lab = _rays(labels, lateral_axis)
    first = np.argmax(lab > 0, axis=0)
    return lab[first, np.arange(lab.shape[1])]


def _segmentation(shape, e0, e1, lateral_axis) -> GapSegmentation:
    return GapSegmentation(mask_from_edges(e0, e1, shape, lateral_axis), e0, e1)


def segment_gap(frame: np.ndarray, gap: SubpixelGap) -> GapSegmentation:
    """The glottal gap of one frame with sub-pixel edges, smoothed along the glottis only.

    :func:`raw_edges`, then :func:`smooth_edges` with robustness weights
    (:func:`robustness_weights`), then the mask of the pixel centres strictly between the
    edges (the way a pixel-centre truth is defined); the area is the sum of the edge
    distances (:meth:`GapSegmentation.area_mm2`). :func:`segment_stream` adds the
    smoothing in time.

    Parameters
    ----------
    frame : (H, W) array of counts
    gap : SubpixelGap

    Returns
    -------
    GapSegmentation
    """
    e0, e1 = raw_edges(frame, gap)
    if gap.model is not None:
        h = gap.half_window_px
        e0 = smooth_edges(e0, h, weights=robustness_weights(e0, h))
        e1 = smooth_edges(e1, h, weights=robustness_weights(e1, h))
    return _segmentation(np.shape(frame), e0, e1, gap.lateral_axis)


def segment_stream(frames: Iterable[np.ndarray], gap: SubpixelGap) -> Iterator[tuple[np.ndarray, GapSegmentation]]:
    """Stream the sub-pixel gap over a video: (frame, its GapSegmentation), in order.

    Each frame's raw edges (:func:`raw_edges`) and robustness weights are kept for
    ``2 * half_window_frames + 1`` frames, so a frame is yielded once the
    ``half_window_frames`` frames after it have been read (at the end of the video the
    window is one-sided); memory does not grow with the number of frames.

    Parameters
    ----------
    frames : iterable of (H, W) arrays of counts
    gap : SubpixelGap

    Yields
    ------
    (frame, GapSegmentation)
    """
    ht = max(0, int(gap.half_window_frames)) if gap.model is not None else 0
    h = gap.half_window_px
    window: deque = deque()  # (frame, e0, e1, w0, w1) of the frames not yet yielded and the ht before

    def emit(j: int):
        stack = list(window)
        f = stack[j][0]
        if gap.model is None:
            return f, _segmentation(np.shape(f), stack[j][1], stack[j][2], gap.lateral_axis)
        e0 = smooth_edges(np.stack([x[1] for x in stack]), h, centre=j, half_window_frames=ht,
                          weights=np.stack([x[3] for x in stack]))
        e1 = smooth_edges(np.stack([x[2] for x in stack]), h, centre=j, half_window_frames=ht,
                          weights=np.stack([x[4] for x in stack]))
        return f, _segmentation(np.shape(f), e0, e1, gap.lateral_axis)

    pending = 0  # frames read but not yet yielded (the last `pending` entries of the window)
    for frame in frames:
        frame = np.array(frame)  # a copy: a view would keep the caller's whole batch of frames alive
        e0, e1 = raw_edges(frame, gap)
        w0 = robustness_weights(e0, h) if gap.model is not None else None
        w1 = robustness_weights(e1, h) if gap.model is not None else None
        window.append((frame, e0, e1, w0, w1))
        pending += 1
        if pending > ht:
            yield emit(len(window) - pending)
            pending -= 1
        while len(window) > 2 * ht + 1:
            window.popleft()
    while pending:
        yield emit(len(window) - pending)
        pending -= 1
