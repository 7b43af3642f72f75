"""Confirm a screening lead: refit the baseline extended by the candidate, compare held-out errors.

:func:`refit_order` lists the candidates to refit in turn (the user's ``--refit NAME``, or with ``auto`` the
calibrated leads, smallest family-wise p first, then the profile leads; each is refitted, and of the confirmed ones
the one that predicts held-out data best is named, :func:`vfcli.diagnose.decide.best_confirmed`);
:func:`confirm_run` refits it on the whole window (:func:`vfcli.diagnose.refit.refit`), runs the
held-out comparisons (:mod:`vfcli.diagnose.heldout`) and Locate on the extended model (the
"after" residual), and returns them in a :class:`Confirmed`.
"""
from __future__ import annotations

import builtins
import logging
import time
from dataclasses import dataclass

import numpy as np

from vfcli.diagnose.bound import refit_at_own_bound
from vfcli.diagnose.candidate import Baseline
from vfcli.diagnose.confirmation import Confirmation, heldout_sd, mesh_corrected
from vfcli.diagnose.heldout import across_instruments, cycle_groups, leave_cycles_out
from vfcli.diagnose.refit import RefitResult, refit, with_displacements
from vfcli.diagnose.words import percent_size

log = logging.getLogger(__name__)

#: the --refit choices besides a candidate's name
REFIT_MODES = ("auto", "none")
#: a refit's E counts as below the baseline's when lower by more than this relative amount (rounding only: a refit
#: that kept no step from the baseline's own state returns its E to the bit)
LOWER_RTOL = 1e-9
#: refits one diagnosis makes at most with ``--refit auto`` (the leads in turn): each costs
#: about what the run's own fit did (docs/diagnose.md, where the time goes)
MAX_REFITS = 3


@dataclass(frozen=True)
class Confirmed:
    """refit : the extended model's fit on the whole window.  confirmation : its evidence for the decision.
    after : Locate on the extended model (:class:`vfcli.diagnose.run.LocateResult`), or None."""

    refit: RefitResult
    confirmation: Confirmation
    after: object


def choose(screening, candidates, mode: str, alpha: float = 0.05, profile_leads=()):
    """The candidate to refit first, or None: the first of :func:`refit_order`.

    Raises
    ------
    ValueError
        ``mode`` names no candidate (the caller turns it into a user error naming the choices).
    """
    order = refit_order(screening, candidates, mode, alpha, profile_leads)
    return order[0] if order else None


def refit_order(screening, candidates, mode: str, alpha: float = 0.05, profile_leads=(),
                limit: int = MAX_REFITS) -> list:
    """The candidates to refit, in turn (at most ``limit``; each is refitted, the best confirmed one named:
    :func:`vfcli.diagnose.decide.best_confirmed`).

    mode : "none" (no refit), a candidate's name (that one alone), or "auto": the calibrated leads (the
        identifiable candidates whose bootstrap-calibrated family-wise p-value ``p_family`` is at most ``alpha``;
        smallest ``p_family`` first, ties by the uncalibrated p), then ``profile_leads`` (:mod:`vfcli.diagnose.profile`,
        in the caller's order) that are not calibrated leads; none when the screening could not be calibrated
        and no profile lead was found.  A finding is still a lead whose own refit is confirmed
        (:mod:`vfcli.diagnose.decide`), but leads on recordings without the term are common (model error locked in
        phase with the motion), so each further refit is one more chance for such a lead to pass its held-out
        comparisons: the nulls with several leads are measured in docs/benchmarks.md ("Session 52").

    Raises
    ------
    ValueError
        ``mode`` names no candidate (the caller turns it into a user error naming the choices).
    """
    if mode == "none":
        return []
    by_name = {c.name: c for c in candidates}
    if mode != "auto":
        if mode not in by_name:
            raise ValueError(f"--refit {mode!r}: choose one of {', '.join((*REFIT_MODES, *by_name))}")
        return [by_name[mode]]
    leads = sorted((s for s in screening if s.identifiable and np.isfinite(s.p_family) and s.p_family <= alpha),
                   key=lambda s: (s.p_family, s.p_value))
    names = dict.fromkeys([*(s.name for s in leads), *profile_leads])     # in order, each once
    return [by_name[n] for n in names if n in by_name][:max(int(limit), 0)]


