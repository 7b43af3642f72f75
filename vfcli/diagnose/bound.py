"""The extended model's own bound on the loads' free correction: the corner of its L-curve.

optimize bounds the free part of a load model (the Bernstein correction of the ``pressure`` loads, the
``free-regularised`` fields) by a ridge weight at the corner of the L-curve of the run's model
(:func:`vfcli.inverse.regularization.lcurve`, when ``optimize.ridge_weight`` is null). That corner is a
property of the model as much as of the data. Where the baseline misses physics the loads have to make up
for, its corner lies low and the free correction is left almost unbounded. On the blind panel's three inertia
phantoms the quasi-static baseline's corner was 1.6e-9 to 5.5e-6 1/Pa^2; on the nulls and the other effects it was
3-90. With the free correction unbounded, the gains on the measured pressure no longer carry the load's mean
(panel seed 2012: inferior gain -66 Pa and a free mean of +1048 Pa). So the static shape, which neither instrument's
velocity sees, follows the free correction. A refit that adds the inertia the baseline missed but keeps the
baseline's weight kept that freedom too. 2012's refit let its static shape go (mean vertical displacement of the
inferior surface 1.31 -> 0.12 mm for a true 1.29).

The extended model of a candidate that states its own response (inertia, damping: linear in the loads at
fixed theta) has an L-curve of its own. It is computed exactly as optimize computes the baseline's:
on the Gauss-Newton model at zero loads, with the ridge left out. On 2012 at the refit's density its corner is
9.8 1/Pa^2 (2.73 with the reduction recentred on the estimate, as the diagnosis computes it). The loads refitted at
9.8 with the density fixed carry the mean through the pressure gains again (inferior gain 767 Pa, free mean 0) and
the static shape reads 1.07 mm; the diagnosis's refit run is 16 % off on the inferior surface, its baseline 47 %
(docs/benchmarks.md, "Session 55").
"""
from __future__ import annotations

import dataclasses

import numpy as np

from vfcli.diagnose.refit import RefitResult, extended_problem, joint_fit
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.inverse.regularization import lcurve


def own_ridge_weight(problem) -> float:
    """The corner of the L-curve of ``problem``'s model (1/Pa^2), computed as optimize computes a run's
    (:func:`vfcli.inverse.setup.build_problem` with ``optimize.ridge_weight`` null): the Gauss-Newton model of
    the data terms at zero loads, the penalty the load model's.

    problem : a :class:`vfcli.inverse.problem.Problem` (e.g. the baseline's with an extended response);
        its own ridge weight is ignored.
    """
    p = problem.with_weights(ridge_weight=0.0)
    zero = np.zeros(p.n_params)
    return float(lcurve(gauss_newton_model(p, zero), zero, p.penalty).chosen)


def refit_at_own_bound(baseline, candidate, result: RefitResult, max_iterations: int = 8):
    """``result`` (the refit of ``candidate`` under the baseline's ridge weight) continued under the extended
    model's own weight (:func:`own_ridge_weight` at the fitted theta): the loads and theta refitted by
    :func:`vfcli.diagnose.refit.joint_fit` from where ``result`` ended.

    Only a candidate with its own response is rebounded; for the others the loads enter the extended model
    as they enter the baseline (dU0/dx), so its L-curve is the baseline's. A one-sided term fitted to 0 is the
    baseline. Returns (the problem the fit ended under, the refit): the baseline's problem and ``result`` as
    given where nothing changes, else a problem with the extended model's weight and the continued refit (its
    history continues ``result``'s; ``ridge_weight`` set; the history's E is under the new weight from
    the first continued iteration on).
    """
    from vfcli.diagnose.heldout import switched_off

    if not callable(getattr(candidate, "response", None)) or switched_off(candidate, result.theta):
        return baseline.problem, result
    weight = own_ridge_weight(extended_problem(baseline, candidate, result.theta))
    if np.isclose(weight, baseline.problem.settings.ridge_weight, rtol=1e-9, atol=0.0):
        return baseline.problem, result
    problem = baseline.problem.with_weights(ridge_weight=weight)
    more = joint_fit(problem, result.x, candidate, baseline.f0_hz, theta0=result.theta,
                     max_iterations=max_iterations, model=getattr(baseline, "model", None))
    history = {}
    for key, first in result.history.items():
        later = np.asarray(more.history[key])[1:]
        if key == "iteration":
            later = later + first[-1]
        history[key] = np.concatenate([np.asarray(first), later])
    return problem, dataclasses.replace(more, history=history, profiled=result.profiled, ridge_weight=weight)
