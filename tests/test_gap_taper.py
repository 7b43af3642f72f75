"""The glottis narrows toward its clamped ends (issue 15): a dark streak touching the gap's tip is not gap, an
hourglass-shaped gap is.

Widened seeds 1100 and 3025: a dark patch of texture (1100) and the shadow line along the folds' end (3025)
touch the tip of the gap, and on the rays past the glottis' end the edge fit found a "gap" 40-50 px wide along
the ray, in 98-109 of 250 frames: a tenth of the whole glottal area (area +7.7 % and +13.0 %, of which the
streak +9.6 % and +11.0 %). :func:`vfcli.flow.gap.subpixel.taper.taper_limits` limits each ray outside the
central half of the glottis to 1.5 times the widest opening of the rays between it and that half. (Session 24's
limit, 1.5 times the central half's widest opening on every ray outside it, closed the wide ends of widened seed
1131's hourglass-shaped gap: area -34 %.)
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from vfcli.config import FlowConfig
from vfcli.flow.gap.subpixel import segment_stream
from vfcli.flow.gap.subpixel.taper import TAPER_FACTOR, taper_limits
from vfcli.flow.pipeline import calibrate

SIZE, MID = 256, 120.3            # rows lateral (one ray per column), the glottal midline row
C0, C1 = 30.0, 226.0              # the glottis' clamped ends, columns
STREAK_COLS, STREAK_ROWS = (221, 232), (121, 162)      # a dark band along the rays at the glottis' end
#: widest opening per frame, px: one 125 Hz cycle at 10 kHz, open for half of it
CYCLE = [max(0.0, 8.0 * np.sin(2 * np.pi * k / 80)) for k in range(80)]


def _hourglass(x: np.ndarray) -> np.ndarray:
    """Width profile over the glottis (x = 0 .. 1 between the clamped ends) of an hourglass-shaped gap: 0 at the
    ends, 1.05 at x = 0.12 and 0.88, 0.30-0.35 over the middle half (widened seed 1131: its widest openings
    near the ends 2.5-3 times the middle's)."""
    bumps = np.exp(-(((x - 0.12) / 0.07) ** 2)) + np.exp(-(((x - 0.88) / 0.07) ** 2))
    return np.sin(np.pi * x) * (0.35 + 2.5 * bumps)


def _frame(width_px: float, seed: int, streak: bool = True, hourglass: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) counts and each pixel's true gap fraction: a slit of half-sine widths between C0 and C1, blurred
    by 0.8 px, with Gaussian noise; ``streak``: a dark band (500 counts) on the rays past the end, touching it,
    while the glottis is open (a dark patch of texture that moves with the folds: in the closed frames, where
    the flow step measures each ray's closed crease, it is not there)."""
    sub = 4
    r = (np.arange(SIZE * sub) + 0.5) / sub - 0.5
    rr, cc = np.meshgrid(r, r, indexing="ij")
    x = np.clip((cc - C0) / (C1 - C0), 0.0, 1.0)
    w = width_px * (_hourglass(x) if hourglass else np.sin(np.pi * x))
    frac = (np.abs(rr - MID) < 0.5 * w).reshape(SIZE, sub, SIZE, sub).mean(axis=(1, 3))
    image = 2000.0 - 1800.0 * frac
    if streak and width_px > 0:
        band = np.zeros((SIZE, SIZE), bool)
        band[STREAK_ROWS[0]:STREAK_ROWS[1], STREAK_COLS[0]:STREAK_COLS[1]] = True
        image = np.where(band & (frac == 0), 500.0, image)
    image = gaussian_filter(image, 0.8) + np.random.default_rng(seed).normal(0, 15, image.shape)
    return np.clip(image, 0, 4095).astype(np.uint16), frac


def test_a_clamped_glottis_seen_whole_or_cut_by_the_image_is_never_limited():
    """Half-sine width profiles (scaled per frame, 5 % noise) over the whole glottis and over the half from its
    middle to one end (the other half beyond the image): every ray within its limit."""
    rng = np.random.default_rng(0)
    rays = np.arange(200)
    profile = 10.0 * np.sin(np.pi * np.clip((rays - 20) / 160, 0, 1))
    widths = np.outer(rng.uniform(0.2, 1.0, 16), profile) * rng.normal(1.0, 0.05, (16, 200))
    widths[widths < 0.5] = np.nan                                     # closed where narrower than half a pixel
    for w in (widths, widths[:, 100:]):
        lim = taper_limits(w)
        assert np.all(np.nan_to_num(w, nan=0.0) <= lim[None, :])
        assert np.isinf(lim).sum() >= 0.4 * np.isfinite(w).any(axis=0).sum()        # the central half: no limit
    assert np.isinf(taper_limits(np.full((4, 50), np.nan))).all()


def test_an_hourglass_shaped_gap_wider_toward_its_ends_is_never_limited():
    """Its ends open three times as wide as its middle, rising gradually ray by ray (5 % noise per ray and
    frame): every ray within its limit. Session 24's limit (1.5 times the central half's widest) closed them."""
    rng = np.random.default_rng(1)
    rays = np.arange(200)
    profile = 10.0 * _hourglass(np.clip((rays - 20) / 160, 0, 1))
    widths = np.outer(rng.uniform(0.2, 1.0, 16), profile) * rng.normal(1.0, 0.05, (16, 200))
    widths[widths < 0.5] = np.nan
    lim = taper_limits(widths)
    assert np.all(np.nan_to_num(widths, nan=0.0) <= lim[None, :])


def test_a_wide_ray_past_the_middle_gets_the_middles_width_times_the_factor():
    widths = np.full((3, 100), np.nan)
    widths[:, 10:90] = 6.0
    widths[1, 50] = 8.0                                # the middle's widest
    widths[:, 85:90] = 30.0                            # a streak on the last rays
    lim = taper_limits(widths)
    assert np.all(lim[85:90] == TAPER_FACTOR * 8.0) and np.isinf(lim[40:60]).all()


def test_a_dark_streak_touching_the_gaps_tip_is_not_gap_and_the_area_holds():
    """The analytic glottis with a dark band along the rays at its end while it is open: the flow step's
    calibration and sub-pixel gap leave the band out and the glottal area holds (measured -2.7 %; -4.6 % on the
    same glottis without the band, its tips narrower than a pixel unseen).  Without the limit (taper_limits
    returning inf) the band was gap on its rays in 40 of the 80 frames, the area +77.4 % (measured)."""
    video, truth = zip(*[_frame(w, seed=k) for k, w in enumerate(CYCLE)])
    cal = calibrate(np.stack(video[::2]), FlowConfig(), 1e4, 15.0, 0.0)
    assert cal.gap is not None and cal.gap.ray_max_width is not None
    masks, found, true = [], 0.0, 0.0
    for (_, seg), frac in zip(segment_stream(iter(video), cal.gap), truth):
        masks.append(seg.mask)
        found += float(np.nansum(seg.e1 - seg.e0))
        true += float(frac.sum())
    band = np.stack(masks)[:, STREAK_ROWS[0] + 3:STREAK_ROWS[1], STREAK_COLS[0]:STREAK_COLS[1]]
    print(f"frames with the band in the gap mask: {int(band.any(axis=(1, 2)).sum())}; "
          f"area {100 * (found / true - 1):+.1f} %")
    assert not band.any()
    assert abs(found / true - 1) < 0.05


def test_the_wide_ends_of_an_hourglass_shaped_gap_are_gap_and_the_area_holds():
    """The analytic glottis with an hourglass-shaped gap (no streak): the flow step's sub-pixel gap keeps its wide
    ends. Measured: area -4.5 % (-43.4 % with session 24's limit, its wide ends closed in the open frames; -4.6 % for
    the half-sine glottis of the test above, its tips narrower than a pixel unseen)."""
    video, truth = zip(*[_frame(w, seed=k, streak=False, hourglass=True) for k, w in enumerate(CYCLE)])
    cal = calibrate(np.stack(video[::2]), FlowConfig(), 1e4, 15.0, 0.0)
    assert cal.gap is not None and cal.gap.ray_max_width is not None
    found, true = 0.0, 0.0
    for (_, seg), frac in zip(segment_stream(iter(video), cal.gap), truth):
        found += float(np.nansum(seg.e1 - seg.e0))
        true += float(frac.sum())
    print(f"area {100 * (found / true - 1):+.1f} %")
    assert abs(found / true - 1) < 0.05
