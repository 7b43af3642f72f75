"""Sub-pixel gap segmentation of frames and of a streamed video (detection, fit, smoothing, mask)."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Iterable, Iterator, NamedTuple

import numpy as np

from vfcli.flow.gap.detect import gap_mask
from vfcli.flow.gap.rays import as_rays, outermost_silhouette
from vfcli.flow.gap.subpixel.area import GapSegmentation, mask_from_edges
from vfcli.flow.gap.subpixel.profile import EdgeModel
from vfcli.flow.gap.subpixel.ray_edges import fit_ray_edges_many, fit_ray_edges_twice
from vfcli.flow.gap.subpixel.smoothing import robustness_weights, smooth_edges


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
    midline : float or (n_rays,) float, optional
        Lateral coordinate of the glottal midline, px, or its coordinate on each ray
        (:func:`vfcli.flow.gap.detect.midline_line`).
    lateral_axis : {0, 1}
    half_window_px : float
        Half-window of the edge smoothing along the glottis, px (0: none).
    half_window_frames : int
        Half-window of the edge smoothing in time, frames (0: none).
    ray_levels : (n_rays,) float, optional
        Per-ray detection level, counts (:func:`vfcli.flow.gap.subpixel.crease.detection_levels`:
        darker than the ray's closed crease by its scatter, as dark as a one-pixel slit under the
        PSF); a ray is detected at the higher of
        it and ``threshold`` (NaN rays: ``threshold``). None: ``threshold`` everywhere.
    ray_crease : (n_rays,) float, optional
        The closed crease's level on each ray, counts (:func:`vfcli.flow.gap.subpixel.crease.crease_levels`);
        a component is gap when its fitted gap level is nearer the recording's than this
        (rule (b) of :func:`raw_edges`). None or NaN: ``threshold`` instead.
    ray_gap : (n_rays,) float, optional
        The gap level seen on each ray, counts (:func:`vfcli.flow.gap.subpixel.gap_level.ray_gap_levels`): the
        edge fit's prior and rule (b)'s reference on that ray. None: ``model.gap_counts`` on every ray.
    ray_max_width : (n_rays,) float, optional
        The widest gap each ray may show, px (:func:`vfcli.flow.gap.subpixel.taper.taper_limits`: toward the
        glottis' ends a gap widens only gradually from ray to ray); a ray fitted wider is closed (rule (c) of
        :func:`raw_edges`). None or inf: no limit.
    ray_closed_floor : (n_rays,) float, optional
        The darkest the closed crease gets on each ray, counts (:func:`vfcli.flow.gap.subpixel.crease.closed_floor`:
        its median over the frames where the whole glottis is closed, less 3 times their scatter); a ray shows
        the gap only where the detection's darkest pixel on it is darker than this (rule (d) of :func:`raw_edges`).
        None or NaN: no such rule.
    exclude : (H, W) bool, optional
        Never gap: the folds' dark surroundings (:func:`vfcli.flow.gap.surround.dark_surround`).
    """

    threshold: float
    model: EdgeModel | None
    median_px: int = 5
    midline: float | np.ndarray | None = None
    lateral_axis: int = 0
    half_window_px: float = 0.0
    half_window_frames: int = 0
    ray_levels: np.ndarray | None = None
    ray_crease: np.ndarray | None = None
    ray_gap: np.ndarray | None = None
    ray_max_width: np.ndarray | None = None
    ray_closed_floor: np.ndarray | None = None
    exclude: np.ndarray | None = None

    def gap_levels(self, n_rays: int) -> np.ndarray:
        """(n_rays,) the gap level of each ray, counts (``ray_gap``, else the model's one level)."""
        if self.ray_gap is not None:
            g = np.asarray(self.ray_gap, float)
            return np.where(np.isfinite(g), g, float(self.model.gap_counts))
        return np.full(n_rays, float(self.model.gap_counts))

    def tissue_levels(self, n_rays: int) -> np.ndarray:
        """(n_rays,) the darkest tissue beside the gap on each ray, counts: the closed crease
        (``ray_crease``), else the threshold."""
        tissue = np.full(n_rays, float(self.threshold))
        if self.ray_crease is not None:
            tissue = np.where(np.isfinite(self.ray_crease), self.ray_crease, tissue)
        return tissue

    def gap_like_below(self, n_rays: int) -> np.ndarray:
        """(n_rays,) rule (b) of :func:`raw_edges`: a fitted gap level below this (half-way from the ray's
        gap level to its tissue, :meth:`tissue_levels`) is the gap's, counts."""
        return 0.5 * (self.gap_levels(n_rays) + self.tissue_levels(n_rays))


