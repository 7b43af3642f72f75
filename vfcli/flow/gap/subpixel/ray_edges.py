"""The edge fit of every open ray of frames: windows, starts, passes, and the readings the ambiguity check compares.

Each ray across the glottis (:mod:`vfcli.flow.gap.rays`) is fitted with the blurred-slit model
(:func:`vfcli.flow.gap.subpixel.profile.fit_slit_profiles`) in a window around the detection's edges, from that
start and from the pixels surely in the gap, re-centred over passes (:func:`fit_ray_edges`,
:func:`fit_ray_edges_many`); :func:`fit_ray_edges_twice` also searches each edge's neighbourhood
(:func:`vfcli.flow.gap.subpixel.profile.searched_edges`), and with ``free_level_noise`` a ray whose data reject its
prior gap level is read with the level free (:func:`free_level_where_rejected`): the readings
:mod:`vfcli.flow.gap.subpixel.ambiguity` compares. Units: lateral px (pixel centres at integers), counts.
"""
from __future__ import annotations

import numpy as np

from vfcli.flow.gap.rays import as_rays
from vfcli.flow.gap.subpixel.profile import (MIN_WINDOW_PX, WINDOW_SIGMAS, EdgeModel, SlitFit, fit_slit_profiles,
                                             searched_edges)

#: A ray's data reject its prior gap level when freeing the level lowers the fit's summed squared residual by more
#: than this many times the pixels' noise variance: the chi-square quantile of one degree of freedom (the level) at
#: 0.999 (:func:`free_level_where_rejected`)
LEVEL_REJECT_CHI2 = 10.83

#: Weight of the gap-level prior in a fit with the level free, in samples: enough to keep the linear solve regular
#: on a slit too narrow to show its level, too little to move a level the data show
FREE_LEVEL_WEIGHT = 1e-6

#: A ray is fitted a second time, from its inner bounds, when they lie more than this inside its start, px.
SECOND_START_PX = 1.0


def _fit_from_either_start(prof: np.ndarray, rows: np.ndarray, start0: np.ndarray, start1: np.ndarray, sigma: float,
                           prior: np.ndarray, inner: tuple[np.ndarray, np.ndarray], held: bool = False,
                           free_level_noise: float = 0.0) -> SlitFit:
    """:func:`~vfcli.flow.gap.subpixel.profile.fit_slit_profiles` from the given starts and, on the rays whose inner bounds (the pixels surely in the
    gap) lie more than :data:`SECOND_START_PX` inside them, again from those bounds, on the same window; each ray
    keeps the fit of lower cost.  With ``held`` the edges also stay at or beyond those bounds (the reading
    :mod:`vfcli.flow.gap.subpixel.ambiguity` compares); without, the bounds are a start only.

    The start is a detection run's edges, and a run detected at a level above dark medial walls holds wall pixels:
    from there the fit can stay in a local minimum with the walls taken as gap at a raised gap level (widened seeds
    1104, 1030, 1038: the gap 1-4 % too wide; tests/test_gap_tilted.py: a 6 px gap read 11.5 px wide).

    Held, the bounds kept wall pixels as gap where a medial wall in shade is darker than they allow: on the 41 seeds
    of the regression set under Lambert shading the glottal area of the resolved seeds was 12.0 % off on average
    (4165 +40 %, 4112 +55 %), free 6.7 % (+16, +40 %; docs/benchmarks.md, "Session 59").

    With ``free_level_noise`` (counts, > 0) each ray whose data reject its prior gap level is fitted again with the
    level free (:func:`free_level_where_rejected`): the reading :mod:`vfcli.flow.gap.subpixel.ambiguity` compares
    with the product's."""
    bound = inner if held else None
    fit = fit_slit_profiles(prof, rows, start0, start1, sigma, prior, inner=bound)
    lo, hi = (np.asarray(v, float) for v in inner)
    s0 = np.where(np.isfinite(lo), lo - 0.5, start0)
    s1 = np.where(np.isfinite(hi), hi + 0.5, start1)
    again = np.flatnonzero((s1 > s0) & ((s0 - start0 > SECOND_START_PX) | (start1 - s1 > SECOND_START_PX)))
    if again.size:
        fit = lower_cost(fit, fit_slit_profiles(prof[again], rows[again], s0[again], s1[again], sigma, prior[again],
                                                 inner=None if bound is None else (lo[again], hi[again])), again)
    if not held:
        fit = _open_where_surely_gap(fit, prof, rows, sigma, prior, (lo, hi))
    if free_level_noise > 0:
        fit = free_level_where_rejected(fit, prof, rows, start0, start1, sigma, prior, free_level_noise)
    return fit


