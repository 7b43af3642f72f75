"""Fitting the control values: L-BFGS with exact gradients, or the paper's method.

Methods
-------
``"lbfgs"`` (default)
    Limited-memory BFGS (two-loop recursion, ``memory`` pairs) on the exact
    frozen-raster gradient of :meth:`vfcli.inverse.problem.Problem.value_and_grad`,
    with an Armijo backtracking line search (quadratic interpolation; the first iteration, which has no
    curvature information, expands its step by doubling while E decreases).
    Implemented here rather than taken from scipy so that its whole state (x,
    E, gradient, curvature pairs) is saved in :class:`FitState`: a resumed run
    continues exactly where it stopped and ends where an uninterrupted run ends.
``"gauss-newton"``
    Levenberg-Marquardt on the Gauss-Newton model of E around the raster of the
    current iterate (:func:`vfcli.inverse.linearization.gauss_newton_model`: the motion
    term's exact Hessian, the gap term's majoriser curvature, the ridge): solve
    ``(H + mu D) s = -g`` with D the diagonal of H (floored at ``1e-6`` of its
    mean), accept s when the re-rasterised E decreases, and adapt mu from the
    ratio of actual to predicted decrease (Nielsen's rule).  Needs a
    :class:`vfcli.inverse.problem.Problem` whose response exposes its basis.  The
    damping mu is part of the saved state, so resuming is exact.
``"scipy-lbfgsb"``
    scipy's L-BFGS-B with the same gradient (resume restarts its memory, so a
    resumed run is close to, not identical with, an uninterrupted one).
``"paper"``
    The paper's method, kept for comparison: forward finite-difference gradient
    (one full objective evaluation, raster included, per control value) and
    gradient descent with an increasing-step line search (double the step while
    E decreases; halve it until E decreases; the accepted step seeds the next
    iteration).

Every accepted iterate decreases E (all three methods).  Iteration 0 of the
history is the starting point.

Examples
--------
>>> import numpy as np
>>> class Quadratic:
...     n_params = 2
...     def value_and_grad(self, x):
...         from vfcli.inverse.problem import Terms
...         return Terms(float(x @ x), float(x @ x), 0.0), 2 * x
...     def evaluate(self, x):
...         return self.value_and_grad(x)[0]
>>> res = fit(Quadratic(), np.array([3.0, -4.0]), max_iter=20)
>>> bool(res.terms.total < 1e-12)
True
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vfcli.errors import ConfigError
from vfcli.inverse.problem import Terms

log = logging.getLogger(__name__)

METHODS = ("lbfgs", "gauss-newton", "scipy-lbfgsb", "paper")
#: per-iteration history: iteration number, E and its weighted motion, gap and ridge terms, length of the
#: accepted step |x_k - x_{k-1}| (x units), cumulative wall time (s, over resumed runs too) and the
#: cumulative number of objective evaluations (a paper-method gradient counts n_params of them)
HISTORY_FIELDS = ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "n_evals")


@dataclass(frozen=True)
class FitOptions:
    """Settings of :func:`fit`.

    memory : L-BFGS curvature pairs kept.
    initial_step : length (in x units) of the first step along -grad (lbfgs and paper).
    armijo : sufficient-decrease constant c1.
    max_line_search : trial points per line search before giving up.
    ftol : stop when the relative decrease of E in an iteration is below this.
    xtol : gauss-newton also stops when an accepted step changes the problem's displacements
        (``problem.displacements(x)``, or x itself) by less than this, RMS relative to their RMS
        (0: off).  A Levenberg-Marquardt step is the damped minimiser of the whole model, so a
        step that barely moves the reconstruction leaves the model nothing to gain; line-search
        methods can take short steps far from the optimum, so they ignore it.
    gtol : stop when max |grad| is below this.
    fd_step : forward-difference step of the paper method, x units.
    lm_damping : initial Levenberg-Marquardt damping mu (gauss-newton), relative to diag(H).
    keep_every : keep the control values of every k-th iteration (and the last).
    """

    memory: int = 10
    initial_step: float = 10.0
    armijo: float = 1e-4
    max_line_search: int = 30
    ftol: float = 1e-12
    xtol: float = 0.0
    gtol: float = 0.0
    fd_step: float = 1e-1
    lm_damping: float = 1e-3
    keep_every: int = 1

    def __post_init__(self) -> None:
        if self.memory < 1 or self.max_line_search < 1 or self.keep_every < 1:
            raise ConfigError("fit memory, max_line_search and keep_every must be >= 1")
        if not (self.initial_step > 0 and self.fd_step > 0 and 0 < self.armijo < 0.5):
            raise ConfigError("fit initial_step and fd_step must be > 0, armijo in (0, 0.5)")


@dataclass
class FitState:
    """Everything needed to continue a fit (see :meth:`to_arrays` for storing it).

    x, value (total, motion, gap, ridge), grad : the current iterate.
    memory_s, memory_y : (m, n) L-BFGS pairs (lbfgs), oldest first.
    gamma : current step of the paper method; current damping mu of gauss-newton.
    history : per iteration lists of :data:`HISTORY_FIELDS`.
    kept_iterations, kept_x : control values kept (every k-th iteration).
    """

    method: str
    x: np.ndarray
    value: np.ndarray
    grad: np.ndarray
    iteration: int = 0
    n_evals: int = 0
    wall_time: float = 0.0
    gamma: float = 0.0
    memory_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    memory_y: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    history: dict = field(default_factory=lambda: {k: [] for k in HISTORY_FIELDS})
    kept_iterations: list = field(default_factory=list)
    kept_x: list = field(default_factory=list)
    converged: bool = False
    message: str = ""

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays (what a checkpoint stores); inverse of :meth:`from_arrays`."""
        out = {"method": np.array(self.method), "x": self.x, "value": self.value, "grad": self.grad,
               "iteration": np.array(self.iteration), "n_evals": np.array(self.n_evals),
               "wall_time": np.array(self.wall_time), "gamma": np.array(self.gamma),
               "memory_s": self.memory_s, "memory_y": self.memory_y,
               "kept_iterations": np.array(self.kept_iterations, dtype=np.int64),
               "kept_x": np.array(self.kept_x).reshape(len(self.kept_x), len(self.x)),
               "converged": np.array(self.converged), "message": np.array(self.message)}
        for k in HISTORY_FIELDS:
            out[f"history_{k}"] = np.array(self.history[k], dtype=np.int64 if k in ("iteration", "n_evals") else float)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict) -> FitState:
        a = {k: np.asarray(v) for k, v in arrays.items()}
        return cls(method=str(a["method"]), x=a["x"].astype(float), value=a["value"].astype(float),
                   grad=a["grad"].astype(float), iteration=int(a["iteration"]), n_evals=int(a["n_evals"]),
                   wall_time=float(a["wall_time"]), gamma=float(a["gamma"]),
                   memory_s=a["memory_s"].astype(float), memory_y=a["memory_y"].astype(float),
                   history={k: a[f"history_{k}"].tolist() for k in HISTORY_FIELDS},
                   kept_iterations=a["kept_iterations"].tolist(), kept_x=list(a["kept_x"]),
                   converged=bool(a["converged"]), message=str(a["message"]))


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    x : (n,) final control values.  terms : final E.  state : to resume from.
    history : dict of (n_iter + 1,) arrays (:data:`HISTORY_FIELDS`).
    kept_iterations : (k,) int, kept_x : (k, n) control values kept.
    """

    x: np.ndarray
    terms: Terms
    state: FitState
    history: dict
    kept_iterations: np.ndarray
    kept_x: np.ndarray
    converged: bool
    message: str


class _Counter:
    """Objective wrapper counting evaluations."""

    def __init__(self, problem, state: FitState) -> None:
        self.problem, self.state = problem, state
        self.model = None   # Gauss-Newton model at state.x, when the last step built it

    def value_and_grad(self, x: np.ndarray) -> tuple[Terms, np.ndarray]:
        self.state.n_evals += 1
        return self.problem.value_and_grad(x)

    def value(self, x: np.ndarray) -> Terms:
        self.state.n_evals += 1
        return self.problem.evaluate(x)

    def linearize(self, x: np.ndarray):
        """E at x with the frozen rasters and displacements (one evaluation), for :meth:`quadratic`."""
        self.state.n_evals += 1
        u = self.problem.displacements(x)
        frames = self.problem.freeze(x, u)
        return self.problem.frozen_value(x, frames), (frames, u)

    def quadratic(self, x: np.ndarray, frozen=None):
        """The Gauss-Newton model at an already evaluated x (reusing ``frozen`` from :meth:`linearize`
        at the same x; without it, as after a resume, x is rasterised again). Not counted as an
        evaluation, so a resumed run's history equals an uninterrupted one's."""
        from vfcli.inverse.linearization import gauss_newton_model

        if frozen is None:
            return gauss_newton_model(self.problem, x)
        return gauss_newton_model(self.problem, x, frozen[0], frozen[1])

    def fd_grad(self, x: np.ndarray, f0: float, h: float) -> np.ndarray:
        g = np.empty_like(x)
        for i in range(len(x)):
            xi = x.copy()
            xi[i] += h
            g[i] = (self.value(xi).total - f0) / h
        return g


def _relative_change(problem, x_old: np.ndarray, x_new: np.ndarray) -> float:
    """RMS of the change of ``problem.displacements`` (or of x) from x_old to x_new over the RMS at x_new."""
    disp = getattr(problem, "displacements", None)
    a, b = (disp(x_old), disp(x_new)) if disp is not None else (x_old, x_new)
    return float(np.sqrt(np.mean((b - a) ** 2)) / max(np.sqrt(np.mean(b ** 2)), 1e-300))


def _terms_array(t: Terms) -> np.ndarray:
    return np.array([t.total, t.motion, t.gap, t.ridge], dtype=float)


def _record(state: FitState, step: float, opts: FitOptions, t_start: float, force_keep: bool = False) -> None:
    h = state.history
    for k, v in zip(HISTORY_FIELDS,
                    (state.iteration, *state.value, step, state.wall_time + time.perf_counter() - t_start,
                     state.n_evals)):
        h[k].append(v)
    if state.iteration % opts.keep_every == 0 or force_keep:
        if not state.kept_iterations or state.kept_iterations[-1] != state.iteration:
            state.kept_iterations.append(state.iteration)
            state.kept_x.append(state.x.copy())


def _two_loop(g: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """-H g by the L-BFGS two-loop recursion (pairs oldest first)."""
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


def _lbfgs_step(obj: _Counter, st: FitState, opts: FitOptions) -> tuple[bool, float]:
    """One L-BFGS iteration; returns (moved, step length)."""
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
        return False, 0.0
    alpha, terms, g = best
    s = alpha * d
    y = g - g0
    st.x = st.x + s
    st.value, st.grad = _terms_array(terms), g
    if s @ y > 1e-12 * np.linalg.norm(s) * np.linalg.norm(y):
        n = len(s)
        ms = st.memory_s.reshape(-1, n)
        my = st.memory_y.reshape(-1, n)
        st.memory_s = np.vstack([ms, s])[-opts.memory:]
        st.memory_y = np.vstack([my, y])[-opts.memory:]
    return True, float(np.linalg.norm(s))


def _lm_solve(hess, grad: np.ndarray, mu: float) -> np.ndarray:
    """The Levenberg-Marquardt step ``-(H + mu D)^-1 g`` (H a :class:`vfcli.inverse.linearization.BlockMatrix`),
    D = diag(H) floored at 1e-6 of its mean."""
    d = hess.diagonal()
    mean = float(np.mean(d)) if np.mean(d) > 0 else 1.0
    return -hess.solve(grad, mu * np.maximum(d, 1e-6 * mean))


def _gn_step(obj: _Counter, st: FitState, opts: FitOptions) -> tuple[bool, float]:
    """One Levenberg-Marquardt iteration on the Gauss-Newton model at the current raster."""
    model = obj.model if obj.model is not None else obj.quadratic(st.x)
    obj.model = None
    f0, g, hess = st.value[0], model.grad, model.hessian
    mu = st.gamma if st.gamma > 0 else opts.lm_damping
    nu = 2.0
    for _ in range(opts.max_line_search):
        s = _lm_solve(hess, g, mu)
        predicted = -(g @ s + 0.5 * s @ (hess @ s))
        if predicted <= opts.ftol * abs(f0):
            # even the model's own (damped) minimiser would not lower E by the stopping fraction, and more
            # damping predicts less: converged
            st.message = "predicted decrease below ftol"
            return False, 0.0
        x_new = st.x + s
        terms, frozen = obj.linearize(x_new)
        if terms.total < f0 and predicted > 0:
            rho = (f0 - terms.total) / predicted
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            st.x, st.gamma = x_new, mu
            obj.model = obj.quadratic(x_new, frozen)
            st.value, st.grad = _terms_array(obj.model.terms), obj.model.grad
            return True, float(np.linalg.norm(s))
        mu *= nu
        nu *= 2.0
    st.gamma = mu
    return False, 0.0


def _paper_step(obj: _Counter, st: FitState, opts: FitOptions) -> tuple[bool, float]:
    """One gradient-descent iteration with the increasing-step line search."""
    f0, g = st.value[0], st.grad
    gamma = st.gamma if st.gamma > 0 else opts.initial_step / max(np.linalg.norm(g), 1e-300)
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
        return False, 0.0
    gamma, t = best
    st.x = st.x - gamma * g
    st.value = _terms_array(t)
    st.gamma = gamma
    st.grad = obj.fd_grad(st.x, t.total, opts.fd_step)
    return True, float(gamma * np.linalg.norm(g))


def _scipy_run(obj: _Counter, st: FitState, opts: FitOptions, max_iter: int, t_start: float,
               callback: Callable | None) -> None:
    from scipy.optimize import minimize

    class _Stop(Exception):
        pass

    cache: dict = {}

    def fun(x):
        terms, g = obj.value_and_grad(x)
        cache[x.tobytes()] = (terms, g)
        return terms.total, g

    def cb(intermediate_result):
        x = np.asarray(intermediate_result.x, float)
        terms, g = cache.get(x.tobytes()) or obj.value_and_grad(x)
        step = float(np.linalg.norm(x - st.x))
        st.x, st.value, st.grad = x.copy(), _terms_array(terms), g
        st.iteration += 1
        _record(st, step, opts, t_start)
        if callback is not None and callback(st):
            raise _Stop

    remaining = max_iter - st.iteration
    try:
        res = minimize(fun, st.x, jac=True, method="L-BFGS-B", callback=cb,
                       options={"maxiter": remaining, "maxcor": opts.memory, "ftol": opts.ftol,
                                "gtol": opts.gtol})
        st.converged = bool(res.success) and st.iteration < max_iter
        st.message = str(res.message)
    except _Stop:
        st.message = "stopped by callback"


def fit(problem, x0: np.ndarray | None = None, method: str = "lbfgs", max_iter: int = 100,
        callback: Callable[[FitState], bool | None] | None = None, *, state: FitState | None = None,
        options: FitOptions | None = None) -> FitResult:
    """Minimise E over the control values.

    Parameters
    ----------
    problem : object with ``n_params``, ``value_and_grad(x) -> (Terms, (n,))`` and
        ``evaluate(x) -> Terms`` (e.g. :class:`vfcli.inverse.problem.Problem`).
    x0 : (n,) start (default zeros, the paper's start); ignored when ``state`` is given.
    method : "lbfgs", "gauss-newton", "scipy-lbfgsb" or "paper".
    max_iter : total iteration count to reach (counting those of ``state``).
    callback : called with the :class:`FitState` after every iteration (checkpoint
        it with ``state.to_arrays()``); returning True stops the fit.
    state : continue from this state (see :func:`resume`).
    options : FitOptions.

    Returns
    -------
    FitResult
    """
    opts = options or FitOptions()
    t_start = time.perf_counter()
    if state is None:
        if method not in METHODS:
            raise ConfigError(f"fit method must be one of {METHODS}, got {method!r}")
        x = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
        if x.shape != (problem.n_params,):
            raise ConfigError(f"x0 must have shape ({problem.n_params},), got {x.shape}")
        state = FitState(method=method, x=x, value=np.zeros(4), grad=np.zeros_like(x))
        obj = _Counter(problem, state)
        if method == "paper":
            t = obj.value(x)
            state.grad = obj.fd_grad(x, t.total, opts.fd_step)
        elif method == "gauss-newton":
            # the first step needs the model at x0: build it on the rasters of this evaluation
            t, frozen = obj.linearize(x)
            obj.model = obj.quadratic(x, frozen)
            state.grad = obj.model.grad
        else:
            t, state.grad = obj.value_and_grad(x)
        state.value = _terms_array(t)
        _record(state, 0.0, opts, t_start)
    else:
        obj = _Counter(problem, state)
        method = state.method
        if not state.converged:
            state.message = ""
    if method == "scipy-lbfgsb" and not state.converged and state.iteration < max_iter:
        _scipy_run(obj, state, opts, max_iter, t_start, callback)
    step_fn = {"lbfgs": _lbfgs_step, "gauss-newton": _gn_step, "paper": _paper_step}.get(method)
    while step_fn is not None and not state.converged and state.iteration < max_iter:
        if np.max(np.abs(state.grad), initial=0.0) <= opts.gtol:
            state.converged, state.message = True, "gradient below gtol"
            break
        f_before, x_before = state.value[0], state.x
        moved, step = step_fn(obj, state, opts)
        if not moved:
            state.converged, state.message = True, state.message or "line search found no decrease"
            break
        state.iteration += 1
        _record(state, step, opts, t_start)
        log.info("fit %s iteration %d: E = %.6g (motion %.6g, gap %.6g, ridge %.6g)", method, state.iteration,
                 *state.value)
        if f_before - state.value[0] <= opts.ftol * max(abs(f_before), 1e-300):
            state.converged, state.message = True, "relative decrease below ftol"
            break
        if method == "gauss-newton" and opts.xtol > 0 and _relative_change(problem, x_before, state.x) < opts.xtol:
            state.converged, state.message = True, "reconstruction change below xtol"
            break
        if callback is not None and callback(state):
            state.message = "stopped by callback"
            break
    if not state.message:
        state.message = "max_iter reached"
    state.wall_time += time.perf_counter() - t_start
    if not state.kept_iterations or state.kept_iterations[-1] != state.iteration:
        state.kept_iterations.append(state.iteration)
        state.kept_x.append(state.x.copy())
    hist = {k: np.asarray(v) for k, v in state.history.items()}
    return FitResult(x=state.x.copy(), terms=Terms(*map(float, state.value)), state=state, history=hist,
                     kept_iterations=np.asarray(state.kept_iterations, dtype=np.int64),
                     kept_x=np.array(state.kept_x).reshape(len(state.kept_x), len(state.x)),
                     converged=state.converged, message=state.message)


def resume(problem, state: FitState, max_iter: int, callback: Callable | None = None,
           options: FitOptions | None = None) -> FitResult:
    """Continue a fit from a saved state (``FitState.from_arrays(checkpoint)``) up to ``max_iter``.

    With the same problem and options, a run stopped at iteration k and resumed
    ends exactly where an uninterrupted run ends ("lbfgs", "paper").
    """
    return fit(problem, method=state.method, max_iter=max_iter, callback=callback, state=state, options=options)
