"""``method="gauss-newton"``: Levenberg-Marquardt on the Gauss-Newton model of E.

Around the raster of the current iterate, :func:`vfcli.inverse.linearization.gauss_newton_model`
gives E's exact gradient g and Gauss-Newton Hessian H (the motion term's exact Hessian,
the gap term's majoriser curvature, the ridge).  Solve ``(H + mu D) s = -g`` with D the
diagonal of H (floored at ``1e-6`` of its mean), accept s when the re-rasterised E
decreases, and adapt mu from the ratio of actual to predicted decrease (Nielsen's rule).
The damping mu is saved as ``FitState.gamma``, so resuming is exact.  The model at the
accepted point is built on the rasters of the evaluation that accepted it, and reused by
the next iteration.  Work arrays come from the fit's workspace.
"""
from __future__ import annotations

import numpy as np

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.optimizers.base import FitOptions, FitState, Method, Objective, no_decrease, terms_array
from vfcli.inverse.terms import Terms
from vfcli.inverse.workspace import Workspace


def lm_solve(hess: BlockMatrix, grad: np.ndarray, mu: float, workspace: Workspace | None = None) -> np.ndarray:
    """The Levenberg-Marquardt step ``-(H + mu D)^-1 g`` (n,), D = diag(H) floored at 1e-6 of its mean."""
    d = hess.diagonal()
    mean = float(np.mean(d)) if np.mean(d) > 0 else 1.0
    return -hess.solve(grad, mu * np.maximum(d, 1e-6 * mean), workspace)


def _linearize(obj: Objective, x: np.ndarray):
    """E at x with the frozen rasters and displacements (one evaluation), for :func:`_quadratic`."""
    obj.state.n_evals += 1
    u = obj.problem.displacements(x)
    frames = obj.problem.freeze(x, u)
    return obj.problem.frozen_value(x, frames), (frames, u)


def _quadratic(obj: Objective, x: np.ndarray, frozen=None):
    """The Gauss-Newton model at an already evaluated x (reusing ``frozen`` from :func:`_linearize`
    at the same x; without it, as after a resume, x is rasterised again). Not counted as an
    evaluation, so a resumed run's history equals an uninterrupted one's."""
    from vfcli.inverse.linearization import gauss_newton_model

    if frozen is None:
        return gauss_newton_model(obj.problem, x, workspace=obj.workspace)
    return gauss_newton_model(obj.problem, x, frozen[0], frozen[1], workspace=obj.workspace)


class LevenbergMarquardt(Method):
    """Levenberg-Marquardt on the Gauss-Newton model (module docstring); stops on ``xtol`` too."""

    name = "gauss-newton"
    uses_xtol = True

    def start(self, obj: Objective, x: np.ndarray, opts: FitOptions) -> Terms:
        # the first step needs the model at x0: build it on the rasters of this evaluation
        t, frozen = _linearize(obj, x)
        obj.model = _quadratic(obj, x, frozen)
        obj.state.grad = obj.model.grad
        return t

    def step(self, obj: Objective, st: FitState, opts: FitOptions) -> tuple[bool, float]:
        """One Levenberg-Marquardt iteration on the Gauss-Newton model at the current raster."""
        model = obj.model if obj.model is not None else _quadratic(obj, st.x)
        obj.model = None
        f0, g, hess = st.value[0], model.grad, model.hessian
        mu = st.gamma if st.gamma > 0 else opts.lm_damping
        nu = 2.0
        first = None
        for _ in range(opts.max_line_search):
            s = lm_solve(hess, g, mu, obj.workspace)
            predicted = -(g @ s + 0.5 * s @ (hess @ s))
            if predicted <= opts.ftol * abs(f0):
                # even the model's own (damped) minimiser would not lower E by the stopping fraction, and more
                # damping predicts less: converged
                st.converged, st.message = True, "predicted decrease below ftol"
                return False, 0.0
            first = predicted if first is None else first
            x_new = st.x + s
            terms, frozen = _linearize(obj, x_new)
            if terms.total < f0 and predicted > 0:
                rho = (f0 - terms.total) / predicted
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                st.x, st.gamma = x_new, mu
                obj.model = _quadratic(obj, x_new, frozen)
                st.value, st.grad = terms_array(obj.model.terms), obj.model.grad
                return True, float(np.linalg.norm(s))
            mu *= nu
            nu *= 2.0
        st.gamma = mu
        return no_decrease(st, first, opts)