def free_level_where_rejected(fit: SlitFit, prof: np.ndarray, rows: np.ndarray, start0: np.ndarray,
                              start1: np.ndarray, sigma: float, prior: np.ndarray, noise: float) -> SlitFit:
    """``fit`` with each ray whose data reject its prior gap level taken from a fit with the level free.

    The prior (:data:`vfcli.flow.gap.subpixel.profile.GAP_LEVEL_WEIGHT`, one pixel's worth at the recording's or the ray's level) pins the level of
    a slit too narrow to show it, and so claims the level is known to within a pixel's noise. Where the channel seen
    through the gap is brighter in one part of the glottis than where the level was measured, and the slit there is
    never wide enough to show its own level (:mod:`vfcli.flow.gap.subpixel.gap_level`), the prior makes the fit
    read it narrower, or closed: the tissue ramps take the dip for a crease (widened seed 4279, blur 0.91 px, its
    channel 310-376 counts toward the glottis' ends beside 142 in the middle: the glottal area read 25 % low with
    the edge readings 2 % apart, unwarned; docs/benchmarks.md, "Session 68"). Each ray is fitted again from the same
    start (``start0``, ``start1``, px) with the level free (:data:`FREE_LEVEL_WEIGHT`); where that lowers the summed
    squared residual by more than :data:`LEVEL_REJECT_CHI2` times ``noise`` squared and the free fit is open, it
    replaces the ray's fit. A narrow slit at the prior's level fits about as well with the level free (its width
    and level trade against each other), so it keeps its fit.

    Parameters
    ----------
    fit : SlitFit of the n rays.
    prof, rows : (n, L) the rays' windows, counts and px (:func:`~vfcli.flow.gap.subpixel.profile.fit_slit_profiles`).
    start0, start1 : (n,) float, the starts ``fit`` came from, px.
    sigma : float, PSF standard deviation, px.
    prior : (n,) float, the prior gap levels, counts.
    noise : float, one pixel's noise about the model, counts.

    Returns
    -------
    SlitFit of the n rays.
    """
    bound = LEVEL_REJECT_CHI2 * float(noise) ** 2
    n = np.isfinite(np.asarray(prof, float)).sum(axis=1)
    # the drop cannot exceed the fit's own summed squares: only the rays misfitted by more than the bound are refitted
    rays = np.flatnonzero(fit.rms ** 2 * n > bound)
    if rays.size == 0:
        return fit
    free = fit_slit_profiles(prof[rays], rows[rays], start0[rays], start1[rays], sigma, prior[rays],
                             gap_weight=FREE_LEVEL_WEIGHT)
    drop = (fit.rms[rays] ** 2 - free.rms ** 2) * n[rays]
    return replaced_rays(fit, free, rays, (drop > bound) & (free.e1 > free.e0))


def _open_where_surely_gap(fit: SlitFit, prof: np.ndarray, rows: np.ndarray, sigma: float, prior: np.ndarray,
                           inner: tuple[np.ndarray, np.ndarray]) -> SlitFit:
    """``fit`` with each ray whose edges crossed (``e1 <= e0``: closed) although a pixel centre on it is surely in the
    gap (``inner[0] <= inner[1]``) fitted again with its edges held at or beyond those pixels.

    Crossed edges are how the slit model says "no gap": its gap basis turns negative between them, so that the two
    tissue ramps meet in a V. That V also fits a dip that is the gap seen between medial walls in shade, which
    darken gradually toward it, better than the flat-floored slit under the recording's blur does: on widened
    phantom 4199 (blur 1.05 px, walls shaded) 12 of the 167 rays across the gap in its widest frame were closed that
    way, each with pixels at the gap's own level (docs/benchmarks.md, "Session 61"). A pixel darker than half-way
    from the tissue beside the gap to the gap level is more gap than tissue, so such a ray is open; where it is, the
    held fit says."""
    lo, hi = inner
    redo = np.flatnonzero(~(fit.e1 > fit.e0) & np.isfinite(lo) & np.isfinite(hi) & (lo <= hi))
    if redo.size == 0:
        return fit
    held = fit_slit_profiles(prof[redo], rows[redo], np.minimum(fit.e0[redo], lo[redo]),
                             np.maximum(fit.e1[redo], hi[redo]), sigma, prior[redo], inner=(lo[redo], hi[redo]))
    return replaced_rays(fit, held, redo, np.ones(len(redo), bool))


def lower_cost(fit: SlitFit, other: SlitFit, rays: np.ndarray) -> SlitFit:
    """``fit`` with the rays ``rays`` (indices) taken from ``other`` (their fits, in that order) where its cost is
    lower."""
    return replaced_rays(fit, other, rays, other.cost < fit.cost[rays])


