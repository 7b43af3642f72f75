"""The ridge term of E: an optional bound on the loads.

    E_ridge = ridge_weight * x^T Omega x / n_params

Omega (n_params, n_params) sparse PSD is the response's ``penalty_operator()`` (the load
model's: identity, or size plus first differences of the free fields), dimension Pa^2.
It is a prior term (a function of x only): exactly quadratic, Hessian
``2 ridge_weight Omega / n_params``.
"""
from __future__ import annotations

import scipy.sparse as sp

from vfcli.inverse.terms.base import Evaluation, Term


class RidgeTerm(Term):
    """``ridge_weight * x^T Omega x / n`` with Omega the problem's ``penalty`` (module docstring)."""

    name = "ridge"
    data = False

    def value(self, ev: Evaluation) -> float:
        w = self.weight(ev.problem.settings)
        omega_x = ev.problem.penalty @ ev.x
        if ev.grad_x is not None:
            ev.grad_x += (2.0 * w / len(ev.x)) * omega_x
        return w * float(ev.x @ omega_x) / len(ev.x)

    def hessian_matrix(self, ev: Evaluation) -> sp.spmatrix | None:
        w = self.weight(ev.problem.settings)
        if not w:
            return None
        return (2.0 * w / ev.problem.n_params) * sp.csr_matrix(ev.problem.penalty)
