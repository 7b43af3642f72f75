"""The glottis tapers toward its ends: the widest a ray's gap can be, from the sampled frames.

The folds are clamped at the anterior and posterior ends, so the glottal gap's widest opening along the
glottis rises from the ends to the middle: no ray near an end opens wider than the middle does. A dark
patch of texture or a shadow line that touches the tip of the gap can fall on a ray past the end and be
fitted there as a gap tens of pixels wide along the ray (widened seeds 1100 and 3025: 40-50 px, a tenth of
the whole glottal area). :func:`taper_limits` turns the fitted widths of the sampled frames into a largest
width per ray; :func:`vfcli.flow.gap.subpixel.segment.ray_fits` closes a ray wider than that.
"""
from __future__ import annotations

import numpy as np

#: A ray outside the central half of the glottis may open at most this many times the widest opening found
#: on the central half's rays. A clamped glottis never opens wider near its ends than in the middle (factor 1);
#: the slack covers the fitted widths' scatter and a glottis cut by the image, whose visible central half may
#: miss the middle (a sine profile seen from the middle to one end: the visible quarter points reach 0.92 of
#: the peak).
TAPER_FACTOR = 1.5


def taper_limits(widths: np.ndarray, factor: float = TAPER_FACTOR) -> np.ndarray:
    """(n_rays,) the widest gap each ray may show, px (inf: no limit).

    The middle of the glottis is the central half of the rays, by how often each was open in the sample
    (between the quartiles of the ray index weighted by that count); its rays get no limit, every other ray
    ``factor`` times the widest opening fitted on them. (Not a limit growing outward with the widths met
    on the way: a dark patch widening ray by ray would raise it step by step.)

    Parameters
    ----------
    widths : (k, n_rays) float
        Fitted gap widths of sampled frames along the rays, px (NaN or <= 0: closed).
    factor : float
        :data:`TAPER_FACTOR`.

    Returns
    -------
    (n_rays,) float, px.
    """
    w = np.asarray(widths, dtype=float)
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    n = w.shape[1]
    limits = np.full(n, np.inf)
    count = (w > 0).sum(axis=0)
    if count.sum() == 0:
        return limits
    cum = np.cumsum(count) / count.sum()
    lo, hi = int(np.searchsorted(cum, 0.25)), int(np.searchsorted(cum, 0.75))
    middle = float(w[:, lo:hi + 1].max())
    if middle > 0:
        limits[:lo] = factor * middle
        limits[hi + 1:] = factor * middle
    return limits