def replaced_rays(fit: SlitFit, other: SlitFit, rays: np.ndarray, pick: np.ndarray) -> SlitFit:
    """``fit`` with the rays ``rays[pick]`` taken from ``other`` (the fits of ``rays``, in that order)."""
    better = rays[pick]
    e0, e1, levels, rms, cost = (np.array(v, copy=True) for v in (fit.e0, fit.e1, fit.levels, fit.rms, fit.cost))
    e0[better], e1[better], levels[better] = other.e0[pick], other.e1[pick], other.levels[pick]
    rms[better], cost[better] = other.rms[pick], other.cost[pick]
    return SlitFit(e0, e1, levels, rms, cost)


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
    img = as_rays(frame, lateral_axis)
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


def fit_ray_edges(
    frame: np.ndarray, e0: np.ndarray, e1: np.ndarray, model: EdgeModel, lateral_axis: int = 0, passes: int = 2,
    inner: tuple[np.ndarray, np.ndarray] | None = None, gap_counts: np.ndarray | None = None, held: bool = False,
) -> SlitFit:
    """Sub-pixel edges of every open ray of one frame, starting from a threshold mask's edges.

    The window of each ray reaches :data:`~vfcli.flow.gap.subpixel.profile.WINDOW_SIGMAS` PSF widths beyond its edges
    (at least :data:`~vfcli.flow.gap.subpixel.profile.MIN_WINDOW_PX`);
    after each pass it is re-centred on the edges found. Where ``inner`` (the pixels surely in the gap)
    lies more than :data:`SECOND_START_PX` inside the run, the fit also starts there
    (:func:`_fit_from_either_start`); with ``held`` the edges are also kept at or beyond it.

    Parameters
    ----------
    frame : (H, W) array of counts
    e0, e1 : (n_rays,) float
        Pixel boundaries of the threshold mask's run on each ray (:func:`vfcli.flow.gap.rays.outermost_silhouette`),
        lateral px; NaN on closed rays.
    model : EdgeModel
    lateral_axis : {0, 1}
    passes : int
        Window placements.
    inner : ((n_rays,) float, (n_rays,) float), optional
        The pixels surely in the gap per ray, px (+inf / -inf: none): a second start, and with ``held`` bounds
        ``e0 <= inner[0]``, ``e1 >= inner[1]``; default: the starting run's outermost pixel centres (the run is a
        threshold mask's: darker than the threshold, which lies at most half-way between gap and tissue).
    gap_counts : (n_rays,) float, optional
        Prior gap level of each ray, counts (:func:`vfcli.flow.gap.subpixel.gap_level.ray_gap_levels`);
        default: the model's one level.
    held : bool
        Keep the edges at or beyond ``inner`` (:func:`_fit_from_either_start`).

    Returns
    -------
    SlitFit over all rays (NaN edges on rays that were NaN on input).
    """
    return fit_ray_edges_many([frame], [e0], [e1], model, lateral_axis, passes,
                              None if inner is None else [inner], None if gap_counts is None else [gap_counts],
                              held)[0]


def fit_ray_edges_many(
    frames: list, e0s: list, e1s: list, model: EdgeModel, lateral_axis: int = 0, passes: int = 2,
    inners: list | None = None, gap_counts: list | None = None, held: bool = False, free_level_noise: float = 0.0,
) -> list[SlitFit]:
    """:func:`fit_ray_edges` of several frames in one :func:`~vfcli.flow.gap.subpixel.profile.fit_slit_profiles` call per pass (their rays stacked,
    each frame's windows padded to the longest with samples of no weight): every ray is fitted on its own, so the
    edges are those of one call per frame, for a fraction of the per-call cost of the Levenberg-Marquardt loop
    (:data:`vfcli.flow.gap.subpixel.segment.FIT_BATCH_FRAMES`).

    frames : K (H, W) arrays of counts.  e0s, e1s : K (n_rays,) float.  inners : K pairs or None.
    gap_counts : K (n_rays,) float or None.  held : as :func:`fit_ray_edges`'s.  free_level_noise : counts; > 0: each
    ray whose data reject its prior gap level is fitted with the level free (:func:`free_level_where_rejected`).
    Returns K :class:`SlitFit`.
    """
    return _fit_passes(frames, e0s, e1s, model, lateral_axis, passes, inners, gap_counts, held=held,
                       free_level_noise=free_level_noise)[0]


def fit_ray_edges_twice(
    frames: list, e0s: list, e1s: list, model: EdgeModel, search_px: float, lateral_axis: int = 0, passes: int = 2,
    inners: list | None = None, gap_counts: list | None = None, held: bool = False,
) -> tuple[list[SlitFit], list[SlitFit]]:
    """Two readings of the same rays (:mod:`vfcli.flow.gap.subpixel.ambiguity`): :func:`fit_ray_edges_many`'s, and the
    same with its last pass's fits competing with :func:`~vfcli.flow.gap.subpixel.profile.searched_edges` over ``search_px`` px (a ray keeps the lower
    misfit).  One pass loop: the searched reading costs the search only.  Arguments as :func:`fit_ray_edges_many`'s.
    Returns (started, searched), each K :class:`SlitFit`.
    """
    searched, started = _fit_passes(frames, e0s, e1s, model, lateral_axis, passes, inners, gap_counts, search_px,
                                    held)
    return started, searched


