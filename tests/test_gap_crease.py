"""Per-ray detection levels from the closed crease (vfcli.flow.gap.subpixel.crease, issue 15 item 4).

Analytic blurred slits (the slit model of vfcli.flow.gap.subpixel.profile, exact at any blur) with
Gaussian noise: a video whose folds close into a dark crease and open into slits 1.5-10 px wide
under a 3 px PSF. At the recording's threshold a narrow blurred slit is too shallow to be found;
at the crease-based levels it is found and its width comes out right, and the closed frames stay
closed.
"""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.flow.gap.detect import gap_threshold
from vfcli.flow.gap.subpixel import EdgeModel, SubpixelGap, segment_gap, slit_profile_model
from vfcli.flow.gap.subpixel.crease import (crease_levels, detection_levels, dip_minima, search_band, slit_depth,
                                             straddled_depth)

H, W, MID = 90, 120, 44.3          # rows lateral, one ray per column; glottal midline row
OPEN_COLS = slice(10, 110)         # the glottis; outside, the folds stay closed
G, T, SLOPE, NOISE = 150.0, 1500.0, 40.0, 15.0
WIDTHS = [0.0, 0.0, 0.0, 0.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 6.0, 3.0, 0.0, 0.0, 0.0]  # one cycle, px


def _frame(width: float, sigma: float, rng) -> np.ndarray:
    rows = np.arange(H, dtype=float)
    img = np.empty((H, W))
    for c in range(W):
        w = width if OPEN_COLS.start <= c < OPEN_COLS.stop else 0.0
        # the medial walls darken towards the gap (the ramp); closed (w = 0): a blurred crease
        img[:, c] = slit_profile_model(rows, MID - w / 2, MID + w / 2, [G, T - 300, SLOPE, T - 300, SLOPE], sigma)
    return img + rng.normal(0.0, NOISE, img.shape)


@pytest.fixture(scope="module")
def video_3px():
    rng = np.random.default_rng(11)
    frames = np.stack([_frame(w, 3.0, rng) for w in WIDTHS * 2])
    return frames


def _gap(frames, sigma, with_levels):
    model = EdgeModel(G, sigma)
    threshold = gap_threshold(frames)
    masks = np.zeros(frames.shape, bool)
    masks[:, int(MID) - 1:int(MID) + 2, OPEN_COLS] = np.asarray(WIDTHS * 2)[:, None, None] >= 6  # the sampled rough gap
    centre = np.full(W, np.nan)
    centre[OPEN_COLS] = MID
    levels = None
    if with_levels:
        c, half = search_band(centre, masks, 0, sigma)
        levels = detection_levels(dip_minima(frames, c, half, 0), G, sigma)
    return SubpixelGap(threshold, model, 5, MID, 0, ray_levels=levels), threshold, levels


def test_slit_depth_is_the_blurred_models_centre():
    rows = np.array([50.0])
    for w, s in [(1.0, 0.3), (1.0, 3.0), (2.0, 1.5), (5.0, 2.0)]:
        centre = slit_profile_model(rows, 50 - w / 2, 50 + w / 2, [G, T, 0.0, T, 0.0], s)[0]
        assert slit_depth(w, s) == pytest.approx((T - centre) / (T - G), rel=1e-6)


def test_straddled_depth_is_the_blurred_models_pixel_half_a_pixel_off_the_slits_centre():
    for w, s in [(1.0, 0.3), (1.0, 3.0), (2.0, 1.5), (1.0, 0.05)]:
        pixel = slit_profile_model(np.array([50.5]), 50 - w / 2, 50 + w / 2, [G, T, 0.0, T, 0.0], s)[0]
        assert straddled_depth(w, s) == pytest.approx((T - pixel) / (T - G), rel=1e-6)
    assert straddled_depth(1.0, 0.05) == pytest.approx(0.5, abs=1e-6)          # half in each pixel
    assert straddled_depth(1.0, 3.0) == pytest.approx(slit_depth(1.0, 3.0), rel=0.02)   # blur: placement is moot


