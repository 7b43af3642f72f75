"""The closed glottis's crease on each ray: how dark a ray gets without a gap, from the recording itself.

Where the folds touch, their medial walls are seen edge-on and darken towards the contact line,
so a closed ray has a dark dip too (a crease); a gap adds the darkness of the channel seen through
it. How dark the crease is depends on the optics (a sharp image shows the dark walls, a blurred one
averages them with the bright top surface) and on the fold's shape, so it is measured per ray from
the sampled frames: the folds close (or nearly close) in every cycle, so over a sample spread over
cycles the lightest dips of a ray are its closed phase. A ray is open when its dip is darker than
that crease level by more than the sampled closed dips scatter, and at least as dark as a
one-pixel slit makes it under the recording's PSF (:func:`detection_levels`); the sub-pixel
segmentation detects at the higher of that level and the recording's threshold, and keeps a
component whose fitted gap level is nearer the gap's than the crease's
(:class:`vfcli.flow.gap.subpixel.segment.SubpixelGap`, ``flow.gap_detection = 'crease'``).

Units: lateral px (pixel centres at integers), counts.
"""
from __future__ import annotations

import warnings

import numpy as np

from vfcli.flow.gap.rays import as_rays, outermost_silhouette
from vfcli.flow.gap.subpixel.profile import WINDOW_SIGMAS

#: Share of the sampled frames taken as a ray's closed phase: its lightest dips. The glottis of a
#: phonating larynx is closed (or nearest to closing) for a part of each cycle; a quarter is a
#: conservative closed quotient (a ray that never closes in the sample reads a darker "crease",
#: which makes its detection stricter, not looser).
CLOSED_FRACTION = 0.25

#: Standard deviations of the closed dips' scatter below their median at which a dip is called
#: open: one-sided normal tail 0.13 % (3 sigma).
Z_OPEN = 3.0

#: Narrowest slit the detection levels are set to find, px: the sub-pixel segmentation keeps a
#: gap only where it is at least one pixel wide (a narrower blurred dip cannot be told from a
#: crease, and it holds a pixel centre only by chance).
MIN_WIDTH_PX = 1.0


#: A sampled frame whose rough gap mask crosses fewer than this share of the glottis' rays (those
#: the sample sees open at all) counts as closed for :func:`closed_frames`.
CLOSED_RAY_SHARE = 0.5


def closed_frames(masks: np.ndarray, lateral_axis: int = 0, share: float = CLOSED_RAY_SHARE) -> int:
    """How many sampled frames show the glottis closed: an empty rough mask, or one that crosses fewer
    than ``share`` of the rays the sample sees open at all.

    A closed glottis's crease is dark: under sharp optics its medial walls, seen edge-on, fall below a
    threshold set between the gap and the top surface, and the rough mask keeps them as short dark
    stretches along the glottis (widened seed 298: 16-32 of its 255 rays in each of the 19 closed frames
    of 64, where an open glottis crosses 28-255), so counting empty masks alone found 1 closed frame and
    the crease was never measured. A frame that is only just open counts too; on the rays where it is open
    its dips are dark and stay out of their ray's lightest quarter (:func:`crease_levels`).

    Parameters
    ----------
    masks : (k, H, W) bool, the sampled frames' rough gap masks.
    lateral_axis : {0, 1}
    share : float, in (0, 1].
    """
    m = np.asarray(masks, bool)
    if not len(m):
        return 0
    rays = np.stack([as_rays(f, lateral_axis).any(axis=0) for f in m])
    seen = int(rays.any(axis=0).sum())
    return int((rays.sum(axis=1) < share * seen).sum()) if seen else len(m)


