"""The decision: which left-out physics the diagnosis names, or "no missing physics detected".

A candidate is a **lead** when the loads cannot absorb it (identifiable) and its calibrated
family-wise p-value (:mod:`vfcli.diagnose.calibrate`: parametric bootstrap from the fitted
baseline, noise resampled in whole cycles, the periodic model error no candidate explains
included, Westfall-Young min-p over all candidates) is at most alpha.  A lead is a **finding**
only when its confirmation refit (``vfcli.diagnose.confirmation.Confirmation`` of the refit,
duck-typed here: ``candidate`` and ``improves``) also predicts data the fit did not see better
than the baseline, beyond the spread over splits.  Without a confirmation a lead stays a lead:
the answer is then still "no missing physics detected", with the unconfirmed leads named.
When several leads' refits are confirmed, the one whose refit predicts the held-out data best (the largest mean
relative reduction of the held-out error over the held-out kinds, ``gain``) is the finding: they are alternative
explanations of one residual, and the others' lines say which explained it better.  This changes which physics is
named, never whether one is.

The family-wise false-alarm rate of the leads is alpha (0.05) when the residual holds noise and a periodic model
error that leans on the candidates' signatures no more than it would at a random phase of the cycle (the
calibration's null, :mod:`vfcli.diagnose.calibrate`).  A model error locked in phase with the motion, as the
candidates' columns are, leans further, and the null does not hold it: on widened null phantoms (no effect, the
load distribution and geometry the model does not have) the screening raises a lead on about half of them.  The rate
stated for the verdict is therefore the findings': a lead must also pass its confirmation refit, and the
findings' rate is measured on nulls, not derived (the running figures: docs/diagnose.md, "What the stated rate
covers").  The decision's first line says both.

A **profile lead** (:mod:`vfcli.diagnose.profile`: a candidate the score test cannot reach, whose fit with
the loads refitted at one of its start values beats the baseline's) is outside that calibration.  It
becomes a finding on the same condition, its confirmation refit predicting held-out data better beyond
the spread; the rate of false findings is then at most alpha plus that of a profile lead passing its
held-out comparisons on a recording without the term.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from vfcli.diagnose.confirmation import NOT_BEYOND_SPREAD
from vfcli.diagnose.words import percent_size

#: the family-wise false-alarm rate the decision is calibrated for
FAMILY_ALPHA = 0.05


@dataclass(frozen=True)
class Decision:
    """names : the candidates, in screening order.  p_family : (C,) calibrated family-wise p-values.
    leads : names of the calibrated leads (smallest p first).  findings : leads confirmed by refit.
    alpha : the family-wise false-alarm rate.  n_replicates : the bootstrap's replicates.
    lines : the plain-words lines.  profile_leads : names of the profile leads that are not calibrated leads.
    limits : candidate name -> the words on the smallest size the screening would have named (appended to
    its line when it is no lead; :func:`detection_words`)."""

    names: tuple[str, ...]
    p_family: np.ndarray
    leads: tuple[str, ...]
    findings: tuple[str, ...]
    alpha: float
    n_replicates: int
    lines: list[str] = field(default_factory=list)
    profile_leads: tuple[str, ...] = ()
    limits: Mapping[str, str] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """"missing physics: <names>" or "no missing physics detected"."""
        return f"missing physics: {', '.join(self.findings)}" if self.findings else "no missing physics detected"


def _gain(confirmation: Any) -> float:
    """A confirmation's held-out gain (``gain``: the mean relative reduction of the held-out error); -inf without."""
    g = float(getattr(confirmation, "gain", float("nan")))
    return g if np.isfinite(g) else -np.inf


def best_confirmed(confirmations: Sequence[Any]) -> int:
    """Index of the confirmed refit (``improves``) whose held-out gain (``gain``) is largest, the first on a tie; 0
    when none is confirmed (the first refit's figures are then the ones shown).  The finding :func:`decide` names
    among several confirmed leads."""
    best, score = 0, -np.inf
    for i, c in enumerate(confirmations):
        if bool(getattr(c, "improves", False)) and _gain(c) > score:
            best, score = i, _gain(c)
    return best


def _p(p: float, n_replicates: int) -> str:
    floor = 1.0 / (n_replicates + 1)
    return f"p <= {floor:.2g}" if p <= floor + 1e-12 else f"p = {p:.2g}"


def detection_words(parameter: str, limit: float, full_value: float | None = None, full_meaning: str = "",
                    one_sided: bool = False) -> str:
    """The words on a candidate's smallest detectable size ``limit`` (:func:`vfcli.diagnose.calibrate.smallest_detectable`;
    "" when it is not a number): the size, and with a physical full strength ``full_value`` whether even that
    would have been seen."""
    if not np.isfinite(limit):
        return "" if np.isnan(limit) else f"no {parameter} of any size would have been named here"
    size = f"{parameter} of {'' if one_sided else '+-'}{limit:.3g}"
    text = f"the screening would name about half the time a {size}"
    if full_value is not None:
        text += f" ({full_value:g}: {full_meaning})"
        if limit > full_value:
            text += ": this recording cannot show it"
    return text


