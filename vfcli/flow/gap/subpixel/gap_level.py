"""The gap level seen on each ray: what the channel below looks like through each part of the glottis.

The edge fit of a ray (:mod:`vfcli.flow.gap.subpixel.profile`) pins the gap level of a slit too narrow
to show it by a prior; with one level for the whole recording (:class:`EdgeModel`) a glottis whose
channel looks brighter in one part than another reads too narrow there and too wide in the other,
since on a narrow slit width and depth trade against each other ((tissue - gap) x width is what the
image holds). The channel seen through the gap is fixed in the image (far below the folds, lit by
the same light), so each ray's level is measured where the gap shows it: on the sampled frames in
which the ray's fitted slit is wide enough for the fit's level to come from the data rather than
the prior (:data:`RESOLVED_SIGMAS` PSF widths, at least :data:`RESOLVED_MIN_PX`) and its floor is flat
at the fitted level (:func:`flat_floor`), then smoothed along the glottis; a ray never seen that wide keeps
the recording's level.

Units: counts; rays along the glottis (:mod:`vfcli.flow.gap.rays`).
"""
from __future__ import annotations

import warnings

import numpy as np

from vfcli.flow.gap.subpixel.crease import running_median

#: A ray's fitted gap level counts when its slit is at least this many PSF standard deviations wide: its
#: centre lies 3 sigma from either edge, where the blurred slit reaches the gap level to within 0.3 %
#: (erf(3 / sqrt 2)); the level then comes from the gap's own pixels, not from the ramps beside it
RESOLVED_SIGMAS = 6.0
#: ... and at least this many pixels (two whole pixels of gap beside the edges' pixels)
RESOLVED_MIN_PX = 3.0
#: Running median along the glottis, rays (odd)
SMOOTH_RAYS = 9
#: Fewest rays with a measured level for a per-ray level at all (else the recording's one level)
MIN_RAYS = 5
#: Significance of :func:`flat_floor`'s test: a floor as flat as the fits' noise fails it with this probability
FLAT_FLOOR_ALPHA = 0.01
#: Fewest pixel centres a floor is judged flat on: the fitted level is drawn to the dip's darkest pixels, so one or
#: two of them sit at it whatever the dip's shape, and only a third can show a V (a blurred slit narrower than it
#: was fitted: widened seed 4161, a slit at most 3 px wide read 5 px, "resolved", its area +156 %)
FLAT_FLOOR_MIN_PX = 3


def resolved_width_px(sigma: float) -> float:
    """Narrowest slit whose fitted gap level comes from its own pixels, px: :data:`RESOLVED_SIGMAS` PSF
    standard deviations ``sigma`` (px), at least :data:`RESOLVED_MIN_PX`."""
    return max(RESOLVED_MIN_PX, RESOLVED_SIGMAS * float(sigma))