def test_under_a_sharp_psf_a_one_pixel_slit_on_a_pixel_boundary_is_darker_than_its_rays_level():
    """The one-slit bound is the depth of the slit's worst placement on the pixel grid.

    Before, it was the depth of the slit's centre: under a 0.3 px PSF the gap level itself (150.3
    counts for a gap at 150), so a one-pixel slit straddling two pixels (each 575 counts) or a gap
    whose own level lies a little above the recording's was left to the threshold (widened seed
    1060: the gap seen through it runs from 80 to 275 counts along the glottis, threshold 266).
    """
    rng = np.random.default_rng(3)
    closed = rng.normal(1000.0, 10.0, (48, 30))
    minima = np.vstack([closed, np.full((16, 30), G)])       # a quarter of the sample open, at the gap level
    levels = detection_levels(minima, G, 0.3)
    rows = np.array([49.0, 50.0])                             # the two pixels of a slit [49, 50]
    straddled = slit_profile_model(rows, 49.0, 50.0, [G, 1000.0, 0.0, 1000.0, 0.0], 0.3)
    assert np.all(straddled.min() < levels)                   # found: 575 counts against levels of 575-576
    assert np.all(levels < 1000.0 - 3 * 10.0)                 # and the closed crease is not


def test_crease_level_and_scatter_of_the_lightest_quarter():
    rng = np.random.default_rng(5)
    k, n = 64, 40
    open_ = np.tile(np.arange(k) % 8 < 5, (n, 1)).T                     # open 5/8 of each cycle
    minima = np.where(open_, rng.uniform(200, 700, (k, n)), rng.normal(1000.0, 20.0, (k, n)))
    level, scatter = crease_levels(minima)
    # the lightest 16 of 24 closed samples: median about 1000 + 0.43 * 20, scatter a narrowed 20
    assert np.all((level > 1000) & (level < 1020))
    assert np.all((scatter > 6) & (scatter < 20))


def test_a_narrow_slit_under_3px_blur_is_found_at_the_crease_levels_and_not_at_the_threshold(video_3px):
    frames = video_3px
    gap_thr, threshold, _ = _gap(frames, 3.0, False)
    gap_lv, _, levels = _gap(frames, 3.0, True)
    assert np.all(levels[OPEN_COLS] > threshold)                       # shallower than the threshold lets through
    inner = slice(OPEN_COLS.start + 10, OPEN_COLS.stop - 10)
    for i, w in enumerate(WIDTHS):
        if w not in (1.5, 2.0, 3.0):
            continue
        old = segment_gap(frames[i], gap_thr)
        new = segment_gap(frames[i], gap_lv)
        assert np.isfinite(old.e0[inner]).mean() < 0.1                 # the threshold misses it
        width = (new.e1 - new.e0)[inner]
        assert np.isfinite(width).mean() > 0.9                          # the crease levels find it (95-100 %)
        assert abs(np.nanmedian(width) - w) < 0.1 * w                   # measured: within 1 %


def test_closed_creases_stay_closed_and_wide_slits_keep_their_width(video_3px):
    frames = video_3px
    gap_lv, _, _ = _gap(frames, 3.0, True)
    inner = slice(OPEN_COLS.start + 10, OPEN_COLS.stop - 10)
    for i, w in enumerate(WIDTHS * 2):
        seg = segment_gap(frames[i], gap_lv)
        if w == 0.0:
            assert not seg.mask.any()
        elif w >= 6.0:
            width = (seg.e1 - seg.e0)[inner]
            assert np.isfinite(width).all()
            assert abs(np.median(width) - w) < 0.03 * w                 # measured: within 1 %


def test_under_a_sharp_psf_the_levels_lie_half_way_and_closed_frames_stay_closed():
    """Under a 0.3 px PSF the one-slit bound is half-way between the crease and the gap (a one-pixel slit on a
    pixel boundary); the crease itself stays above it, so the closed frames stay closed and the slits keep
    their width. (Before: at the gap level, below the threshold, which decided alone.)"""
    rng = np.random.default_rng(12)
    frames = np.stack([_frame(w, 0.3, rng) for w in WIDTHS * 2])
    gap_lv, threshold, levels = _gap(frames, 0.3, True)
    ok = np.isfinite(levels)
    assert ok.sum() >= OPEN_COLS.stop - OPEN_COLS.start - 2
    crease = crease_levels(dip_minima(frames, np.where(ok, MID, np.nan), 5.0, 0))[0]
    half = G + 0.5 * (crease - G)
    assert np.all(np.abs(levels[ok] - half[ok]) < 0.002 * (crease[ok] - G))   # measured: 0.04 %
    inner = slice(OPEN_COLS.start + 10, OPEN_COLS.stop - 10)
    for i, w in enumerate(WIDTHS * 2):
        seg = segment_gap(frames[i], gap_lv)
        if w == 0.0:
            assert not seg.mask.any()
        else:
            width = (seg.e1 - seg.e0)[inner]
            assert np.isfinite(width).all()
            assert abs(np.median(width) - w) < 0.01 * w                 # measured: within 0.3 %


