"""The surface velocity field: the LDV thin-plate spline in space, combined with the optical flow."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from vfcli.errors import InputDataError
from vfcli.flow.velocity_field import (
    GapAwareFill,
    LdvTps,
    points_in_gap,
    hull_mask,
    pixel_grid,
    combine_fields,
)


def _ldv_grid(rows=17, cols=22, shape=(128, 160), jitter=1.5, seed=0):
    """A not-exactly-regular scan grid over the frame, (n, 2) (col, row) px."""
    rng = np.random.default_rng(seed)
    r, c = np.meshgrid(np.linspace(8, shape[0] - 9, rows), np.linspace(8, shape[1] - 9, cols), indexing="ij")
    pts = np.stack([c.ravel(), r.ravel()], axis=1)
    return pts + rng.uniform(-jitter, jitter, pts.shape)


def _smooth_w(p):
    """A smooth vertical velocity field over the frame, mm/s."""
    x, y = p[..., 0] / 160, p[..., 1] / 128
    return 200 * np.sin(np.pi * x) * np.cos(1.3 * y) + 50 * x * y


def test_tps_operator_equals_a_direct_rbf_fit():
    pts = _ldv_grid(6, 7, (40, 50))
    w = _smooth_w(pts * 3)
    tps = LdvTps(pts, smoothing=0.5).fit_grid((40, 50))
    direct = RBFInterpolator(pts, w, kernel="thin_plate_spline", smoothing=0.5)(pixel_grid((40, 50))).reshape(40, 50)
    np.testing.assert_allclose(tps.frames(w), direct, atol=1e-3 * np.abs(w).max())


def test_tps_predicts_held_out_points_of_a_smooth_field():
    pts = _ldv_grid()
    w = _smooth_w(pts)
    held = np.zeros(len(pts), bool)
    held[np.random.default_rng(3).choice(len(pts), 40, replace=False)] = True
    interior = (pts[:, 0] > 20) & (pts[:, 0] < 140) & (pts[:, 1] > 20) & (pts[:, 1] < 108)
    held &= interior
    assert held.sum() > 20  # 27 interior points held out
    w_flagged = np.where(held, np.nan, w)  # flagged points may carry NaN: they are left out
    tps = LdvTps(pts, good=~held)
    pred = tps.at(pts[held], w_flagged)
    err = np.abs(pred - w[held]).max() / np.abs(w).max()
    assert err < 4e-4  # measured 1.65e-4 of the amplitude


def test_flagged_points_are_left_out_of_the_grid_operator():
    pts = _ldv_grid(5, 6, (40, 50))
    good = np.ones(len(pts), bool)
    good[[3, 10]] = False
    tps = LdvTps(pts, good=good).fit_grid((40, 50))
    assert tps.grid_operator_.shape == (40 * 50, len(pts) - 2)
    w = _smooth_w(pts * 3)
    w_bad = w.copy()
    w_bad[[3, 10]] = np.nan
    frame = tps.frames(w_bad)
    assert np.isfinite(frame).all()
    np.testing.assert_allclose(frame, LdvTps(pts[good]).fit_grid((40, 50)).frames(w[good]), atol=1e-3)


def test_tps_is_linear_in_time_columns_and_reproduces_linear_fields():
    pts = _ldv_grid(5, 6, (40, 50))
    tps = LdvTps(pts).fit_grid((40, 50))
    w = np.stack([1.0 + 0.2 * pts[:, 0] - 0.1 * pts[:, 1], _smooth_w(pts * 3)], axis=1)  # (n, T=2)
    frames = tps.frames(w)
    assert frames.shape == (2, 40, 50)
    np.testing.assert_allclose(frames[1], tps.frames(w[:, 1]), atol=1e-3)
    g = pixel_grid((40, 50))
    np.testing.assert_allclose(frames[0].ravel(), 1.0 + 0.2 * g[:, 0] - 0.1 * g[:, 1], atol=1e-3)


def test_smoothing_trades_interpolation_for_a_least_squares_fit():
    pts = _ldv_grid(8, 9, (64, 80), seed=2)
    rng = np.random.default_rng(5)
    w_true = 1.0 + 0.05 * pts[:, 0]
    w_noisy = w_true + rng.normal(0, 1.0, len(pts))
    exact = LdvTps(pts).at(pts, w_noisy)
    smooth = LdvTps(pts, smoothing=1e3).at(pts, w_noisy)
    np.testing.assert_allclose(exact, w_noisy, atol=1e-6)
    assert np.abs(smooth - w_true).mean() < 0.5 * np.abs(w_noisy - w_true).mean()


def test_too_few_good_points_is_an_input_data_error():
    with pytest.raises(InputDataError):
        LdvTps(np.zeros((3, 2)), good=np.array([True, True, False]))


def test_hull_mask_marks_pixels_inside_the_points():
    m = hull_mask(np.array([[2.0, 2.0], [8.0, 2.0], [8.0, 6.0], [2.0, 6.0]]), (10, 12))
    assert m[4, 5] and not m[0, 0] and not m[4, 10]
    assert m.sum() == 7 * 5


# ---- time -------------------------------------------------------------------------------
def test_surface_velocity_stacks_uv_and_w_and_flags_the_gap():
    flow = np.ones((2, 3, 4, 2))
    w = np.full((2, 3, 4), 5.0)
    w[1, 0, 0] = np.nan
    gap = np.zeros((2, 3, 4), bool)
    gap[0, 1, 1] = True
    inside = np.ones((3, 4), bool)
    inside[2, 3] = False
    field, valid = combine_fields(flow, w, gap, inside)
    assert field.shape == (2, 3, 4, 3) and field.dtype == np.float32
    assert not valid[0, 1, 1] and not valid[1, 0, 0] and not valid[0, 2, 3] and valid.sum() == 24 - 4


def _slit(shape=(128, 160), k=3, half_widths=(0.0, 4.0, 9.0)):
    """k gap masks: a vertical slit around column 80 of growing half-width, (k, H, W) bool."""
    cols = np.arange(shape[1])[None, None, :]
    hw = np.asarray(half_widths)[:, None, None]
    return np.broadcast_to(np.abs(cols - 80) <= hw - 0.5, (k, *shape)).copy()


def test_points_in_gap_reads_the_spot_pixel_and_the_margin():
    gap = _slit()
    pts = np.array([[80.0, 50], [83.4, 50], [85.0, 50], [86.2, 50], [200.0, 50]])
    in0 = points_in_gap(pts, gap, 0.0)
    assert in0.tolist() == [[False] * 5, [True, True, False, False, False], [True, True, True, True, False]]
    in2 = points_in_gap(pts, gap, 2.0)      # 2 px more on each side of the slit
    assert in2.tolist() == [[False] * 5, [True, True, True, False, False], [True, True, True, True, False]]


def test_spots_in_the_gap_no_longer_pull_the_medial_edge_to_zero():
    """Through the gap the vibrometer reads ~0: the fill restores the field next to the gap."""
    shape = (128, 160)
    pts = _ldv_grid(shape=shape)
    gap = _slit(shape, 1, (10.0,))
    truth = _smooth_w(pts)
    meas = truth.copy()
    in_gap = points_in_gap(pts, gap, 1.0)
    assert 34 <= in_gap.sum() <= 68        # 2 to 4 columns of the 17 x 22 grid
    meas[in_gap[0]] = 0.0                                   # no surface returns the beam
    good = np.ones(len(pts), bool)
    tps = LdvTps(pts, good).fit_grid(shape)
    filled = GapAwareFill(pts, good)(meas[:, None], in_gap)[:, 0]
    grid = pixel_grid(shape).reshape(*shape, 2)
    cols = grid[..., 0]
    edge = (np.abs(cols - 80) > 10) & (np.abs(cols - 80) <= 16) & (grid[..., 1] > 10) & (grid[..., 1] < 117)
    want = _smooth_w(grid)[edge]
    err_raw = np.sqrt(np.mean((tps.frames(meas)[edge] - want) ** 2))
    err_fill = np.sqrt(np.mean((tps.frames(filled)[edge] - want) ** 2))
    # measured: 57.2 and 0.04 mm/s (the field's amplitude is 200 mm/s)
    assert err_raw > 30
    assert err_fill < 0.5
    # the spots outside the gap keep their values; with interpolation the result is exactly the
    # spline through the other spots
    np.testing.assert_array_equal(filled[~in_gap[0]], meas[~in_gap[0]])
    direct = RBFInterpolator(pts[~in_gap[0]], meas[~in_gap[0]], kernel="thin_plate_spline")(pixel_grid(shape))
    np.testing.assert_allclose(tps.frames(filled).ravel(), direct, atol=2e-3 * np.abs(truth).max())


def test_gap_fill_leaves_frames_without_spots_in_the_gap_alone_and_caches_patterns():
    pts = _ldv_grid()
    gap = _slit(k=3, half_widths=(0.0, 6.0, 6.0))
    w = np.stack([_smooth_w(pts)] * 3, axis=1)
    fill = GapAwareFill(pts, np.ones(len(pts), bool))
    out = fill(w, points_in_gap(pts, gap, 0.0))
    np.testing.assert_array_equal(out[:, 0], w[:, 0])
    np.testing.assert_array_equal(out[:, 1], out[:, 2])
    assert len(fill._ops) == 1
