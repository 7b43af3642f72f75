"""The term family of E: a new term is one class, and the problem, the Gauss-Newton model and the fit take it.

The new term written here is a periodicity penalty (the folds end a period where they began):
``E_period = w |U(t_F) - U(t_0)|^2 / N`` (mm^2 / vertex), a data term of the displacements whose
Gauss-Newton Hessian ``2 w / N sum_{j,k} (R_j^T R_k) (x) (db_j db_k^T)``, db_j = B_j(t_F) - B_j(t_0),
is exact.
"""
import numpy as np
import pytest

from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.optimizers.base import fit
from vfcli.inverse.problem import ObjectiveSettings, Problem
from vfcli.inverse.terms import DEFAULT_TERMS, GapTerm, MotionTerm, RidgeTerm, Term, Terms
from vfcli.inverse.terms.base import term_pairs

try:
    from _forward_case import CAMERA, forward_case
except ModuleNotFoundError:
    from tests._forward_case import CAMERA, forward_case


class Periodicity(Term):
    name = "period"

    def __init__(self, weight: float) -> None:
        self.w = weight

    def weight(self, settings) -> float:
        return self.w

    def value(self, ev):
        d = ev.disp[-1] - ev.disp[0]
        n = len(d)
        if ev.wants_grad:
            ev.grad_disp[-1] += 2.0 * self.w * d / n
            ev.grad_disp[0] -= 2.0 * self.w * d / n
        return self.w * float(np.sum(d * d)) / n

    def n_kron(self, problem, n_lin_terms):
        return n_lin_terms ** 2

    def kron_blocks(self, ev, lin, groups, out):
        n = ev.disp.shape[1]
        db = [b[-1] - b[0] for b in lin.temporal]
        for i, (j, k) in enumerate(term_pairs(lin.n_terms)):
            for stack, rj, rk in zip(out.blocks, lin.spatial[j], lin.spatial[k]):
                a, b = rj.reshape(-1, rj.shape[2]), rk.reshape(-1, rk.shape[2])
                stack[i] = (2.0 * self.w / n) * (a.T @ b)
            out.outers[i] = np.outer(db[j], db[k])


@pytest.fixture(scope="module")
def case():
    return forward_case(resolution=(2, 2, 3), sides=("inferior", "superior"), n_frames=8)


def _problem(case, terms=None, **weights):
    return Problem(case.model.mesh, CAMERA, case.response, case.measurement,
                   ObjectiveSettings(**{"motion_weight": 1e-4, "gap_weight": 1.0, "ridge_weight": 1e-7, **weights}),
                   terms=terms)


def test_default_terms_are_motion_gap_ridge_and_sum_to_e(case):
    p = _problem(case)
    assert [type(t) for t in p.terms] == [MotionTerm, GapTerm, RidgeTerm] == list(DEFAULT_TERMS)
    t = p.evaluate(0.5 * case.x_true)
    assert t.motion > 0 and t.gap > 0 and t.ridge > 0 and t.extra == {}
    assert t.total == t.motion + t.gap + t.ridge
    # each term alone is the problem with the other weights at zero
    for name in ("motion", "gap", "ridge"):
        alone = p.with_weights(**{f"{o}_weight": 0.0 for o in ("motion", "gap", "ridge") if o != name})
        assert alone.evaluate(0.5 * case.x_true).total == pytest.approx(getattr(t, name), rel=1e-12)


def test_a_new_term_adds_its_value_exact_gradient_and_exact_gauss_newton_blocks(case):
    base = _problem(case, gap_weight=0.0)
    p = _problem(case, terms=(*base.terms, Periodicity(50.0)), gap_weight=0.0)
    x0 = 0.5 * case.x_true + np.random.default_rng(0).normal(0, 30.0, p.n_params)
    frames = p.freeze(x0)
    t, g = p.frozen_value_and_grad(x0, frames)
    t0, g0 = base.frozen_value_and_grad(x0, frames)
    u = p.displacements(x0)
    expected = 50.0 * np.sum((u[-1] - u[0]) ** 2) / u.shape[1]
    assert t.extra["period"] == pytest.approx(expected, rel=1e-12) and expected > 1e-3 * t0.total
    assert t.total == pytest.approx(t0.total + expected, rel=1e-12)
    assert not np.allclose(g, g0)
    gn = gauss_newton_model(p, x0, frames)
    rng = np.random.default_rng(1)
    for d in rng.normal(size=(3, p.n_params)):
        fd = (p.frozen_value(x0 + d, frames).total - p.frozen_value(x0 - d, frames).total) / 2.0
        assert g @ d == pytest.approx(fd, rel=1e-7)
        fdg = (p.frozen_value_and_grad(x0 + d, frames)[1] - p.frozen_value_and_grad(x0 - d, frames)[1]) / 2.0
        np.testing.assert_allclose(gn.hessian @ d, fdg, rtol=1e-7, atol=1e-9 * np.abs(fdg).max())


def test_a_fit_with_the_new_term_trades_motion_for_periodicity(case):
    """With a heavy periodicity weight the Gauss-Newton fit ends nearer to periodic than without it."""
    plain = _problem(case)
    heavy = _problem(case, terms=(*plain.terms, Periodicity(1e3)))
    gaps = []
    for p in (plain, heavy):
        x = fit(p, method="gauss-newton", max_iter=10).x
        u = p.displacements(x)
        gaps.append(float(np.sqrt(np.mean((u[-1] - u[0]) ** 2))))
    assert gaps[1] < 0.5 * gaps[0]


def test_terms_need_distinct_names(case):
    with pytest.raises(ValueError, match="distinct"):
        _problem(case, terms=(MotionTerm(), MotionTerm()))


def test_terms_from_parts_sums_in_order_and_names_the_extras():
    t = Terms.from_parts({"motion": 1.0, "gap": 2.0, "ridge": 0.5, "physics": 0.25})
    assert (t.total, t.motion, t.gap, t.ridge, dict(t.extra)) == (3.75, 1.0, 2.0, 0.5, {"physics": 0.25})
    assert t.as_dict() == {"total": 3.75, "motion": 1.0, "gap": 2.0, "ridge": 0.5, "physics": 0.25}
