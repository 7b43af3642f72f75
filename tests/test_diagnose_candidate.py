"""The seam of the Explain step (vfcli/diagnose/candidate.py) and the residual of a window
(vfcli/diagnose/residual.py), on a forward-simulated case with known control values: the
residual vanishes where the model made the data, the Jacobian columns of the predicted
measurement match finite differences, and the rows agree with the objective's own residuals."""
from __future__ import annotations

import numpy as np
import pytest

from _forward_case import forward_case
from vfcli.diagnose.candidate import Baseline, Candidate, available_candidates, screen
from vfcli.diagnose.regions import N_REGIONS, gap_region_names, region_names
from vfcli.diagnose.residual import region_means, window_residual


@pytest.fixture(scope="module")
def case():
    return forward_case(n_frames=8)


def test_residual_vanishes_at_the_controls_that_made_the_data(case):
    b = Baseline.at(case.problem, case.x_true)
    r = b.residual_vector()
    assert r.size == b.n_motion_rows + len(b.gap_residual()) and b.n_motion_rows > 1000
    scale = np.abs(b.measured_motion()).max()
    assert np.abs(r[:b.n_motion_rows]).max() < 1e-9 * scale
    assert np.abs(r[b.n_motion_rows:]).max() < 1e-9
    res = window_residual(b)
    assert np.nanmax(np.abs(res.gap)) < 1e-9 and np.isfinite(res.gap).any()
    seen = res.motion[np.isfinite(res.motion)]
    assert seen.size and np.abs(seen).max() < 1e-9 * scale
    # the pixels the model shows get regions of both folds, the medial edge among them
    regions = np.unique(res.pixel_region[res.pixel_region >= 0])
    names = [region_names()[i] for i in regions]
    assert any(n.startswith("left fold, medial edge") for n in names)
    assert any(n.startswith("right fold, medial edge") for n in names)


def test_region_means_are_the_nan_means_over_each_regions_pixels():
    """Against a loop of np.nanmean over each region's mask: NaN pixels left out, a region with no valid
    pixel (or none at all) NaN, unlabelled pixels (-1) ignored."""
    rng = np.random.default_rng(3)
    values = rng.normal(size=(5, 12, 9, 3))
    values[rng.random(values.shape) < 0.3] = np.nan
    labels = rng.integers(-1, 6, size=(12, 9))
    labels[labels == 4] = 2                                        # region 4: no pixel
    values[:, labels == 5, 1] = np.nan                             # region 5: component 1 never valid
    got = region_means(values, labels, 7)
    assert got.shape == (5, 7, 3)
    for r in range(7):
        inside = values[:, labels == r, :]
        for f in range(5):
            for c in range(3):
                x = inside[f, :, c]
                want = np.nanmean(x) if np.isfinite(x).any() else np.nan
                np.testing.assert_allclose(got[f, r, c], want, rtol=1e-12, atol=0, equal_nan=True)
    assert np.isnan(got[:, 4]).all() and np.isnan(got[:, 6]).all() and np.isnan(got[:, 5, 1]).all()


def _problem(case, slide: bool):
    from dataclasses import replace

    from vfcli.inverse.problem import Problem

    p = case.problem
    return Problem(p.mesh, p.camera, p.response, p.meas, replace(p.settings, motion_slide=slide)) if slide else p


@pytest.mark.parametrize("slide", [False, True])
def test_jacobian_columns_match_finite_differences(case, slide):
    """With and without the surface sliding under the pixels (motion_slide: the frozen frames' model)."""
    p = _problem(case, slide)
    x0 = 0.9 * case.x_true
    b = Baseline.at(p, x0)
    rng = np.random.default_rng(4)
    dx = rng.normal(size=(p.n_params, 2)) * 20.0          # Pa
    dudp = np.stack([p.displacements(x0 + dx[:, j]) - b.displacements for j in range(2)], axis=-1)
    jac = b.measure_linear(dudp)
    assert jac.shape == (b.n_motion_rows + len(b.gap_residual()), 2)
    for j in range(2):
        for eps in (1e-3,):
            moved = Baseline(p, x0 + eps * dx[:, j], p.displacements(x0 + eps * dx[:, j]), b.frames)
            fd = (b.residual_vector() - moved.residual_vector()) / eps   # residual = measured - predicted
            err = np.abs(fd - jac[:, j]).max() / np.abs(jac[:, j]).max()
            assert err < 1e-4, err
    # the motion rows are the objective's own residuals (simulated minus measured), sign flipped
    obj = p.motion_residuals(x0, b.frames)
    rows = np.concatenate([obj[f].reshape(-1, 3)[fr.pix_both].ravel() for f, fr in enumerate(b.frames)])
    assert np.allclose(-rows, b.residual_vector()[:b.n_motion_rows], rtol=1e-12, atol=1e-9)
    # and their region means are those of the window residual
    res = window_residual(b)
    means = region_means(res.motion, res.pixel_region, N_REGIONS)
    assert means.shape == (p.n_frames, N_REGIONS, 3) and np.isfinite(means).any()


