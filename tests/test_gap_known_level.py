"""The edge model with the gap's level known (estimate_edge_model(gap_counts=...), issue 15, narrow slits).

Analytic blurred slits (the slit model of vfcli.flow.gap.subpixel.profile, exact at any blur: channel G
between medial walls that brighten away from the edges, Gaussian PSF, Gaussian noise), one cycle of
widths 2-5 px under a 2.5 px PSF: no frame shows the channel's level. The median of the rough mask's
interior is then the blurred dip's floor, and with that level the PSF search under-reads the blur
and the fit reads the widest frame too wide (the widened phantoms' failure, docs/benchmarks.md). With
the level known, blur and widths follow from the same fit. (On the phantoms the level alone does not
fix the area: their rounded dark rims are not the model's ramps; bench/bench_gap_level.py.)
"""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.flow.gap.detect import gap_threshold
from vfcli.flow.gap.rays import outermost_silhouette
from vfcli.flow.gap.subpixel import estimate_edge_model, fit_ray_edges, slit_profile_model

H, W, MID = 90, 120, 44.3          # rows lateral, one ray per column; glottal midline row
OPEN_COLS = slice(10, 110)         # the glottis; outside, the folds stay closed
INNER = slice(20, 100)
G, WALL, SLOPE, NOISE, SIGMA = 200.0, 1200.0, 40.0, 15.0, 2.5
CYCLE = [0.0, 0.0, 2.0, 3.0, 4.0, 5.0, 4.0, 3.0, 2.0, 0.0]    # px, never 2 x 2 sigma wide


def _frame(width: float, rng) -> np.ndarray:
    rows = np.arange(H, dtype=float)
    img = np.empty((H, W))
    for c in range(W):
        w = width if OPEN_COLS.start <= c < OPEN_COLS.stop else 0.0
        img[:, c] = slit_profile_model(rows, MID - w / 2, MID + w / 2, [G, WALL, SLOPE, WALL, SLOPE], SIGMA)
    return img + rng.normal(0.0, NOISE, img.shape)


@pytest.fixture(scope="module")
def video():
    rng = np.random.default_rng(3)
    frames = np.stack([_frame(w, rng) for w in CYCLE * 3])
    masks = frames < gap_threshold(frames)                              # the rough gap: darker than the threshold
    masks[:, : int(MID) - 10] = False
    masks[:, int(MID) + 11:] = False
    return frames, masks


def test_with_the_level_known_an_unresolved_slit_gives_the_blur(video):
    frames, masks = video
    measured = estimate_edge_model(frames, masks, 0)
    known = estimate_edge_model(frames, masks, 0, gap_counts=G)
    assert measured.gap_counts > G + 0.3 * (WALL - G)                   # the dip's floor: 610 counts
    assert measured.psf_sigma_px < 0.7 * SIGMA                          # under-read: 1.33 px
    assert known.gap_counts == G
    assert abs(known.psf_sigma_px - SIGMA) < 0.03 * SIGMA               # measured: 2.50 px


def test_with_the_level_known_the_widest_unresolved_slit_keeps_its_width(video):
    frames, masks = video
    measured = estimate_edge_model(frames, masks, 0)
    known = estimate_edge_model(frames, masks, 0, gap_counts=G)
    i = CYCLE.index(5.0)
    e0, e1 = outermost_silhouette(masks[i], 0, border_is_edge=True)
    assert np.isfinite(e0[INNER]).all()
    old = fit_ray_edges(frames[i], e0, e1, measured, 0)
    new = fit_ray_edges(frames[i], e0, e1, known, 0)
    assert np.median((old.e1 - old.e0)[INNER]) > 1.1 * 5.0             # measured: 5.83 px
    assert abs(np.median((new.e1 - new.e0)[INNER]) - 5.0) < 0.03 * 5.0  # measured: 5.00 px


def test_the_psf_search_range_is_the_callers(video):
    frames, masks = video
    capped = estimate_edge_model(frames, masks, 0, gap_counts=G, sigma_range_px=(0.2, 2.0))
    assert capped.psf_sigma_px == pytest.approx(2.0, rel=1e-6)          # the range's top: the blur is wider