def test_the_crease_is_searched_along_the_whole_glottis_when_the_masks_see_only_its_darkest_part():
    """The level seen through the gap varies along the glottis: 130 counts on one half, 290 on the other, and the
    threshold (266, as the gap-core fallback gives on widened seed 1060) lies between. The calibration's masks see the
    dark half only. Before, the crease was searched on the rays they saw, so the bright half had no detection level
    and was detected at the threshold: never. Now the search runs along the fitted midline as far as the sampled dips
    reach a one-pixel slit's depth (glottis_extent), and the bright half is found with its width, since each ray's
    edge fit has that ray's own gap level as its prior (ray_gap_levels)."""
    from vfcli.config import FlowConfig
    from vfcli.flow.pipeline import calibrate

    rng = np.random.default_rng(21)
    rows = np.arange(H, dtype=float)
    bright = np.arange(W) >= 60

    def frame(w):
        img = np.empty((H, W))
        for c in range(W):
            wc = w if OPEN_COLS.start <= c < OPEN_COLS.stop else 0.0
            g = 290.0 if bright[c] else 130.0
            img[:, c] = slit_profile_model(rows, MID - wc / 2, MID + wc / 2, [g, T - 300, SLOPE, T - 300, SLOPE], 0.4)
        return img + rng.normal(0.0, NOISE, img.shape)

    frames = np.stack([frame(w) for w in WIDTHS * 4])
    cal = calibrate(frames, FlowConfig(threshold=266.0), 1e4, 15.0, 0.0)
    gap = cal.gap
    half = slice(70, 100)                                   # inside the bright half, away from its ends
    assert np.isfinite(gap.ray_levels[half]).all() and np.all(gap.ray_levels[half] > 290.0 + 3 * NOISE)
    # each ray's gap level, from the sampled frames where its slit is resolved: measured 265 and 130.5
    assert abs(np.median(gap.ray_gap[half]) - 290.0) < 30.0 and abs(np.median(gap.ray_gap[20:50]) - 130.0) < 5.0
    for i, w in enumerate(WIDTHS):
        seg = segment_gap(frames[i], gap)
        width = (seg.e1 - seg.e0)[half]
        if w == 0.0:
            assert not seg.mask.any()
        elif w >= 2.0:
            assert np.isfinite(width).all()
            # measured: 2 px -3.1 %, 3-10 px within 0.9 %. Before the rays' own gap levels (ray_gap_levels) the
            # fit's prior was the recording's one level (130), which pulled a narrow slit seen at 290 narrower:
            # 2 px -25 %, 3 px -3 to -4 %, 4-10 px -0.3 to -2.2 %
            assert abs(np.median(width) - w) < (0.05 if w == 2.0 else 0.015) * w


