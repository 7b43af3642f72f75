"""A resolved slit shows a flat floor at its fitted level (issue 15, items 1 and 4: no silent failure).

On widened seeds 4121 and 3006 the edge fit took a wide stretch of dark tissue at one end of the
glottis for the gap: "slits" 16-36 px wide at 700-1075 counts around a 3-5 px gap whose blurred dip
reached 300-500 counts below them. Being wider than six blur widths they passed the width test, so
4121's video, whose slit is never resolved, was stated resolved (its glottal area +41.8 %, no
warning). :func:`flat_floor` asks what a resolved width stands for: the middle of the slit at the
fitted level, as flat as the noise allows. Profiles here are analytic (Gaussian PSF, Gaussian noise).
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from vfcli.flow.gap.subpixel.gap_level import FLAT_FLOOR_ALPHA, flat_floor, ray_gap_levels

SIGMA = 1.87      # px, 4121's drawn blur
NOISE = 20.0      # counts


def _slit(rows: np.ndarray, e0: float, e1: float, gap: float, tissue: np.ndarray, sigma: float) -> np.ndarray:
    """The blurred scene: ``tissue`` (per row) outside [e0, e1], ``gap`` inside, counts."""
    inside = ndtr((rows - e0) / sigma) - ndtr((rows - e1) / sigma)
    return tissue * (1 - inside) + gap * inside


def test_a_resolved_slit_passes_and_fails_only_at_the_tests_rate():
    """Slits 6 to 20 blur widths wide at the gap level, noise of the stated size: the floor is judged flat on all
    but about FLAT_FLOOR_ALPHA of them (the bounds: the binomial's three standard deviations, 1 +- 0.3 %)."""
    rng = np.random.default_rng(7)
    rows = np.arange(80, dtype=float)
    n = 10000
    widths = rng.uniform(6 * SIGMA, 20 * SIGMA, n)
    e0 = 40 - widths / 2 + rng.uniform(-0.5, 0.5, n)
    e1 = e0 + widths
    rays = np.stack([_slit(rows, a, b, 160.0, np.full(80, 1400.0), SIGMA) for a, b in zip(e0, e1)], axis=1)
    rays += rng.normal(0, NOISE, rays.shape)
    flat = flat_floor(rays, e0, e1, np.full(n, 160.0), SIGMA, NOISE)
    rate = 1 - flat.mean()
    print(f"rejected {100 * rate:.2f} % at alpha {FLAT_FLOOR_ALPHA}")
    assert 0.007 <= rate <= 0.013, rate


def test_a_wide_fit_over_dark_tissue_around_a_narrow_dip_has_no_flat_floor():
    """4121's end of the glottis, analytic: dark tissue (950 counts, 30 px) with a 3.5 px gap inside it near one
    side, blurred by 1.87 px; fitted as one 31 px slit at the tissue's level (941 counts, as on seed 4121's ray
    220), the floor is not flat, while the same fit's width passes the width test (6 x 1.87 = 11.2 px)."""
    rng = np.random.default_rng(3)
    rows = np.arange(70, dtype=float)
    tissue = _slit(rows, 15.5, 45.5, 950.0, np.full(70, 1800.0), SIGMA)            # the dark stretch, blurred
    profile = _slit(rows, 40.0, 43.5, 160.0, tissue, SIGMA) + rng.normal(0, NOISE, 70)
    assert profile.min() < 941 - 300                                               # the dip 4121 showed
    flat = flat_floor(profile[:, None], np.array([14.5]), np.array([45.5]), np.array([941.0]), SIGMA, NOISE)
    assert not flat[0]
    # the same profile's true slit is no flat floor either (3.5 px: 1.9 blur widths), while a 14 px one is
    assert not flat_floor(profile[:, None], np.array([40.0]), np.array([43.5]), np.array([160.0]), SIGMA, NOISE)[0]
    wide = _slit(rows, 30.0, 44.0, 160.0, np.full(70, 1800.0), SIGMA) + rng.normal(0, NOISE, 70)
    assert flat_floor(wide[:, None], np.array([30.0]), np.array([44.0]), np.array([160.0]), SIGMA, NOISE)[0]


def test_fits_without_a_flat_floor_do_not_make_the_slit_resolved():
    """Six rays fitted 31 px wide in two frames (4121's ray count was 9 such rays in 7 frames) make the slit
    resolved by the widths alone; with their floors judged, the per-ray levels are not measured (None: the flow
    step then states the gap never resolved) and the one ray with a flat floor is no per-ray level."""
    widths = np.full((2, 20), 5.0)
    widths[:, 10:16] = 31.0
    widths[:, 3] = 12.0
    levels = np.full((2, 20), 400.0)
    levels[:, 10:16] = 941.0
    flat = np.zeros((2, 20), bool)
    flat[:, 3] = True
    assert ray_gap_levels(widths, levels, SIGMA) is not None
    assert ray_gap_levels(widths, levels, SIGMA, flat=flat) is None
    flat[:, 10:16] = True
    got = ray_gap_levels(widths, levels, SIGMA, flat=flat)
    assert got is not None and np.nanmax(got) == 941.0


def test_a_narrow_slit_fitted_too_wide_shows_no_floor_at_its_darkest_pixels():
    """Widened seed 4161 (blur 0.77 px, a slit at most 3 px wide): the fit read 5 px, as wide as six blur widths, and
    its level sat at the dip's darkest pixels. Judged on the one or two pixel centres nearest the middle (where none
    lay 3 sigma inside both edges), that bottom was a "flat floor", the slit was stated resolved, and its area read
    +156 %. Analytic: a 3 px slit at 385 counts in 1500-count tissue, blurred by 0.77 px, without noise; fitted as
    19.0-24.0 px with the level at its darkest pixel. Judged on three pixels the V shows; the true 3 px slit has no
    floor either, and a slit of 6 sigma + 2 px has one."""
    sigma, rows = 0.77, np.arange(45, dtype=float)
    profile = _slit(rows, 20.0, 23.0, 385.0, np.full(45, 1500.0), sigma)
    level = np.array([profile.min()])
    # the old rule's pixels (the two nearest the middle, 21 and 22) sit at that level: a "floor" of two pixels
    np.testing.assert_allclose(profile[[21, 22]], level[0], rtol=1e-12)
    assert not flat_floor(profile[:, None], np.array([19.0]), np.array([24.0]), level, sigma, NOISE)[0]
    assert not flat_floor(profile[:, None], np.array([20.0]), np.array([23.0]), np.array([385.0]), sigma, NOISE)[0]
    wide = _slit(rows, 18.0, 18.0 + 6 * sigma + 2, 385.0, np.full(45, 1500.0), sigma)
    assert flat_floor(wide[:, None], np.array([18.0]), np.array([18.0 + 6 * sigma + 2]), np.array([385.0]), sigma,
                      NOISE)[0]