def raw_edges(frame: np.ndarray, gap: SubpixelGap) -> tuple[np.ndarray, np.ndarray]:
    """Detection and per-ray sub-pixel edges of one frame, before smoothing.

    1. Detection, the paper's intensity segmentation (:func:`gap_mask`): pixels darker
       than the threshold (or than the ray's level, ``ray_levels``, where that is higher),
       median-filtered along the glottis (``median_along_slit``, so a one-pixel slit survives),
       dark components near the midline of at least ``median_px`` pixels; on each ray, the
       component nearest the midline.
    2. Sub-pixel edges on every ray the detection crosses (:func:`fit_ray_edges`); a ray
       whose fitted edges cross (width <= 0) is closed. The fit starts from the detection's edges and
       from the outermost pixel centres surely in the gap: darker than half-way between the gap level
       and the ray's closed crease (``ray_crease``; else the threshold), and than the detection level;
       each ray keeps the start of lower misfit. Without a model, the detection's pixel boundaries.
    3. A detected component is kept only if at least ``median_px`` of its rays show the gap
       itself (:func:`_held_rays`): (a) the fitted slit covers a whole pixel: a narrower
       blurred dip cannot be told from a dark line of tissue (the contact line of a closed
       glottis), its width and level trade against each other; and (b) on the same ray, the
       fitted gap level is nearer the ray's gap level (``ray_gap``) than the threshold (than the ray's
       closed crease, with ``ray_crease``): a dark patch of tissue below the threshold is
       fitted with its own, brighter level; and (d) the detection's darkest pixel on the ray is darker
       than the closed crease gets there (``ray_closed_floor``): where the crease itself is darker than the
       threshold, it passes the detection in closed frames, and its narrow dip fits as a one-pixel slit at
       the prior's gap level, which (a) and (b) keep. This replaces the dark-core hysteresis of
       :func:`gap_mask`, whose core a narrow, blurred slit never reaches.
    4. Rule (c): a ray fitted wider than ``ray_max_width`` allows (outside the middle of the glottis, more
       than :data:`~vfcli.flow.gap.subpixel.taper.TAPER_FACTOR` times the widest of the rays between it and
       the middle) is closed: a dark patch or shadow touching the gap's tip, not the gap.

    Parameters
    ----------
    frame : (H, W) array of counts
    gap : SubpixelGap

    Returns
    -------
    e0, e1 : (n_rays,) float
        Lateral px; NaN on closed rays.
    """
    fit = ray_fits(frame, gap)
    return fit.e0, fit.e1


class RayFit(NamedTuple):
    """One frame's edges as :func:`raw_edges` gives them, with the sub-pixel fit's level and misfit on each ray.

    e0, e1 : (n_rays,) float, lateral px, NaN on closed rays.
    level : (n_rays,) float, the fitted gap level, counts, NaN on closed rays.
    rms : (n_rays,) float, the fit's RMS residual on the ray, counts, NaN on closed rays.
    """

    e0: np.ndarray
    e1: np.ndarray
    level: np.ndarray
    rms: np.ndarray


def ray_fits(frame: np.ndarray, gap: SubpixelGap) -> RayFit:
    """:func:`raw_edges` with each open ray's fitted gap level and misfit (:class:`RayFit`)."""
    return ray_fits_many([frame], gap)[0]


def ray_fits_many(frames: list, gap: SubpixelGap) -> list[RayFit]:
    """:func:`ray_fits` of several frames, their sub-pixel fits in one call
    (:func:`vfcli.flow.gap.subpixel.ray_edges.fit_ray_edges_many`)."""
    return ray_fits_twice(frames, gap, 0.0)[0]


