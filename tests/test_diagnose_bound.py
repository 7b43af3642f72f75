"""The extended model's own bound on the loads' free correction (vfcli.diagnose.bound).

On the pressure-load case of tests/_candidates_case.py with the folds' own mass in the data (density factor 1,
24 frames per cycle, as tests/test_diagnose_refit_inertia.py's inertia refit): the quasi-static model's L-curve puts its
corner decades below the extended model's (the loads make up for the missing mass), the refit continued under the
extended model's corner keeps its density, and it is judged against the baseline under the baseline's weight.
"""
from __future__ import annotations

import numpy as np
import pytest

from _candidates_case import pressure_case, reduced_inertia
from _refit_case import case_with
from vfcli.diagnose.bound import extended_problem, own_ridge_weight, refit_at_own_bound
from vfcli.diagnose.candidate import Baseline
from vfcli.diagnose.candidates import StiffnessAsymmetry
from vfcli.diagnose.refit import energy, joint_fit, refit
from vfcli.stages.diagnose import bound_from_lcurve


@pytest.fixture(scope="module")
def inertia_case():
    """(candidate, data with density factor 1, the quasi-static baseline fitted at its own L-curve corner)."""
    b0 = pressure_case(24, 4)
    cand, _ = reduced_inertia(b0)
    data = case_with(cand, (1.0,), n_frames=24)
    problem = data.problem.with_weights(ridge_weight=own_ridge_weight(data.problem))
    fitted = joint_fit(problem, np.zeros_like(data.x), None, data.f0_hz, max_iterations=10)
    return cand, data, Baseline.at(problem, fitted.x, data.f0_hz, model=b0.model)


def test_a_missing_mass_puts_the_quasi_static_models_l_curve_corner_decades_below_the_extended_models(inertia_case):
    """Measured: 4.5e-5 against 31 1/Pa^2 (6 decades); on the blind panel the inertia baselines' corners were
    1.6e-9 to 5.5e-6, the others' 3-90 (docs/benchmarks.md, "Session 55")."""
    cand, data, base = inertia_case
    w_base = base.problem.settings.ridge_weight
    w_ext = own_ridge_weight(extended_problem(base, cand, np.array([1.0])))
    print(f"L-curve corners: quasi-static {w_base:.3g}, with the mass {w_ext:.3g} 1/Pa^2")
    assert w_ext > 1e4 * w_base
    # without the effect the quasi-static model's corner is where the extended model's is (14 against 31)
    clean = pressure_case(24, 4).problem
    assert 0.1 < own_ridge_weight(clean) / w_ext < 10


def test_the_refit_continues_under_the_extended_models_corner_and_keeps_its_density(inertia_case):
    cand, data, base = inertia_case
    first = refit(base, cand, max_iterations=10)
    problem, r = refit_at_own_bound(base, cand, first, max_iterations=10)
    w_own = own_ridge_weight(extended_problem(base, cand, first.theta))
    print(f"density {first.theta[0]:.4f} -> {r.theta[0]:.4f}, weight {base.problem.settings.ridge_weight:.3g} -> "
          f"{r.ridge_weight:.3g}; E {first.history['total'][-1]:.4g} -> {r.history['total'][-1]:.4g}")
    assert r.ridge_weight == pytest.approx(w_own, rel=1e-12)
    assert problem.settings.ridge_weight == r.ridge_weight
    assert abs(r.theta[0] - 1.0) < 0.01
    # the history goes on from the first fit's, its E under the new weight from there
    n = len(first.history["iteration"])
    assert np.array_equal(r.history["total"][:n], first.history["total"])
    assert np.all(np.diff(r.history["iteration"]) == 1)
    # its E under the baseline's weight is the baseline's objective evaluated at its loads and displacements
    under_base = energy(base.problem, r.x, r.displacements, base.problem.freeze(r.x, r.displacements)).total
    assert r.total_at(base.problem.settings.ridge_weight) == pytest.approx(under_base, rel=1e-6)


def test_a_term_without_its_own_response_keeps_the_baselines_bound(inertia_case):
    """A per-fold stiffness factor enters as a change of the baseline response's displacements; the loads reach
    the extended model as they reach the baseline, so its L-curve is the baseline's."""
    _, data, base = inertia_case
    first = refit(base, StiffnessAsymmetry(), max_iterations=2)
    problem, r = refit_at_own_bound(base, StiffnessAsymmetry(), first, max_iterations=2)
    assert problem is base.problem and r is first and r.ridge_weight is None


@pytest.mark.parametrize("optimize, own", [({"loads": "pressure", "ridge_weight": None}, True),
                                           ({"loads": "free-regularised", "ridge_weight": None}, True),
                                           ({"loads": "pressure", "ridge_weight": 5.0}, False),
                                           ({"loads": "free", "ridge_weight": None}, False),
                                           ({}, True)])
def test_only_a_run_whose_weight_the_l_curve_chose_lets_its_refits_choose_theirs(optimize, own):
    assert bound_from_lcurve({"optimize": optimize}) is own


def test_an_l_curve_corner_below_its_reference_weight_says_the_tied_loads_cannot_fit_the_motion(inertia_case, caplog):
    """The quasi-static fit of data with the folds' mass: its corner 0.5 decades below the weight at which penalty
    and data weigh alike (4.5e-5 against 1.4e-4); without the mass 5 decades above it (as on every widened store but
    the inertia phantoms).  optimize warns on the first (vfcli.inverse.setup.warn_unbounded_correction)."""
    import logging

    from vfcli.inverse.linearization import gauss_newton_model
    from vfcli.inverse.regularization import lcurve
    from vfcli.inverse.setup import warn_unbounded_correction

    _, data, _ = inertia_case
    curves = {}
    for name, problem in (("mass", data.problem), ("clean", pressure_case(24, 4).problem)):
        p = problem.with_weights(ridge_weight=0.0)
        zero = np.zeros(p.n_params)
        curves[name] = lcurve(gauss_newton_model(p, zero), zero, p.penalty)
        print(name, f"corner {curves[name].chosen:.3g}, reference {curves[name].reference:.3g}")
    assert curves["mass"].unbounded and not curves["clean"].unbounded
    assert curves["clean"].chosen > 1e4 * curves["clean"].reference
    with caplog.at_level(logging.WARNING, logger="vfcli.inverse.setup"):
        warn_unbounded_correction(curves["mass"])
    assert "do not explain the motion" in caplog.text and "0.5 decades below" in caplog.text