def without_signature(baseline: Baseline, candidates) -> tuple[list, dict[str, str]]:
    """The candidates whose baseline shows their term's signature (or that state none), in their order, and
    {name: why} of those whose baseline does not (the candidate's ``missing_signature(baseline)``): a refit of these
    could confirm nothing (:attr:`vfcli.diagnose.confirmation.Confirmation.improves` needs the signature), so
    ``--refit auto`` does not make it (:class:`vfcli.diagnose.confirmation.NotRefitted`)."""
    keep, missing = [], {}
    for c in candidates:
        check = getattr(c, "missing_signature", None)
        why = check(baseline) if callable(check) else ""
        if why:
            missing[c.name] = why
        else:
            keep.append(c)
    return keep, missing


def refits_to_make(baseline: Baseline, screening, candidates, mode: str, alpha: float = 0.05, profile_leads=(),
                   limit: int = MAX_REFITS) -> tuple[list, dict[str, str]]:
    """The refits a diagnosis makes, in turn (:func:`refit_order`), and {name: why} of the leads it does not refit
    because the baseline lacks their term's signature (:func:`without_signature`; with ``mode`` "auto" only: a refit
    asked for by name is made whatever the baseline shows).  A lead not refitted takes no place among the ``limit``:
    the leads after it are refitted instead.

    Raises
    ------
    ValueError
        ``mode`` names no candidate (as :func:`refit_order`).
    """
    if mode != "auto":
        return refit_order(screening, candidates, mode, alpha, profile_leads, limit), {}
    keep, missing = without_signature(baseline, refit_order(screening, candidates, mode, alpha, profile_leads,
                                                            limit=len(candidates)))
    return keep[:max(int(limit), 0)], missing


def extended_baseline(baseline: Baseline, result: RefitResult) -> Baseline:
    """The extended model at its refit as a :class:`Baseline` (raster frozen at its displacements)."""
    problem = with_displacements(baseline.problem, result.displacements)
    ext = Baseline(problem, result.x, result.displacements, problem.freeze(result.x, result.displacements),
                   baseline.f0_hz)
    if getattr(baseline, "model", None) is not None:
        ext.model = baseline.model
    return ext


def confirm_run(baseline: Baseline, candidate, window_phase: np.ndarray, locate=None,
                max_iterations: int = 8, heldout_iterations: int = 3, max_splits: int = 4,
                own_bound: bool = False, map=None) -> Confirmed:
    """Refit ``candidate`` on the whole window, then the held-out comparisons and the "after" Locate.

    window_phase : (F,) glottal cycle phase of the window's frames.
    locate : ``lambda baseline: LocateResult`` (e.g. :func:`vfcli.diagnose.run.locate_run` with the
        recording), or None to skip the "after" residual.
    own_bound : the baseline's ridge weight is its L-curve's corner (optimize chose it): the extended model of a
        candidate with its own response is then refitted under its own corner
        (:func:`vfcli.diagnose.bound.refit_at_own_bound`), and its held-out fits use that weight. Whether it
        lowers E is judged under the baseline's weight (:meth:`RefitResult.total_at`).
    map : runs the held-out fits (:mod:`vfcli.diagnose.heldout`: two per split, two across instruments; an in-process
        map, :func:`vfcli.parallel.local_map`), default one after the other; the same results whatever the map.
    """
    t0 = time.perf_counter()
    result = refit(baseline, candidate, max_iterations=max_iterations)
    problem = baseline.problem
    if own_bound:
        problem, result = refit_at_own_bound(baseline, candidate, result, max_iterations)
        if result.ridge_weight is not None:
            log.info("refit of %s under its own L-curve corner, ridge weight %.3g 1/Pa^2 (the baseline's %.3g)",
                     candidate.name, result.ridge_weight, baseline.problem.settings.ridge_weight)
    t1 = time.perf_counter()
    groups = cycle_groups(window_phase)
    cyc = leave_cycles_out(baseline, candidate, result, groups, max_splits, heldout_iterations, problem, map)
    t2 = time.perf_counter()
    inst = across_instruments(baseline, candidate, result, groups, heldout_iterations + 1, problem, map)
    t3 = time.perf_counter()
    log.info("refit of %s: %.0f s (%d iterations); held out cycles %.0f s, instruments %.0f s", candidate.name,
             t1 - t0, len(result.history["iteration"]) - 1, t2 - t1, t3 - t2)
    held = tuple(h for h in (cyc, inst) if h is not None)
    mesh_shift = getattr(candidate, "mesh_shift", None)
    t4 = time.perf_counter()
    shift = mesh_shift(baseline, result.theta, result.x) if callable(mesh_shift) else None
    mesh = None if shift is None else np.abs(np.asarray(result.theta, float) * shift)
    if mesh is not None:
        log.info("mesh part of %s: shift %s, sd part %s (%.0f s)", candidate.name, np.round(shift, 6),
                 np.round(mesh, 6), time.perf_counter() - t4)
    sd, name, dof, _ = heldout_sd(result.theta, result.sd, held, mesh)
    estimate, sd = mesh_corrected(result.theta, sd, shift)
    e_base = float(baseline.problem.evaluate(baseline.x).total)
    missing = getattr(candidate, "missing_signature", None)
    conf = Confirmation(candidate.name, tuple(candidate.parameter_names), estimate, sd, name, held, dof=dof,
                        moved=len(result.history["iteration"]) > 1 or result.profiled,
                        lowers_e=bool(result.total_at(baseline.problem.settings.ridge_weight)
                                      < e_base * (1.0 - LOWER_RTOL)), mesh_shift=shift,
                        signature_missing=missing(baseline) if callable(missing) else "")
    return Confirmed(result, conf, locate(extended_baseline(baseline, result)) if locate is not None else None)


