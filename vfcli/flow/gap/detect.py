"""The glottal gap: automatic threshold, segmentation mask and glottal area.

The gap between the folds is the darkest structure of a superior view (no light comes
back through the glottis), so it is segmented by intensity, then cleaned with a median
filter (the paper, section 3.2) and by keeping only the dark connected components that
lie on the glottal midline (the texture of the silicone has dark specks too):
:func:`gap_threshold`, :func:`gap_mask`, :func:`glottal_area`.

The glottis is a slit a few pixels wide, so a mask cut at whole pixels misplaces each edge
by up to a pixel, a large share of the gap: :mod:`vfcli.flow.gap.subpixel` places the edges of what
this module detects to a fraction of a pixel.

The opening function o(y, t) built on this mask lives in :mod:`vfcli.flow.gap.opening`.

Conventions: frames are ``(H, W)`` arrays of counts (uint16 12-bit, or any real type);
rows are the lateral axis y and columns the longitudinal axis x when the rotation is 0
(``docs/conventions.md``); ``lateral_axis`` names the image axis that is lateral.
"""
from __future__ import annotations

import logging

import numpy as np


log = logging.getLogger(__name__)

#: Below this Otsu separation (distance of the class means over the pooled within-class
#: standard deviation) the sample shows no distinct dark gap: a warning is logged.
MIN_SEPARATION = 4.0


def _class_stats(hist: np.ndarray):
    """Cumulative two-class statistics of a histogram, split after each bin."""
    p = hist.astype(float) / max(hist.sum(), 1)
    idx = np.arange(len(p), dtype=float)
    w0 = np.cumsum(p)
    m0 = np.cumsum(p * idx)
    s0 = np.cumsum(p * idx * idx)
    w1 = 1.0 - w0
    with np.errstate(divide="ignore", invalid="ignore"):
        mu0 = m0 / w0
        mu1 = (m0[-1] - m0) / w1
        var0 = s0 / w0 - mu0**2
        var1 = (s0[-1] - s0) / w1 - mu1**2
    return w0, w1, mu0, mu1, var0, var1


def otsu_split(hist: np.ndarray) -> tuple[int, float]:
    """Otsu's split of a histogram: (first bin of the bright class, separation).

    The separation is the distance of the two class means over the pooled within-class
    standard deviation (in bins).
    """
    w0, w1, mu0, mu1, var0, var1 = _class_stats(hist)
    between = w0 * w1 * (mu1 - mu0) ** 2
    between[~np.isfinite(between)] = -1.0
    k = int(np.argmax(between))
    within = max(float(w0[k] * var0[k] + w1[k] * var1[k]), 1e-12)
    return k + 1, float((mu1[k] - mu0[k]) / np.sqrt(within))


def _min_error(hist: np.ndarray, min_fraction: float = 1e-3) -> int:
    """Kittler-Illingworth minimum-error split (two Gaussians of unequal size and
    spread): first bin of the bright class. Classes below ``min_fraction`` are refused."""
    w0, w1, mu0, mu1, var0, var1 = _class_stats(hist)
    with np.errstate(divide="ignore", invalid="ignore"):
        crit = w0 * np.log(var0) + w1 * np.log(var1) - 2 * (w0 * np.log(w0) + w1 * np.log(w1))
    ok = (w0 >= min_fraction) & (w1 >= min_fraction) & (var0 > 0) & (var1 > 0)
    crit[~(ok & np.isfinite(crit))] = np.inf
    return int(np.argmin(crit)) + 1


#: level of the gap core between the darkest pixels and the surface median (see gap_threshold)
CORE_LEVEL = 0.15
#: The darkest this many percent of an open frame's pixels are the gap's and the dark pixels right beside it (the true
#: gap covers 0.3-7 % of the image in the widest frame of the 29 cached widened renders of bench/bench_gap_optics.py);
#: surroundings whose darkest pixels reach below them compete with the gap in :func:`gap_threshold`, %.
GAP_PERCENT = 1.0


