"""The flow step and the tri-variate field of a recording, from arrays (reads nothing).

1. :func:`flow_pipeline`: gap mask, glottal area, opening function and horizontal
   velocity per frame. The gap threshold (unless ``flow.threshold`` is set), the 8-bit
   intensity range, the glottal midline and, for the sub-pixel gap edges
   (``flow.subpixel_edges``, :func:`vfcli.flow.gap.subpixel.segment_stream`), the gap level
   and the blur of the optics (:func:`vfcli.flow.gap.subpixel.estimate_edge_model`) come
   from ``flow.sample_frames`` frames spread evenly over the video
   (:func:`calibrate`); then the video is streamed through
   :func:`vfcli.flow.optical_flow.flow_stream`, one frame at a time, so memory does not grow
   with the number of frames.
2. :func:`velocity_fields`: the synced LDV velocities of the good points (aligned, free of
   dropouts, finite) spread over the pixel grid by the fixed thin-plate-spline operator of
   :class:`vfcli.flow.velocity_field.LdvTps` and stacked with the flow into (u, v, w), a
   chunk of frames at a time.

The lateral image axis (the rays of the opening function, the gap's midline search) is
the one the model's y axis is closest to: rows when ``|cos(rotation)| >= |sin(rotation)|``
(``[col, row] = px_per_mm * R(rotation) @ [x, y] + offset``, so y maps to
``(-sin, cos)`` in (col, row)), else columns.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Protocol

import numpy as np

from vfcli.camera.pose import gap_axis, gap_ray_axis, lateral_axis_for
from vfcli.config import FlowConfig
from vfcli.errors import InputDataError
from vfcli.flow.gap.detect import dark_core_level, gap_mask, gap_threshold, midline_from_masks, midline_line
from vfcli.flow.gap.surround import dark_surround
from vfcli.flow.gap.subpixel import EdgeModel, SubpixelGap, estimate_edge_model
from vfcli.flow.gap.subpixel.crease import (CLOSED_FRACTION, along_midline, closed_floor, closed_frames,
                                             crease_levels, detection_levels, dip_minima, search_band)
from vfcli.flow.gap.subpixel.readings import edge_readings, level_reading, with_ray_gap_levels
from vfcli.flow.optical_flow import FlowEstimator, FlowFrame, flow_stream, intensity_range
from vfcli.flow.plausibility import GAP_END_PX, GAP_LENGTH_WARN, GAP_LONGER_WARN, gap_length_share
from vfcli.flow.velocity_field import GapAwareFill, LdvTps, combine_fields, hull_mask, points_in_gap

log = logging.getLogger(__name__)

#: Frames handled at once (video batches, field chunks).
CHUNK_FRAMES = 16

#: A sampled gap covering more than this fraction of the image is implausible (a slit).
MAX_GAP_FRACTION = 0.05


class Frames(Protocol):
    """A video indexable like a (n, H, W) array: ``len``, ``shape``, ``[slice]`` and ``[int array]``
    (a numpy array, or :class:`vfcli.store.frames.FrameReader` reading the store lazily)."""

    shape: tuple[int, ...]

    def __len__(self) -> int: ...

    def __getitem__(self, key: Any) -> np.ndarray: ...


def sample_indices(n_frames: int, n_sample: int) -> np.ndarray:
    """Up to ``n_sample`` frame indices spread evenly over ``n_frames``, increasing, unique."""
    k = max(1, min(int(n_sample), int(n_frames)))
    return np.unique(np.rint(np.linspace(0, n_frames - 1, k)).astype(int))


def batches(frames: Frames, n_frames: int, size: int = CHUNK_FRAMES) -> Iterator[np.ndarray]:
    """Frames 0..n_frames-1 of the video, (<= size, H, W) at a time."""
    for i in range(0, n_frames, size):
        yield frames[i : i + size]


#: A configured camera rotation further than this from the sampled gap's principal axis (modulo a half turn,
#: which the gap cannot tell) is warned about, deg: the axis is measured to 0.1 deg on the widened phantoms
#: (docs/benchmarks.md); 10 deg mixes a sixth of the lateral velocity into the longitudinal one.
ROTATION_WARN_DEG = 10.0


def check_sampled_gap(masks: np.ndarray, threshold: float, auto: bool, lateral_axis: int = 0,
                      rotation_deg: float | None = None, pose_estimated: bool = False) -> None:
    """Warn when the gap masks of the sampled frames (k, H, W) bool do not look like a glottis.

    The folds close in every cycle and the gap is a slit: a "gap" in every sampled frame
    or one covering more than :data:`MAX_GAP_FRACTION` of the image is more likely a dark
    fixture, shadow or texture below the threshold. A gap whose principal axis runs along
    the lateral image axis means the configured camera rotation is a quarter turn off; given
    ``rotation_deg`` of a configured pose (not ``pose_estimated``: there the rotation is only the search's
    prior), one more than :data:`ROTATION_WARN_DEG` from it (modulo 180 deg) is warned about too.
    """
    how = "automatic" if auto else "configured"
    open_share = float(masks.any(axis=(1, 2)).mean())
    area_share = float(masks.mean())
    if open_share == 0:
        log.warning("flow: no glottal gap in the %d sampled frames (%s threshold %.1f counts); check that the "
                    "glottis opens in view, camera.rotation_deg (the gap must run along image %s) and "
                    "flow.threshold (counts)", len(masks), how, threshold, _ALONG[lateral_axis])
        return
    if len(masks) >= 8 and (open_share == 1 or area_share > MAX_GAP_FRACTION):
        log.warning("flow: the %s threshold %.1f counts finds a gap in %.0f%% of the %d sampled frames, covering "
                    "%.1f%% of the image on average; the folds close every cycle and the gap is a slit, so it "
                    "probably segments a dark fixture, shadow or texture (set flow.threshold, counts, by hand) or a "
                    "seam where the folds meet in shade (which no threshold separates where it is as dark as the gap)",
                    how, threshold, 100 * open_share, len(masks), 100 * area_share)
    counts = masks.sum(axis=0)
    if (counts > 0).sum() >= 3:
        angle = gap_axis(counts).rotation_deg
        other = angle - 180 if angle > 0 else angle + 180
        if gap_ray_axis(angle, lateral_axis)[1]:
            log.warning("flow: the sampled gap runs at %.0f deg in the image (along image %s) but the camera rotation "
                        "makes image %s lateral; set camera.rotation_deg (about %.0f or %.0f deg) and camera.pose, "
                        "then rerun ingest-hsc and flow", angle, _ALONG[lateral_axis_for(angle)],
                        _LATERAL[lateral_axis], angle, other)
        elif rotation_deg is not None and not pose_estimated:
            apart = abs((angle - rotation_deg + 90.0) % 180.0 - 90.0)
            if apart > ROTATION_WARN_DEG:
                log.warning("flow: the sampled gap runs at %.1f deg in the image, %.0f deg from camera.rotation_deg "
                            "%.1f deg, which the fit uses (camera.pose = 'config'): set camera.rotation_deg (about "
                            "%.0f or %.0f deg: the gap cannot tell a half turn), or camera.pose = 'estimate', then "
                            "rerun ingest-hsc and flow", angle, apart, rotation_deg, angle, other)


#: The image axis the glottis runs along, and the lateral one, for lateral_axis 0 and 1.
_ALONG = {0: "columns (left-right)", 1: "rows (top-bottom)"}
_LATERAL = {0: "rows", 1: "columns"}


def check_flow_product(area_mm2: np.ndarray, calib: "FlowCalibration", gap_counts: np.ndarray | None = None,
                       length_px: float | None = None) -> None:
    """Check the glottal area of every frame (n,) mm^2: fail on no gap at all and on a gap in every frame that is
    longer than the folds, warn on a gap in every frame (with its narrowest frame's area: on widened seed 4297, sharp
    optics, the seam where the folds meet lay in shade as dark as the open gap, 121-146 counts against the gap's
    98-413, and was read as gap in all 63 closed frames; fitted without the gap its inferior surface came out 2 %
    off against 4 % with it, docs/benchmarks.md "Session 69"), and (given the gap counts (H, W) over the frames
    and the folds' length in px) warn when the gap was found
    over less than :data:`vfcli.flow.plausibility.GAP_LENGTH_WARN` of the glottis in view, or over more than the
    folds' length (:data:`vfcli.flow.plausibility.GAP_LONGER_WARN`: the scale or the length is wrong).

    Raises
    ------
    InputDataError
        No gap in any frame: the opening, the gap term and the pose have nothing to work on. A gap in every frame
        that also spans more than the folds' length: each alone is a doubt (a stretch of open phase; a wrong scale),
        together the dark region is not the glottis of these folds, or the scale is wrong as well, and a fit to it
        is a fit to something else (widened null 2042: dark texture spots taken as gap, gap IoU 0.00, the inferior
        surface 23-33 % off with exit 0).
    """
    n = len(area_mm2)
    open_frames = int((np.asarray(area_mm2) > 0).sum())
    how = "automatic" if calib.auto else "configured"
    if open_frames == 0:
        raise InputDataError(
            f"flow: no glottal gap in any of the {n} frames ({how} threshold {calib.threshold:.1f} counts, gap "
            f"searched along image {_ALONG[calib.lateral_axis]}); check that the glottis opens in view, "
            "camera.rotation_deg with camera.pose (a glottis along the other image axis needs a rotation near "
            "+-90 deg) and flow.threshold (counts between the gap's and the folds' brightness); a glottis that "
            "never opens wider than about a pixel (a dark line in every frame) cannot be measured at this zoom: "
            "film it closer")
    every_frame = n >= 8 and open_frames == n
    measured = gap_counts is not None and length_px and (np.asarray(gap_counts) > 0).sum() >= 3
    found, in_view = gap_length_share(gap_counts, length_px) if measured else (0.0, 0.0)
    longer = measured and found > GAP_LONGER_WARN * length_px + 2 * GAP_END_PX
    if every_frame and longer:
        raise InputDataError(
            f"flow: the region taken as the glottal gap is dark in all {n} frames and spans {found:.0f} px along the "
            f"glottis, {found / length_px:.1f} times the folds' length (mesh.length_mm times camera.px_per_mm: "
            f"{length_px:.0f} px), so it is not the glottis of these folds: check flow.threshold (counts between the "
            f"gap's and the folds' brightness; the {how} one was {calib.threshold:.1f}, which may segment a dark "
            "fixture, shadow or texture), camera.px_per_mm (measured in the folds' plane, at this zoom) and "
            "mesh.length_mm")
    if every_frame:
        area = np.asarray(area_mm2, dtype=float)
        least, most = float(area.min()), float(area.max())
        log.warning("flow: a glottal gap in all %d frames, %.3g mm^2 in the narrowest (%.0f %% of the widest, %.3g "
                    "mm^2); the folds close every cycle, so either they never close in this recording, or the %s "
                    "threshold %.1f counts segments a dark fixture or shadow (check flow.threshold, counts), or the "
                    "seam where the folds meet lies in shade as dark as the gap, which no threshold separates: the "
                    "glottal area and the gap term then hold about %.3g mm^2 of seam in every frame (for a new "
                    "recording light the folds along the camera's axis; `--set optimize.gap_weight=0` fits this one "
                    "without the gap)", n, least, 100 * least / most, most, how, calib.threshold, least)
    if longer:
        log.warning("flow: the glottal gap spans %.0f px along the glottis, %.1f times the folds' length "
                    "(mesh.length_mm times camera.px_per_mm: %.0f px), which folds clamped at both ends cannot "
                    "open over: check camera.px_per_mm (measured in the folds' plane, at this zoom) and "
                    "mesh.length_mm, then rerun ingest-hsc and flow", found, found / length_px, length_px)
    if measured and in_view > 0 and found < GAP_LENGTH_WARN * in_view:
        log.warning("flow: the glottal gap was found over %.0f px of the %.0f px of glottis in view (%.0f %%; folds "
                    "clamped at both ends open over about three quarters of it): its narrow parts are not "
                    "resolved (a slit one or two pixels wide stays above the %s threshold %.1f counts), or only "
                    "part of the glottis opens. The glottal area, the gap term and the pose use the part found; "
                    "check mesh.length_mm and camera.px_per_mm, and for a new recording zoom in or sharpen the "
                    "focus", found, in_view, 100 * found / in_view, how, calib.threshold)


@dataclass(frozen=True)
class FlowCalibration:
    """What the sampled frames fix for the whole video.

    Attributes
    ----------
    threshold : float
        Gap threshold, counts.
    auto : bool
        The threshold was found automatically (flow.threshold null).
    counts_range : (float, float)
        8-bit intensity mapping, counts.
    lateral_axis : int
        0 (rows) or 1 (columns), :func:`lateral_axis_for`.
    centre : (n_rays,) float or None
        Gap centre on each ray over the sample, lateral px (None: the gap never opens).
    midline : float or None
        Median gap centre, lateral px.
    edge_model : EdgeModel or None
        Gap level and blur of the optics (sub-pixel edges; None: off or not measurable).
    gap : SubpixelGap or None
        The sub-pixel gap segmentation (None: the binary mask, pixel edges).
    midline_line : (n_rays,) float or None
        The midline on each ray, lateral px (:func:`vfcli.flow.gap.detect.midline_line`: the glottis
        at any angle to the image axis); the gap's components are kept near it. None: the gap never opens.
    gap_resolved : bool
        The sampled gap is wide enough to show its own level (the channel's darkness) in two frames on at least
        :data:`vfcli.flow.gap.subpixel.gap_level.MIN_RAYS` rays (:func:`~vfcli.flow.gap.subpixel.readings.warn_unresolved_gap`); False also
        without sub-pixel edges.
    median_along_slit : bool
        The gap was found only with the median along the glottis (:func:`vfcli.flow.gap.detect.gap_mask`): a slit the
        square median erases in every sampled frame; the binary masks use it too.
    surround : (H, W) bool or None
        The folds' dark surroundings (:func:`vfcli.flow.gap.surround.dark_surround`): never gap, and left out of the
        automatic threshold where they are as dark as the gap; None: none found, or ``flow.exclude_surround`` off.
    edge_disagreement : float
        How far the video pins the gap's edges (:func:`~vfcli.flow.gap.subpixel.readings.edge_readings`): the relative difference of the sampled
        gap's area read with the edges held beyond the pixels surely in the gap and searched over each edge's
        neighbourhood; NaN when the gap is not resolved or without sub-pixel edges.
    level_disagreement : float
        How far the video pins the gap's level along the glottis (:func:`~vfcli.flow.gap.subpixel.readings.level_reading`): the relative difference of
        the sampled gap's area read as the product reads it and with the level free on the rays whose data reject
        their prior level; NaN when the gap is not resolved or without sub-pixel edges.
    """

    threshold: float
    auto: bool
    counts_range: tuple[float, float]
    lateral_axis: int
    centre: np.ndarray | None
    midline: float | None
    edge_model: EdgeModel | None
    gap: SubpixelGap | None
    midline_line: np.ndarray | None = None
    gap_resolved: bool = False
    median_along_slit: bool = False
    surround: np.ndarray | None = None
    edge_disagreement: float = float("nan")
    level_disagreement: float = float("nan")


def _gap_agrees(masks: np.ndarray, lateral: int) -> bool:
    """The sampled gap masks (k, H, W) show a gap whose principal axis makes ``lateral`` the lateral axis, or lies
    within :data:`vfcli.camera.pose.DIAGONAL_TOLERANCE_DEG` of a diagonal, where either axis is
    (:func:`gap_ray_axis`)."""
    counts = masks.sum(axis=0)
    return bool((counts > 0).sum() >= 3 and not gap_ray_axis(gap_axis(counts).rotation_deg, lateral)[1])


def calibrate(sample: np.ndarray, cfg: FlowConfig, fps: float, px_per_mm: float, rotation_deg: float,
              axis_from_gap: bool = False) -> FlowCalibration:
    """Threshold, intensity range, lateral axis, midline and edge model from sampled frames (k, H, W) counts.

    The lateral image axis is the rotation's (:func:`lateral_axis_for`); with ``axis_from_gap``
    (the pose is estimated, the rotation only a prior) the other axis is taken when the gap
    segmented along it runs across it and the rotation's does not. Where the square median of the paper's
    segmentation erases the gap in every sampled frame (a slit never wider than about half its window), the gap is
    searched again with the median along the glottis (``median_along_slit``).
    The folds' dark surroundings (:func:`vfcli.flow.gap.surround.dark_surround`, with ``flow.exclude_surround``) are
    never gap, and are left out of the automatic threshold where they are as dark as the gap.
    Logs a warning when the sampled gap does not look like a glottis (:func:`check_sampled_gap`)
    or when sub-pixel edges are asked for but no gap is wide enough to measure them on.
    """
    auto = cfg.threshold is None
    surround = dark_surround(sample) if cfg.exclude_surround else None
    if surround is not None:
        log.info("flow: %.0f%% of the image stays dark in every sampled frame around the folds; never gap, and left "
                 "out of the automatic threshold where as dark as the gap (flow.exclude_surround)", 100 * surround.mean())
    threshold = float(gap_threshold(sample, exclude=surround)) if auto else float(cfg.threshold)
    counts_range = intensity_range(sample)
    along = False
    masks, lateral, core = _sampled_masks(sample, threshold, cfg.median_px, lateral_axis_for(rotation_deg),
                                          axis_from_gap, along, surround)
    if not masks.any():
        # a slit never wider than about half the median window: the paper's square median erases all of it
        # (widened seed 1138: a 1-3 px slit under sharp optics, no gap in any frame and `flow` exit 3)
        along = True
        masks, lateral, core = _sampled_masks(sample, threshold, cfg.median_px, lateral_axis_for(rotation_deg),
                                              axis_from_gap, along, surround)
        if masks.any():
            log.info("flow: the gap is a slit the %d px square median erases in every sampled frame; detected with "
                     "the median along the glottis", cfg.median_px)
    check_sampled_gap(masks, threshold, auto, lateral, rotation_deg, axis_from_gap)
    centre = midline_from_masks(masks, lateral)
    line = midline_line(centre)
    if line is not None:
        # again against the midline on each ray: a glottis at an angle to the image axis drifts laterally,
        # and the parts of its gap near the image's ends lie far from the largest part's centre
        masks = np.stack([gap_mask(f, threshold, cfg.median_px, lateral_axis=lateral, core_level=core, midline=line,
                                   median_along_slit=along, exclude=surround) for f in sample])
        centre = midline_from_masks(masks, lateral)
        line = midline_line(centre)
    seen = np.isfinite(centre)
    midline = float(np.median(centre[seen])) if seen.any() else None
    gap, model, resolved, disagreement, level_share = None, None, False, float("nan"), float("nan")
    if cfg.subpixel_edges:
        model = estimate_edge_model(sample, masks, lateral)
        if model is None:
            log.warning("flow: the %d sampled frames show no gap wide enough to measure the gap level and blur "
                        "on; using the binary gap mask (pixel edges)", len(sample))
        else:
            ray_levels = ray_crease = ray_floor = None
            closed = closed_frames(masks, lateral)
            if cfg.gap_detection == "crease" and closed < CLOSED_FRACTION * len(sample):
                # the crease levels are the lightest quarter of each ray's sampled dips: without a closed
                # quarter in the sample they are the open gap's own level
                log.info("flow: the glottis is closed in %d of the %d sampled frames, fewer than the quarter the "
                         "closed crease is measured on; the gap is detected at the threshold (flow.gap_detection = "
                         "'threshold')", closed, len(sample))
            elif cfg.gap_detection == "crease":
                ray_centre, search = search_band(centre, masks, lateral, model.psf_sigma_px)
                if ray_centre is not None and line is not None:
                    ray_centre = along_midline(sample, ray_centre, line, search, lateral, model)
                if ray_centre is not None:
                    minima = dip_minima(sample, ray_centre, search, lateral)
                    ray_levels = detection_levels(minima, model.gap_counts, model.psf_sigma_px)
                    ray_crease = crease_levels(minima)[0]
                    ray_floor = closed_floor(minima, gap_like_below=0.5 * (model.gap_counts + threshold))
            gap = SubpixelGap(threshold, model, cfg.median_px, line if line is not None else midline, lateral,
                              half_window_px=cfg.edge_window_mm * px_per_mm,
                              half_window_frames=int(round(cfg.edge_window_ms * 1e-3 * fps)), ray_levels=ray_levels,
                              ray_crease=ray_crease, ray_closed_floor=ray_floor, exclude=surround)
            gap, resolved, noise = with_ray_gap_levels(sample, masks, gap)
            if resolved:
                disagreement = edge_readings(sample, masks, gap)
                level_share = level_reading(sample, masks, gap, noise)
    return FlowCalibration(threshold, auto, counts_range, lateral, centre if seen.any() else None, midline, model, gap,
                           line, resolved, along, surround, disagreement, level_share)


def _sampled_masks(sample: np.ndarray, threshold: float, median_px: int, lateral: int, axis_from_gap: bool,
                   along: bool, surround: np.ndarray | None = None) -> tuple[np.ndarray, int, float | None]:
    """The sampled frames' gap masks (k, H, W) at ``threshold`` counts, the lateral axis and the core level
    (None: half the threshold) they were found with; ``along``: the median along the glottis
    (:func:`gap_mask`'s ``median_along_slit``) in place of the square one; ``surround`` (H, W) bool: never gap.

    A gap with no dark core anywhere (a blurred gap never gets near black) is searched again with its core measured
    from the darkest pixels; with ``axis_from_gap`` (the pose is estimated, the rotation only a prior) the other axis
    is taken when the gap segmented along it runs across it and the rotation's does not."""
    core = None
    masks = np.stack([gap_mask(f, threshold, median_px, lateral_axis=lateral, median_along_slit=along,
                               exclude=surround) for f in sample])
    if not masks.any():
        core = dark_core_level(sample, threshold, exclude=surround)
        masks = np.stack([gap_mask(f, threshold, median_px, lateral_axis=lateral, core_level=core,
                                   median_along_slit=along, exclude=surround) for f in sample])
        if masks.any():
            log.info("flow: no sampled gap reaches %.1f counts (half the threshold); gap cores taken below %.1f "
                     "counts, half-way from the darkest pixels to the threshold", 0.5 * threshold, core)
    if axis_from_gap and not _gap_agrees(masks, lateral):
        other = np.stack([gap_mask(f, threshold, median_px, lateral_axis=1 - lateral, core_level=core,
                                   median_along_slit=along, exclude=surround) for f in sample])
        if _gap_agrees(other, 1 - lateral):
            log.info("flow: the gap runs along image %s; taking image %s as lateral (camera.pose = 'estimate')",
                     _ALONG[1 - lateral], _LATERAL[1 - lateral])
            lateral, masks = 1 - lateral, other
    return masks, lateral, core


def flow_pipeline(frames: Frames, cfg: FlowConfig, *, fps: float, px_per_mm: float, rotation_deg: float,
                  t0_s: float, axis_from_gap: bool = False) -> tuple[FlowCalibration, Iterator[FlowFrame]]:
    """The flow step of a video: its calibration and the stream of its frames' results.

    Parameters
    ----------
    frames : (n, H, W) counts, indexable (:class:`Frames`)
        The video; read ``flow.sample_frames`` frames at once, then :data:`CHUNK_FRAMES` at a time.
    cfg : FlowConfig
        The ``[flow]`` settings.
    fps : float
        Frame rate, frames/s.
    px_per_mm : float
        Image scale, px/mm.
    rotation_deg : float
        Camera rotation, degrees.
    t0_s : float
        Time of frame 0, s.
    axis_from_gap : bool
        The rotation is a prior only (camera.pose = 'estimate'): the lateral axis may follow the gap
        (:func:`calibrate`).

    Returns
    -------
    (FlowCalibration, iterator of FlowFrame)
        One :class:`vfcli.flow.optical_flow.FlowFrame` per frame, in order (mask, opening in px,
        velocity in mm/s, area in mm^2); memory does not grow with the number of frames.
    """
    n = len(frames)
    calib = calibrate(frames[sample_indices(n, cfg.sample_frames)], cfg, fps, px_per_mm, rotation_deg, axis_from_gap)
    estimator = FlowEstimator(cfg.method, grid_step=cfg.grid_step, dis_preset=cfg.dis_preset)
    stream = flow_stream(
        batches(frames, n), fps=fps, px_per_mm=px_per_mm, threshold=calib.threshold, counts_range=calib.counts_range,
        median_px=cfg.median_px, rotation_deg=rotation_deg, lateral_axis=calib.lateral_axis,
        initial_center=calib.centre, midline=calib.midline if calib.midline_line is None else calib.midline_line,
        t0_s=t0_s,
        estimator=estimator, split_folds=cfg.split_folds, gap=calib.gap, median_along_slit=calib.median_along_slit,
        exclude=calib.surround,
    )
    return calib, stream


def good_ldv_points(ok: np.ndarray, dropout: np.ndarray, finite: np.ndarray) -> np.ndarray:
    """The LDV points the thin-plate spline uses (P,) bool: aligned, free of dropouts, finite.

    Raises
    ------
    InputDataError
        Fewer than 3 such points.
    """
    good = ok & ~dropout
    if (good & ~finite).any():
        log.warning("fields: %d aligned LDV points have non-finite velocities; left out", int((good & ~finite).sum()))
    good = good & finite
    if good.sum() < 3:
        raise InputDataError(f"only {int(good.sum())} of {len(good)} LDV points are aligned, finite and free of "
                             "dropouts; the thin-plate spline needs at least 3")
    return good


def velocity_fields(chunks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], points_px: np.ndarray,
                    good: np.ndarray, shape: tuple[int, int], cfg: FlowConfig
                    ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The tri-variate surface velocity field, a chunk of frames at a time.

    Parameters
    ----------
    chunks : iterable of (flow (k, H, W, 2) mm/s, gap (k, H, W) bool, aligned_w (P, k) mm/s)
        The flow, the gap masks and the synced LDV velocities of consecutive frames.
    points_px : (P, 2) float
        Screen position (col, row) of each LDV point on the frames' grid, px.
    good : (P,) bool
        Points the thin-plate spline uses (:func:`good_ldv_points`).
    shape : (H, W)
        Frame shape.
    cfg : FlowConfig
        ``flow.rbf_smoothing``, ``flow.ldv_skip_gap`` and ``flow.ldv_gap_margin_px`` (spots in the gap left out per
        frame, :class:`GapAwareFill`)
        and ``flow.w_inside_hull``.

    Yields
    ------
    field : (k, H, W, 3) float32, (u, v, w) mm/s
    valid : (k, H, W) bool
    """
    tps = LdvTps(points_px, good, smoothing=cfg.rbf_smoothing).fit_grid(shape)
    inside = hull_mask(points_px[good], shape) if cfg.w_inside_hull else None
    fill = GapAwareFill(points_px, good, smoothing=cfg.rbf_smoothing) if cfg.ldv_skip_gap else None
    for flow, gap, aligned in chunks:
        if fill is not None:
            aligned = fill(aligned, points_in_gap(points_px, gap, cfg.ldv_gap_margin_px))
        yield combine_fields(flow, tps.frames(aligned), gap, inside)
