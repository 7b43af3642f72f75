"""The surface velocity field: the LDV thin-plate spline in space, combined with the optical flow."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from vfcli.errors import InputDataError
from vfcli.flow.velocity_field import (
    LdvTps,
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
