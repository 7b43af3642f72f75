"""The blurred-slit model of one ray across the glottis and its least-squares fit.

Across the glottis (along one ray, :mod:`vfcli.flow.gap.rays`) the image is the blurred
profile of "tissue - gap - tissue": a gap level between two edges, tissue levels that ramp
away from each edge, all convolved with a Gaussian PSF. :func:`fit_slit_profiles` fits the
edges of many rays at once; :func:`fit_ray_edges` does it for every open ray of a frame,
starting from a threshold mask's edges. Units: lateral px (pixel centres at integers), counts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vfcli.flow.gap.rays import as_rays

# A binary mask can only be as good as the pixels it is cut from: on a slit a few pixels wide,
# a threshold that misplaces each edge by a fraction of a pixel costs a large share of the gap.
# The image itself holds the edges to a fraction of a pixel: across the glottis (along one
# ray) it is the blurred profile of "tissue - gap - tissue". The functions below fit that
# profile per ray (the other modules of this package smooth the edges and cut the mask).

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

#: The fit window's least half-width beyond each edge, px. Under a PSF below half a pixel
#: WINDOW_SIGMAS gives one pixel, which leaves the tissue ramp nearly undetermined (one sample
#: per side beside the edge): sharp slits read 8-16 % too narrow on widened phantoms (1034,
#: 1042, 1044), and the analytic walled slit of the tests 0.22 px too wide per edge (0.05 px
#: with two).
MIN_WINDOW_PX = 2

#: A ray's data reject its prior gap level when freeing the level lowers the fit's summed squared residual by more
#: than this many times the pixels' noise variance: the chi-square quantile of one degree of freedom (the level) at
#: 0.999 (:func:`free_level_where_rejected`)
LEVEL_REJECT_CHI2 = 10.83

#: Weight of the gap-level prior in a fit with the level free, in samples: enough to keep the linear solve regular
#: on a slit too narrow to show its level, too little to move a level the data show
FREE_LEVEL_WEIGHT = 1e-6


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
    """Basis (n, L, 5) of the blurred slit model, the normal densities and CDFs at the normalised distances
    to the edges (phi(z0), phi(z1), Phi(z0), Phi(z1), each (n, L))."""
    from scipy.special import ndtr

    za = (e0[:, None] - rows) / sigma
    zb = (rows - e1[:, None]) / sigma
    pa, pb = ndtr(za), ndtr(zb)
    fa, fb = _phi(za), _phi(zb)
    ra = za * pa + fa
    rb = zb * pb + fb
    basis = np.stack([1.0 - pa - pb, pa, sigma * ra, pb, sigma * rb], axis=-1)
    return basis, fa, fb, pa, pb


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
    cost (n,), (phi(z0), phi(z1), P0, P1, weighted basis (n, L, 5), normal matrix (n, 5, 5)))."""
    r, y, w, sw, sigma, gap_counts, gap_weight, ridge = data
    basis, fa, fb, pa, pb = _slit_basis(r, e0, e1, sigma)
    bt = (basis * w[..., None]).transpose(0, 2, 1)
    lhs = bt @ basis
    rhs = (bt @ y[..., None])[..., 0]
    lhs[:, 0, 0] += gap_weight
    rhs[:, 0] += gap_weight * gap_counts
    lhs += (ridge * np.einsum("nii->n", lhs))[:, None, None] * np.eye(5)  # numerical safety only
    x = np.linalg.solve(lhs, rhs[..., None])[..., 0]
    res = ((basis @ x[..., None])[..., 0] - y) * sw
    cost = (res**2).sum(axis=1) + gap_weight * (x[:, 0] - gap_counts) ** 2
    return x, res, cost, (fa, fb, pa, pb, basis * sw[..., None], lhs)


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
    gap_counts : float or (n,) float
        Prior gap level, counts (one per ray, or the recording's).
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
    gap_counts = np.broadcast_to(np.asarray(gap_counts, dtype=float), (n,))

    x, res, cost, aux = _slit_levels((r, y, w, sw, sigma, gap_counts, gap_weight, ridge), e0, e1)
    aux = list(aux)
    damping = np.full(n, 1e-3)
    act = np.arange(n)  # rays still moving
    k = 1 if closed else 2
    # the Gauss-Newton system of each ray at its current edges; a ray whose trial step was refused keeps its
    # edges, so only the damping changes and its system is reused (about a third of the ray-iterations of a
    # flow run); each ray's arithmetic is its own, so the result is the same as recomputing it
    jtj_all, grad_all, diag_all = np.empty((n, k, k)), np.empty((n, k)), np.empty((n, k))
    stale = np.ones(n, bool)
    eye = np.eye(k)
    for _ in range(iterations):
        if act.size == 0:
            break
        need = act[stale[act]]
        if need.size:
            fa, fb, pa, pb, bw, lhs = (v[need] for v in aux)
            swa, xa = sw[need], x[need]
            g_lvl, t0, s0, t1, s1 = xa.T
            d0 = ((t0 - g_lvl)[:, None] * fa / sigma + s0[:, None] * pa) * swa
            d1 = (-(t1 - g_lvl)[:, None] * fb / sigma - s1[:, None] * pb) * swa
            jac = (d0 + d1)[..., None] if closed else np.stack([d0, d1], axis=-1)
            # variable projection (Kaufman): the Jacobian of the residual with the levels re-solved
            # is the edge derivative projected off the basis (the prior on G is one more row)
            c = np.linalg.solve(lhs, bw.transpose(0, 2, 1) @ jac)          # (m, 5, k)
            jac = jac - bw @ c
            prior_row = -np.sqrt(gap_weight) * c[:, :1, :]                  # (m, 1, k)
            prior_res = (np.sqrt(gap_weight) * (xa[:, 0] - gap_counts[need]))[:, None]
            jt = jac.transpose(0, 2, 1)
            jtj = jt @ jac + prior_row.transpose(0, 2, 1) @ prior_row
            jtj_all[need] = jtj
            grad_all[need] = (jt @ res[need][..., None])[..., 0] + (prior_row.transpose(0, 2, 1) @ prior_res[..., None])[..., 0]
            diag_all[need] = np.einsum("nii->ni", jtj) + 1e-12
            stale[need] = False
        jtj, grad, diag = jtj_all[act], grad_all[act], diag_all[act]
        damp = damping[act]
        step = -np.linalg.solve(jtj + damp[:, None, None] * (diag[:, :, None] * eye), grad[..., None])[..., 0]
        step = np.clip(step, -0.5, 0.5)
        a = np.clip(e0[act] + step[:, 0], lo[act], hi0[act])
        b = a if closed else np.clip(e1[act] + step[:, 1], lo1[act], hi[act])
        sub = (r[act], y[act], w[act], sw[act], sigma, gap_counts[act], gap_weight, ridge)
        nx, nres, ncost, naux = _slit_levels(sub, a, b)
        better = ncost < cost[act]
        damping[act] = np.where(better, damp * 0.3, damp * 10.0)
        upd = act[better]
        e0[upd], e1[upd], x[upd], res[upd], cost[upd] = a[better], b[better], nx[better], nres[better], ncost[better]
        for v, nv in zip(aux, naux):
            v[upd] = nv[better]
        stale[upd] = True
        done = (better & (np.abs(step).max(axis=1) < 1e-3)) | (damping[act] > 1e6)
        act = act[~done]
    rms = np.sqrt((res**2).sum(axis=1) / np.maximum(ok.sum(axis=1), 1.0))
    return SlitFit(e0, e1, x, rms, cost)


#: A ray is fitted a second time, from its inner bounds, when they lie more than this inside its start, px.
SECOND_START_PX = 1.0


def _fit_from_either_start(prof: np.ndarray, rows: np.ndarray, start0: np.ndarray, start1: np.ndarray, sigma: float,
                           prior: np.ndarray, inner: tuple[np.ndarray, np.ndarray], held: bool = False,
                           free_level_noise: float = 0.0) -> SlitFit:
    """:func:`fit_slit_profiles` from the given starts and, on the rays whose inner bounds (the pixels surely in the
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
        fit = _lower_cost(fit, fit_slit_profiles(prof[again], rows[again], s0[again], s1[again], sigma, prior[again],
                                                 inner=None if bound is None else (lo[again], hi[again])), again)
    if not held:
        fit = _open_where_surely_gap(fit, prof, rows, sigma, prior, (lo, hi))
    if free_level_noise > 0:
        fit = free_level_where_rejected(fit, prof, rows, start0, start1, sigma, prior, free_level_noise)
    return fit


def free_level_where_rejected(fit: SlitFit, prof: np.ndarray, rows: np.ndarray, start0: np.ndarray,
                              start1: np.ndarray, sigma: float, prior: np.ndarray, noise: float) -> SlitFit:
    """``fit`` with each ray whose data reject its prior gap level taken from a fit with the level free.

    The prior (:data:`GAP_LEVEL_WEIGHT`, one pixel's worth at the recording's or the ray's level) pins the level of
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
    prof, rows : (n, L) the rays' windows, counts and px (:func:`fit_slit_profiles`).
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
    return _replaced(fit, free, rays, (drop > bound) & (free.e1 > free.e0))


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
    return _replaced(fit, held, redo, np.ones(len(redo), bool))


def _lower_cost(fit: SlitFit, other: SlitFit, rays: np.ndarray) -> SlitFit:
    """``fit`` with the rays ``rays`` (indices) taken from ``other`` (their fits, in that order) where its cost is
    lower."""
    return _replaced(fit, other, rays, other.cost < fit.cost[rays])


def _replaced(fit: SlitFit, other: SlitFit, rays: np.ndarray, pick: np.ndarray) -> SlitFit:
    """``fit`` with the rays ``rays[pick]`` taken from ``other`` (the fits of ``rays``, in that order)."""
    better = rays[pick]
    e0, e1, levels, rms, cost = (np.array(v, copy=True) for v in (fit.e0, fit.e1, fit.levels, fit.rms, fit.cost))
    e0[better], e1[better], levels[better] = other.e0[pick], other.e1[pick], other.levels[pick]
    rms[better], cost[better] = other.rms[pick], other.cost[pick]
    return SlitFit(e0, e1, levels, rms, cost)


#: Step of the search of :func:`searched_edges`, px: a quarter of a pixel, finer than a misfit basin of any optics (an
#: edge's basin is about a PSF width, at least the pixel's own 0.29 px), so that the Levenberg-Marquardt polish starts
#: in the basin of the search's minimum (with a step of 0.1 px, a third sweep and a search in every pass, 3-4 times
#: the cost, the 41 regression seeds' disagreements were within -0.9 to +4.7 points of these and one more seed was
#: warned, 4145 at 5.5 for 4.8 %; docs/benchmarks.md, "Session 58")
SEARCH_STEP_PX = 0.25


def searched_edges(profiles: np.ndarray, rows: np.ndarray, e0: np.ndarray, e1: np.ndarray, sigma: float,
                   gap_counts, reach_px: float, step_px: float = SEARCH_STEP_PX) -> SlitFit:
    """The slit model's lowest misfit over each edge's neighbourhood, not only the basin of a start.

    :func:`fit_slit_profiles` finds the minimum nearest its start, inside its bounds.  Beside a medial wall that
    faces away from the lamp (a dark band between the gap and the lit tissue) the misfit can have two minima, the
    edge at the gap and the edge at the wall's far side, and a fit started beyond the wall, or held there by wall
    pixels taken as surely gap, stays there (widened seed 4165 under Lambert shading: the shaded side's edges 1.5 px
    out on average, the glottal area +40 %).  Here each edge in turn (e1, then e0) is moved over a grid of
    ``step_px`` from ``reach_px`` inside its start to half a pixel outside it, the other edge held, the levels solved
    at each point; then Levenberg-Marquardt polishes from the best point, with no inner bounds.  Same arguments as
    :func:`fit_slit_profiles` (``e0``, ``e1``: the starts, px); the gap stays at least 0.2 px wide during the search.

    Returns
    -------
    SlitFit of the polished fits.
    """
    y = np.asarray(profiles, dtype=float)
    r = np.asarray(rows, dtype=float)
    ok = np.isfinite(y)
    w = ok.astype(float)
    n = len(y)
    prior = np.broadcast_to(np.asarray(gap_counts, dtype=float), (n,))
    data = (r, np.where(ok, y, 0.0), w, np.sqrt(w), sigma, prior, GAP_LEVEL_WEIGHT, 1e-12)
    lo = np.where(ok, r, np.inf).min(axis=1)
    hi = np.where(ok, r, -np.inf).max(axis=1)
    edges = [np.array(e0, dtype=float), np.array(e1, dtype=float)]
    inward = np.arange(-reach_px, 0.5 + 1e-9, step_px)   # negative: into the gap
    for side in (1, 0):
        other = edges[1 - side]
        best, best_cost = edges[side].copy(), np.full(n, np.inf)
        for d in inward:
            cand = np.clip(edges[side] + (d if side else -d), lo, hi)
            valid = cand > other + 0.2 if side else cand < other - 0.2
            trial = np.where(valid, cand, edges[side])
            cost = _slit_levels(data, *((other, trial) if side else (trial, other)))[2]
            take = valid & (cost < best_cost)
            best[take], best_cost[take] = cand[take], cost[take]
        edges[side] = best
    return fit_slit_profiles(y, r, edges[0], edges[1], sigma, prior)


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

    The window of each ray reaches :data:`WINDOW_SIGMAS` PSF widths beyond its edges
    (at least :data:`MIN_WINDOW_PX`);
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
    """:func:`fit_ray_edges` of several frames in one :func:`fit_slit_profiles` call per pass (their rays stacked,
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
    same with its last pass's fits competing with :func:`searched_edges` over ``search_px`` px (a ray keeps the lower
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
            fit = _lower_cost(started, searched_edges(prof, rows, started.e0, started.e1, model.psf_sigma_px, prior,
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