def confirm_all(baseline: Baseline, candidates, window_phase: np.ndarray, locate=None, own_bound: bool = False,
                map=None) -> list[Confirmed]:
    """:func:`confirm_run` for each of ``candidates`` (in their order; the refits are independent: each starts from
    the baseline), through ``map``, an in-process map (:func:`vfcli.parallel.local_map`: they share the baseline and
    the recording's open store; each sends back its :class:`Confirmed`), default one after the other; the same
    results whatever the map."""
    return list((map or builtins.map)(
        lambda c: confirm_run(baseline, c, window_phase, locate, own_bound=own_bound), candidates))


def words(conf: Confirmation, candidate=None) -> list[str]:
    """Plain lines: the estimate with its interval (and, when ``candidate``, the refitted term, reads it: its
    ``reading(theta)``, in the lab's terms), the held-out errors before and after."""
    est = ", ".join(f"{n} = {e:.3g} (95 % interval {a:.3g} .. {b:.3g}, {conf.uncertainty})"
                    for n, e, (a, b) in zip(conf.parameter_names, conf.estimate, conf.interval))
    reading = getattr(candidate, "reading", None)
    if conf.mesh_shift is not None:
        est += "; " + ", ".join(f"the fit mesh's {f:.4g} less the {percent_size(m)} % its discretisation adds against "
                                "a mesh 1.2 times finer" for f, m in zip(conf.fit_mesh_estimate, conf.mesh_shift))
    if callable(reading):
        est += f"; {reading(conf.estimate)}"
    out = [f"refit with {conf.candidate}{f' (run {conf.run})' if conf.run else ''}: {est}"]
    if not conf.moved:
        off = " (the term switched off)" if not np.any(np.asarray(conf.estimate, float)) else ""
        out[0] += ("; the refit never left its start (no step of it lowered E): this is the value it started "
                   f"from{off}, not a fitted one")
    if not conf.lowers_e:
        out[0] += ("; its E is not below the baseline's: the extended model explains nothing of the window the "
                   "baseline did not, so its held-out errors cannot confirm it")
    names = {"cycles": "leaving frames out (by cycle, or by block in a short window)",
             "instruments": "vertical velocity predicted from the camera"}
    for h in conf.heldout:
        verdict = "beyond the spread over splits" if h.beyond_spread() else "not beyond the spread over splits"
        direction = "lower" if h.reduction >= 0 else "higher"
        if h.theta is not None and not np.any(np.asarray(h.theta, float)) and np.array_equal(h.extended, h.baseline):
            verdict += f"; its fits switched {conf.candidate} off, which is the baseline"
        out.append(f"held-out error {names[h.kind]}: {np.sqrt(np.mean(h.baseline ** 2)):.3g} -> "
                   f"{np.sqrt(np.mean(h.extended ** 2)):.3g} {h.units} ({percent_size(h.reduction)} % {direction}, "
                   f"{h.n_splits} splits, {verdict})")
    if not conf.heldout:
        out.append("held-out error: no split possible (too few cycles in the window)")
    return out