def dip_minima(frames: np.ndarray, centre: np.ndarray, half_px: float, lateral_axis: int = 0) -> np.ndarray:
    """Darkest pixel of each ray within ``half_px`` of its midline, for each frame.

    Parameters
    ----------
    frames : (k, H, W) counts
    centre : (n_rays,) float
        Midline on each ray, lateral px; NaN: not searched.
    half_px : float
    lateral_axis : {0, 1}

    Returns
    -------
    (k, n_rays) float, counts; NaN where not searched.
    """
    frames = np.asarray(frames)
    if frames.ndim == 2:
        frames = frames[None]
    c = np.asarray(centre, float)
    ok = np.isfinite(c)
    n_lat = as_rays(frames[0], lateral_axis).shape[0]
    h = int(np.ceil(half_px))
    rows = np.round(np.nan_to_num(c)).astype(int)[None, :] + np.arange(-h, h + 1)[:, None]
    inside = (rows >= 0) & (rows < n_lat) & ok[None, :]
    rays = np.arange(len(c))[None, :]
    out = np.empty((len(frames), len(c)))
    for i, f in enumerate(frames):
        img = as_rays(f, lateral_axis).astype(float)
        vals = np.where(inside, img[np.clip(rows, 0, n_lat - 1), rays], np.inf)
        out[i] = vals.min(axis=0)
    return np.where(ok, out, np.nan)


