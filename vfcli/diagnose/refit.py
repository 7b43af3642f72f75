"""Confirmation refit: the baseline extended by one candidate, its loads x and the term's theta fitted jointly.

The extended model's vertex displacements are

    U(x, theta) = U0(x) + D(x, theta)

with U0 the baseline's response and D the candidate's change (``candidate.extension``: exact
at any theta, e.g. the periodic steady state of the modal reduction for a finite density or
retardation time; the linear column ``dU/dtheta @ theta`` for a term that is linear).  E is the
run's own objective (motion, gap, ridge; :mod:`vfcli.inverse.problem`) evaluated at U with the
raster frozen at U.

Gauss-Newton (:func:`joint_fit`), each iteration at (x, theta):

* dE/dU at U, hence the exact gradient in theta ``g_c = <dE/dU, dU/dtheta>`` (dU/dtheta by central
  differences of D) and the gradient in x through the baseline response's adjoint;
* the load block ``H_LL`` of the run's Gauss-Newton Hessian (:func:`vfcli.inverse.linearization.
  gauss_newton_model`, raster frozen at U), the cross and own blocks ``H_Lc``, ``H_cc``
  (:func:`vfcli.diagnose.candidates.blocks.candidate_blocks`);
* the joint step from the Schur complement ``S = H_cc - H_Lc^T H_LL^-1 H_Lc`` (stopped at theta = 0 for a
  ``one_sided`` candidate, :func:`_physical_step`) and a backtracking line search on E.

A candidate that states its extended model as a response (``candidate.response(baseline, theta)``, a
:class:`vfcli.model.response.base.Response` linear in x at fixed theta: inertia's steady state,
:class:`vfcli.model.response.steady_state.SteadyStateResponse`) is fitted with that response: the
x-columns, the load block and the adjoint are those of U(., theta), exact.  This matters where D is
not small: with the tissue's density the steady state differs from the quasi-static motion by about
its own size, and loads fitted to the quasi-static model are far from the loads of the extended one
(on an inertia phantom E at the baseline's loads was 5 to 23 times the baseline's at the start
densities, and 0.48 times it at rho = 1 once the loads were refitted with the dynamics).  Its start
values are each given Gauss-Newton steps of the loads under that response until E settles
(:data:`START_STEPS`, :data:`START_RTOL`).  When its steps settle, a candidate with ``recentre(baseline,
theta)`` (inertia: the Ritz reduction's shifts, exact at one density only) may rebuild its response about the
estimate; the steps then continue from the same (x, theta), at most :data:`MAX_RECENTRES` times.
For the other candidates the x-columns are those of the baseline response, dU0/dx: the change of D
with x is left out of the step (D is small next to U0, and the truth remains a fixed point when the
residual vanishes, since the theta gradient is exact and the x gradient vanishes with the residual).
A candidate that states how a gradient in U pulls back through its change (``candidate.pullback``:
contact, whose forces are piecewise linear in U0) gets the exact gradient in x; the load block stays the
baseline's, a preconditioner of the step that the line search on E keeps safe.

Stated uncertainty: the **sandwich** over frames, as optimize states its own
(:func:`sandwich_theta`, :mod:`vfcli.inverse.sandwich`): ``Cov(theta) = S^-1 V S^-1`` with V the
long-run covariance of theta's per-frame efficient scores.  The Laplace form with the residual's own
scale (as the screening's one-step estimate, :mod:`vfcli.diagnose.candidates.blocks`:
``(kappa S)^-1``, ``kappa = (n_eff - dof - p) / (2 E_motion)``) is kept beside it (``sd_laplace``);
it reads the gap term's silhouettes as if they were as noisy as the velocity, and on a small case
with pixel-quantised silhouettes it was 3 times too narrow.

A subset of the data (held-out splits, :mod:`vfcli.diagnose.heldout`): ``keep`` (F,) bool frames
(the others contribute nothing to E), and ``problem.with_weights(component_weights=...)`` for the
instruments (in-plane camera motion only).  With ``frozen`` the raster stays where it was at the start
for the whole fit: E is then the Gauss-Newton model's own (quadratic in x at fixed theta for a candidate
with a response), so a fit that starts at the whole window's fit and leaves frames out reaches the
minimum of its own data.  Refrozen at each trial it could not move from there: along the load step of a
split E rose by 1.1-3.1 % (its frozen model predicted a fall of 0.09-0.34 %, and with the raster frozen E
fell by that much), so every leave-cycles-out fit stopped at its start and its "held-out" error was the
whole window's fit's (test phantom seed 31, 8 of 8 such fits; docs/benchmarks.md, "Held-out fits that
did not move (session 25)").
"""
from __future__ import annotations