def _fit_passes(frames: list, e0s: list, e1s: list, model: EdgeModel, lateral_axis: int, passes: int,
                inners: list | None, gap_counts: list | None, search_px: float = 0.0, held: bool = False,
                free_level_noise: float = 0.0) -> tuple[list[SlitFit], list[SlitFit]]:
    """The pass loop of :func:`fit_ray_edges_many`: (fits, the last pass's fits before the search); with ``search_px``
    = 0 the two are the same."""
    margin = max(MIN_WINDOW_PX, int(np.ceil(WINDOW_SIGMAS * model.psf_sigma_px)))
    e0s = [np.asarray(e, float).copy() for e in e0s]
    e1s = [np.asarray(e, float).copy() for e in e1s]
    sels, inner_lo, inner_hi, priors = [], [], [], []
    for k, (e0, e1) in enumerate(zip(e0s, e1s)):
        sel = np.flatnonzero(np.isfinite(e0) & np.isfinite(e1))
        inner = None if inners is None else inners[k]
        # the rough run's outermost pixels are darker than the threshold, which lies at most half-way
        # between gap and tissue: their centres are in the gap (a second start; held, a bound)
        lo, hi = (e0[sel] + 0.5, e1[sel] - 0.5) if inner is None else (np.asarray(inner[0], float)[sel],
                                                                         np.asarray(inner[1], float)[sel])
        g = model.gap_counts if gap_counts is None or gap_counts[k] is None else gap_counts[k]
        sels.append(sel)
        inner_lo.append(lo)
        inner_hi.append(hi)
        priors.append(np.broadcast_to(np.asarray(g, float), e0.shape)[sel])
    levels = [np.full((len(e0), 5), np.nan) for e0 in e0s]
    rms = [np.full(len(e0), np.nan) for e0 in e0s]
    cost = [np.full(len(e0), np.nan) for e0 in e0s]
    at = np.concatenate([[0], np.cumsum([len(sel) for sel in sels])]).astype(int)
    if at[-1] == 0:
        fits = [SlitFit(*parts) for parts in zip(e0s, e1s, levels, rms, cost)]
        return fits, fits
    inner = (np.concatenate(inner_lo), np.concatenate(inner_hi))
    prior = np.concatenate(priors)
    for k_pass in range(max(1, passes)):
        windows = [ray_windows(f, e0, e1, margin, lateral_axis) for f, e0, e1 in zip(frames, e0s, e1s)]
        length = max(w[0].shape[1] for w in windows)
        prof = np.full((at[-1], length), np.nan)
        rows = np.zeros((at[-1], length))
        for k, ((pk, rk), sel) in enumerate(zip(windows, sels)):
            n = pk.shape[1]
            prof[at[k]:at[k + 1], :n] = pk[sel]
            rows[at[k]:at[k + 1], :n] = rk[sel]
            rows[at[k]:at[k + 1], n:] = rk[sel][:, -1:] + np.arange(1, length - n + 1)
        start0 = np.concatenate([e0[sel] for e0, sel in zip(e0s, sels)])
        start1 = np.concatenate([e1[sel] for e1, sel in zip(e1s, sels)])
        fit = started = _fit_from_either_start(prof, rows, start0, start1, model.psf_sigma_px, prior, inner, held,
                                               free_level_noise)
        if search_px > 0 and k_pass == max(1, passes) - 1:
            fit = lower_cost(started, searched_edges(prof, rows, started.e0, started.e1, model.psf_sigma_px, prior,
                                                      search_px), np.arange(len(started.e0)))
        for k, sel in enumerate(sels):                  # the next pass's windows are centred on these edges
            part = slice(at[k], at[k + 1])
            e0s[k][sel], e1s[k][sel] = fit.e0[part], fit.e1[part]
            levels[k][sel], rms[k][sel], cost[k][sel] = fit.levels[part], fit.rms[part], fit.cost[part]
    fits = [SlitFit(*parts) for parts in zip(e0s, e1s, levels, rms, cost)]
    if search_px <= 0:
        return fits, fits
    before = []                                         # the last pass's fits as they were before the search
    for k, (fit_k, sel) in enumerate(zip(fits, sels)):
        part = slice(at[k], at[k + 1])
        arrays = [np.array(v, copy=True) for v in (fit_k.e0, fit_k.e1, fit_k.levels, fit_k.rms, fit_k.cost)]
        for mine, theirs in zip(arrays, (started.e0, started.e1, started.levels, started.rms, started.cost)):
            mine[sel] = theirs[part]
        before.append(SlitFit(*arrays))
    return fits, before