def ray_fits_twice(frames: list, gap: SubpixelGap, search_px: float, held: bool = False
                   ) -> tuple[list[RayFit], list[RayFit]]:
    """Two readings of :func:`ray_fits_many`: as it reads them, and with each edge also searched over ``search_px`` px
    around it (:func:`vfcli.flow.gap.subpixel.ray_edges.fit_ray_edges_twice`); (started, searched), the same list when
    ``search_px`` is 0.  ``held``: the started reading's edges kept at or beyond the pixels surely in the gap
    (:func:`vfcli.flow.gap.subpixel.ray_edges.fit_ray_edges`), as :mod:`vfcli.flow.gap.subpixel.ambiguity` compares."""
    found, todo, starts = _detections(frames, gap)
    started, searched = (fit_ray_edges_twice(*starts[:3], gap.model, search_px, gap.lateral_axis, inners=starts[3],
                                             gap_counts=starts[4], held=held) if todo else ([], []))
    first = _ray_fits(found, todo, started, gap)
    return first, (first if search_px <= 0 else _ray_fits(found, todo, searched, gap))


def ray_fits_level_free(frames: list, gap: SubpixelGap, noise: float) -> tuple[list[RayFit], list[RayFit]]:
    """Two readings of the same detections: :func:`ray_fits_many`'s, and with each ray whose data reject its prior gap
    level fitted with the level free (:func:`vfcli.flow.gap.subpixel.ray_edges.free_level_where_rejected`;
    ``noise``: one pixel's noise about the model, counts); (product, level-free), as
    :mod:`vfcli.flow.gap.subpixel.ambiguity` compares them."""
    found, todo, starts = _detections(frames, gap)
    readings = []
    for level_noise in (0.0, noise):
        fits = (fit_ray_edges_many(*starts[:3], gap.model, gap.lateral_axis, inners=starts[3], gap_counts=starts[4],
                                   free_level_noise=level_noise) if todo else [])
        readings.append(_ray_fits(found, todo, fits, gap))
    return readings[0], readings[1]


def _detections(frames: list, gap: SubpixelGap) -> tuple[list, list, tuple]:
    """Step 1 of :func:`raw_edges` for each frame (:func:`_detected`): (found, todo, starts), todo the indices of the
    frames with rays to fit, starts their (frames, e0s, e1s, inners, gap_counts) lists for the edge fit."""
    found = [_detected(frame, gap) for frame in frames]
    todo = [k for k, d in enumerate(found) if d[3] is not None]
    starts = ([frames[k] for k in todo], [found[k][0] for k in todo], [found[k][1] for k in todo],
              [found[k][3] for k in todo], [found[k][4] for k in todo])
    return found, todo, starts


def _ray_fits(found: list, todo: list, fits: list, gap: SubpixelGap) -> list[RayFit]:
    """The :class:`RayFit` of each frame from its detection (``found``, :func:`_detected`) and, for the frames ``todo``,
    its sub-pixel fit (``fits``, in that order), closed rays' rules applied."""
    out = [RayFit(e0, e1, np.full(len(e0), np.nan), np.full(len(e0), np.nan)) for e0, e1, *_ in found]
    for k, fit in zip(todo, fits):
        e0, e1, level = _closed_rays(fit, found[k][2], gap, found[k][5])
        out[k] = RayFit(e0, e1, level, np.where(np.isfinite(e0), fit.rms, np.nan))
    return out


def _detected(frame: np.ndarray, gap: SubpixelGap):
    """Step 1 of :func:`raw_edges` for one frame: (e0, e1, component, inner, gap_counts, dip) with inner None when
    there is nothing to fit (no model, or no ray crossing the detection); dip: the detection's darkest pixel on each
    ray (:func:`run_minima`), counts."""
    level = _level_map(np.shape(frame), gap)
    rough = gap_mask(frame, level, gap.median_px, core_fraction=1.0, midline=gap.midline,
                     min_area_px=gap.median_px, lateral_axis=gap.lateral_axis, median_along_slit=True,
                     exclude=gap.exclude)
    rough, component = _nearest_component(rough, gap.midline, gap.lateral_axis)
    e0, e1 = outermost_silhouette(rough, gap.lateral_axis, border_is_edge=True)
    if gap.model is None or not np.isfinite(e0).any():
        return e0, e1, component, None, None, None
    # the floor of the edges: the outermost pixel centres surely in the gap, more than half covered by it.
    # Half-way between the gap level and the darkest tissue beside the gap, the ray's closed crease (the
    # medial walls seen edge-on), or the threshold where no crease is measured; never above the detection
    # level. (The threshold alone lies above dark walls under sharp optics: widened seed 1030 read its
    # walls as gap, 1-2 px too wide on each ray and in 62 closed frames.) Beyond the floor the fit decides.
    g = gap.gap_levels(len(e0))
    half = np.minimum(gap.gap_like_below(len(e0)), gap.threshold)
    floor = np.minimum(level, half[None, :] if gap.lateral_axis == 0 else half[:, None])
    # on each ray only the core's run through the pixel nearest the midline: a dark speck of texture on the wall,
    # inside the rough run (whose level lies above the walls), is below the floor too, and its pixels held the edge
    # at the speck (widened seed 1104 at the glottis' ends: edges 3-10 px too far out)
    core, _ = _nearest_component(rough & (np.asarray(frame) < floor), gap.midline, gap.lateral_axis)
    c0, c1 = outermost_silhouette(core, gap.lateral_axis, border_is_edge=True)
    inner = (np.where(np.isfinite(c0), c0 + 0.5, np.inf), np.where(np.isfinite(c1), c1 - 0.5, -np.inf))
    return e0, e1, component, inner, g, run_minima(frame, rough, gap.lateral_axis)