def crease_levels(minima: np.ndarray, closed_fraction: float = CLOSED_FRACTION,
                  smooth_rays: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Per-ray crease level and its scatter, counts.

    On each ray the lightest ``closed_fraction`` of the sampled dip minima are its closed phase;
    their median is the crease level and their scatter (1.4826 MAD; noise, texture and the
    shading's change with the folds' motion together) says how much darker an open dip must be.
    Both are smoothed along the glottis by a running median of ``smooth_rays`` rays (the crease
    changes slowly along the folds; a single ray's few closed samples scatter).

    Parameters
    ----------
    minima : (k, n_rays) float
        :func:`dip_minima` of the sampled frames.
    closed_fraction : float
        In (0, 1].
    smooth_rays : int
        Odd running-median length along the rays.

    Returns
    -------
    level, scatter : (n_rays,) float, counts; NaN on rays not searched.
    """
    m = np.asarray(minima, float)
    if not 0 < closed_fraction <= 1:
        raise ValueError(f"crease levels: closed_fraction must lie in (0, 1], got {closed_fraction}")
    n_top = max(2, int(np.ceil(closed_fraction * m.shape[0])))
    top = -np.sort(-np.where(np.isfinite(m), m, -np.inf), axis=0)[:n_top]      # lightest first
    ok = np.isfinite(top).all(axis=0)
    top = np.where(ok[None, :], top, np.nan)
    med = np.median(top, axis=0)
    scatter = 1.4826 * np.median(np.abs(top - med[None, :]), axis=0)
    return running_median(med, smooth_rays, ok), running_median(scatter, smooth_rays, ok)


def closed_sample(minima: np.ndarray, closed_fraction: float = CLOSED_FRACTION) -> np.ndarray:
    """(k,) bool: the sampled frames in which the whole glottis is surely closed.

    A frame's darkness along the glottis is the mean over the searched rays of its dip minima
    (:func:`dip_minima`): an open glottis darkens its rays at once, a closed one shows only its crease
    (the mean, not the median: a glottis that opens over only part of the searched rays still darkens it,
    while each ray's noise and texture average out). The lightest ``closed_fraction`` of the frames (at least two) are taken as closed: the same
    assumption as :func:`crease_levels` (the folds close for a quarter of the cycle), but the frames
    are chosen for the glottis as a whole, not ray by ray. Ray by ray, the lightest dips are the crease at
    its lightest (widened seed 4106, closed for more than half the cycle: the lightest quarter of one ray's
    dips 774 counts, its truly closed dips 445 in the median), since the crease darkens and lightens with the
    phase; the frames the whole glottis calls closed sample each ray's crease as it comes.

    Parameters
    ----------
    minima : (k, n_rays) float, counts; NaN on rays not searched.
    closed_fraction : float, in (0, 1].

    Returns
    -------
    (k,) bool; all False when no ray was searched.
    """
    m = np.asarray(minima, float)
    if not 0 < closed_fraction <= 1:
        raise ValueError(f"closed sample: closed_fraction must lie in (0, 1], got {closed_fraction}")
    ok = np.isfinite(m).any(axis=0)
    out = np.zeros(m.shape[0], bool)
    if not ok.any():
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # a frame with no finite dip
        lightness = np.nan_to_num(np.nanmean(m[:, ok], axis=1), nan=-np.inf)   # (k,) counts, lighter: closed
    n_closed = min(m.shape[0], max(2, int(np.ceil(closed_fraction * m.shape[0]))))
    out[np.argsort(-lightness, kind="stable")[:n_closed]] = True
    return out


def closed_floor(minima: np.ndarray, closed_fraction: float = CLOSED_FRACTION, z: float = Z_OPEN,
                 smooth_rays: int = 5, gap_like_below: float | np.ndarray | None = None) -> np.ndarray:
    """Per-ray floor of the closed crease, counts: a dip no darker than this cannot be told from the crease.

    On the frames where the whole glottis is closed (:func:`closed_sample`) each ray's dips are its crease
    as the cycle brings it (the closed phase's own shading, texture and noise); their median less ``z``
    times their scatter (1.4826 MAD) is the darkest the crease gets but for a one-sided tail (0.13 % at
    3 sigma). A dip in another frame is distinguishable from the crease only below this floor: where the
    crease is darker than the recording's threshold (a dark contact line under sharp optics; widened seed
    4106: 410-480 counts on a stretch of the glottis against a threshold of 551, read as a slit in 72 of its
    130 closed frames), the threshold cannot tell it from a slit, the floor can. A slit that is truly there
    is darker than the crease beside it: a one-pixel slit straddling two pixels under a sharp PSF reaches
    half-way from the crease to the gap level (:func:`straddled_depth`). Smoothed along the glottis by a
    running median of ``smooth_rays`` rays, as the crease levels are.

    The crease need not scatter normally about its median: where the folds' contact rolls through the closed
    phase, its dips fall into a dark and a light cluster, and the normal tail lies far below the darkest dip
    the crease shows (widened seed 4503: on one ray dips of 346-372, 459-529 and 693-939 counts over its 16
    sampled closed frames; the tail below 0 on 62 of its 173 rays, against a gap of 140-215, so that no opening
    could pass there; 65 of its 188 open frames read closed, openings up to 3.75 px among them). The floor is
    never lower than the darkest closed dip less ``z`` times the pixels' noise and texture
    (:func:`along_glottis_scatter`): darker than any closed frame shows, beyond noise.

    A ray whose closed frames' median dip is gap-like (below ``gap_like_below``: the flow step passes
    half-way from the recording's gap level to its threshold, rule (b) of
    :func:`vfcli.flow.gap.subpixel.segment.raw_edges` without a crease) shows a gap that does not close
    there (a posterior chink): its dips in those frames are that gap's, not a crease's, and it gets no
    floor (a 3 px chink open in every frame was lost from all closed frames without this).

    Parameters
    ----------
    minima : (k, n_rays) float
        :func:`dip_minima` of the sampled frames; NaN on rays not searched.
    closed_fraction, z : float
    smooth_rays : int, odd.
    gap_like_below : float or (n_rays,) float, counts, optional.

    Returns
    -------
    (n_rays,) float, counts; NaN on rays not searched (or not searched in two closed frames) and on
    gap-like rays.
    """
    m = np.asarray(minima, float)[closed_sample(minima, closed_fraction)]
    ok = np.isfinite(m).sum(axis=0) >= 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN rays
        med = np.nanmedian(m, axis=0)
        scatter = 1.4826 * np.nanmedian(np.abs(m - med[None, :]), axis=0)
        darkest = np.nanmin(m, axis=0)
    floor = np.maximum(med - z * scatter, darkest - z * along_glottis_scatter(m))
    if gap_like_below is not None:
        ok &= ~(med < np.asarray(gap_like_below, float))
    return running_median(floor, smooth_rays, ok)


def along_glottis_scatter(minima: np.ndarray) -> float:
    """How much the dips of neighbouring rays in one frame differ by the pixels' noise and texture, counts: the
    scatter (1.4826 MAD) of the differences of ``minima`` (k, n_rays) between neighbouring rays, over sqrt(2); 0 when
    no two neighbours were searched. The crease's shading changes slowly along the glottis, noise and texture from
    ray to ray."""
    d = np.diff(np.asarray(minima, float), axis=1)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def running_median(x: np.ndarray, n: int, ok: np.ndarray) -> np.ndarray:
    """Running median of ``n`` (odd) entries of ``x`` along the rays, NaN ignored; NaN where not ``ok``."""
    if n <= 1:
        return np.where(ok, x, np.nan)
    h = n // 2
    win = np.lib.stride_tricks.sliding_window_view(np.pad(np.where(ok, x, np.nan), h, constant_values=np.nan), n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN windows
        return np.where(ok, np.nanmedian(win, axis=1), np.nan)


def straddled_depth(width_px: float, sigma: float) -> float:
    """Depth, as a fraction of (tissue - gap), of the darkest pixel of a blurred slit centred on the
    boundary between two pixels (its worst placement on the pixel grid).

    The slit model samples the blurred slit at pixel centres (:func:`slit_depth`'s model, ``sigma``
    the PSF of optics and pixel); those lie half a pixel off the slit's centre, so the pixel reads
    ``T - (T - G) (Phi((w/2 + 1/2) / sigma) - Phi((1/2 - w/2) / sigma))``. Under a sharp PSF a one-pixel
    slit so placed is only half as deep as its centre (:func:`slit_depth`); under a blur of a few
    pixels the two agree.
    """
    from scipy.special import ndtr

    s = max(sigma, 1e-6)
    return float(ndtr((0.5 * width_px + 0.5) / s) - ndtr((0.5 - 0.5 * width_px) / s))


def slit_depth(width_px: float, sigma: float) -> float:
    """Depth of a blurred slit's centre as a fraction of (tissue - gap): ``erf(w / (2 sqrt(2) sigma))``.

    A slit of width ``w`` (px) under a Gaussian PSF of ``sigma`` (px) between tissue T and gap G
    reads ``T - (T - G) erf(w / (2 sqrt 2 sigma))`` at its centre.
    """
    from scipy.special import erf

    return float(erf(width_px / (2.0 * np.sqrt(2.0) * max(sigma, 1e-6))))


def detection_levels(minima: np.ndarray, gap_counts: float, sigma: float, *, z: float = Z_OPEN,
                     min_width_px: float = MIN_WIDTH_PX) -> np.ndarray:
    """Per-ray level below which a dip is gap, counts: the lower of two bounds.

    * Darker than the ray's closed crease by ``z`` times the closed dips' scatter
      (:func:`crease_levels`): a closed ray stays above it but for a 0.13 % tail.
    * Only as shallow as a slit of ``min_width_px`` reaches under the PSF, in the darkest
      pixel of its worst placement on the pixel grid (:func:`straddled_depth`, with the crease
      as the tissue level): a narrower slit cannot be told from the crease (the sub-pixel
      segmentation's own limit, :func:`vfcli.flow.gap.subpixel.segment.raw_edges` rule (a)).
      Under a sharp PSF this bound lies half-way between the crease and the gap level (it lay
      at the gap level, from the slit's centre, before: a one-pixel slit on a pixel boundary, or a
      gap whose own level varies along the glottis, was not detected); under a blur of a few
      pixels a narrow slit is shallow and the crease bound decides.

    Parameters
    ----------
    minima : (k, n_rays) float
        :func:`dip_minima` of the sampled frames.
    gap_counts : float
        The recording's gap level, counts.
    sigma : float
        PSF standard deviation (optics and pixel), px.
    z : float
    min_width_px : float

    Returns
    -------
    (n_rays,) float, counts; NaN on rays not searched.
    """
    level, scatter = crease_levels(minima)
    below_crease = level - z * scatter
    one_slit = level - straddled_depth(min_width_px, sigma) * (level - gap_counts)
    return np.fmin(below_crease, one_slit)


def search_band(centre: np.ndarray | None, masks: np.ndarray, lateral_axis: int, sigma: float):
    """Where :func:`dip_runs` looks for the gap: the midline on each ray and the search's half-width.

    Parameters
    ----------
    centre : (n_rays,) float or None
        Per-ray gap centre over the sampled masks (:func:`vfcli.flow.gap.detect.midline_from_masks`),
        lateral px, NaN where never seen; None: no gap seen.
    masks : (k, H, W) bool
        The sampled frames' rough gap masks.
    lateral_axis : {0, 1}
    sigma : float
        PSF standard deviation, px.

    Returns
    -------
    centre : (n_rays,) float or None
        Linearly interpolated between the rays where the gap was seen, NaN outside their range.
    half_px : float
        The farthest sampled gap edge from its ray's centre, plus the blur's reach
        (:data:`vfcli.flow.gap.subpixel.profile.WINDOW_SIGMAS` sigma) and one pixel, px.
    """
    if centre is None or not np.isfinite(centre).any():
        return None, 0.0
    c = np.asarray(centre, float)
    seen = np.flatnonzero(np.isfinite(c))
    rays = np.arange(len(c))
    inside = (rays >= seen[0]) & (rays <= seen[-1])
    out = np.where(inside, np.interp(rays, seen, c[seen]), np.nan)
    reach = 0.0
    for m in np.asarray(masks, bool):
        e0, e1 = outermost_silhouette(m, lateral_axis, border_is_edge=True)
        d = np.fmax(np.abs(e0 - out), np.abs(e1 - out))
        if np.isfinite(d).any():
            reach = max(reach, float(np.nanmax(d)))
    return out, reach + WINDOW_SIGMAS * sigma + 1.0


#: A ray of the glottis opens in at least this share of the sampled frames (:func:`glottis_extent`)
OPEN_SHARE = 0.1


def glottis_extent(minima: np.ndarray, levels: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(n_rays,) bool: the rays of the glottis along its midline, as far as the sampled dips show it.

    A ray belongs to the glottis when its sampled dips along the midline (:func:`dip_minima`)
    reach ``levels`` in at least :data:`OPEN_SHARE` of the frames (the flow step passes the lower
    of the detection level, :func:`detection_levels`, and half-way between the crease and the
    gap level: the glottis opened there by more than a pixel, more than now and then); the
    extent is the run of such rays that holds the rays where the sampled gap masks saw the gap
    (``seen``), with the seen rays themselves. Beyond the glottis' ends the midline crosses
    tissue or the fixture, whose dips stay near their own crease. (With the darkest dip alone
    and the detection level alone, heavy blur let the extent run on along the tissue: widened
    seed 293, area -0.7 % -> +82 %.)

    The masks see only the gap's darkest parts when the level seen through the gap varies along
    the glottis and the threshold lies near the darkest (widened seed 1060: 80-275 counts, the
    gap-core threshold 266; the masks saw 25 of its 142 rays), and the crease was searched on
    those rays alone.

    Parameters
    ----------
    minima : (k, n_rays) float, counts; NaN where not searched.
    levels : (n_rays,) float, counts (NaN: no level).
    seen : (n_rays,) bool
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN rays
        open_dip = np.nanpercentile(np.asarray(minima, float), 100 * OPEN_SHARE, axis=0)
    reach = (open_dip < levels) | np.asarray(seen, bool)
    out = np.zeros(len(reach), bool)
    idx = np.flatnonzero(seen)
    if not len(idx):
        return out
    lo, hi = int(idx.min()), int(idx.max())
    while lo > 0 and reach[lo - 1]:
        lo -= 1
    while hi < len(reach) - 1 and reach[hi + 1]:
        hi += 1
    out[lo:hi + 1] = True
    return out


def along_midline(sample: np.ndarray, centre: np.ndarray, line: np.ndarray, half_px: float, lateral_axis: int,
                  model) -> np.ndarray:
    """The crease search's per-ray centre (:func:`search_band`) continued along the fitted midline
    over the whole glottis (:func:`glottis_extent`), lateral px, NaN outside it.

    Parameters
    ----------
    sample : (k, H, W) counts, the sampled frames.
    centre : (n_rays,) float, :func:`search_band`'s centre (NaN beyond the rays the masks saw).
    line : (n_rays,) float, the fitted midline (:func:`vfcli.flow.gap.detect.midline_line`).
    half_px : float, the search's half-width.
    lateral_axis : {0, 1}
    model : :class:`vfcli.flow.gap.subpixel.profile.EdgeModel`, the gap level and PSF.
    """
    along = dip_minima(sample, line, half_px, lateral_axis)
    half = 0.5 * (crease_levels(along)[0] + model.gap_counts)
    reach = np.fmin(half, detection_levels(along, model.gap_counts, model.psf_sigma_px))
    extent = glottis_extent(along, reach, np.isfinite(centre))
    return np.where(extent & ~np.isfinite(centre), line, centre)
