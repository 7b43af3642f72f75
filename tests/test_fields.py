"""The surface velocity field: TPS in space, quadratic C1 / linear interpolation in time."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from vfcli.errors import ConfigError
from vfcli.flow.velocity_field import (
    LdvTps,
    evaluate_field,
    hull_mask,
    pixel_grid,
    quadratic_spline_coefficients,
    quadratic_spline_eval,
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


def test_too_few_good_points_is_a_config_error():
    with pytest.raises(ConfigError):
        LdvTps(np.zeros((3, 2)), good=np.array([True, True, False]))


def test_hull_mask_marks_pixels_inside_the_points():
    m = hull_mask(np.array([[2.0, 2.0], [8.0, 2.0], [8.0, 6.0], [2.0, 6.0]]), (10, 12))
    assert m[4, 5] and not m[0, 0] and not m[4, 10]
    assert m.sum() == 7 * 5


# ---- time -------------------------------------------------------------------------------
def test_quadratic_spline_interpolates_the_samples_and_is_exact_for_lines():
    rng = np.random.default_rng(0)
    f = rng.normal(size=(12, 3))
    c = quadratic_spline_coefficients(f)
    np.testing.assert_allclose(quadratic_spline_eval(c, np.arange(12.0)), f, atol=1e-12)
    line = 2.0 + 0.3 * np.arange(9.0)
    tau = np.linspace(0, 8, 101)
    np.testing.assert_allclose(quadratic_spline_eval(quadratic_spline_coefficients(line), tau), 2.0 + 0.3 * tau, atol=1e-12)


def test_quadratic_spline_is_c1_but_not_c2_at_its_knots():
    f = np.sin(np.arange(15.0) * 0.7) + 0.1 * np.arange(15.0) ** 1.5
    c = quadratic_spline_coefficients(f)
    knots = np.arange(0.5, 14.0, 1.0)
    h = 1e-6
    s = lambda x: quadratic_spline_eval(c, np.asarray(x, float))
    left = (s(knots - h) - s(knots - 2 * h)) / h
    right = (s(knots + 2 * h) - s(knots + h)) / h
    np.testing.assert_allclose(left, right, atol=1e-4)  # C1: slopes match
    np.testing.assert_allclose(s(knots - h), s(knots + h), atol=1e-5)  # C0
    curv = lambda x: (s(x + 1e-3) - 2 * s(x) + s(x - 1e-3)) / 1e-6
    assert np.abs(curv(knots - 0.01) - curv(knots + 0.01)).max() > 1e-2  # second derivative jumps


def test_quadratic_spline_converges_at_third_order_inside():
    errs = []
    for n in (20, 40, 80):
        tt = np.linspace(0, 1, n)
        c = quadratic_spline_coefficients(np.sin(2 * np.pi * tt))
        tau = np.linspace(0.3, 0.7, 200) * (n - 1)
        errs.append(np.abs(quadratic_spline_eval(c, tau) - np.sin(2 * np.pi * tau / (n - 1))).max())
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 2.7), rates


# ---- the field ----------------------------------------------------------------------------
def _analytic_field(T=7, H=12, W=15, dt=1e-4):
    times = 0.01 + dt * np.arange(T)
    tt, rr, cc = np.meshgrid(times, np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    s = (tt - times[0]) / dt
    u = 3.0 + 0.5 * cc - 0.2 * rr + 0.8 * s  # bilinear in space, linear in time: reproduced exactly
    v = 1.0 + 0.1 * cc * rr - 2.0 * s
    w = -4.0 + 0.3 * cc + 0.7 * rr + 5.0 * s
    return times, np.stack([u, v, w], axis=-1), lambda c, r, t: np.stack(
        [3.0 + 0.5 * c - 0.2 * r + 0.8 * (t - times[0]) / dt, 1.0 + 0.1 * c * r - 2.0 * (t - times[0]) / dt,
         -4.0 + 0.3 * c + 0.7 * r + 5.0 * (t - times[0]) / dt], axis=-1)


def test_evaluate_field_reproduces_bilinear_and_linear_fields_exactly():
    times, field, exact = _analytic_field()
    rng = np.random.default_rng(0)
    y = np.column_stack([rng.uniform(0, 14, 50), rng.uniform(0, 11, 50)])
    t = rng.uniform(times[0], times[-1], 50)
    got = evaluate_field(field, times, None, y, t)
    np.testing.assert_allclose(got, exact(y[:, 0], y[:, 1], t), atol=1e-9)


def test_evaluate_field_uses_the_quadratic_spline_for_uv_and_lines_for_w():
    times, field, _ = _analytic_field()
    rng = np.random.default_rng(1)
    field = field + rng.normal(size=field.shape)  # arbitrary time series per pixel
    y = np.array([[4.0, 5.0]])  # a pixel centre: no spatial interpolation
    t = times[2] + 0.3 * (times[1] - times[0])
    got = evaluate_field(field, times, None, y, [t])[0]
    c = quadratic_spline_coefficients(field[:, 5, 4, :2])
    np.testing.assert_allclose(got[:2], quadratic_spline_eval(c, np.array([2.3]))[0], atol=1e-9)
    assert got[2] == pytest.approx(0.7 * field[2, 5, 4, 2] + 0.3 * field[3, 5, 4, 2])


def test_evaluate_field_with_the_exact_tps_matches_the_grid_between_pixels():
    pts = _ldv_grid(6, 7, (40, 50))
    times = np.arange(3) * 1e-4
    w_pts = np.stack([_smooth_w(pts * 3) * (1 + 0.5 * k) for k in range(3)], axis=1)
    tps = LdvTps(pts).fit_grid((40, 50))
    w_grid = tps.frames(w_pts)
    field, valid = combine_fields(np.zeros((3, 40, 50, 2)), w_grid, np.zeros((3, 40, 50), bool))
    y = np.array([[10.3, 20.6], [33.5, 7.25]])
    t = np.array([0.4e-4, 1.5e-4])
    exact = evaluate_field(field, times, valid, y, t, tps=tps, w_points=w_pts)
    gridded = evaluate_field(field, times, valid, y, t)
    np.testing.assert_allclose(exact[:, 2], gridded[:, 2], rtol=2e-3)
    k0 = np.floor(t / 1e-4).astype(int)
    a = t / 1e-4 - k0
    direct = [(1 - a[i]) * tps.at(y[i : i + 1], w_pts[:, k0[i]])[0] + a[i] * tps.at(y[i : i + 1], w_pts[:, k0[i] + 1])[0] for i in range(2)]
    np.testing.assert_allclose(exact[:, 2], direct, rtol=1e-6)


def test_invalid_and_out_of_range_queries_are_nan():
    times, field, _ = _analytic_field()
    gap = np.zeros(field.shape[:3], bool)
    gap[3, 5, 6] = True
    field, valid = combine_fields(field[..., :2], field[..., 2], gap)
    assert not valid[3, 5, 6] and valid.sum() == valid.size - 1
    y = np.array([[6.2, 4.9], [6.0, 5.0], [-1.0, 3.0], [3.0, 3.0]])
    t = np.array([times[3], times[1], times[2], times[-1] + 1e-3])
    out = evaluate_field(field, times, valid, y, t)
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all() and np.isnan(out[2]).all() and np.isnan(out[3]).all()


def test_non_uniform_times_are_refused():
    times, field, _ = _analytic_field(T=4)
    with pytest.raises(ConfigError):
        evaluate_field(field, np.array([0.0, 1.0, 3.0, 4.0]), None, np.zeros((1, 2)), [0.5])


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
