"""``method="paper"``: the paper's method, kept for comparison.

Forward finite-difference gradient (one full objective evaluation, raster included,
per control value) and gradient descent with an increasing-step line search (double
the step while E decreases; halve it until E decreases; the accepted step seeds the
next iteration and is saved as ``FitState.gamma``, so a resumed run is exact).
"""
from __future__ import annotations

import numpy as np

from vfcli.inverse.optimizers.base import FitOptions, FitState, Method, Objective, no_decrease, terms_array
from vfcli.inverse.terms import Terms


def fd_grad(obj: Objective, x: np.ndarray, f0: float, h: float) -> np.ndarray:
    """(n,) forward-difference gradient of E at x (E(x) = f0 given), step h in x units."""
    g = np.empty_like(x)
    for i in range(len(x)):
        xi = x.copy()
        xi[i] += h
        g[i] = (obj.value(xi).total - f0) / h
    return g


class Paper(Method):
    """Gradient descent on a finite-difference gradient (module docstring)."""

    name = "paper"

    def start(self, obj: Objective, x: np.ndarray, opts: FitOptions) -> Terms:
        t = obj.value(x)
        obj.state.grad = fd_grad(obj, x, t.total, opts.fd_step)
        return t

    def step(self, obj: Objective, st: FitState, opts: FitOptions) -> tuple[bool, float]:
        """One gradient-descent iteration with the increasing-step line search."""
        f0, g = st.value[0], st.grad
        gamma = st.gamma if st.gamma > 0 else opts.initial_step / max(np.linalg.norm(g), 1e-300)
        promised = gamma * float(g @ g)
        best = None
        for _ in range(opts.max_line_search):
            t = obj.value(st.x - gamma * g)
            if t.total < f0:
                best = (gamma, t)
                while True:  # increase the step while E decreases
                    t2 = obj.value(st.x - 2 * gamma * g)
                    if not t2.total < best[1].total:
                        break
                    gamma *= 2.0
                    best = (gamma, t2)
                break
            gamma *= 0.5
        if best is None:
            return no_decrease(st, promised, opts)
        gamma, t = best
        st.x = st.x - gamma * g
        st.value = terms_array(t)
        st.gamma = gamma
        st.grad = fd_grad(obj, st.x, t.total, opts.fd_step)
        return True, float(gamma * np.linalg.norm(g))