def gap_threshold(
    frames_sample: np.ndarray,
    *,
    open_fraction: float = 0.25,
    dark_percentile: float = 1.0,
    band_px: int = 4,
    n_bins: int = 1024,
    exclude: np.ndarray | None = None,
) -> float:
    """Automatic gap threshold of one recording, counts.

    Otsu on the whole histogram fails here: the gap is a few percent of the pixels, so
    Otsu splits the silicone's texture instead, and a closed frame has no gap at all.
    The threshold is therefore found where the gap is, in three steps:

    1. *Open frames.* The frames of the sample are ranked by their
       ``dark_percentile``-th intensity percentile (low when a dark gap is visible);
       the darkest ``open_fraction`` of them (at least one) are pooled.
    2. *Gap core.* The gap is the darkest object of an open frame: pixels darker than
       ``darkest + CORE_LEVEL (median - darkest)`` (darkest = 0.05th percentile of the
       pooled frames, median = the fold surface), median-filtered 5 x 5, are the gap
       core of each open frame. (A minimum-error threshold of the whole histogram
       was tried first and picked up the dark fixture border instead of a narrow gap.)
    3. *Edge threshold.* Otsu's threshold of the pixels within ``band_px`` of the core
       (the gap and the fold surface right next to it, in comparable proportions):
       the intensity half-way between gap and adjacent surface, where an edge pixel is
       about half covered.

    If the band has no distinct edge (Otsu separation in step 3 below
    :data:`MIN_SEPARATION`: a gap whose walls look dark edge-on, a blurred slit, or one that
    never opens), the gap-core level of step 2 is returned and the choice logged at INFO level
    (``-v``). It was a stored warning until session 38, and it did not tell a good gap from a bad
    one: it fired on the demo phantom and on 7 of the 8 fresh widened seeds 4101-4108, the two at
    issue 15's target among them (docs/benchmarks.md); the flow stage's own checks (no gap, a gap in
    every frame, a gap never resolved ...) are the warnings. Set the threshold by hand with
    ``flow.threshold`` if the mask looks wrong.

    Parameters
    ----------
    frames_sample : (k, H, W) or (H, W) array of counts
        Frames spread over at least one cycle (e.g. 64 evenly over the recording).
    open_fraction : float
        Fraction of the sample (darkest first) pooled, in (0, 1].
    dark_percentile : float
        Percentile (in %) that ranks the frames by how dark their darkest pixels are.
    band_px : int
        Width of the band around the gap core used in step 3, px.
    n_bins : int
        Histogram bins over the pooled intensity range.
    exclude : (H, W) bool, optional
        The folds' dark surroundings (:func:`vfcli.flow.gap.surround.dark_surround`), left out of every step
        where they are as dark as the gap: their darkest pixels (the 0.05th percentile over the open frames)
        below the darkest :data:`GAP_PERCENT` % of the rest of the image, the gap's and its edges'. (Under a blur
        of 2.75 px a slit is no darker than the surroundings: widened null 2042, threshold 745 from the surround,
        the mask on the texture. Where the slit is far darker, the darkest pixels are the slit's anyway, and
        leaving the surroundings out only raised the median the gap core is measured against: the threshold of
        widened seed 4127, sharp optics beside textured silicone, went from 346 to 519 counts and took dark
        texture beside the slit, area +6 -> +42 %.)

    Returns
    -------
    float
        Threshold in counts: pixels strictly below it are gap candidates.
    """
    import cv2

    frames = np.asarray(frames_sample)
    if frames.ndim == 2:
        frames = frames[None]
    if frames.ndim != 3 or frames.shape[0] == 0:
        raise ValueError(f"gap threshold: expected (k, H, W) frames, got shape {frames.shape}")
    if not 0 < open_fraction <= 1:
        raise ValueError(f"gap threshold: open_fraction must lie in (0, 1], got {open_fraction}")

    def darkest_frames(pixels: np.ndarray) -> np.ndarray:
        """The ``open_fraction`` of frames (k, n_pixels) whose ``dark_percentile``-th percentile is lowest."""
        score = np.percentile(pixels, dark_percentile, axis=1)
        return np.argsort(score, kind="stable")[:max(1, int(round(open_fraction * len(frames))))]

    flat, order = frames.reshape(len(frames), -1), None
    inside = None if exclude is None else ~np.asarray(exclude, dtype=bool)
    if inside is not None:
        if not inside.any():
            raise ValueError("gap threshold: every pixel is excluded")
        rest = frames[:, inside]
        order = darkest_frames(rest)
        if np.percentile(frames[order][:, ~inside], 0.05) < np.percentile(rest[order], GAP_PERCENT):
            flat = rest                   # as dark as the gap: left out
        else:
            inside, order = None, None    # lighter than the gap: as if nothing were excluded
    if order is None:
        order = darkest_frames(flat)
    chosen, pixels = frames[order].astype(np.float32), flat[order].astype(np.float32)
    lo, hi = float(pixels.min()), float(pixels.max())
    if hi <= lo:
        return hi + 0.5
    # the gap is the darkest object in an open frame: its core lies well below the surface
    darkest = float(np.percentile(pixels, 0.05))
    core_threshold = darkest + CORE_LEVEL * (float(np.median(pixels)) - darkest)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    band = []
    for f in chosen:
        dark = f < core_threshold if inside is None else (f < core_threshold) & inside
        near = cv2.dilate(cv2.medianBlur(dark.astype(np.uint8) * 255, 5), kernel) > 0
        band.append(f[near if inside is None else near & inside])
    pooled = np.concatenate(band) if band else np.empty(0)
    if pooled.size < 16:
        log.warning("gap threshold: no gap core found in the sampled frames; using the "
                    "minimum-error threshold %.1f counts", core_threshold)
        return core_threshold
    hist, edges = np.histogram(pooled, bins=n_bins, range=(float(pooled.min()), float(pooled.max()) + 1e-3))
    k, separation = otsu_split(hist)
    threshold = float(edges[k])
    if separation < MIN_SEPARATION:
        log.info(
            "gap threshold: no distinct edge between gap and surface (Otsu separation %.2f < %.1f, "
            "e.g. dark medial walls seen edge-on, or a blurred slit); using the gap-core level %.1f counts instead "
            "of %.1f. Check the detected gap outlined on four frames of a cycle in `vfcli report`'s page; set "
            "flow.threshold by hand only if it misses the gap",
            separation, MIN_SEPARATION, core_threshold, threshold,
        )
        return core_threshold
    return threshold


