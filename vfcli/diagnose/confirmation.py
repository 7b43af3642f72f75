"""What a confirmation refit hands to the decision: the refit's parameter and the held-out errors.

A screening lead (:mod:`vfcli.diagnose.candidates.screening`) is confirmed only when the baseline
extended by the candidate, refitted (:mod:`vfcli.diagnose.refit`), also predicts data the fit
did not see better than the baseline, beyond the spread over splits (:mod:`vfcli.diagnose.heldout`).
These two small frozen records carry that evidence; the decision (:mod:`vfcli.diagnose.decide`)
reads them and nothing else of the refit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the held-out kinds: whole glottal cycles left out; the vibrometer's vertical velocity left out
HELDOUT_KINDS = ("cycles", "instruments")


@dataclass(frozen=True)
class HeldOutError:
    """Held-out prediction error of the baseline and of the extended model, on the same splits.

    kind : "cycles" (fit on some whole cycles of the window, predict the others) or "instruments"
        (fit the camera's in-plane motion, the gap and the pressure; predict the vertical velocity).
    units : of the errors, e.g. "mm/s".
    baseline : (n_splits,) RMS prediction error of the refitted baseline on each split's held-out rows.
    extended : (n_splits,) the same for the baseline extended by the candidate (same splits, same rows).
    """

    kind: str
    units: str
    baseline: np.ndarray
    extended: np.ndarray

    def __post_init__(self) -> None:
        b, e = np.asarray(self.baseline, float), np.asarray(self.extended, float)
        if self.kind not in HELDOUT_KINDS or b.shape != e.shape or b.ndim != 1 or b.size == 0:
            raise ValueError(f"held-out errors: kind in {HELDOUT_KINDS} and equal (n_splits,) arrays, "
                             f"got {self.kind!r}, {b.shape}, {e.shape}")

    @property
    def n_splits(self) -> int:
        return int(np.asarray(self.baseline).size)

    @property
    def reduction_per_split(self) -> np.ndarray:
        """(n_splits,) fractional error reduction ``1 - extended / baseline`` of each split (0.3 = 30 % lower)."""
        b = np.asarray(self.baseline, float)
        with np.errstate(invalid="ignore", divide="ignore"):
            return 1.0 - np.asarray(self.extended, float) / b

    @property
    def reduction(self) -> float:
        """Fractional reduction of the mean squared error over splits: ``1 - sqrt(mean e^2 / mean b^2)``."""
        b, e = np.asarray(self.baseline, float), np.asarray(self.extended, float)
        return float(1.0 - np.sqrt(np.mean(e ** 2) / max(float(np.mean(b ** 2)), 1e-300)))

    @property
    def spread(self) -> float:
        """Standard error of the mean per-split reduction (sd / sqrt(n_splits)); NaN with one split."""
        r = self.reduction_per_split
        return float(np.std(r, ddof=1) / np.sqrt(r.size)) if r.size > 1 else float("nan")

    def beyond_spread(self, level: float = 0.95) -> bool:
        """True when the mean per-split reduction is positive and beyond its spread: above the one-sided
        ``level`` quantile of Student's t with n_splits - 1 degrees of freedom times the standard error
        (t, not a normal quantile: with 2-4 splits the spread itself is uncertain).  Never with one split."""
        from scipy import stats

        r = self.reduction_per_split
        s = self.spread
        if not np.isfinite(s) or r.size < 2:
            return False
        return bool(float(np.mean(r)) > max(float(stats.t.ppf(level, r.size - 1)) * s, 0.0))

    def as_dict(self) -> dict:
        return {"kind": self.kind, "units": self.units, "baseline": [float(v) for v in self.baseline],
                "extended": [float(v) for v in self.extended], "reduction": round(self.reduction, 4),
                "spread": round(self.spread, 4) if np.isfinite(self.spread) else None,
                "beyond_spread": self.beyond_spread()}


@dataclass(frozen=True)
class Confirmation:
    """The confirmation refit of one candidate.

    candidate : its name ("inertia", ...).  parameter_names : (p,) with units.
    estimate : (p,) refitted theta.  sd : (p,) its stated standard deviation (``uncertainty`` says which).
    uncertainty : "sandwich" (over frames, as optimize's; :mod:`vfcli.diagnose.refit`) or "laplace".
    heldout : the held-out comparisons (:class:`HeldOutError`), one per kind that could be made.
    run : name of the /optimize run the extended model was stored as ("" when not stored).
    """

    candidate: str
    parameter_names: tuple[str, ...]
    estimate: np.ndarray
    sd: np.ndarray
    uncertainty: str = "sandwich"
    heldout: tuple[HeldOutError, ...] = ()
    run: str = ""

    @property
    def interval(self) -> np.ndarray:
        """(p, 2) 95 % interval, estimate -+ 1.96 sd."""
        e, s = np.asarray(self.estimate, float), np.asarray(self.sd, float)
        return np.column_stack([e - 1.96 * s, e + 1.96 * s])

    def heldout_of(self, kind: str) -> HeldOutError | None:
        return next((h for h in self.heldout if h.kind == kind), None)

    @property
    def improves(self) -> bool:
        """Every held-out comparison made improves beyond its spread (False when none could be made)."""
        return bool(self.heldout) and all(h.beyond_spread() for h in self.heldout)

    def as_dict(self) -> dict:
        return {"candidate": self.candidate, "run": self.run, "uncertainty": self.uncertainty,
                "parameters": {n: {"estimate": float(e), "sd": float(s), "interval": [float(a), float(b)]}
                               for n, e, s, (a, b) in zip(self.parameter_names, self.estimate, self.sd,
                                                          self.interval)},
                "heldout": [h.as_dict() for h in self.heldout], "improves": self.improves}
