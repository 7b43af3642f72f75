"""Fitting the control values: what every method shares (validation, state, history, checkpoints).

Methods (one module each, implementing only its step)
------------------------------------------------------
``"lbfgs"`` (default)
    L-BFGS with exact frozen-raster gradients (:mod:`vfcli.inverse.optimizers.lbfgs`).
``"gauss-newton"``
    Levenberg-Marquardt on the Gauss-Newton model of E
    (:mod:`vfcli.inverse.optimizers.levenberg_marquardt`); needs a
    :class:`vfcli.inverse.problem.Problem`.
``"paper"``
    The paper's finite-difference gradient descent (:mod:`vfcli.inverse.optimizers.paper`).

Every accepted iterate decreases E (all three methods).  Iteration 0 of the history
is the starting point.  The whole state of a method is saved in :class:`FitState`, so
a resumed run ends exactly where an uninterrupted run ends.  A fit owns its work
arrays (:class:`vfcli.inverse.workspace.Workspace`): fits in threads of one process
do not share any.

Examples
--------
>>> import numpy as np
>>> class Quadratic:
...     n_params = 2
...     def value_and_grad(self, x):
...         from vfcli.inverse.terms import Terms
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

from vfcli.inverse.terms import Terms
from vfcli.inverse.workspace import Workspace

log = logging.getLogger(__name__)

#: the methods :func:`fit` knows (``optimize.method`` of the config)
METHODS = ("lbfgs", "gauss-newton", "paper")
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

    Raises ValueError for values out of range (the config bounds the fields it sets; a bad value
    here is a caller's bug).
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
            raise ValueError("fit memory, max_line_search and keep_every must be >= 1")
        if not (self.initial_step > 0 and self.fd_step > 0 and 0 < self.armijo < 0.5):
            raise ValueError("fit initial_step and fd_step must be > 0, armijo in (0, 0.5)")


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


class Objective:
    """The problem as a method sees it: counts evaluations, carries the fit's workspace.

    problem : object with ``n_params``, ``value_and_grad`` and ``evaluate`` (a Problem).
    state : the fit's :class:`FitState` (``n_evals`` is counted there).
    workspace : work arrays of this fit.  model : a method's cache (the Gauss-Newton model at state.x).
    """

    def __init__(self, problem, state: FitState, workspace: Workspace | None = None) -> None:
        self.problem, self.state = problem, state
        self.workspace = workspace if workspace is not None else Workspace()
        self.model = None

    def value_and_grad(self, x: np.ndarray) -> tuple[Terms, np.ndarray]:
        self.state.n_evals += 1
        return self.problem.value_and_grad(x)

    def value(self, x: np.ndarray) -> Terms:
        self.state.n_evals += 1
        return self.problem.evaluate(x)


class Method:
    """One optimisation method: subclasses set ``name`` and implement :meth:`step` (and :meth:`start`
    when the first gradient is not the exact one)."""

    name = ""
    #: stop when a step changes the reconstruction by less than ``FitOptions.xtol``
    uses_xtol = False

    def start(self, obj: Objective, x: np.ndarray, opts: FitOptions) -> Terms:
        """E at the start x; sets ``obj.state.grad``."""
        t, obj.state.grad = obj.value_and_grad(x)
        return t

    def step(self, obj: Objective, st: FitState, opts: FitOptions) -> tuple[bool, float]:
        """One iteration from ``st`` (updated in place): (moved, length of the step in x units).

        A step that does not move sets ``st.converged`` when the point is a minimum by the
        stopping rules (e.g. with :func:`no_decrease`); otherwise the fit stops unconverged."""
        raise NotImplementedError


#: a promised decrease below this fraction of the start's E is lost in E's round-off
ROUND_OFF = 1e-13


def no_decrease(st: FitState, promised: float, opts: FitOptions) -> tuple[bool, float]:
    """A line search that found no lower E along a direction whose first trial promised a decrease
    of ``promised`` (first-order or the method's model, E units): a minimum when that promise is
    below ``opts.ftol`` of E or lost in round-off (:data:`ROUND_OFF` of the start's E), else a stop
    before a minimum (an inexact gradient, as the paper method's coarse finite differences).
    Sets ``st.converged`` and ``st.message``; returns ``(False, 0.0)`` for :meth:`Method.step`."""
    f0 = float(st.value[0])
    start = float(st.history["total"][0]) if st.history["total"] else f0
    rel = promised / max(abs(f0), 1e-300)
    if promised <= max(opts.ftol * abs(f0), ROUND_OFF * abs(start)):
        st.converged = True
        st.message = (f"line search found no decrease where the direction promised {rel:.2g} of E, within ftol or "
                      "round-off: a minimum")
    else:
        st.message = (f"line search found no decrease where the direction promised {rel:.2g} of E: "
                      "stopped before a minimum")
    return False, 0.0


def get_method(name: str) -> Method:
    """The :class:`Method` called ``name`` (one of :data:`METHODS`)."""
    from vfcli.inverse.optimizers.lbfgs import LBFGS
    from vfcli.inverse.optimizers.levenberg_marquardt import LevenbergMarquardt
    from vfcli.inverse.optimizers.paper import Paper

    known = {m.name: m for m in (LBFGS, LevenbergMarquardt, Paper)}
    if name not in known:
        raise ValueError(f"fit method must be one of {METHODS}, got {name!r}")
    return known[name]()


def _relative_change(problem, x_old: np.ndarray, x_new: np.ndarray) -> float:
    """RMS of the change of ``problem.displacements`` (or of x) from x_old to x_new over the RMS at x_new."""
    disp = getattr(problem, "displacements", None)
    a, b = (disp(x_old), disp(x_new)) if disp is not None else (x_old, x_new)
    return float(np.sqrt(np.mean((b - a) ** 2)) / max(np.sqrt(np.mean(b ** 2)), 1e-300))


def terms_array(t: Terms) -> np.ndarray:
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


def fit(problem, x0: np.ndarray | None = None, method: str = "lbfgs", max_iter: int = 100,
        callback: Callable[[FitState], bool | None] | None = None, *, state: FitState | None = None,
        options: FitOptions | None = None) -> FitResult:
    """Minimise E over the control values.

    Parameters
    ----------
    problem : object with ``n_params``, ``value_and_grad(x) -> (Terms, (n,))`` and
        ``evaluate(x) -> Terms`` (e.g. :class:`vfcli.inverse.problem.Problem`).
    x0 : (n,) start (default zeros, the paper's start); ignored when ``state`` is given.
    method : one of :data:`METHODS`.
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
    workspace = Workspace()
    if state is None:
        algo = get_method(method)
        x = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
        if x.shape != (problem.n_params,):
            raise ValueError(f"x0 must have shape ({problem.n_params},), got {x.shape}")
        state = FitState(method=method, x=x, value=np.zeros(4), grad=np.zeros_like(x))
        obj = Objective(problem, state, workspace)
        state.value = terms_array(algo.start(obj, x, opts))
        _record(state, 0.0, opts, t_start)
    else:
        algo = get_method(state.method)
        obj = Objective(problem, state, workspace)
        if not state.converged:
            state.message = ""
    while not state.converged and state.iteration < max_iter:
        if np.max(np.abs(state.grad), initial=0.0) <= opts.gtol:
            state.converged, state.message = True, "gradient below gtol"
            break
        f_before, x_before = state.value[0], state.x
        moved, step = algo.step(obj, state, opts)
        if not moved:
            state.message = state.message or "no step found: stopped before a minimum"
            break
        state.iteration += 1
        _record(state, step, opts, t_start)
        log.info("fit %s iteration %d: E = %.6g (motion %.6g, gap %.6g, ridge %.6g)", algo.name, state.iteration,
                 *state.value)
        if f_before - state.value[0] <= opts.ftol * max(abs(f_before), 1e-300):
            state.converged, state.message = True, "relative decrease below ftol"
            break
        if algo.uses_xtol and opts.xtol > 0 and _relative_change(problem, x_before, state.x) < opts.xtol:
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
