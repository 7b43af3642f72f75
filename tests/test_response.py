"""The Response seam: a response that is not ``U = R C b(t)`` plugs into the objective, the Gauss-Newton
model, the Levenberg-Marquardt fit and the uncertainty through the Response protocol only.

The response under test is written here (not in the package): a quasi-static part plus a slowly relaxing
part, ``U(t) = R_fast C b(t) + R_slow C (h * b)(t)`` with h a first-order low-pass of time constant tau
(a crude viscoelastic fold).  Its linearisation has two separable terms, so the Gauss-Newton blocks are
sums over four term pairs.
"""
import numpy as np
import pytest

from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.optimizers.base import FitOptions, fit
from vfcli.inverse.problem import Problem, synthesize_measurement
from vfcli.inverse.uncertainty import ResidualCorrelation, displacement_std, posterior
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.mesh import TAG_SUPERIOR
from vfcli.model.response.base import Linearization, Response, SeparableTerm
from vfcli.model.response.quasi_static import QuasiStaticResponse

try:
    from _forward_case import CAMERA, F0_HZ, SETTINGS, elastic_model, true_controls
except ModuleNotFoundError:
    from tests._forward_case import CAMERA, F0_HZ, SETTINGS, elastic_model, true_controls


class RelaxingResponse:
    """``U(t) = R_fast C b(t) + R_slow C (h * b)(t)``; (h * b) by the exact first-order recursion on a fine
    fixed grid over the load's time range (so any subset of times gives the same values)."""

    def __init__(self, quasi_static: QuasiStaticResponse, t_range: tuple[float, float], tau_s: float) -> None:
        self.qs = quasi_static
        r = quasi_static.basis_
        self.spatial = (0.7 * r, 0.3 * r * np.array([1.0, 1.3, 0.6])[None, :, None])
        grid = np.linspace(t_range[0], t_range[1], 4001)
        b = quasi_static.time_basis(grid)
        a = np.exp(-np.diff(grid) / tau_s)
        y = np.empty_like(b)
        y[0] = b[0]
        for i in range(1, len(grid)):
            y[i] = a[i - 1] * y[i - 1] + (1.0 - a[i - 1]) * b[i]
        self._grid, self._filtered = grid, y

    @property
    def n_params(self) -> int:
        return self.qs.n_params

    @property
    def n_vertices(self) -> int:
        return self.qs.n_vertices

    def _temporal(self, times):
        times = np.asarray(times, dtype=float)
        slow = np.stack([np.interp(times, self._grid, col) for col in self._filtered.T], axis=1)
        return self.qs.time_basis(times), slow

    def displacements(self, x, times):
        c = np.asarray(x, dtype=float).reshape(self.spatial[0].shape[2], -1)
        out = 0.0
        for r, b in zip(self.spatial, self._temporal(times)):
            out = out + np.einsum("ncs,st,Tt->Tnc", r, c, b)
        return out

    def adjoint(self, g, times, x=None):
        return sum(np.einsum("ncs,Tnc,Tt->st", r, g, b) for r, b in zip(self.spatial, self._temporal(times))).ravel()

    def linearize(self, x, times):
        return Linearization(tuple(SeparableTerm(r, b) for r, b in zip(self.spatial, self._temporal(times))))

    def penalty_operator(self):
        return self.qs.penalty_operator()


@pytest.fixture(scope="module")
def relaxing():
    model = elastic_model()
    n_frames = 10
    fps = n_frames * F0_HZ
    times = 0.002 + np.arange(n_frames) / fps
    t_range = (times[0], times[-1] + 1.0 / fps)
    field = ForceField(ForceFieldSpec((2, 2, 6), ("inferior", "superior")), t_range)
    resp = RelaxingResponse(QuasiStaticResponse(model, field), t_range, tau_s=0.3 / F0_HZ)
    x_true = true_controls(field, seed=1)
    meas = synthesize_measurement(model.mesh, CAMERA, resp, times, x_true, SETTINGS)
    return model, field, resp, meas, x_true


def _x0(x_true):
    return 0.6 * x_true + np.random.default_rng(5).normal(0, 40.0, x_true.size)


def test_the_test_response_satisfies_the_protocol_and_its_linearization_is_its_derivative(relaxing):
    _, _, resp, meas, x_true = relaxing
    assert isinstance(resp, Response)
    times = np.append(meas.times, meas.times[-1] + meas.dt)
    lin = resp.linearize(x_true, times)
    assert len(lin.terms) == 2
    dx = np.random.default_rng(0).normal(size=resp.n_params)
    np.testing.assert_allclose(lin.apply(dx), resp.displacements(x_true + dx, times) - resp.displacements(x_true, times),
                               rtol=1e-9, atol=1e-12)
    # the low-pass really changes the time course (else the test would prove nothing about two terms)
    b_fast, b_slow = (t.temporal for t in lin.terms)
    assert np.abs(b_fast - b_slow).max() > 0.2 * np.abs(b_fast).max()