def _shortfall(conf) -> str:
    """Why a refit does not confirm its lead (:attr:`vfcli.diagnose.confirmation.Confirmation.shortfall`; the
    held-out words for an object that does not say)."""
    return getattr(conf, "shortfall", "") or NOT_BEYOND_SPREAD


def decide(names: Sequence[str], p_family: np.ndarray, identifiable: Sequence[bool], n_replicates: int,
           alpha: float = FAMILY_ALPHA, confirmations: Mapping[str, Any] | None = None,
           profile_leads: Sequence[str] = (), limits: Mapping[str, str] | None = None) -> Decision:
    """Leads and findings (module docstring).

    names : (C,) candidate names.  p_family : (C,) calibrated family-wise p-values.
    identifiable : (C,) whether the loads cannot absorb each.  n_replicates : B of the bootstrap.
    confirmations : candidate name -> its confirmation refit (an object with ``improves``), when one was made.
    profile_leads : names of the candidates whose profile beats the baseline (:mod:`vfcli.diagnose.profile`).
    limits : candidate name -> :func:`detection_words`, added to its line when it is neither a lead nor a
        profile lead ("no evidence" is then not "absent" when the recording could not show the term).
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    p = np.asarray(p_family, dtype=float)
    confirmations = dict(confirmations or {})
    limits = {k: v for k, v in (limits or {}).items() if v}
    order = np.argsort(p, kind="stable")
    leads = tuple(names[i] for i in order if identifiable[i] and p[i] <= alpha)
    profiled = tuple(n for n in profile_leads if n in names and n not in leads)
    confirmed = tuple(n for n in leads + profiled
                      if n in confirmations and bool(getattr(confirmations[n], "improves", False)))
    # one residual, several terms that each explain some of it: the one whose refit predicts held-out data best is
    # named (docs/diagnose.md, "Model it"); the others' lines say so
    findings = (confirmed[best_confirmed([confirmations[n] for n in confirmed])],) if confirmed else ()

    def bettered(n: str) -> str:
        """Why a confirmed refit ``n`` is not named: the named one predicts held-out data better."""
        best = findings[0]
        mine, theirs = (f"{percent_size(_gain(confirmations[k]))} %" for k in (n, best))
        return (f"its refit predicts held-out data better than the baseline beyond the spread too, but {best}'s "
                f"predicts it better ({mine} against {theirs} lower held-out error): not named, {best} explains the "
                "residual")
    head = (f"decision: screening at family-wise rate {alpha:g} over {len(names)} candidates, calibrated by "
            f"{n_replicates} bootstrap replicates (noise resampled in whole cycles, periodic model error included as "
            "if at a random phase of the cycle; a model error in phase with the motion raises leads beyond that "
            "rate), and a lead named only when its refit predicts held-out data better beyond the spread and the "
            "baseline shows the term's signature")
    lines = [head]
    for i in order:
        n = names[i]
        if not identifiable[i] and n not in profiled:
            continue
        if n in profiled:
            why = ("its refit predicts held-out data better than the baseline beyond the spread: missing physics found"
                   if n in findings else bettered(n) if n in confirmed
                   else _shortfall(confirmations[n]) if n in confirmations else "not confirmed: no held-out refit")
            lines.append(f"{n}: no evidence in the calibrated screening (family-wise {_p(p[i], n_replicates)}), "
                         f"a profile lead: {why}")
        elif n in findings:
            lines.append(f"{n}: missing physics found (calibrated family-wise {_p(p[i], n_replicates)}; its refit "
                         "predicts held-out data better than the baseline beyond the spread)")
        elif n in leads:
            why = (bettered(n) if n in confirmed
                   else _shortfall(confirmations[n]) if n in confirmations else "not confirmed: no held-out refit")
            lines.append(f"{n}: a calibrated lead (family-wise {_p(p[i], n_replicates)}), {why}")
        else:
            # a refit asked for by name (--refit NAME) of a candidate that is no lead: say why it cannot count, which
            # ever way its held-out check went (a confirmed refit beside "no missing physics detected" read as a
            # contradiction)
            asked = ("" if n not in confirmations else
                     "; its refit, asked for by name, predicts held-out data better beyond the spread, but a finding "
                     "needs a calibrated lead as well (the false-alarm rate is controlled over the screening)"
                     if bool(getattr(confirmations[n], "improves", False)) else
                     f"; its refit, asked for by name, does not confirm it either: {_shortfall(confirmations[n])}"
                     if getattr(confirmations[n], "signature_missing", "") else
                     "; its refit, asked for by name, does not predict held-out data better beyond the spread either")
            lines.append(f"{n}: no evidence beyond noise and model error (calibrated family-wise "
                         f"{_p(p[i], n_replicates)})" + (f"; {limits[n]}" if n in limits else "") + asked)
    d = Decision(tuple(names), p, leads, findings, float(alpha), int(n_replicates), profile_leads=profiled)
    tail = d.verdict
    open_leads = [n for n in leads + profiled if n not in findings]
    if not findings and open_leads:
        tail += f" (unconfirmed lead{'s' if len(open_leads) > 1 else ''}: {', '.join(open_leads)})"
    lines.append(tail)
    return Decision(d.names, d.p_family, d.leads, d.findings, d.alpha, d.n_replicates, lines, profiled, limits)