import builtins
import copy
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vfcli.diagnose.candidate import Baseline

#: relative decrease of E per iteration below which the refit has converged
FTOL = 1e-6
#: backtracking halvings of a step before the refit stops (the shortest step tried: 1/8 of the Gauss-Newton
#: step).  E is refrozen at each trial (the raster moves with x): near a minimum it rises along a step the
#: frozen model says lowers it, and is rough on the scale of single pixels.  With 6 halvings (to 1/64) the
#: held-out fits of a refit spent most of their time in such searches (13 of 25 Gauss-Newton iterations tried
#: 7 steps, 10 of them in vain; the others gained 1-3e-5 of E) for the same estimates and held-out errors to
#: 0.05 % (test phantom seed 31; docs/benchmarks.md, "Held-out fits that did not move (session 25)")
MAX_HALVINGS = 3
#: rounds of ``candidate.recentre`` (a response rebuilt about the estimate) after the Gauss-Newton steps
MAX_RECENTRES = 3
#: at most this many Gauss-Newton steps of the loads at each start value of a candidate with its own
#: response, until E decreases by less than START_RTOL (relative) in a step: from loads fitted without the
#: term E can be 100 times its minimum at that theta (inertia phantom seed 37, rho = 0.5: 12070 -> 155,
#: 58.6, 28.8, ..., 25.7 in 1, 2, 3, 5 steps; after 2 steps rho = 0.25 looked better, 52.5)
START_STEPS = 8
START_RTOL = 1e-2
#: golden-section steps of the profile of E over a one-parameter theta (the loads refitted at each value)
#: between the neighbours of the best start value, for a candidate with its own response: E of the model
#: with mass is rough in the density at fixed loads (resonances cross the harmonics; with the raster
#: refrozen a Gauss-Newton step from a start value can fail its line search), its profile is not
REFINE_STEPS = 6


@dataclass(frozen=True)
class RefitResult:
    """The extended model refitted (module docstring).

    candidate : its name ("" for a baseline refit).  parameter_names : (p,).
    theta : (p,) fitted parameters.  sd : (p,) stated standard deviations (``uncertainty``: the
        sandwich over frames, :func:`sandwich_theta`).  covariance : (p, p) of theta, the same.
    x : (n_params,) fitted load controls.  displacements : (F + 1, N, 3) mm, at ``problem.sim_times``.
    history : {"iteration", "total", "motion", "gap", "ridge", "step", "wall_time": (n_it + 1,),
        "theta": (n_it + 1, p)}; row 0 is the start.
    converged : E stopped decreasing (relative change below :data:`FTOL`).
    kappa : the Laplace scale (1 / (2 sigma^2) per unit E).
    uncertainty : "sandwich".  sd_laplace : (p,) the Laplace standard deviations, for comparison.
    profiled : the start is the minimum of a profile search over theta (a one-parameter candidate with its own
        response, :func:`_best_start`): a fitted value even where no Gauss-Newton step follows it.
    ridge_weight : the ridge weight the fit ended under where it is not the problem's it started with
        (:func:`vfcli.diagnose.bound.refit_at_own_bound`: the extended model's own L-curve corner), 1/Pa^2; None:
        the baseline's.
    """

    candidate: str
    parameter_names: tuple[str, ...]
    theta: np.ndarray
    sd: np.ndarray
    covariance: np.ndarray
    x: np.ndarray
    displacements: np.ndarray
    history: dict
    converged: bool
    kappa: float
    uncertainty: str = "sandwich"
    sd_laplace: np.ndarray | None = None
    profiled: bool = False
    ridge_weight: float | None = None

    def total_at(self, ridge_weight: float) -> float:
        """The fit's final E with its ridge term taken at ``ridge_weight`` (1/Pa^2) instead of its own: E under
        another model's objective (the baseline's, whose weight a rebounded refit left)."""
        total, ridge = float(self.history["total"][-1]), float(self.history["ridge"][-1])
        if self.ridge_weight is None or self.ridge_weight == ridge_weight:
            return total
        return total - ridge + ridge * float(ridge_weight) / float(self.ridge_weight)

    @property
    def interval(self) -> np.ndarray:
        """(p, 2) 95 % interval theta -+ 1.96 sd."""
        return np.column_stack([self.theta - 1.96 * self.sd, self.theta + 1.96 * self.sd])