def run_minima(frame: np.ndarray, mask: np.ndarray, lateral_axis: int) -> np.ndarray:
    """(n_rays,) the darkest pixel of ``mask`` (H, W) bool on each ray of ``frame`` (H, W), counts; inf where
    the mask does not cross the ray."""
    vals = np.where(np.asarray(mask, bool), np.asarray(frame, float), np.inf)
    return as_rays(vals, lateral_axis).min(axis=0)


def _closed_rays(fit, component: np.ndarray, gap: SubpixelGap,
                 dip: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2-4 of :func:`raw_edges` after the sub-pixel fit: (e0, e1, fitted gap level), NaN on closed rays;
    ``dip``: the detection's darkest pixel on each ray, counts (rule (d))."""
    e0, e1 = fit.e0.copy(), fit.e1.copy()
    closed = ~(e1 > e0)
    # step 3: whole components with enough rays that hold a pixel of the gap, at the gap's level
    held = _held_rays(e0, e1, fit.levels[:, 0], component, gap, dip)
    closed |= (component == 0) | (held[component] < gap.median_px)
    if gap.ray_max_width is not None:
        closed |= (e1 - e0) > gap.ray_max_width       # rule (c): a patch touching the gap's tip
    e0[closed] = np.nan
    e1[closed] = np.nan
    return e0, e1, np.where(closed, np.nan, fit.levels[:, 0])


def _held_rays(e0: np.ndarray, e1: np.ndarray, level: np.ndarray, component: np.ndarray, gap: SubpixelGap,
               dip: np.ndarray | None = None) -> np.ndarray:
    """Per detected component, the number of its rays that show the gap itself (rules (a), (b), (d) of
    :func:`raw_edges`): the fitted slit covers a whole pixel (the pixel's area, not just its centre, lies
    between the edges), the ray's fitted gap level is nearer the ray's gap level (``gap.ray_gap``, else
    the recording's) than the ray's closed crease (else the threshold), and the detection's darkest pixel on
    the ray (``dip``) is darker than the closed crease gets there (``gap.ray_closed_floor``; no rule without
    either).

    Both are judged per ray. A slit that covers no whole pixel only shares pixels with the tissue beside
    it; its width and level trade against each other, so the level is the prior's (the recording's gap
    level), not the data's: under sharp optics a closed crease with dark texture fits as such a 1 px slit
    at the gap level. And a wide dip of dark texture fits with its own, brighter level on the rays that
    are wide, while its narrow rays carry the prior's level: a median over all the component's rays (the
    rule before) let those decide (widened seed 1030: 62 closed frames with a gap under a 2 px window).

    Parameters
    ----------
    e0, e1 : (n_rays,) float, fitted edges, lateral px (NaN or ``e1 <= e0``: closed).
    level : (n_rays,) float, each ray's fitted gap level, counts.
    component : (n_rays,) int, the detected component on each ray (0: none).
    dip : (n_rays,) float, optional, the detection's darkest pixel on each ray, counts (:func:`run_minima`).

    Returns
    -------
    (n_components,) int, indexed by component label.
    """
    a, b = np.nan_to_num(e0, nan=np.inf), np.nan_to_num(e1, nan=-np.inf)
    whole = np.floor(b - 0.5) >= np.ceil(a + 0.5)     # a pixel [c - 1/2, c + 1/2] inside [e0, e1]
    dark = level < gap.gap_like_below(len(e0))
    if dip is not None and gap.ray_closed_floor is not None:
        floor = np.asarray(gap.ray_closed_floor, float)
        dark &= ~np.isfinite(floor) | (np.asarray(dip, float) < floor)      # rule (d)
    return np.bincount(component, weights=whole & dark, minlength=int(component.max()) + 1).astype(int)


def _level_map(shape: tuple[int, int], gap: SubpixelGap):
    """Detection level per pixel (H, W) counts, or the scalar threshold without ray levels."""
    if gap.ray_levels is None:
        return gap.threshold
    lv = np.fmax(gap.ray_levels, gap.threshold)   # never below the threshold (NaN: the threshold)
    return np.broadcast_to(lv[None, :] if gap.lateral_axis == 0 else lv[:, None], shape)


def _nearest_component(mask: np.ndarray, midline, lateral_axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Each ray's run of the 8-connected component of ``mask`` nearest the midline on it.

    A dark speck of texture beside the gap is a component of its own that may pass the detection's
    tests, or part of the gap's component when it touches the gap on a neighbouring ray; on a ray that
    crosses both, the edges are the gap's run alone. (The component met first along the ray and all of
    its pixels on the ray were used before: a speck before the gap closed the ray, and the edges spanned
    both; widened seed 1038, a glottis at 45 deg with texture beside it: area +6.4 % -> +3.1 %.)

    Parameters
    ----------
    mask : (H, W) bool
    midline : float, (n_rays,) float or None
        Lateral px (None: the component met first along each ray).
    lateral_axis : {0, 1}

    Returns
    -------
    mask : (H, W) bool
        ``mask`` with, on each ray, only that component's run through the pixel nearest the midline
        (with ``midline`` None: all of the first component's pixels on the ray).
    component : (n_rays,) int
        Its label on each ray, 0 where the ray meets none.
    """
    import cv2

    _, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    lab = as_rays(labels, lateral_axis)
    n_lat, n_rays = lab.shape
    if midline is None:
        pick = np.argmax(lab > 0, axis=0)
    else:
        line = np.broadcast_to(np.asarray(midline, dtype=float), (n_rays,))
        dist = np.abs(np.arange(n_lat, dtype=float)[:, None] - line[None, :])
        pick = np.argmin(np.where(lab > 0, dist, np.inf), axis=0)
    component = lab[pick, np.arange(n_rays)]
    keep = (lab == component[None, :]) & (lab > 0)
    if midline is not None:
        # on the ray, only the run through that pixel: a speck of texture joined to the gap through a
        # neighbouring ray (8-connected) is the same component, but on this ray tissue lies between them
        start = np.vstack([keep[:1], keep[1:] & ~keep[:-1]])
        run = np.cumsum(start, axis=0)
        keep &= run == run[pick, np.arange(n_rays)][None, :]
    return (keep if lateral_axis == 0 else keep.T), component


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


#: frames whose rays are fitted in one call (:func:`ray_fits_many`): one frame's rays at a time left the fit's
#: per-call cost dominant (cProfile of `vfcli flow` on a 200-frame 128 x 128 px phantom: the fits 3.7 s of 10 s one
#: frame at a time, 2.1 s of 7.6 s sixteen at a time; the same masks)
FIT_BATCH_FRAMES = 16


def _batches(frames: Iterable[np.ndarray], n: int) -> Iterator[list[np.ndarray]]:
    """Lists of up to ``n`` frames, each a copy (a view would keep the caller's whole batch of frames alive)."""
    batch: list[np.ndarray] = []
    for frame in frames:
        batch.append(np.array(frame))
        if len(batch) == n:
            yield batch
            batch = []
    if batch:
        yield batch


def segment_stream(frames: Iterable[np.ndarray], gap: SubpixelGap) -> Iterator[tuple[np.ndarray, GapSegmentation]]:
    """Stream the sub-pixel gap over a video: (frame, its GapSegmentation), in order.

    Each frame's raw edges (:func:`raw_edges`, fitted :data:`FIT_BATCH_FRAMES` frames at a time) and robustness
    weights are kept for ``2 * half_window_frames + 1`` frames, so a frame is yielded once the
    ``half_window_frames`` frames after it and the rest of their batch have been read (at the end of the video the
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
    for batch in _batches(frames, FIT_BATCH_FRAMES):
        for frame, (e0, e1, *_) in zip(batch, ray_fits_many(batch, gap)):
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
