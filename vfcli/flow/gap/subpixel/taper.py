"""The glottis narrows toward its ends: the widest a ray's gap can be, from the sampled frames.

The folds are clamped at the anterior and posterior ends, so the glottal gap closes toward them. A dark
patch of texture or a shadow line that touches the tip of the gap can fall on a ray past the end and be
fitted there as a gap tens of pixels wide along the ray (widened seeds 1100 and 3025: 40-50 px, a tenth of
the whole glottal area), a jump of ten times the width of the gap's last rays. :func:`taper_limits` turns
the fitted widths of the sampled frames into a largest width per ray that grows outward from the middle of
the glottis only as fast as the gap's own widths do; :func:`vfcli.flow.gap.subpixel.segment.ray_fits`
closes a ray wider than that.
"""
from __future__ import annotations

import numpy as np

#: A ray outside the central half of the glottis may open at most this many times the widest opening found on the
#: rays between it and that half (the half's own widest included). The slack covers the fitted widths' scatter from
#: ray to ray; the gap's widths change by far less from one ray to the next (a half-sine of 200 rays: 1.6 % at its
#: quarter points), a patch touching its tip by ten times.
TAPER_FACTOR = 1.5


def taper_limits(widths: np.ndarray, factor: float = TAPER_FACTOR) -> np.ndarray:
    """(n_rays,) the widest gap each ray may show, px (inf: no limit).

    The middle of the glottis is the central half of the rays, by how often each was open in the sample
    (between the quartiles of the ray index weighted by that count); its rays get no limit. Walking outward from
    it to each end, a ray may open ``factor`` times the widest opening of the rays passed on the way (the middle's
    included) that kept within their own limits: the gap may widen toward an end, as an hourglass-shaped glottis
    does (widened seed 1131: its widest openings near the ends 2.5-3 times the middle's, which a limit of
    ``factor`` times the middle's widest closed, area -34 %), but a ray that jumps to many times the width of the
    rays inside it is a patch touching the gap's tip, and the rays beyond it do not raise the limit.

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
    widest = w.max(axis=0)
    middle = float(widest[lo:hi + 1].max())
    if middle <= 0:
        return limits
    for rays in (range(lo - 1, -1, -1), range(hi + 1, n)):
        reached = middle
        for i in rays:
            limits[i] = factor * reached
            if widest[i] <= limits[i]:
                reached = max(reached, float(widest[i]))
    return limits
