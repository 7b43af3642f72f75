"""Profile screening of a candidate the score test cannot reach: the loads refitted at its start values.

The score test (:mod:`vfcli.diagnose.candidates.screening`) linearises a term at theta = 0.  Inertia is
far from linear in the density where it matters: the folds' lowest mode lies near 50 Hz, below f0, so
the derivative at density 0 reaches densities up to about (f_1 / f0)^2 = 0.17 and the model's own
density (1) lies beyond it (:meth:`vfcli.diagnose.candidates.inertia.Inertia.evidence`).  A candidate
that says so (``profile_screening = True``) is also screened by its profile: E with the loads refitted
under the extended response at each of its ``start_values`` (:func:`vfcli.diagnose.refit.load_profile`),
against E of the baseline given the same load-only steps (three per value; the best value, when still
above the baseline, up to eight: the refit's start scan).

It is a **profile lead** when some value fits better than none: E(theta) below E(0), no threshold.  A
mass the recording does not have makes the fit worse at every density: with the loads refitted the
steady state of a massive fold cannot take the quasi-static motion's shape (on the short null phantom of
bench/bench_inertia_refit.py, seed 36, E rose 12 to 31 times at densities 0.25-3 with up to 8 load steps
each; on the demo and the blind panel's nulls 4.7 to 14 times at the best density, docs/benchmarks.md).

A profile lead is not a finding.  It is refitted and must predict held-out data better than the
baseline beyond the spread over splits, in every held-out kind, as a calibrated lead must
(:mod:`vfcli.diagnose.confirm`, :class:`vfcli.diagnose.confirmation.Confirmation.improves`).  The
bootstrap of :mod:`vfcli.diagnose.calibrate` does not cover this path, so the false-alarm rate of the
findings is at most the calibrated alpha plus the rate at which a profile lead on a recording without
the term passes its held-out comparisons (each a one-sided t test at 0.05); it is measured on null
recordings (docs/benchmarks.md, the diagnose panel).  One profile costs the candidate's modal reduction
(shared with its refit) and ``len(start_values) * steps`` load-only Gauss-Newton steps.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from vfcli.diagnose.words import percent_size

log = logging.getLogger(__name__)

#: load-only Gauss-Newton steps at each start value; the best value, when still above the baseline, gets
#: steps on up to the refit's start scan's (:data:`vfcli.diagnose.refit.START_STEPS`, 8): from the
#: quasi-static loads E at a density's first step can be 100 times its minimum there (docs/diagnose.md)
PROFILE_STEPS = 3


@dataclass(frozen=True)
class ProfileScreen:
    """The profile of one candidate.

    name : the candidate's.  parameter : its (one) parameter's name.  thetas : (k,) the values tried.
    e0 : E of the baseline after the same load steps.  e : (k,) E at each value (inf where it failed).
    """

    name: str
    parameter: str
    thetas: np.ndarray
    e0: float
    e: np.ndarray

    @property
    def relative(self) -> np.ndarray:
        """(k,) relative change of E from the baseline's, ``E(theta) / E0 - 1``."""
        return np.asarray(self.e, float) / max(self.e0, 1e-300) - 1.0

    @property
    def best(self) -> float:
        """The value with the lowest E."""
        return float(np.asarray(self.thetas, float)[int(np.argmin(self.e))])

    @property
    def lead(self) -> bool:
        """Some value fits better than none."""
        return bool(np.min(self.e) < self.e0)

    def words(self) -> str:
        rel = self.relative
        k = int(np.argmin(self.e))
        change = ("-" if rel[k] < 0 else "+") + percent_size(rel[k])   # not "-0 %" for a lead
        head = (f"{self.name}: profile with the loads refitted at {self.parameter} = "
                f"{', '.join(f'{t:g}' for t in self.thetas)}: E {change} % at {self.thetas[k]:g}")
        if self.lead:
            return head + " against the baseline's, a profile lead (refitted and checked on held-out data)"
        return head + ", worse than the baseline's at every value (no profile lead)"

    def as_dict(self) -> dict:
        return {"name": self.name, "parameter": self.parameter, "thetas": [float(t) for t in self.thetas],
                "e0": float(self.e0), "e": [float(v) for v in self.e], "lead": self.lead}


def leads_by_fall(profiles) -> list[str]:
    """Names of the profile leads among ``profiles`` (:class:`ProfileScreen`), the largest fall of E first (the
    order the confirmation refits try them in, :func:`vfcli.diagnose.confirm.refit_order`)."""
    return [p.name for p in sorted((p for p in profiles if p.lead), key=lambda q: float(np.min(q.relative)))]


def profile_screens(baseline, candidates, steps: int = PROFILE_STEPS, map=None) -> list[ProfileScreen]:
    """The profile (module docstring) of every candidate with ``profile_screening`` and one parameter,
    when the baseline's f0 is known (the steady state works per harmonic of it); in the given order.

    map : an in-process map (:func:`vfcli.parallel.local_map`) for the independent pieces: the reduction's
        factorisations at its shifts and the values of each profile; default one after the other."""
    from vfcli.diagnose.refit import load_profile

    if not (np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0):
        return []
    out = []
    for c in candidates:
        if not getattr(c, "profile_screening", False) or len(c.parameter_names) != 1:
            continue
        thetas = np.asarray(c.start_values, dtype=float)
        t0 = time.perf_counter()
        if callable(getattr(c, "reduction", None)):
            c.reduction(baseline, map=map)            # built once, shared with the refit
        t1 = time.perf_counter()
        e0, e = load_profile(baseline, c, thetas, steps, map=map)
        log.info("profile of %s: reduction %.0f s, %d values %.0f s", c.name, t1 - t0, len(thetas),
                 time.perf_counter() - t1)
        out.append(ProfileScreen(c.name, c.parameter_names[0], thetas, e0, e))
    return out