@pytest.mark.parametrize("slide", [False, True])
def test_the_calibrations_load_adjoint_is_the_transpose_of_the_motion_rows(case, slide):
    """``motion_adjoint(s)`` (the load fit's right-hand side in the bootstrap) against the motion rows of
    :meth:`Baseline.measure_linear` through the response's linearisation: ``dx . J^T Omega s = (J dx) . Omega s``,
    on random dx and s, with and without the slide (then a rigid in-plane shift moves the velocity seen too)."""
    from vfcli.diagnose.calibrate_run import motion_adjoint, row_weights

    p = _problem(case, slide)
    b = Baseline.at(p, 0.9 * case.x_true)
    lin = p.response.linearize(b.x, p.sim_times)
    rng = np.random.default_rng(8)
    weights = row_weights(b)
    n = b.n_motion_rows
    for _ in range(3):
        dx, s = rng.normal(size=p.n_params), rng.normal(size=weights.size)
        rows = b.measure_linear(lin.apply(dx)[..., None])[:n, 0]
        assert dx @ motion_adjoint(b, s, weights) == pytest.approx(rows @ (weights[:n] * s[:n]), rel=1e-10)
    shift = np.zeros(b.displacements.shape + (1,))
    shift[:, :, 0, 0] = 1.0
    moved = np.abs(b.measure_linear(shift)[:n]).max()
    assert (moved > 1.0) if slide else (moved < 1e-9)


def test_screening_seam_without_candidates(case):
    b = Baseline.at(case.problem, case.x_true)
    assert screen(None, [], b) == []
    assert all(isinstance(c, Candidate) for c in available_candidates())

    class Shift:
        name, n_params, parameter_names = "shift", 1, ("offset_mm",)
        signature = "a constant lateral offset of both folds"

        def jacobian(self, baseline):
            du = np.zeros(baseline.displacements.shape + (1,))
            du[:, :, 1, 0] = 1.0
            return baseline.measure_linear(du)

    assert isinstance(Shift(), Candidate)
    cols = Shift().jacobian(b)
    # a rigid shift moves no velocity: the motion rows are zero, the silhouettes move by 1 mm
    assert np.abs(cols[:b.n_motion_rows]).max() < 1e-9
    assert np.allclose(np.abs(cols[b.n_motion_rows:, 0]), 1.0, atol=1e-6)


def test_gap_residual_is_medial_positive_on_the_fold_that_moved(case):
    p = case.problem
    u = p.displacements(case.x_true)
    fold = np.zeros(len(p.mesh.nodes), int)
    fold[np.unique(p.mesh.tets[p.mesh.tet_fold == 1])] = 1
    moved = u.copy()
    moved[:, fold == 0, 1] += 0.1     # the simulated left fold (y < 0) 0.1 mm towards the midline
    b = Baseline(p, case.x_true, moved, p.freeze(case.x_true, moved))
    res = window_residual(b)
    left, right = (list(p.fold_order).index(k) for k in (0, 1))
    # the measured edge lies 0.1 mm lateral of the simulated one: measured minus simulated, medial positive
    assert np.nanmedian(res.gap[..., left]) == pytest.approx(-0.1, abs=0.01)
    assert np.nanmax(np.abs(res.gap[..., right])) < 1e-9
    # the left fold's side of every ray is one of the left fold's gap regions, all three thirds present
    seen = {gap_region_names()[i] for i in np.unique(res.gap_region[:, left]) if i >= 0}
    assert seen == {f"left fold, medial edge, {t} third" for t in ("anterior", "middle", "posterior")}