def masked(frames: list, keep: np.ndarray | None) -> list:
    """``frames`` with the frames not in ``keep`` (F,) bool emptied (nothing compared: a held-out frame)."""
    if keep is None:
        return frames
    return [fr if k else fr.emptied() for fr, k in zip(frames, np.asarray(keep, bool))]


def energy(problem, x: np.ndarray, disp: np.ndarray, frames: list):
    """:class:`vfcli.inverse.terms.Terms` of E at displacements ``disp`` with the frozen ``frames``."""
    from vfcli.inverse.terms import Evaluation, Terms

    ev = Evaluation(problem, x, disp, frames)
    return Terms.from_parts({t.name: t.value(ev) for t in problem.terms})


@dataclass
class _State:
    x: np.ndarray
    theta: np.ndarray
    disp: np.ndarray
    frames: list
    terms: object


class _Extended:
    """U(x, theta) of the baseline response extended by ``candidate`` (None: the baseline itself)."""

    def __init__(self, problem, candidate, f0_hz: float, model, keep):
        self.problem, self.candidate, self.f0_hz, self.model, self.keep = problem, candidate, f0_hz, model, keep
        #: the frames every state uses when the raster is frozen for the whole fit (None: frozen at each state)
        self.frames = None
        self.p = int(candidate.n_params) if candidate is not None else 0
        #: the candidate states its extended model as a response (linear in x at fixed theta)
        self.has_response = candidate is not None and callable(getattr(candidate, "response", None))
        self._problems: dict = {}

    def baseline(self, x, disp, frames, problem=None) -> Baseline:
        b = Baseline(self.problem if problem is None else problem, x, disp, frames, self.f0_hz)
        if self.model is not None:
            b.model = self.model
        return b

    def problem_at(self, theta: np.ndarray):
        """The problem whose response is U(., theta) (the candidate's own response), or the baseline's."""
        if not self.has_response:
            return self.problem
        key = tuple(np.asarray(theta, dtype=float).ravel())
        got = self._problems.get(key)
        if got is None:          # a local: another thread's profile value may clear the dict (load_profile's map)
            if len(self._problems) > 8:
                self._problems.clear()
            got = self._problems[key] = extended_problem(self.baseline(None, None, []), self.candidate, theta)
        return got

    def change(self, x: np.ndarray, u0: np.ndarray, theta: np.ndarray) -> np.ndarray:
        if self.p == 0:
            return np.zeros_like(u0)
        if self.has_response:
            return self.problem_at(theta).response.change(x, self.problem.sim_times)
        return self.candidate.extension(self.baseline(x, u0, []), theta)

    def state(self, x: np.ndarray, theta: np.ndarray) -> _State:
        u0 = self.problem.displacements(x)
        disp = u0 + self.change(x, u0, theta)
        frames = self.frames if self.frames is not None else masked(self.problem.freeze(x, disp), self.keep)
        return _State(x, theta, disp, frames, energy(self.problem, x, disp, frames))

    def pull(self, st: _State, grad: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) a gradient with respect to U at the state, pulled back to the baseline response's
        U0 through the candidate's change when it states how (``candidate.pullback``: contact), else as is
        (the change of D with x left out, module docstring)."""
        if self.p == 0 or self.has_response or not callable(getattr(self.candidate, "pullback", None)):
            return grad
        u0 = self.problem.displacements(st.x)
        return self.candidate.pullback(self.baseline(st.x, u0, []), grad, st.theta)

    def columns(self, st: _State) -> np.ndarray:
        """(F + 1, N, 3, p) dU/dtheta at the state (central differences of the exact change)."""
        u0 = self.problem.displacements(st.x)
        out = np.zeros(st.disp.shape + (self.p,))
        for j in range(self.p):
            h = 1e-4 * (1.0 + abs(float(st.theta[j])))
            e = np.zeros(self.p)
            e[j] = h
            out[..., j] = (self.change(st.x, u0, st.theta + e) - self.change(st.x, u0, st.theta - e)) / (2 * h)
        return out


def _blocks(ext: _Extended, st: _State, loads_only: bool = False):
    """(g_L, H_LL model, g_c, H_Lc, H_cc, dU/dtheta) at the state (``loads_only``: the load blocks alone,
    theta's left empty)."""
    from vfcli.diagnose.candidates.blocks import _grad_disp, candidate_blocks
    from vfcli.inverse.linearization import gauss_newton_model

    p = ext.problem_at(st.theta)                  # the extended response's x-columns when it states one
    gd, gx = _grad_disp(p, st.x, st.disp, st.frames)
    g_l = p.response.adjoint(ext.pull(st, gd), p.sim_times, st.x) + gx
    model = gauss_newton_model(p, st.x, st.frames, st.disp)
    if ext.p == 0 or loads_only:
        return g_l, model, np.zeros(0), np.zeros((p.n_params, 0)), np.zeros((0, 0)), None
    dudp = ext.columns(st)
    g_c, h_lc, h_cc = candidate_blocks(ext.baseline(st.x, st.disp, st.frames, p), dudp)
    return g_l, model, g_c, h_lc, h_cc, dudp


def _pinv_sym(a: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    w, v = np.linalg.eigh(0.5 * (a + a.T))
    keep = w > rtol * max(float(w.max(initial=0.0)), 1e-300)
    return (v[:, keep] / w[keep]) @ v[:, keep].T


def joint_fit(problem, x0: np.ndarray, candidate=None, f0_hz: float = float("nan"), theta0=None,
              keep: np.ndarray | None = None, max_iterations: int = 8, model=None,
              fixed_theta: bool = False, stated: bool = True, frozen: bool = False) -> RefitResult:
    """Fit the loads x and the candidate's theta jointly by Gauss-Newton (module docstring).

    Parameters
    ----------
    problem : the run's :class:`vfcli.inverse.problem.Problem` (or ``with_weights`` of it).
    x0 : (n_params,) start, the baseline's fitted controls.
    candidate : a :class:`vfcli.diagnose.candidates.base.DisplacementTerm` (``extension``), or None:
        refit the baseline alone (theta empty).
    f0_hz : the window's f0 (candidates whose change is a periodic steady state need it), Hz.
    theta0 : (p,) start (default 0: the term switched off).
    keep : (F,) bool frames that count in E (default all).
    max_iterations : Gauss-Newton iterations at most.
    model : the :class:`vfcli.model.fem.ElasticModel` of the baseline (the modal terms need its
        material); default the candidate's own.
    fixed_theta : keep theta at theta0 (refit the loads only, e.g. a held-out prediction).
    stated : compute the stated uncertainty (False: NaN sd and kappa, e.g. the held-out fits).
    frozen : keep the raster frozen at the start for the whole fit (module docstring; the held-out fits).
    """
    t_start = time.perf_counter()
    ext = _Extended(problem, candidate, f0_hz, model, keep)
    theta = np.zeros(ext.p) if theta0 is None else np.asarray(theta0, dtype=float).reshape(ext.p)
    st = ext.state(np.asarray(x0, dtype=float), theta)
    if frozen:
        ext.frames = st.frames
    hist = {k: [] for k in ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "theta")}

    def record(it: int, state: _State, step: float) -> None:
        for k, v in (("iteration", it), ("total", state.terms.total), ("motion", state.terms.motion),
                     ("gap", state.terms.gap), ("ridge", state.terms.ridge), ("step", step),
                     ("wall_time", time.perf_counter() - t_start)):
            hist[k].append(v)
        hist["theta"].append(np.array(state.theta, float))

    profiled = False
    if theta0 is None and not fixed_theta:
        st, profiled = _best_start(ext, st, getattr(candidate, "start_values", ()))
    record(0, st, 0.0)
    st, blocks, converged, it = _gauss_newton(ext, st, max_iterations, fixed_theta, record, 0)
    recentre = getattr(candidate, "recentre", None)
    for _round in range(MAX_RECENTRES if ext.p and theta0 is None and not fixed_theta and callable(recentre) else 0):
        # the candidate's response rebuilt about the estimate (inertia's shifted Ritz vectors): the same
        # (x, theta) under it, then Gauss-Newton again, until the estimate stays near the centre.  Fits that
        # start at a given theta (the held-out fits, from the refit's estimate) keep the centre they find
        if not recentre(ext.baseline(None, None, []), st.theta):
            break
        ext._problems.clear()
        st = ext.state(st.x, st.theta)
        record(it, st, 0.0)
        st, blocks, converged, it = _gauss_newton(ext, st, max_iterations, fixed_theta, record, it)
    if stated:
        blocks = _blocks(ext, st) if blocks is None else blocks
        cov_laplace, kappa = laplace(ext, st, blocks)
        cov = sandwich_theta(ext, st, blocks)[0] if ext.p else cov_laplace
    else:
        cov_laplace = cov = np.full((ext.p, ext.p), np.nan)
        kappa = float("nan")
    history = {k: np.asarray(v, dtype=float) for k, v in hist.items()}
    history["theta"] = history["theta"].reshape(len(hist["iteration"]), ext.p)
    names = tuple(candidate.parameter_names) if candidate is not None else ()
    return RefitResult(candidate.name if candidate is not None else "", names, st.theta.copy(),
                       np.sqrt(np.maximum(np.diag(cov), 0.0)), cov, st.x.copy(), st.disp, history,
                       bool(converged), float(kappa), "sandwich",
                       np.sqrt(np.maximum(np.diag(cov_laplace), 0.0)), profiled)


def _gauss_newton(ext: _Extended, st: _State, max_iterations: int, fixed_theta: bool, record, it0: int):
    """Gauss-Newton steps of (x, theta) from ``st`` (module docstring): (state, its blocks or None,
    converged, last iteration number); ``record(it, state, step)`` after each accepted step."""
    converged = False
    blocks = None
    it = it0
    for it in range(it0 + 1, it0 + max_iterations + 1):
        blocks = _blocks(ext, st)
        g_l, qm, g_c, h_lc, h_cc, _ = blocks
        solved = qm.hessian.solve(np.column_stack([g_l, h_lc]))
        if ext.p and not fixed_theta:
            schur = h_cc - h_lc.T @ solved[:, 1:]
            dtheta = _physical_step(ext.candidate, st.theta, -_pinv_sym(schur) @ (g_c - h_lc.T @ solved[:, 0]))
            dx = -(solved[:, 0] + solved[:, 1:] @ dtheta)
        else:
            dtheta = np.zeros(ext.p)
            dx = -solved[:, 0]
        alpha, trial = 1.0, None
        for _ in range(MAX_HALVINGS + 1):
            try:
                trial = ext.state(st.x + alpha * dx, st.theta + alpha * dtheta)
            except ValueError:                          # e.g. a softening >= 1 on the way: shorter step
                trial = None
            if trial is not None and trial.terms.total < st.terms.total:
                break
            alpha *= 0.5
            trial = None
        if trial is None:
            converged = True
            break
        rel = (st.terms.total - trial.terms.total) / max(abs(st.terms.total), 1e-300)
        st = trial
        record(it, st, alpha * float(np.linalg.norm(dx)))
        blocks = None
        if rel < FTOL:
            converged = True
            break
    return st, blocks, converged, it


def _physical_step(candidate, theta: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """``dtheta`` (p,), stopped at theta = 0 for a ``one_sided`` candidate (one parameter; contact, damping: a
    negative share or retardation time is no physics).  The load step that goes with it, ``-H_LL^-1 (g_L + H_Lc
    dtheta)``, is then the Gauss-Newton model's minimum over theta >= 0 (its profile in theta is a convex
    parabola), so the fit stays on the physical side and a term the data do not want ends switched off
    (a camera-only fit of contact phantom 2014 went to a share of -1.5: folds pulled through the midplane,
    docs/benchmarks.md, "Session 54")."""
    if not getattr(candidate, "one_sided", False):
        return dtheta
    theta = np.asarray(theta, dtype=float)
    return np.maximum(theta + dtheta, 0.0) - theta


def _best_start(ext: _Extended, st: _State, values) -> tuple[_State, bool]:
    """The best of ``st`` and the candidate's ``start_values`` (each a theta, the loads given one
    Gauss-Newton step at that theta, or steps until E settles under the candidate's own response): a term
    far from linear in theta (a density that puts a harmonic of f0 above a resonance) is not reached
    from theta = 0 by Gauss-Newton steps.  Also whether that best is the minimum of a profile search
    (:func:`_refine_profile`), a fitted value, rather than one of the values tried."""
    best = st
    profile = {0.0: st} if ext.p == 1 else {}
    for v in values:
        theta = np.asarray(v, dtype=float).reshape(ext.p)
        try:
            trial = ext.state(st.x, theta)
            if ext.has_response:
                stepped = _load_steps(ext, trial, START_STEPS, START_RTOL)
                if ext.p == 1:
                    profile[float(theta[0])] = stepped
            else:
                g_l, qm, *_ = _blocks(ext, trial, loads_only=True)
                # the loads' step at this theta: the baseline's Hessian with the gradient at the extended U
                stepped = ext.state(st.x - qm.hessian.solve(g_l), theta)
        except ValueError:
            continue
        for cand in (trial, stepped):
            if cand.terms.total < best.terms.total:
                best = cand
    if ext.has_response and ext.p == 1 and len(profile) > 2 and best is not st:
        return _refine_profile(ext, profile, best), True
    return best, False


def _refine_profile(ext: _Extended, profile: dict, best: _State) -> _State:
    """Golden-section search (:data:`REFINE_STEPS` steps) of the profile ``theta -> E`` (the loads refitted
    by :func:`_load_steps` from the nearest evaluated state's) between the neighbours of ``best`` among
    the evaluated thetas ``profile`` {theta: state}; the best state seen."""
    keys = sorted(profile)
    i = keys.index(min(keys, key=lambda k: abs(k - float(best.theta[0]))))
    lo, hi = keys[max(i - 1, 0)], keys[min(i + 1, len(keys) - 1)]

    def at(theta: float) -> _State:
        near = profile[min(profile, key=lambda k: abs(k - theta))]
        got = _load_steps(ext, ext.state(near.x, np.array([theta])), START_STEPS, START_RTOL)
        profile[theta] = got
        return got

    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    try:
        fc, fd = at(c), at(d)
        for _ in range(int(REFINE_STEPS)):
            if fc.terms.total < fd.terms.total:
                b, d, fd = d, c, fc
                c = b - g * (b - a)
                fc = at(c)
            else:
                a, c, fc = c, d, fd
                d = a + g * (b - a)
                fd = at(d)
    except ValueError:
        pass
    return min(profile.values(), key=lambda s_: s_.terms.total)


def _load_steps(ext: _Extended, st: _State, n_steps: int, rtol: float = 0.0) -> _State:
    """Up to ``n_steps`` Gauss-Newton steps of the loads alone at the state's theta, under the extended
    response (exact x-columns), each with a backtracking line search on E; stops when a step lowers E by
    less than ``rtol`` (relative)."""
    for _ in range(int(n_steps)):
        g_l, qm, *_ = _blocks(ext, st, loads_only=True)
        dx = -qm.hessian.solve(g_l)
        alpha, trial = 1.0, None
        for _ in range(MAX_HALVINGS + 1):
            trial = ext.state(st.x + alpha * dx, st.theta)
            if trial.terms.total < st.terms.total:
                break
            alpha *= 0.5
            trial = None
        if trial is None:
            break
        rel = (st.terms.total - trial.terms.total) / max(abs(st.terms.total), 1e-300)
        st = trial
        if rel < rtol:
            break
    return st


def sandwich_theta(ext: _Extended, st: _State, blocks) -> tuple[np.ndarray, int]:
    """((p, p) Cov(theta), lag) by the sandwich over frames, as optimize's (:mod:`vfcli.inverse.sandwich`).

    The efficient score of theta per frame, ``s_f = g_c,f - H_Lc^T H_LL^-1 g_L,f`` (the frame's data
    terms' gradient in theta, its load part projected out), has a long-run covariance S over the
    frames that count (:func:`vfcli.inverse.sandwich.long_run_covariance`); ``Cov = I^-1 S I^-1``
    with ``I`` the Schur complement.  It holds when the residual is model error correlated in space
    and time and when the gap term's silhouettes carry errors the Laplace scale does not see.
    """
    from vfcli.inverse.sandwich import _only_frame, linearization_adjoint, long_run_covariance
    from vfcli.inverse.terms import Evaluation

    g_l, qm, g_c, h_lc, h_cc, dudp = blocks
    p = ext.problem
    used = [f for f, fr in enumerate(st.frames) if fr.m_both.shape[0] or any(len(side[0]) for side in fr.sil)]
    data_terms = [t for t in p.terms if t.data]
    proj = qm.hessian.solve(h_lc)                                      # H_LL^-1 H_Lc (n, p)
    scores = np.zeros((len(used), ext.p))
    for i, f in enumerate(used):
        ev = Evaluation(p, st.x, st.disp, _only_frame(st.frames, f), np.zeros_like(st.disp), np.zeros(len(st.x)))
        for term in data_terms:
            term.value(ev)
        g_lf = linearization_adjoint(qm.linearization, ev.grad_disp)
        g_cf = np.array([np.sum(ev.grad_disp * dudp[..., j]) for j in range(ext.p)])
        scores[i] = g_cf - proj.T @ g_lf
    lr = long_run_covariance(scores)
    inv = _pinv_sym(h_cc - h_lc.T @ proj)
    return inv @ lr.covariance @ inv, lr.lag


def laplace(ext: _Extended, st: _State, blocks) -> tuple[np.ndarray, float]:
    """((p, p) Cov(theta), kappa): ``(kappa S)^-1`` at the state (module docstring)."""
    from vfcli.diagnose.candidates.blocks import _kappa_after
    from vfcli.inverse.uncertainty import effective_sample_size, posterior

    g_l, qm, g_c, h_lc, h_cc, _ = blocks
    p = ext.problem
    corr = effective_sample_size(with_displacements(p, st.disp).motion_residuals(st.x, st.frames),
                                 pixel_stride=p.meas.pixel_stride)
    dof = posterior(qm, corr).dof
    kappa = _kappa_after(ext.baseline(st.x, st.disp, st.frames), qm, dof, st.disp, ext.p)
    if ext.p == 0:
        return np.zeros((0, 0)), kappa
    schur = h_cc - h_lc.T @ qm.hessian.solve(h_lc)
    return _pinv_sym(schur) / kappa, kappa


def extended_problem(baseline, candidate, theta: np.ndarray):
    """A shallow copy of the baseline's problem with ``candidate``'s extended response at ``theta`` (a candidate
    that states one, ``candidate.response``: linear in the loads at fixed theta); the ridge weight and everything
    else the baseline's."""
    other = copy.copy(baseline.problem)
    other.response = candidate.response(baseline, np.asarray(theta, dtype=float))
    return other


def with_displacements(problem, disp: np.ndarray):
    """A shallow copy of ``problem`` whose model shows ``disp`` (F + 1, N, 3) whatever its controls
    (an extended model's displacements, for what reads ``problem.displacements``: the motion residual
    images, Locate and the residual maps)."""
    other = copy.copy(problem)
    other.displacements = lambda x: disp
    return other


def load_profile(baseline: Baseline, candidate, thetas, steps: int = 3,
                 best_steps: int = START_STEPS, rtol: float = START_RTOL, map: Callable | None = None
                 ) -> tuple[float, np.ndarray]:
    """E of the baseline and of the extended model at each theta with the loads refitted, from the baseline's fit.

    Every theta gets up to ``steps`` Gauss-Newton steps of the loads alone (:func:`_load_steps`, stopping
    when a step gains less than ``rtol``, default :data:`START_RTOL`; 0: all of them) under the candidate's own
    response (or under the baseline's, the gradient pulled back through a term that states its pullback)
    (``candidate.response``); the best of them, if it is not yet below the baseline, gets steps on up to
    ``best_steps`` in all, the refit's own start scan (:data:`START_STEPS`): from the quasi-static loads E at
    the right density can still be above the baseline's after three steps (panel seed 2007, density 1.07:
    +7 % at 1).  The baseline gets up to ``best_steps`` under its response at theta = 0 (it starts at its
    optimum, so it stops at once).  The loads fitted without the term are far from those of a model with it
    (inertia at the tissue's density), so E at fixed loads says nothing; refitted, the profile says whether
    some theta fits better than none.

    map : runs the baseline's steps and each theta's (independent pieces; an in-process map,
        :func:`vfcli.parallel.local_map`: they share the baseline), default one after the other; the same numbers
        whatever the map.

    Returns
    -------
    (E0, (k,) E(theta)), E as the objective (:func:`vfcli.inverse.problem.energy`); E(theta) is inf where the
    extended model could not be built or stepped (a ValueError of the candidate).
    """
    ext = _Extended(baseline.problem, candidate, baseline.f0_hz, getattr(baseline, "model", None), None)
    x = np.asarray(baseline.x, dtype=float)

    def steps_at(item):
        """(E, loads) after the steps at one theta (the state they ended in is ``ext.state(loads, theta)``, to the
        bit: what a piece sends back is small), or None where the term failed."""
        theta, n, term = item
        try:
            st = _load_steps(ext, ext.state(x, theta), n, rtol)
        except ValueError:
            if not term:
                raise                     # the baseline's own steps: not a failure of the term
            return None
        return float(st.terms.total), st.x

    thetas = [np.asarray(v, dtype=float).reshape(ext.p) for v in thetas]
    items = [(np.zeros(ext.p), max(steps, best_steps), False), *((v, steps, True) for v in thetas)]
    (e0, _), *ends = (map or builtins.map)(steps_at, items)
    out = np.asarray([np.inf if end is None else end[0] for end in ends], dtype=float)
    k = int(np.argmin(out))
    if best_steps > steps and np.isfinite(out[k]) and out[k] >= e0:
        try:
            out[k] = _load_steps(ext, ext.state(ends[k][1], thetas[k]), best_steps - steps, rtol).terms.total
        except ValueError:
            pass
    return float(e0), out


def refit(baseline: Baseline, candidate, keep: np.ndarray | None = None, max_iterations: int = 8,
          problem=None) -> RefitResult:
    """Refit ``baseline`` extended by ``candidate`` from its fit (theta = 0), on the frames ``keep``.

    problem : the problem to fit (default the baseline's; e.g. ``with_weights`` for one instrument).
    """
    return joint_fit(problem if problem is not None else baseline.problem, baseline.x, candidate,
                     baseline.f0_hz, keep=keep, max_iterations=max_iterations,
                     model=getattr(baseline, "model", None))
