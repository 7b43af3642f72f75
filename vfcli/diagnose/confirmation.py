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

#: why a refit that lowers E is not confirmed, in the decision's words
NOT_BEYOND_SPREAD = "its refit does not predict held-out data better beyond the spread"

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
    theta : (n_fits, p) the extended model's parameters as each of its fits found them (cycles: one fit per
        split, on the frames outside it; instruments: the one fit to the camera, gap and pressure), or None.
    """

    kind: str
    units: str
    baseline: np.ndarray
    extended: np.ndarray
    theta: np.ndarray | None = None

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
                "beyond_spread": self.beyond_spread(),
                **({"theta": np.asarray(self.theta, float).tolist()} if self.theta is not None else {})}


def heldout_sd(theta: np.ndarray, sd: np.ndarray, heldout, mesh_sd: np.ndarray | None = None
               ) -> tuple[np.ndarray, str, float, dict]:
    """The refitted parameters' stated standard deviation with what the held-out fits say apart, and its name.

    The sandwich over frames (:func:`vfcli.diagnose.refit.sandwich_theta`) measures how the noise moves
    theta; a model error that repeats in every cycle or that one instrument carries and the other not
    moves it too, and the sandwich does not see it (on an asymmetry phantom the softening came out 0.231
    for a true 0.25, outside its interval).  The held-out fits refit theta on other data:

    * **cycles**, a delete-a-group jackknife (Efron and Stein 1981): with theta_k fitted without group k
      (G groups), ``var_J = (G - 1) / G sum_k (theta_k - mean theta_k)^2``; it estimates the variance of the
      whole-window theta from the groups' disagreement, noise and phase-dependent model error alike, so it
      replaces the sandwich where it is larger (both count the noise: they are not added);
    * **instruments**: theta fitted to the camera, gap and pressure alone against the whole fit, whose
      difference is what the vibrometer alone moves; its square is added (one sample of that
      disagreement, as optimize states the instruments' part of its uncertainty).

    and a bias no refit on the same mesh sees:

    * **mesh** (``mesh_sd``: ``|theta shift|``, ``shift`` the term's :meth:`mesh_shift`): how far the fit mesh's
      discretisation moves theta, from the same folds on a finer mesh; its square is added (the estimate is then
      corrected by that shift, :func:`mesh_corrected`: what is left is the distance to the continuum).

    Parameters
    ----------
    theta : (p,) the refit on the whole window.  sd : (p,) its sandwich standard deviation.
    heldout : the :class:`HeldOutError` records (those without ``theta`` are ignored).
    mesh_sd : (p,) the mesh part, or None (not stated).

    With G groups the jackknife's variance has G - 1 degrees of freedom (exactly so for a location model
    with normal group effects): where it sets the sd, the 95 % interval is Student's t (with 4 groups and
    nothing added: -+ 3.18 sd, not -+ 1.96 sd) with the effective degrees of freedom of the sum,
    ``(G - 1) sd^4 / var_J^2`` (Welch-Satterthwaite, as the GUM combines a part estimated from few samples
    with parts taken as known): a mesh part ten times the jackknife's leaves it practically normal (before
    session 67 it stayed G - 1, which with the new mesh part made widened phantom 2002's density interval
    -+ 7.8 % for an sd of 2.5 %).

    Returns
    -------
    sd : (p,) stated standard deviation ``sqrt(max(sd^2, var_J) + (theta_camera - theta)^2 + mesh_sd^2)``.
    name : which parts entered, e.g. "sandwich, cycles jackknife, instruments and mesh".
    dof : effective degrees of freedom of sd (infinite unless the jackknife exceeds the sandwich for some
        parameter; the smallest over the parameters).
    parts : {"sandwich", "jackknife", "instruments", "mesh": (p,) standard deviations or None}.
    """
    theta, sd = np.asarray(theta, float).reshape(-1), np.asarray(sd, float).reshape(-1)
    var = np.where(np.isfinite(sd), sd, 0.0) ** 2
    parts: dict = {"sandwich": sd, "jackknife": None, "instruments": None, "mesh": None}
    names = ["sandwich"] if np.all(np.isfinite(sd)) else []
    dof = float("inf")
    jack = np.full(theta.shape, np.nan)
    for h in heldout:
        t = None if h.theta is None else np.asarray(h.theta, float).reshape(-1, theta.size)
        if t is None or not np.all(np.isfinite(t)):
            continue
        if h.kind == "cycles" and len(t) >= 2:
            g = len(t)
            var_j = (g - 1) / g * np.sum((t - t.mean(axis=0)) ** 2, axis=0)
            if np.any(var_j > var):
                dof = float(g - 1)
                jack = np.where(var_j > var, var_j, np.nan)        # where the jackknife sets the noise part
            var = np.maximum(var, var_j)
            parts["jackknife"] = np.sqrt(var_j)
            names.append("cycles jackknife")
        elif h.kind == "instruments" and len(t) >= 1:
            d = t[0] - theta
            var = var + d * d
            parts["instruments"] = np.abs(d)
            names.append("instruments")
    if mesh_sd is not None and np.all(np.isfinite(mesh_sd)):
        m = np.asarray(mesh_sd, float).reshape(theta.shape)
        var = var + m * m
        parts["mesh"] = np.abs(m)
        names.append("mesh")
    if np.isfinite(dof):
        # Welch-Satterthwaite (the GUM's effective degrees of freedom): the jackknife's variance has G - 1, the
        # parts added to it are taken as known; a mesh part far above the jackknife leaves the interval normal
        with np.errstate(divide="ignore", invalid="ignore"):
            eff = dof * var ** 2 / jack ** 2
        dof = float(np.nanmin(eff))
    name = ", ".join(names[:-1]) + (" and " if len(names) > 1 else "") + names[-1] if names else "none"
    out = np.sqrt(var) if names else np.full(theta.shape, np.nan)
    return out, name, dof, parts


def mesh_corrected(theta: np.ndarray, sd: np.ndarray, shift: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The refitted parameters on the same folds meshed finer: ``theta / (1 + shift)``, and their sd alike.

    A conforming finite-element model is stiffer than the body it discretises (its eigenvalues are Rayleigh-Ritz
    upper bounds), so a parameter that trades against the stiffness comes out biased the same way on any mesh, and
    a finer mesh moves it toward the continuum's value: by ``shift`` (relative, the term's :meth:`mesh_shift`, from
    the same folds on a mesh 1.2 times finer, :mod:`vfcli.model.refine`). The corrected value lies nearer the
    continuum's than the fit mesh's does, by the first-order change that refinement makes; what is left of the
    distance (a continuum lies further than one refinement) stays in the stated sd's mesh part, ``|theta shift|``
    (:func:`heldout_sd`).  Measured: inertia's density on widened phantoms 2002, 2007 and 2012, 1.0-1.8 % above the
    synth's (a 1.25 mm mesh, the fit's 1.5 mm refined 1.2 times), corrected 0.5-0.8 % below it (docs/diagnose.md).

    theta, sd : (p,).  shift : (p,) or None (not stated: theta and sd as given).  Returns (theta, sd), each (p,).
    """
    theta, sd = np.asarray(theta, float).reshape(-1), np.asarray(sd, float).reshape(-1)
    if shift is None or not np.all(np.isfinite(shift)):
        return theta, sd
    scale = 1.0 / (1.0 + np.asarray(shift, float).reshape(theta.shape))
    return theta * scale, sd * scale


