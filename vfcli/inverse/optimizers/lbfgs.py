"""``method="lbfgs"``: limited-memory BFGS with exact frozen-raster gradients.

Two-loop recursion over ``memory`` curvature pairs on the gradient of
:meth:`vfcli.inverse.problem.Problem.value_and_grad`, with an Armijo backtracking line
search (quadratic interpolation; the first iteration, which has no curvature
information, expands its step by doubling while E decreases).  Written here rather than
taken from scipy so that its whole state (x, E, gradient, curvature pairs) is saved in
:class:`vfcli.inverse.optimizers.base.FitState`: a resumed run continues exactly where
it stopped and ends where an uninterrupted run ends.
"""
from __future__ import annotations

import numpy as np

from vfcli.inverse.optimizers.base import FitOptions, FitState, Method, Objective, no_decrease, terms_array


def _two_loop(g: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """-H g by the L-BFGS two-loop recursion; g (n,), pairs s, y (m, n) oldest first."""
    q = g.copy()
    rho = 1.0 / np.einsum("ij,ij->i", s, y)
    alpha = np.zeros(len(s))
    for i in range(len(s) - 1, -1, -1):
        alpha[i] = rho[i] * (s[i] @ q)
        q -= alpha[i] * y[i]
    q *= (s[-1] @ y[-1]) / (y[-1] @ y[-1])
    for i in range(len(s)):
        q += (alpha[i] - rho[i] * (y[i] @ q)) * s[i]
    return -q


class LBFGS(Method):
    """L-BFGS (module docstring)."""

    name = "lbfgs"

    def step(self, obj: Objective, st: FitState, opts: FitOptions) -> tuple[bool, float]:
        """One L-BFGS iteration; returns (moved, step length in x units)."""
        f0, g0 = st.value[0], st.grad
        if len(st.memory_s):
            d = _two_loop(g0, st.memory_s, st.memory_y)
            if d @ g0 >= 0:  # not a descent direction: restart from steepest descent
                st.memory_s = st.memory_s[:0]
                st.memory_y = st.memory_y[:0]
        if not len(st.memory_s):
            d = -g0 * (opts.initial_step / max(np.linalg.norm(g0), 1e-300))
        slope = d @ g0
        alpha, best = 1.0, None
        for _ in range(opts.max_line_search):
            terms, g = obj.value_and_grad(st.x + alpha * d)
            if terms.total <= f0 + opts.armijo * alpha * slope:
                best = (alpha, terms, g)
                break
            # backtrack to the minimiser of the quadratic through f0, slope and f(alpha), within [0.1, 0.5] alpha
            curv = terms.total - f0 - slope * alpha
            alpha = float(np.clip(-slope * alpha * alpha / (2.0 * curv), 0.1 * alpha, 0.5 * alpha)) \
                if curv > 0 else 0.5 * alpha
        if best is not None and not len(st.memory_s) and best[0] == 1.0:
            # no curvature information yet and the first trial was accepted: expand while E decreases
            for _ in range(opts.max_line_search):
                t2, g2 = obj.value_and_grad(st.x + 2.0 * best[0] * d)
                if not t2.total < best[1].total:
                    break
                best = (2.0 * best[0], t2, g2)
        if best is None:
            return no_decrease(st, -slope, opts)
        alpha, terms, g = best
        s = alpha * d
        y = g - g0
        st.x = st.x + s
        st.value, st.grad = terms_array(terms), g
        if s @ y > 1e-12 * np.linalg.norm(s) * np.linalg.norm(y):
            n = len(s)
            ms = st.memory_s.reshape(-1, n)
            my = st.memory_y.reshape(-1, n)
            st.memory_s = np.vstack([ms, s])[-opts.memory:]
            st.memory_y = np.vstack([my, y])[-opts.memory:]
        return True, float(np.linalg.norm(s))