def gap_mask(
    frame: np.ndarray,
    threshold: float,
    median_px: int = 5,
    *,
    core_fraction: float = 0.5,
    midline: float | np.ndarray | None = None,
    band_px: float | None = None,
    min_area_px: int | None = None,
    lateral_axis: int = 0,
    median_along_slit: bool = False,
    core_level: float | None = None,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Segment the glottal gap of one frame.

    1. Threshold: pixels strictly darker than ``threshold`` (counts).
    2. Median filter of the binary image, ``median_px`` x ``median_px`` (the paper's
       robustness to noise; it also erases a closed glottis's thin dark contact line,
       of width below about ``median_px / 2``). With ``median_along_slit`` the window is
       ``median_px`` pixels along the longitudinal axis only (1 x ``median_px`` when rows
       are lateral), turned along the midline when ``midline`` is given per ray
       (:func:`binary_median_line`): it removes noise pixels and specks shorter than
       ``median_px / 2`` along the glottis but keeps a slit of any width and angle, down to
       one pixel (a square window erases the glottis just after it opens and just before it
       closes).
    3. Keep the gap component(s), rejecting the fixture (:func:`fixture_components`: a dark
       region that runs along a lateral image border, reaches one on most of its own rays or is
       far thicker than a glottis; a gap that runs off the image at its ends is kept), the dark
       specks of the
       texture and of a closed glottis's contact line: an 8-connected dark component is kept when

       * it holds at least ``median_px`` *core* pixels, darker than
         ``core_fraction * threshold`` (hysteresis: the open gap is black, much darker
         than any texture; the threshold itself sits half-way between gap and
         surface, where the darkest texture may reach),
       * it has at least ``min_area_px`` pixels (default ``median_px**2``),
       * its centroid lies within ``band_px`` (default 15% of the lateral image size)
         of the glottal midline along the lateral axis; the midline is ``midline``
         when given (one lateral position, or one per ray for a glottis at an angle to
         the image axes: :func:`midline_line`), else the lateral centroid of the largest
         qualifying component.

       Several components may be kept (a glottis can open in two places).

    Parameters
    ----------
    frame : (H, W) array of counts
    threshold : float
        Counts; see :func:`gap_threshold`.
    median_px : int
        Odd median filter size, px; 1 disables the filter.
    core_fraction : float
        Core pixels are darker than ``core_fraction * threshold``; 0 < core_fraction <= 1
        (1 disables the hysteresis).
    midline : float or (n_rays,) float, optional
        Lateral pixel coordinate of the glottal midline (row when ``lateral_axis=0``), or
        its coordinate on each ray (:func:`midline_line`): a component is then measured
        against the midline at the ray through its centroid. A glottis at 20 deg to the
        image axis drifts 90 px laterally over a 256 px image, so one lateral position
        rejects the parts of the gap near the image's ends.
    band_px : float, optional
        Largest lateral distance of a kept component's centroid from the midline, px.
    min_area_px : int, optional
        Smallest kept component, px.
    lateral_axis : {0, 1}
        Image axis that is lateral: 0 = rows (rotation 0), 1 = columns.
    median_along_slit : bool
        Median window along the longitudinal axis only (see step 2).
    core_level : float, optional
        Core pixels are darker than this (counts) instead of ``core_fraction * threshold``
        (:func:`dark_core_level`: under a blur of a few pixels the gap's interior never gets
        that dark).
    exclude : (H, W) bool, optional
        Never gap: the folds' dark surroundings (:func:`vfcli.flow.gap.surround.dark_surround`); a slit
        that reaches them is cut there rather than joined to them (and then rejected as the fixture).

    Returns
    -------
    (H, W) bool
        True in the gap.
    """
    import cv2

    if median_px < 1 or median_px % 2 == 0:
        raise ValueError(f"gap mask: median_px must be odd and >= 1, got {median_px}")
    if not 0 < core_fraction <= 1:
        raise ValueError(f"gap mask: core_fraction must lie in (0, 1], got {core_fraction}")
    if lateral_axis not in (0, 1):
        raise ValueError(f"gap mask: lateral_axis must be 0 (rows) or 1 (columns), got {lateral_axis}")
    dark = np.asarray(frame) < threshold
    if exclude is not None:
        dark &= ~np.asarray(exclude, dtype=bool)
    dark = dark.astype(np.uint8) * 255
    if median_px > 1 and median_along_slit:
        slope = midline_slope(midline) if np.ndim(midline) == 1 else 0.0
        dark = binary_median_line(dark > 0, median_px, 1 - lateral_axis, slope).astype(np.uint8) * 255
    elif median_px > 1:
        dark = cv2.medianBlur(dark, median_px)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(dark, connectivity=8)
    if n <= 1:
        return np.zeros(dark.shape, dtype=bool)
    area = stats[1:, cv2.CC_STAT_AREA]
    lateral = centroids[1:, 1 - lateral_axis]  # centroids are (x=col, y=row)
    core = np.asarray(frame) < (core_fraction * threshold if core_level is None else core_level)
    n_core = np.bincount(labels[core], minlength=n)[1:]
    if min_area_px is None:
        min_area_px = median_px * median_px
    if band_px is None:
        band_px = 0.15 * dark.shape[lateral_axis]
    keep = (area >= min_area_px) & (n_core >= median_px)
    keep &= ~fixture_components(labels, stats[1:], lateral_axis)
    if not keep.any():
        return np.zeros(dark.shape, dtype=bool)
    if midline is None:
        midline = float(lateral[int(np.argmax(np.where(keep, area, -1)))])
    if np.ndim(midline) == 1:
        line = np.asarray(midline, dtype=float)
        along = centroids[1:, lateral_axis]   # the ray through each component's centroid
        midline = np.interp(along, np.arange(len(line), dtype=float), line)
    keep &= np.abs(lateral - midline) <= band_px
    lut = np.concatenate([[False], keep])
    return lut[labels]


def dark_core_level(frames_sample: np.ndarray, threshold: float, core_fraction: float = 0.5,
                    dark_percentile: float = 0.05, exclude: np.ndarray | None = None) -> float:
    """Core level of :func:`gap_mask` measured from the recording's own darkest pixels, counts.

    ``darkest + core_fraction * (threshold - darkest)``, darkest = the ``dark_percentile``-th
    percentile of the sampled frames (k, H, W) (the gap at its widest): the core is the half of the
    range between the gap and the threshold nearer the gap. ``core_fraction * threshold`` measures
    that range from zero counts instead, which only a sharp, black gap reaches: under a blur of 3 px
    (widened seed 174) the widest gap's darkest pixels stay at 380-420 counts against a core level
    of 297, so no gap was found in any frame. Pixels in ``exclude`` (H, W) bool, the folds' dark surroundings,
    are left out.
    """
    frames = np.asarray(frames_sample)
    darkest = float(np.percentile(frames if exclude is None else frames[..., ~np.asarray(exclude, dtype=bool)],
                                  dark_percentile))
    return darkest + core_fraction * (float(threshold) - darkest)


#: A dark component whose mean lateral thickness exceeds this fraction of the lateral image size is not a gap.
MAX_GAP_LATERAL_FRACTION = 0.4
#: A dark component running along a lateral image border for more than this fraction of it is the fixture.
MAX_BORDER_RUN_FRACTION = 0.5
#: A dark component reaching a lateral image border on more than this fraction of its own rays (its longitudinal
#: extent) is the fixture: the fixture's dark surroundings cut into pieces, each shorter than half a border.
MAX_OWN_BORDER_FRACTION = 0.5


def fixture_components(labels: np.ndarray, stats: np.ndarray, lateral_axis: int = 0) -> np.ndarray:
    """Which dark components (labels 1..n) are fixture, not gap.

    The glottis is a slit along the longitudinal image axis at any angle up to 45 deg from it;
    it may run past the image at either end (a field of view shorter than the glottis), through
    the longitudinal borders or, turned, through the lateral ones, where it crosses the border
    over a short run of its rays. A component is the fixture, a channel wall or a shadow when

    * it runs along a lateral image border (the first or last row when rows are lateral) for more
      than :data:`MAX_BORDER_RUN_FRACTION` of it,
    * it reaches one lateral image border on more than :data:`MAX_OWN_BORDER_FRACTION` of its own rays
      (its longitudinal extent): the fixture's dark surroundings broken by brighter spots into pieces,
      each shorter than half a border (widened seed 4206, blur 2.89 px, passed as gap, and the largest
      piece set the glottal midline far from the slit),
    * or its mean lateral thickness (area over its longitudinal extent) is more than
      :data:`MAX_GAP_LATERAL_FRACTION` of the lateral image size.

    Parameters
    ----------
    labels : (H, W) int
        ``cv2.connectedComponentsWithStats`` labels (0: background).
    stats : (n, 5) int
        Its stats rows of components 1..n (left, top, width, height, area), px.
    lateral_axis : {0, 1}
        0: rows are lateral (the gap runs along the columns), 1: columns are lateral.

    Returns
    -------
    (n,) bool
        True for the fixture.
    """
    import cv2

    st = np.asarray(stats).reshape(-1, 5)
    n = len(st)
    lab = np.asarray(labels) if lateral_axis == 0 else np.asarray(labels).T   # rows lateral
    n_lat, n_long = lab.shape
    # rays (longitudinal positions, px) on which each component reaches the first and the last lateral row
    run = np.maximum(np.bincount(lab[0], minlength=n + 1)[1:], np.bincount(lab[-1], minlength=n + 1)[1:])
    extent = st[:, cv2.CC_STAT_WIDTH] if lateral_axis == 0 else st[:, cv2.CC_STAT_HEIGHT]   # longitudinal, px
    thickness = st[:, cv2.CC_STAT_AREA] / np.maximum(extent, 1)
    return ((run > MAX_BORDER_RUN_FRACTION * n_long) | (run > MAX_OWN_BORDER_FRACTION * extent)
            | (thickness > MAX_GAP_LATERAL_FRACTION * n_lat))


def midline_slope(midline: np.ndarray) -> float:
    """The glottal midline's drift across the rays, lateral px per ray: the slope of a least-squares
    line through its finite entries (0 with fewer than two).

    Parameters
    ----------
    midline : (n_rays,) float, lateral px (NaN: unknown)
    """
    m = np.asarray(midline, float)
    ok = np.flatnonzero(np.isfinite(m))
    if len(ok) < 2:
        return 0.0
    return float(np.polyfit(ok.astype(float), m[ok], 1)[0])


def binary_median_line(mask: np.ndarray, size: int, axis: int, slope: float = 0.0) -> np.ndarray:
    """Median filter of a binary image along a straight digital line (majority of ``size`` pixels).

    The window holds the pixels ``(k, round(k * slope))``, ``k = -size//2 .. size//2``, with ``k``
    along ``axis`` and the offset along the other axis: along the glottis when ``slope`` is the
    midline's drift (:func:`midline_slope`). A slit one pixel wide at an angle to the image axes is
    a staircase; a window along the image axis crosses it in one or two of its pixels and erases it
    (widened seed 1015, a glottis at 41 deg: a slit about 1 px wide found on 50 of its 116 rays).

    Parameters
    ----------
    mask : (H, W) bool
    size : int
        Odd window length, px.
    axis : {0, 1}
        Image axis along which ``k`` runs (the longitudinal axis).
    slope : float
        Offset along the other axis per pixel along ``axis``; 0: the window along the image axis.

    Returns
    -------
    (H, W) bool
        True where more than half of the window is True (the border pixel is repeated).
    """
    import cv2

    h = int(size) // 2
    k = np.arange(-h, h + 1)
    off = np.round(k * float(slope)).astype(int)
    reach = int(np.abs(off).max(initial=0))
    kernel = np.zeros((2 * h + 1, 2 * reach + 1), np.float32)
    kernel[k + h, off + reach] = 1.0
    if axis == 1:
        kernel = kernel.T
    # a correlation (cv2.filter2D does not flip the kernel), the border pixel repeated; the counts are exact
    counts = cv2.filter2D(np.asarray(mask, dtype=np.float32), -1, kernel, borderType=cv2.BORDER_REPLICATE)
    return counts > h + 0.5


def midline_line(centre: np.ndarray, *, clip_px: float = 2.0) -> np.ndarray | None:
    """The glottal midline on every ray: a straight line fitted to the per-ray gap centres, lateral px.

    The glottis is straight in a superior view but may run at any angle to the image axes
    (up to 45 deg from the longitudinal one); a least-squares line through the centres
    (:func:`midline_from_masks`), refitted once without the centres further from it than
    ``max(clip_px, 3 x`` their median distance``)`` (a speck of texture next to the gap), gives the
    midline on the rays where the gap was never seen too (extrapolated).

    Parameters
    ----------
    centre : (n_rays,) float
        Gap centre per ray, lateral px; NaN where the gap was never seen.
    clip_px : float
        Smallest distance from the first line at which a centre is left out, px.

    Returns
    -------
    (n_rays,) float, or None when fewer than 2 rays hold a centre.
    """
    c = np.asarray(centre, dtype=float)
    ray = np.arange(len(c), dtype=float)
    ok = np.isfinite(c)
    if ok.sum() < 2:
        return None
    for _ in range(2):
        slope, offset = np.polyfit(ray[ok], c[ok], 1)
        dist = np.abs(c - (offset + slope * ray))
        keep = ok & (dist <= max(clip_px, 3.0 * float(np.median(dist[ok]))))
        if keep.sum() < 2 or keep.sum() == ok.sum():
            break
        ok = keep
    return offset + slope * ray


def glottal_area(mask: np.ndarray, px_per_mm: float) -> np.ndarray | float:
    """Glottal area, mm^2: gap pixels over px_per_mm^2.

    Parameters
    ----------
    mask : (H, W) or (T, H, W) bool
    px_per_mm : float
        Image scale, px/mm.

    Returns
    -------
    float, or (T,) float array for a stack of masks.
    """
    if px_per_mm <= 0:
        raise ValueError(f"glottal area: px_per_mm must be positive, got {px_per_mm}")
    m = np.asarray(mask, dtype=bool)
    count = m.sum(axis=(-2, -1))
    area = count / float(px_per_mm) ** 2
    return float(area) if m.ndim == 2 else area.astype(float)


def midline_from_masks(masks: np.ndarray, lateral_axis: int = 0) -> np.ndarray:
    """Per-ray centre of the gap pooled over several masks, lateral px.

    A ray is one column (``lateral_axis=0``) or one row (``lateral_axis=1``). The
    result is the mean lateral coordinate of the gap pixels of that ray over all masks,
    NaN where the ray never meets the gap. Feed it to
    :class:`vfcli.flow.gap.opening.OpeningTracker` as ``initial_center``.

    Parameters
    ----------
    masks : (k, H, W) or (H, W) bool

    Returns
    -------
    (n_rays,) float
    """
    m = np.asarray(masks, dtype=bool)
    if m.ndim == 2:
        m = m[None]
    if lateral_axis == 1:
        m = np.swapaxes(m, 1, 2)
    pos = np.arange(m.shape[1], dtype=float)[None, :, None]
    count = m.sum(axis=(0, 1))
    total = (m * pos).sum(axis=(0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)
