"""The gap opening function o(y, t): exact distances on analytic slits."""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.flow.gap.opening import OpeningTracker, gap_centers, opening_distance


def _slit(h=40, w=30, centre=19.0, half=None):
    """Gap rows strictly within centre +- half[col] (half-widths at half-integers)."""
    half = np.linspace(0.5, 6.5, w) if half is None else half
    half = np.round(half - 0.5) + 0.5  # edges exactly between pixel centres
    rows = np.arange(h)[:, None]
    return np.abs(rows - centre) < half[None, :], centre - half, centre + half


def _brute_force(mask, fallback):
    h, w = mask.shape
    out = np.empty((h, w))
    for c in range(w):
        col = mask[:, c]
        edges = [r + 0.5 for r in range(h - 1) if col[r] != col[r + 1]]
        for r in range(h):
            out[r, c] = min(abs(r - e) for e in edges) if edges else abs(r - fallback[c])
    return out


def test_distances_on_an_analytic_slit_are_exact():
    mask, top, bottom = _slit()
    o = opening_distance(mask, 0.0)
    rows = np.arange(mask.shape[0])[:, None]
    exact = np.minimum(np.abs(rows - top[None, :]), np.abs(rows - bottom[None, :]))
    np.testing.assert_allclose(o, exact, atol=1e-6)
    assert o.dtype == np.float32


@pytest.mark.parametrize("seed", range(5))
def test_matches_brute_force_on_random_masks_with_several_runs(seed):
    rng = np.random.default_rng(seed)
    mask = rng.random((25, 12)) < 0.2
    mask[:, 3] = False  # closed rays use the fallback
    fallback = rng.uniform(0, 24, 12)
    np.testing.assert_allclose(opening_distance(mask, fallback), _brute_force(mask, fallback), atol=1e-6)


def test_lateral_axis_columns_is_the_transpose():
    mask, _, _ = _slit()
    np.testing.assert_array_equal(opening_distance(mask.T, 7.0, lateral_axis=1), opening_distance(mask, 7.0).T)


def test_gap_centres_are_the_slit_centre_and_nan_when_closed():
    mask, _, _ = _slit(centre=19.0)
    mask[:, 5] = False
    c = gap_centers(mask)
    assert np.isnan(c[5])
    np.testing.assert_allclose(np.delete(c, 5), 19.0)


def test_closed_ray_measures_to_the_last_known_opening_location():
    h, w = 40, 6
    tracker = OpeningTracker((h, w))
    mask = np.zeros((h, w), bool)
    mask[10:15, :] = True  # open, centred on row 12
    tracker.update(mask)
    mask2 = np.zeros((h, w), bool)
    mask2[20:23, :3] = True  # rays 0-2 open elsewhere (centre 21); rays 3-5 closed
    o = tracker.update(mask2)
    rows = np.arange(h, dtype=float)
    np.testing.assert_allclose(o[:, 4], np.abs(rows - 12.0))
    np.testing.assert_allclose(o[:, 0], np.minimum(np.abs(rows - 19.5), np.abs(rows - 22.5)))
    o3 = tracker.update(np.zeros((h, w), bool))  # all closed: rays 0-2 now remember 21
    np.testing.assert_allclose(o3[:, 1], np.abs(rows - 21.0))
    np.testing.assert_allclose(o3[:, 5], np.abs(rows - 12.0))


def test_never_seen_rays_interpolate_the_known_ones_else_initial_else_image_centre():
    h, w = 31, 5
    assert np.allclose(OpeningTracker((h, w)).fallback_center(), 15.0)
    assert np.allclose(OpeningTracker((h, w), initial_center=9.0).fallback_center(), 9.0)
    tracker = OpeningTracker((h, w))
    mask = np.zeros((h, w), bool)
    mask[9:12, 0] = True  # centre 10
    mask[19:22, 4] = True  # centre 20
    tracker.update(mask)
    np.testing.assert_allclose(tracker.fallback_center(), [10, 12.5, 15, 17.5, 20])


def test_simulated_mask_uses_the_measured_fallback():
    mask, _, _ = _slit()
    tracker = OpeningTracker(mask.shape)
    tracker.update(mask)
    simulated = np.zeros_like(mask)
    o = opening_distance(simulated, tracker.fallback_center())
    np.testing.assert_allclose(o[:, 0], np.abs(np.arange(mask.shape[0]) - 19.0))


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        opening_distance(np.zeros((4, 4), bool), np.nan)
    with pytest.raises(ValueError):
        OpeningTracker((4, 4)).update(np.zeros((5, 4), bool))
    with pytest.raises(ValueError):
        opening_distance(np.zeros((4, 4), bool), 0.0, lateral_axis=3)
