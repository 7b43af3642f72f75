"""What the sampled frames say of the gap as a whole: each ray's own gap level, and how far the video pins its edges
and its level along the glottis.

The flow step (:func:`vfcli.flow.pipeline.calibrate`) fits the edges of the sampled frames with the largest rough gaps
(the open phase) before it streams the video: :func:`with_ray_gap_levels` measures each ray's gap level where the
gap shows it (or warns that it never does, :func:`warn_unresolved_gap`), and :func:`edge_readings` and
:func:`level_reading` read the same frames two more ways and warn where the readings' glottal areas differ by more
than :data:`vfcli.flow.gap.subpixel.ambiguity.AMBIGUOUS_AREA`. Units: px, counts.
"""
from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from vfcli.flow.gap.rays import as_rays
from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA, SEARCH_REACH_PX, area_disagreement
from vfcli.flow.gap.subpixel.gap_level import (MIN_RAYS, RESOLVED_MIN_PX, RESOLVED_SIGMAS, flat_floor,
                                               ray_gap_levels, resolved_width_px)
from vfcli.flow.gap.subpixel.profile import EdgeModel
from vfcli.flow.gap.subpixel.segment import SubpixelGap, ray_fits, ray_fits_level_free, ray_fits_twice
from vfcli.flow.gap.subpixel.taper import taper_limits

log = logging.getLogger(__name__)


#: The rays' gap levels are measured on at most this many sampled frames, those whose rough gap is largest
#: (the open phase, where the slits are resolved; each frame costs one edge fit of every ray)
RAY_GAP_FRAMES = 16


#: The edges are read twice (:func:`edge_readings`) on this many of the sampled frames, those whose rough gap is
#: largest (the open phase, where a wall beside the gap shows): on the 41 regression seeds and 10 fresh ones the
#: disagreements read on 8 frames were within -0.9 and +5.7 points of those on 16, for half the cost, and the warnings
#: the same but one (4146, 5.1 % on 16 frames, 4.5 % on 8; docs/benchmarks.md, "Session 58")
EDGE_READING_FRAMES = 8


def widest_sampled(masks: np.ndarray, n: int = RAY_GAP_FRAMES) -> np.ndarray:
    """Indices, in order, of the ``n`` sampled frames whose rough gap masks (k, H, W) are largest."""
    return np.sort(np.argsort(-np.asarray(masks, bool).sum(axis=(1, 2)), kind="stable")[:n])


def with_ray_gap_levels(sample: np.ndarray, masks: np.ndarray, gap: SubpixelGap
                         ) -> tuple[SubpixelGap, bool, float]:
    """``gap`` with the gap level of each ray (:func:`ray_gap_levels`) from the edge fits of the sampled
    frames with the largest rough gaps (``masks``, :data:`RAY_GAP_FRAMES`): the edge fit's prior and rule (b)'s
    reference on that ray; and, from the same fits, the widest gap each ray may show (:func:`taper_limits`). The
    detection levels keep the recording's one level (set from the rays' own, in a trial with an earlier form of
    these levels, the 52 widened seeds of docs/benchmarks.md moved by at most 0.006 in IoU).

    Returns (gap, resolved, noise), noise the median RMS misfit of those fits (one pixel's noise about the model,
    counts). Where the slit is never resolved (wide enough to show the gap's own level, with a flat
    floor at it (:func:`flat_floor`, against the fits' median misfit), in two of those frames on fewer than
    :data:`vfcli.flow.gap.subpixel.gap_level.MIN_RAYS` rays: no per-ray level),
    ``gap`` has no per-ray levels (its widths' limits only), ``resolved`` is False and it warns
    (:func:`warn_unresolved_gap`)."""
    widest = widest_sampled(masks)
    fits = [ray_fits(sample[i], gap) for i in widest]
    widths = np.stack([f.e1 - f.e0 for f in fits])
    rms = np.concatenate([f.rms for f in fits])
    noise = float(np.nanmedian(rms)) if np.isfinite(rms).any() else 0.0
    sigma = gap.model.psf_sigma_px
    flat = np.stack([flat_floor(as_rays(sample[i], gap.lateral_axis), f.e0, f.e1, f.level, sigma, noise)
                     for i, f in zip(widest, fits)])
    levels = ray_gap_levels(widths, np.stack([f.level for f in fits]), sigma, gap.gap_like_below(len(fits[0].e0)),
                            flat=flat)
    gap = replace(gap, ray_max_width=taper_limits(widths))
    if levels is None:
        warn_unresolved_gap(np.where(flat, widths, np.nan), gap.model, len(fits))
        return gap, False, noise
    return replace(gap, ray_gap=levels), True, noise