def flat_floor(rays: np.ndarray, e0: np.ndarray, e1: np.ndarray, level: np.ndarray, sigma: float,
               noise: float) -> np.ndarray:
    """Whether each ray's fitted slit shows a flat floor at its fitted level: the slit a resolved width stands for.

    A slit :data:`RESOLVED_SIGMAS` PSF widths wide or wider reaches the gap level over its middle, the pixel
    centres at least half of those widths from both edges: there the image is the fitted level and noise. The
    floor is judged on at least :data:`FLAT_FLOOR_MIN_PX` pixels (where fewer lie that far inside, the
    :data:`FLAT_FLOOR_MIN_PX` nearest the slit's middle): on fewer, the dip's darkest pixels, to which the level is
    fitted, pass for a floor whatever the dip's shape. A fit that took a wide stretch of dark tissue for the gap,
    with a narrower, darker dip inside it, has no such floor (widened seeds 4121 and 3006: "slits" 16-36 px wide
    at one end of the glottis at 700-1075 counts, fitted over tissue and a 3-5 px gap whose dip reached 300-500
    counts below them; they passed the width test and set those rays' levels, and 4121's video, whose gap is
    never resolved, said nothing). The test: the RMS of those pixels about the level is within what ``noise``
    allows at :data:`FLAT_FLOOR_ALPHA` (the chi-square bound of their number, pixels independent). It assumes
    what the slit model does, one gap level across each ray's slit: a channel with structure of its own beyond
    that noise within one slit would fail it, and the gap would then be stated never resolved.

    Parameters
    ----------
    rays : (n_lateral, n_rays) counts, one frame as rays (:func:`vfcli.flow.gap.rays.as_rays`).
    e0, e1 : (n_rays,) float, fitted edges, lateral px (pixel centres at integers); NaN: closed.
    level : (n_rays,) float, fitted gap levels, counts.
    sigma : float, PSF standard deviation, px.
    noise : float, the noise of one pixel about the fitted model, counts (the flow step: the median RMS
        residual of the frames' fits).

    Returns
    -------
    (n_rays,) bool, False on closed rays.
    """
    from scipy.special import gammaincinv      # the chi-square quantile (importing scipy.stats costs 0.35 s)

    a = np.asarray(rays, float)
    e0, e1, g = (np.asarray(v, float) for v in (e0, e1, level))
    half = 0.5 * RESOLVED_SIGMAS * float(sigma)
    centres = np.arange(a.shape[0], dtype=float)[:, None]
    inner = (centres >= e0[None, :] + half) & (centres <= e1[None, :] - half)
    # the FLAT_FLOOR_MIN_PX pixel centres nearest the middle (ties to the lower one)
    dist = np.abs(centres - 0.5 * (e0 + e1)[None, :]) + 1e-9 * centres
    with np.errstate(invalid="ignore"):
        order = np.argsort(np.argsort(np.where(np.isfinite(dist), dist, np.inf), axis=0), axis=0)
        middle = order < FLAT_FLOOR_MIN_PX
        inner = np.where((inner.sum(axis=0) >= FLAT_FLOOR_MIN_PX)[None, :], inner, middle)
        n = inner.sum(axis=0)
        dof = np.maximum(n, 1)
        msq = np.where(inner, (a - g[None, :]) ** 2, 0.0).sum(axis=0) / dof
        bound = float(noise) ** 2 * 2.0 * gammaincinv(0.5 * dof, 1.0 - FLAT_FLOOR_ALPHA) / dof
        return np.isfinite(e0) & np.isfinite(e1) & np.isfinite(g) & (n > 0) & (msq <= bound)


def ray_gap_levels(widths: np.ndarray, levels: np.ndarray, sigma: float,
                   upper: np.ndarray | None = None, flat: np.ndarray | None = None) -> np.ndarray | None:
    """Each ray's gap level from the edge fits of sampled frames, counts.

    Parameters
    ----------
    widths : (k, n_rays) float
        Fitted slit width of each ray in each sampled frame, px (NaN: closed).
    levels : (k, n_rays) float
        The same fits' gap levels, counts.
    sigma : float
        PSF standard deviation, px.
    upper : (n_rays,) float, optional
        A fitted level counts only below this, counts: the flow step passes rule (b) of
        :func:`vfcli.flow.gap.subpixel.segment.raw_edges` (half-way from the recording's gap level to the
        ray's closed crease), so a dark patch of tissue fitted as a wide slit with its own, brighter level
        does not set the ray's gap level (widened seed 293, 2.7 px blur: fitted "gap" levels up to 810
        counts where the gap reads 315).
    flat : (k, n_rays) bool, optional
        A fit counts only where its floor is flat at its level (:func:`flat_floor`).

    Returns
    -------
    (n_rays,) float, or None when fewer than :data:`MIN_RAYS` rays were ever resolved.
        Per ray the median level over the frames where it was resolved (at least two), then a running
        median of :data:`SMOOTH_RAYS` rays along the glottis; NaN on rays never resolved (the caller uses
        the recording's one level there: under a heavy blur only the widest part of the glottis is ever
        resolved, and carrying its level along the glottis read the narrow parts wrong).
    """
    w = np.asarray(widths, float)
    g = np.asarray(levels, float)
    resolved = np.isfinite(w) & (w >= resolved_width_px(sigma)) & np.isfinite(g)
    if upper is not None:
        resolved &= g < np.asarray(upper, float)[None, :]
    if flat is not None:
        resolved &= np.asarray(flat, bool)
    n = resolved.sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # rays never resolved
        per_ray = np.where(n >= 2, np.nanmedian(np.where(resolved, g, np.nan), axis=0), np.nan)
    if np.isfinite(per_ray).sum() < MIN_RAYS:
        return None
    return running_median(per_ray, SMOOTH_RAYS, np.isfinite(per_ray))