def test_gradient_and_gauss_newton_hessian_are_exact_for_the_two_term_response(relaxing):
    model, _, resp, meas, x_true = relaxing
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS.__class__(motion_weight=1e-4, gap_weight=0.0,
                                                                   ridge_weight=1e-6))
    x0 = _x0(x_true)
    frames = p.freeze(x0)
    _, grad = p.frozen_value_and_grad(x0, frames)
    rng = np.random.default_rng(1)
    for d in rng.normal(size=(3, p.n_params)):
        fd = (p.frozen_value(x0 + d, frames).total - p.frozen_value(x0 - d, frames).total) / 2.0
        assert grad @ d == pytest.approx(fd, rel=1e-7)
    gn = gauss_newton_model(p, x0, frames)
    for d in rng.normal(size=(3, p.n_params)):
        fd = (p.frozen_value_and_grad(x0 + d, frames)[1] - p.frozen_value_and_grad(x0 - d, frames)[1]) / 2.0
        np.testing.assert_allclose(gn.hessian @ d, fd, rtol=1e-7, atol=1e-9 * np.abs(fd).max())


def test_gap_curvature_of_the_two_term_response_bounds_the_frozen_gap_term(relaxing):
    model, _, resp, meas, x_true = relaxing
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS.__class__(motion_weight=0.0, gap_weight=1.0))
    x0 = _x0(x_true)
    frames = p.freeze(x0)
    gn = gauss_newton_model(p, x0, frames)
    rng = np.random.default_rng(2)
    for d in rng.normal(size=(4, p.n_params)):
        d *= 30.0 / np.linalg.norm(d) * np.sqrt(p.n_params)
        for t in (0.1, 0.3, 1.0):
            s = t * d
            quad = gn.terms.total + gn.grad @ s + 0.5 * s @ (gn.hessian @ s)
            assert p.frozen_value(x0 + s, frames).total <= quad * (1 + 1e-3) + 1e-9
        # and the model is tangent: its slope is the frozen gap term's
        h = 1e-3
        fd = (p.frozen_value(x0 + h * d, frames).total - p.frozen_value(x0 - h * d, frames).total) / (2 * h)
        assert gn.grad @ d == pytest.approx(fd, rel=1e-5)


def test_gauss_newton_fit_recovers_the_controls_of_the_two_term_response(relaxing):
    model, _, resp, meas, x_true = relaxing
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS)
    res = fit(p, method="gauss-newton", max_iter=30, options=FitOptions(ftol=1e-10))
    total = res.history["total"]
    assert np.all(np.diff(total) < 0)
    assert total[-1] < 1e-3 * total[0]
    sup = np.unique(model.mesh.faces[model.mesh.face_tag == TAG_SUPERIOR])
    vt = np.diff(p.displacements(x_true), axis=0)[:, sup]
    vf = np.diff(p.displacements(res.x), axis=0)[:, sup]
    assert np.linalg.norm(vf - vt) / np.linalg.norm(vt) < 0.05


def test_displacement_std_of_the_two_term_response_is_the_exact_propagation(relaxing):
    """posterior -> displacement_std through the model's linearization equals sqrt(diag(J Cov J^T)) with J
    taken column by column from the response's own displacements (an independent route)."""
    model, _, resp, meas, x_true = relaxing
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS.__class__(motion_weight=1e-4, gap_weight=1.0,
                                                                   ridge_weight=1e-7))
    x = 0.9 * x_true
    gn = gauss_newton_model(p, x)
    post = posterior(gn, ResidualCorrelation(5000, 1.0, 1.0, 5000.0))
    std = displacement_std(post.covariance, gn.linearization)
    assert std.shape == (len(p.sim_times), resp.n_vertices, 3)
    cov = post.covariance.dense()
    u0 = resp.displacements(np.zeros(resp.n_params), p.sim_times)
    jac = np.stack([(resp.displacements(e, p.sim_times) - u0).reshape(len(p.sim_times), -1)
                    for e in np.eye(resp.n_params)], axis=-1)                     # (T, 3N, n)
    for f in (0, 4, len(p.sim_times) - 1):
        expected = np.sqrt(np.einsum("ij,jk,ik->i", jac[f], cov, jac[f])).reshape(-1, 3)
        np.testing.assert_allclose(std[f], expected, rtol=1e-8, atol=1e-12 * expected.max())