@dataclass(frozen=True)
class NotRefitted:
    """A lead that was not refitted because the baseline does not show its term's signature: its refit could confirm
    nothing (:attr:`Confirmation.improves` needs the signature), so ``vfcli diagnose`` (``--refit auto``) spares its
    refit and held-out fits (contact's, a minute or more: docs/diagnose.md, "Session 78: a lead without its signature
    is not refitted").  Duck-typed as a confirmation by :func:`vfcli.diagnose.decide.decide`.

    candidate : its name.  signature_missing : why the baseline does not show its signature (the candidate's
    ``missing_signature(baseline)``, never empty).
    """

    candidate: str
    signature_missing: str

    improves = False

    @property
    def shortfall(self) -> str:
        """Why it is not confirmed, in words."""
        return f"not refitted: the baseline does not show its signature: {self.signature_missing}"

    def as_dict(self) -> dict:
        return {"candidate": self.candidate, "refitted": False, "improves": False,
                "signature_missing": self.signature_missing}


@dataclass(frozen=True)
class Confirmation:
    """The confirmation refit of one candidate.

    candidate : its name ("inertia", ...).  parameter_names : (p,) with units.
    estimate : (p,) refitted theta (on a mesh finer than the fit's where the term states ``mesh_shift``:
        :func:`mesh_corrected`).  sd : (p,) its stated standard deviation (``uncertainty`` says which).
    uncertainty : which parts the sd holds: "sandwich" (over frames, as optimize's; :mod:`vfcli.diagnose.refit`),
        with the held-out fits' disagreement when they were made (:func:`heldout_sd`), or "laplace".
    heldout : the held-out comparisons (:class:`HeldOutError`), one per kind that could be made.
    run : name of the /optimize run the extended model was stored as ("" when not stored).
    dof : degrees of freedom of the stated sd (infinite for the sandwich; G - 1 when a jackknife over G
        held-out groups set it, :func:`heldout_sd`): the interval is Student's.
    moved : False when the refit kept no step from a start value it did not fit (its history holds its start only,
        and the start is not a profile search's minimum, :attr:`vfcli.diagnose.refit.RefitResult.profiled`): the
        estimate is a value it was given (the term switched off, or contact's full share), not a fitted one.  A
        condition of a finding since session 65: a finding states its estimated parameter with its interval (issue
        16, item 5), which a given value is not.  Only contact starts at a value it was given (inertia and damping
        start at their profile's minimum, asymmetry and offset at zero, where an unmoved refit has the baseline's
        E); both false findings of 129 nulls (2061, 2139) were contact at its unmoved full share, and no contact
        finding on the default options was a true one (docs/benchmarks.md, "Session 54" and "Session 65: twenty
        fresh nulls"; docs/diagnose.md, "Session 65: a refit that never left its start confirms nothing").
    lowers_e : False when the refit's final E (re-rasterised, the whole window) is not below the baseline's: the
        extended model explains nothing of the window the baseline did not, whatever the held-out fits (frozen
        rasters, linear in the step) say; then it is no finding.
    mesh_shift : (p,) relative shift of theta the fit mesh's discretisation makes against a mesh 1.2 times finer,
        which ``estimate`` is corrected by (the refit on the fit mesh found ``estimate * (1 + mesh_shift)``, the value
        the stored run's displacements are at), or None (not stated, not corrected).
    signature_missing : "" when the baseline shows the term's own signature or the term states none; else why it does
        not (the candidate's ``missing_signature(baseline)``: contact's crossing of the midplane held open as much as
        closed).  A refit that lowers E and predicts held-out data better without its term's signature has taken up
        another error (contact's constant push reads the folds' mounting), so it is no finding (session 77).
    """

    candidate: str
    parameter_names: tuple[str, ...]
    estimate: np.ndarray
    sd: np.ndarray
    uncertainty: str = "sandwich"
    heldout: tuple[HeldOutError, ...] = ()
    run: str = ""
    dof: float = float("inf")
    moved: bool = True
    lowers_e: bool = True
    mesh_shift: np.ndarray | None = None
    signature_missing: str = ""

    @property
    def fit_mesh_estimate(self) -> np.ndarray:
        """(p,) theta as the refit found it on the fit mesh (``estimate`` before :func:`mesh_corrected`)."""
        e = np.asarray(self.estimate, float)
        return e if self.mesh_shift is None else e * (1.0 + np.asarray(self.mesh_shift, float).reshape(e.shape))

    @property
    def interval(self) -> np.ndarray:
        """(p, 2) 95 % interval, estimate -+ t sd: t = 1.96 (normal) when ``dof`` is infinite, else Student's
        0.975 quantile with ``dof`` degrees of freedom (a jackknife over few groups, :func:`heldout_sd`)."""
        from scipy import stats

        e, s = np.asarray(self.estimate, float), np.asarray(self.sd, float)
        t = 1.96 if not np.isfinite(self.dof) else float(stats.t.ppf(0.975, max(self.dof, 1.0)))
        return np.column_stack([e - t * s, e + t * s])

    def heldout_of(self, kind: str) -> HeldOutError | None:
        return next((h for h in self.heldout if h.kind == kind), None)

    @property
    def predicts_better(self) -> bool:
        """Every held-out comparison made improves beyond its spread (False when none could be made)."""
        return bool(self.heldout) and all(h.beyond_spread() for h in self.heldout)

    @property
    def improves(self) -> bool:
        """The refit left its start (``moved``), lowers E below the baseline's, predicts held-out data better
        (``predicts_better``) and the baseline shows the term's signature (``signature_missing`` empty)."""
        return self.moved and self.lowers_e and self.predicts_better and not self.signature_missing

    @property
    def shortfall(self) -> str:
        """Why it is not confirmed, in words ("" when it is)."""
        if self.improves:
            return ""
        if not self.lowers_e:
            return "its refit explains nothing the baseline did not (E not below the baseline's)"
        if not self.moved:
            return "its refit never left the value it started from, so it estimates nothing"
        if self.signature_missing and self.predicts_better:
            return f"the baseline does not show its signature: {self.signature_missing}"
        return NOT_BEYOND_SPREAD

    @property
    def gain(self) -> float:
        """The mean over the held-out kinds of the relative reduction of the held-out error (NaN without one): how much
        better the extended model predicts data its fits did not see, what ranks several confirmed refits."""
        r = [h.reduction for h in self.heldout if np.isfinite(h.reduction)]
        return float(np.mean(r)) if r else float("nan")

    def as_dict(self) -> dict:
        return {"candidate": self.candidate, "run": self.run, "uncertainty": self.uncertainty,
                "dof": float(self.dof) if np.isfinite(self.dof) else None,
                "parameters": {n: {"estimate": float(e), "sd": float(s), "interval": [float(a), float(b)],
                                   **({} if self.mesh_shift is None else
                                      {"fit_mesh_estimate": float(f), "mesh_shift": float(m)})}
                               for n, e, s, (a, b), f, m in zip(
                                   self.parameter_names, self.estimate, self.sd, self.interval,
                                   self.fit_mesh_estimate,
                                   np.zeros(len(self.sd)) if self.mesh_shift is None else self.mesh_shift)},
                "heldout": [h.as_dict() for h in self.heldout], "improves": self.improves,
                "gain": round(self.gain, 4) if np.isfinite(self.gain) else None, "moved": self.moved,
                "lowers_e": self.lowers_e, "signature_missing": self.signature_missing}
