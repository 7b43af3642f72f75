"""The blurred-slit model of one ray across the glottis and its least-squares fit.

Across the glottis (along one ray, :mod:`vfcli.flow.gap.rays`) the image is the blurred
profile of "tissue - gap - tissue": a gap level between two edges, tissue levels that ramp
away from each edge, all convolved with a Gaussian PSF. :func:`fit_slit_profiles` fits the
edges of many rays at once; :func:`searched_edges` looks for the misfit's lowest minimum over each edge's
neighbourhood (:mod:`vfcli.flow.gap.subpixel.ray_edges` fits every open ray of frames with them).
Units: lateral px (pixel centres at integers), counts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