def edge_readings(sample: np.ndarray, masks: np.ndarray, gap: SubpixelGap) -> float:
    """The relative difference of the two readings of the sampled gap's area
    (:func:`vfcli.flow.gap.subpixel.ambiguity.area_disagreement`: the edge fit held beyond the pixels surely in the
    gap, and searched) on the :data:`EDGE_READING_FRAMES` sampled frames with the largest rough gaps (``masks``);
    these are fitted again, apart from the segmentation's own fits, which are not held; logs it, and warns when it
    exceeds :data:`vfcli.flow.gap.subpixel.ambiguity.AMBIGUOUS_AREA` (the gap masks, the glottal area and the gap term
    are then doubtful; the share is no bound on their error: on fresh widened seeds 4210 and 4213, a slit of 1-2 px
    beside a wall in shade that both readings take for gap, the readings differed by 13 and 7 % and the area read
    +238 and +150 %, docs/benchmarks.md "Proof panel: widened phantoms 4207-4210" and "4211-4214")."""
    widest = widest_sampled(masks, EDGE_READING_FRAMES)
    frames = [sample[i] for i in widest]
    share = area_disagreement(*ray_fits_twice(frames, gap, SEARCH_REACH_PX, held=True))
    if not np.isfinite(share):
        return share
    if share > AMBIGUOUS_AREA:
        log.warning("flow: the video does not pin the gap's edges: in the %d sampled frames with the widest gap the "
                    "glottal area read with the edges held beyond the pixels surely in the gap and the one the edge "
                    "fit finds searching %.0f px around each edge differ by %.0f %% (more than %.0f %%), so the gap "
                    "masks, the glottal area and the gap term are doubtful. That difference is no bound on the error: "
                    "a medial wall in shade (a dark band between the gap and the lit fold) that both readings take "
                    "for gap makes the area too large by more, up to several times on a slit a few pixels wide. Check "
                    "the video beside the gap: such a wall is told from the gap by its level only; light the folds "
                    "along the camera's axis if you can",
                    len(frames), SEARCH_REACH_PX, 100 * share, 100 * AMBIGUOUS_AREA)
    else:
        log.info("flow: the two readings of the gap's edges agree: the sampled glottal area differs by %.1f %%",
                 100 * share)
    return share


def level_reading(sample: np.ndarray, masks: np.ndarray, gap: SubpixelGap, noise: float) -> float:
    """The relative difference of the sampled gap's area as the flow step reads it and read with the gap level free on
    the rays whose data reject their prior level (:func:`vfcli.flow.gap.subpixel.segment.ray_fits_level_free`), on
    the :data:`EDGE_READING_FRAMES` sampled frames with the largest rough gaps (``masks``); ``noise``: one pixel's
    noise about the model, counts (:func:`with_ray_gap_levels`). Logs it, and warns when it exceeds
    :data:`vfcli.flow.gap.subpixel.ambiguity.AMBIGUOUS_AREA`.

    The product fits every ray with a prior at the recording's gap level, or at the ray's own where the gap shows it
    (:mod:`vfcli.flow.gap.subpixel.gap_level`). Where the channel seen through the gap is brighter in a part of the
    glottis the gap never opens wide enough to show it, that prior reads the slit there too narrow, or closed, and
    the two readings of the edges (:func:`edge_readings`), both at that prior, agree: widened seed 4279 read its
    glottal area 25 % low with its edge readings 2 % apart and no warning; this reading differs by 13 %
    (docs/benchmarks.md, "Session 68")."""
    if not np.isfinite(noise) or noise <= 0:
        return float("nan")
    widest = widest_sampled(masks, EDGE_READING_FRAMES)
    frames = [sample[i] for i in widest]
    share = area_disagreement(*ray_fits_level_free(frames, gap, noise))
    if not np.isfinite(share):
        return share
    if share > AMBIGUOUS_AREA:
        log.warning("flow: the video does not pin the gap's level along the glottis: in the %d sampled frames with the "
                    "widest gap, read with the gap level free where a slit's darkness rejects the level the gap shows "
                    "elsewhere, the glottal area differs by %.0f %% (more than %.0f %%), so the gap masks, the glottal "
                    "area and the gap term are doubtful. The channel seen through the gap looks brighter (or darker) "
                    "in a part of the glottis that never opens wide enough to show its own darkness; the glottal area "
                    "then reads low where it is brighter. Check the video along the glottis; light the channel below "
                    "the folds evenly if you can", len(frames), 100 * share, 100 * AMBIGUOUS_AREA)
    else:
        log.info("flow: read with the gap level free where the slit rejects it, the sampled glottal area differs by "
                 "%.1f %%", 100 * share)
    return share


def warn_unresolved_gap(widths: np.ndarray, model: EdgeModel, n_frames: int) -> None:
    """Warn that the glottal gap is never resolved: its width and the blur cannot be told apart.

    A slit shows the channel's own darkness only where it is several blur widths wide
    (:func:`vfcli.flow.gap.subpixel.gap_level.resolved_width_px`); narrower, the image holds only the
    product of its width and its depth, so edges fitted with the blurred dip's floor as the gap level
    (the recording's level, :func:`estimate_edge_model`, is then that floor) are not the slit's: on widened
    phantoms whose gap was never resolved the glottal area read -38 to +790 %, and on none within 10 %
    (docs/benchmarks.md, "A gap never resolved"); the analytic slit of tests/test_gap_blur.py under a 3 px
    blur reads -77 %.

    widths : (k, n_rays) fitted slit widths of the sampled frames with the widest gaps, px (NaN: closed, or a fit
        without a flat floor at its level, :func:`flat_floor`).
    """
    need = resolved_width_px(model.psf_sigma_px)
    w = np.asarray(widths, float)
    widest = (f"widest fit with a flat floor {np.nanmax(w):.1f} px" if np.isfinite(w).any()
              else "no fit with a flat floor")
    log.warning("flow: the glottal gap is never resolved: in the %d sampled frames with the widest gap it opens "
                "wider than %.1f px (%g blur widths of %.2f px, at least %g px), where a slit shows its own "
                "darkness, in two frames at fewer than %d places along the glottis (%s); its edges are fitted to "
                "the blurred dip, whose floor (%.0f counts) is brighter than the gap, so the gap masks, the glottal "
                "area and the gap term are not determined by this video (they can be off by a large factor either "
                "way). For a new recording zoom in or sharpen the focus",
                n_frames, need, RESOLVED_SIGMAS, model.psf_sigma_px, RESOLVED_MIN_PX, MIN_RAYS, widest,
                model.gap_counts)