def test_a_dark_crease_in_stretches_still_counts_the_closed_frames_and_the_crease_is_measured():
    """Under sharp optics the closed crease (the medial walls seen edge-on) falls below the threshold in
    stretches along the glottis, so the rough masks of the closed frames are not empty. Counting only empty
    masks as closed (before) found no closed frame, so the crease was never measured and the gap was detected
    as with ``flow.gap_detection = 'threshold'`` (widened seed 298: 1 closed frame counted of the 19 sampled;
    66 closed frames of 250 with a gap). Now a frame whose mask crosses fewer than half of the glottis' rays
    counts as closed (closed_frames), the crease is measured, and the closed frames show less than a third of
    the false gap the threshold detection shows (before the rays' own gap levels: 2720 px against 6686 px)."""
    from vfcli.config import FlowConfig
    from vfcli.flow.pipeline import calibrate

    rng = np.random.default_rng(31)
    rows = np.arange(H, dtype=float)
    dark = (np.arange(W) // 12) % 3 == 0                   # a third of the crease, in stretches of 12 rays

    def frame(w):
        img = np.empty((H, W))
        for c in range(W):
            wc = w if OPEN_COLS.start <= c < OPEN_COLS.stop else 0.0
            t0, s = (300.0, 80.0) if dark[c] else (1000.0, 150.0)   # the walls' level at the contact line, slope
            img[:, c] = slit_profile_model(rows, MID - wc / 2, MID + wc / 2, [G, t0, s, t0, s], 0.3)
        return img + rng.normal(0.0, NOISE, img.shape)

    frames = np.stack([frame(w) for w in WIDTHS * 4])
    closed = [i for i, w in enumerate(WIDTHS * 4) if w == 0.0]
    cal = calibrate(frames, FlowConfig(threshold=700.0), 1e4, 15.0, 0.0)
    at_threshold = calibrate(frames, FlowConfig(threshold=700.0, gap_detection="threshold"), 1e4, 15.0, 0.0)
    assert cal.gap.ray_crease is not None and np.isfinite(cal.gap.ray_crease[OPEN_COLS]).all()

    def false_area(gap):
        return sum(float(np.nansum(np.fmax((seg := segment_gap(frames[i], gap)).e1 - seg.e0, 0.0))) for i in closed)

    crease, threshold = false_area(cal.gap), false_area(at_threshold.gap)
    assert crease < 0.3 * threshold                        # measured: 1008 px against 5247 px over 28 frames
    inner = slice(OPEN_COLS.start + 10, OPEN_COLS.stop - 10)
    for i, w in enumerate(WIDTHS):
        if w >= 3.0:
            seg = segment_gap(frames[i], cal.gap)
            assert abs(np.median((seg.e1 - seg.e0)[inner]) - w) < 0.05 * w   # measured: +1.6 to +3.4 %


def test_closed_frames_counts_empty_masks_and_masks_across_less_than_half_the_glottis():
    from vfcli.flow.gap.subpixel.crease import closed_frames

    masks = np.zeros((6, 30, 100), bool)
    masks[0, 14:16, 10:90] = True          # open along the whole glottis (80 rays)
    masks[1, 13:17, 20:80] = True          # open on 60 of them
    masks[2, 14:16, 30:45] = True          # a dark stretch of the closed crease: 15 rays
    masks[3, 14:16, 30:45] = masks[3, 14:16, 60:80] = True    # two stretches: 35 rays
    # masks[4], masks[5]: empty
    assert closed_frames(masks, 0) == 4
    assert closed_frames(np.swapaxes(masks, 1, 2), 1) == 4
    assert closed_frames(masks[4:], 0) == 2 and closed_frames(masks[:2], 0) == 0


def test_ray_gap_levels_come_from_resolved_slits_below_the_upper_bound_and_nowhere_else():
    from vfcli.flow.gap.subpixel.gap_level import ray_gap_levels

    n = 40
    level = np.where(np.arange(n) < 20, 100.0, 250.0)           # the channel looks brighter on one half
    widths = np.full((6, n), 8.0)
    widths[:, 30:] = 1.5                                          # never resolved there (6 sigma = 3 px)
    levels = np.tile(level, (6, 1)) + np.random.default_rng(0).normal(0, 5, (6, n))
    levels[:, 10] = 900.0                                         # a dark patch of tissue fitted as a slit
    out = ray_gap_levels(widths, levels, 0.5, upper=np.full(n, 500.0))
    assert np.all(np.abs(out[:9] - 100.0) < 10) and np.all(np.abs(out[21:30] - 250.0) < 10)
    assert np.isnan(out[10])                                      # the patch does not count: the recording's level
    assert np.isnan(out[30:]).all()                               # the caller keeps the recording's level there
    assert ray_gap_levels(np.full((6, n), 2.0), levels, 0.5) is None      # no ray resolved
    assert ray_gap_levels(widths, levels, 2.0) is None            # 6 sigma = 12 px: no 8 px slit is resolved
