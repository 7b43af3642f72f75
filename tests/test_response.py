"""The Response seam: a response that is not ``U = R C b(t)`` plugs into the objective, the Gauss-Newton
model, the Levenberg-Marquardt fit and the uncertainty through the Response protocol only.

The response under test is written here (not in the package): a quasi-static part plus a slowly relaxing
part, ``U(t) = R_fast C b(t) + R_slow C (h * b)(t)`` with h a first-order low-pass of time constant tau
(a crude viscoelastic fold).  Its linearisation has two separable terms, so the Gauss-Newton blocks are
sums over four term pairs.  A second, nonlinear response (a saturating lateral displacement) plugs in
through its tangent, one separable term per time.
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
            out = out + np.einsum("ncs,st,Tt->Tnc", r, c, b, optimize=True)
        return out

    def adjoint(self, g, times, x=None):
        return sum(np.einsum("ncs,Tnc,Tt->st", r, g, b, optimize=True) for r, b in zip(self.spatial, self._temporal(times))).ravel()

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


@pytest.mark.parametrize("slide", [False, True])
def test_gradient_and_gauss_newton_hessian_are_exact_for_the_two_term_response(relaxing, slide):
    """With and without the surface sliding under the pixels (then 2 x 2 terms per frame)."""
    model, _, resp, meas, x_true = relaxing
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS.__class__(motion_weight=1e-4, gap_weight=0.0,
                                                                   ridge_weight=1e-6, motion_slide=slide))
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
    checked = [0, 4, len(p.sim_times) - 1]
    times = p.sim_times[checked]                # the response gives the same values at any subset of times
    u0 = resp.displacements(np.zeros(resp.n_params), times)
    jac = np.stack([(resp.displacements(e, times) - u0).reshape(len(times), -1)
                    for e in np.eye(resp.n_params)], axis=-1)                     # (3, 3N, n)
    for k, f in enumerate(checked):
        expected = np.sqrt(np.einsum("ij,jk,ik->i", jac[k], cov, jac[k])).reshape(-1, 3)
        np.testing.assert_allclose(std[f], expected, rtol=1e-8, atol=1e-12 * expected.max())


class SaturatingResponse:
    """A nonlinear response: the lateral (y) displacement of the quasi-static response saturates,
    ``u_y -> s tanh(u_y / s)`` (a crude contact).  Its tangent at x is separable per time:
    ``dU(t_i) = D_i R dC b(t_i)`` with D_i (N, 3) the saturation's slope at t_i, i.e. one term
    (R_i = D_i R, B_i = b masked to t_i) per time of ``times``."""

    def __init__(self, quasi_static: QuasiStaticResponse, scale_mm: float) -> None:
        self.qs, self.s = quasi_static, scale_mm
        self.n_params, self.n_vertices = quasi_static.n_params, quasi_static.n_vertices

    def _slope(self, u):
        d = np.ones_like(u)
        d[..., 1] = 1.0 - np.tanh(u[..., 1] / self.s) ** 2
        return d

    def displacements(self, x, times):
        u = self.qs.displacements(x, times)
        u[..., 1] = self.s * np.tanh(u[..., 1] / self.s)
        return u

    def adjoint(self, g, times, x=None):
        return self.qs.adjoint(g * self._slope(self.qs.displacements(x, times)), times)

    def linearize(self, x, times):
        d = self._slope(self.qs.displacements(x, times))                 # (T, N, 3)
        b = self.qs.time_basis(times)
        terms = []
        for i in range(len(b)):
            bi = np.zeros_like(b)
            bi[i] = b[i]
            terms.append(SeparableTerm(self.qs.basis_ * d[i][:, :, None], bi))
        return Linearization(tuple(terms))

    def penalty_operator(self):
        return self.qs.penalty_operator()


@pytest.fixture(scope="module")
def saturating():
    model = elastic_model()
    n_frames = 6
    fps = n_frames * F0_HZ
    times = 0.002 + np.arange(n_frames) / fps
    field = ForceField(ForceFieldSpec((2, 2, 3), ("inferior",)), (times[0], times[-1] + 1.0 / fps))
    resp = SaturatingResponse(QuasiStaticResponse(model, field), scale_mm=0.08)
    x_true = true_controls(field, seed=2)
    meas = synthesize_measurement(model.mesh, CAMERA, resp, times, x_true, SETTINGS)
    return model, resp, meas, x_true


def test_a_nonlinear_response_plugs_in_through_its_tangent(saturating):
    """Gradient and Gauss-Newton model use the tangent at x: the gradient matches central differences of
    the frozen E, the linearization is the response's derivative, and a Levenberg-Marquardt fit from zero
    recovers the superior motion; the posterior propagates through the tangent."""
    model, resp, meas, x_true = saturating
    p = Problem(model.mesh, CAMERA, resp, meas, SETTINGS)
    u_true = p.displacements(x_true)
    lin_u = resp.qs.displacements(x_true, p.sim_times)
    assert np.abs(u_true - lin_u).max() > 0.2 * np.abs(lin_u).max()      # really nonlinear at the truth
    x0 = 0.7 * x_true
    lin = resp.linearize(x0, p.sim_times)
    dx = np.random.default_rng(3).normal(0, 1e-3, p.n_params)
    np.testing.assert_allclose(lin.apply(dx), (p.displacements(x0 + dx) - p.displacements(x0 - dx)) / 2,
                               rtol=1e-6, atol=1e-8 * np.abs(lin.apply(dx)).max())
    frames = p.freeze(x0)
    _, grad = p.frozen_value_and_grad(x0, frames)
    for d in np.random.default_rng(4).normal(size=(3, p.n_params)):
        fd = (p.frozen_value(x0 + 0.1 * d, frames).total - p.frozen_value(x0 - 0.1 * d, frames).total) / 0.2
        assert grad @ d == pytest.approx(fd, rel=1e-5)
    res = fit(p, method="gauss-newton", max_iter=30, options=FitOptions(ftol=1e-10))
    total = res.history["total"]
    assert np.all(np.diff(total) < 0) and total[-1] < 1e-3 * total[0]
    sup = np.unique(model.mesh.faces[model.mesh.face_tag == TAG_SUPERIOR])
    vt = np.diff(u_true, axis=0)[:, sup]
    vf = np.diff(p.displacements(res.x), axis=0)[:, sup]
    assert np.linalg.norm(vf - vt) / np.linalg.norm(vt) < 0.05
    gn = gauss_newton_model(p.with_weights(ridge_weight=1e-7), res.x)
    post = posterior(gn, ResidualCorrelation(5000, 1.0, 1.0, 5000.0))
    std = displacement_std(post.covariance, gn.linearization)
    h = 1e-4
    jac = np.stack([((p.displacements(res.x + h * e) - p.displacements(res.x - h * e)) / (2 * h)).reshape(len(p.sim_times), -1)
                    for e in np.eye(p.n_params)], axis=-1)
    cov = post.covariance.dense()
    for f in (1, 4):
        expected = np.sqrt(np.einsum("ij,jk,ik->i", jac[f], cov, jac[f])).reshape(-1, 3)
        np.testing.assert_allclose(std[f], expected, rtol=1e-5, atol=1e-9 * expected.max())
