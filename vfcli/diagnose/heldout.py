"""Held-out prediction error of the baseline and of the extended model, on the same splits.

A refit always lowers E on the data it was fitted to; a term that is really missing also predicts
data the fit did not see better.  Two kinds of split, each giving errors per split so that the
decision can say "beyond the spread" (:class:`vfcli.diagnose.confirmation.HeldOutError`):

* **cycles** (:func:`leave_cycles_out`): the window's frames are grouped by glottal cycle (the
  phase of :mod:`vfcli.diagnose.cycles`; the cycles cut by the window's ends are groups too,
  :func:`cycle_groups`; a window with fewer than three cycles is cut into six contiguous blocks instead,
  the four inner ones held out in turn: then a split is not a cycle).  Split k fits the baseline and the
  extended model on every frame outside group k and predicts the velocity in group k.
* **instruments** (:func:`across_instruments`): both models are fitted to the camera's in-plane
  motion, the gap and the pressure (motion component weights (1, 1, 0)) and predict the vertical
  velocity (model z, which /fields takes from the vibrometer); the error is taken per cycle group,
  the groups being the splits.

The prediction error of a group is the RMS over its frames of measured minus predicted velocity
at the pixels compared in the baseline's frozen raster (the same rows for both models), mm/s.
Both models start from their fits to the whole window (the baseline's x; the extended refit's
x and theta) and are refitted on the training data by :func:`vfcli.diagnose.refit.joint_fit` with the
raster frozen at that start (``frozen``).  Refrozen at each trial the leave-cycles-out fits could not
leave it, so the held-out frames were predicted by a fit that had seen them; the camera-only fits did
move refrozen (2-4 steps on four panel recordings) and gave the same held-out changes within 0.01, but a
fit that stalls at its start would predict the vibrometer with loads fitted to it, and frozen they
cost a third less (docs/benchmarks.md, "Held-out fits that did not move").

A held-out fit that switches a one-sided term off (theta = 0 on its bound, :func:`switched_off`) is the
baseline: its errors are the baseline's.
"""
from __future__ import annotations

import builtins

import numpy as np

from vfcli.diagnose.confirmation import HeldOutError
from vfcli.diagnose.refit import RefitResult, joint_fit
from vfcli.inverse.terms.motion import frame_residual

#: component weights of the camera-only fit (in-plane x, y; no vertical)
CAMERA_ONLY = (1.0, 1.0, 0.0)
#: smallest number of frames a cycle group needs to be a split
MIN_GROUP_FRAMES = 3


def cycle_groups(phase: np.ndarray, n_blocks: int = 6) -> np.ndarray:
    """(F,) group of each window frame: its glottal cycle ``floor(phase)`` (the cycles cut by the
    window's ends included), renumbered 0..G-1; -1 for a cycle with fewer than
    :data:`MIN_GROUP_FRAMES` frames in the window.  A window with fewer than three such cycles (a
    window shorter than two or three cycles: too few splits for a spread) is cut into ``n_blocks`` contiguous blocks of frames instead,
    the inner ones the groups (the first and last block always stay in the fit: a held-out end
    would be an extrapolation of the loads' time basis, which neither model constrains).

    phase : (F,) cycle phase of the window's frames (:attr:`vfcli.diagnose.cycles.Cycles.phase`)."""
    lab = np.floor(np.asarray(phase, dtype=float)).astype(int)
    out = np.full(lab.shape, -1)
    g = 0
    for v in np.unique(lab):
        sel = lab == v
        if sel.sum() >= MIN_GROUP_FRAMES:
            out[sel] = g
            g += 1
    if g < 3 and len(lab) >= n_blocks * MIN_GROUP_FRAMES:
        block = (np.arange(len(lab)) * n_blocks) // len(lab)
        out = np.where((block > 0) & (block < n_blocks - 1), block - 1, -1)
    return out


def prediction_error(baseline, disp: np.ndarray, frames_of: np.ndarray, components=(0, 1, 2)) -> float:
    """RMS of measured minus predicted velocity (mm/s) over the frames ``frames_of`` (indices) at the
    pixels compared in the baseline's frozen raster, for displacements ``disp`` (F + 1, N, 3)."""
    p = baseline.problem
    comps = list(components)
    ss, n = 0.0, 0
    for f in np.asarray(frames_of, int):
        fr = baseline.frames[f]
        if fr.m_both.shape[0] == 0:
            continue
        r = frame_residual(fr, p.frame_velocity(disp, f), disp[f])[:, comps]
        ss += float(np.sum(r * r))
        n += r.size
    return float(np.sqrt(ss / n)) if n else float("nan")


def switched_off(candidate, theta) -> bool:
    """True when a fit of a ``one_sided`` candidate ended on its bound, theta = 0 (:func:`vfcli.diagnose.refit.
    joint_fit` stops it there): that extended model is the baseline, and its held-out errors are the baseline's
    fit's.  Its own fit, from the whole window's extended loads, would differ from them only by where the few
    held-out iterations stopped, a difference with no spread over the splits of one fit that passed for "beyond
    the spread" (contact phantom 2014: 0.058 % lower on all four cycle groups; docs/benchmarks.md, "Session 54")."""
    return bool(getattr(candidate, "one_sided", False)) and not np.any(np.asarray(theta, dtype=float))


def _pick(groups: np.ndarray, max_splits: int) -> np.ndarray:
    ids = np.unique(groups[groups >= 0])
    if len(ids) <= max_splits:
        return ids
    return ids[np.round(np.linspace(0, len(ids) - 1, max_splits)).astype(int)]


def leave_cycles_out(baseline, candidate, extended: RefitResult, groups: np.ndarray, max_splits: int = 4,
                     max_iterations: int = 3, extended_problem=None, map=None) -> HeldOutError | None:
    """Leave-cycles-out errors of the baseline and of ``candidate``'s extension (module docstring).

    extended : the extended model's refit on the whole window (its start).  groups : (F,) from
    :func:`cycle_groups`.  extended_problem : the problem the extension is fitted under (its own ridge weight,
    :func:`vfcli.diagnose.bound.refit_at_own_bound`); default the baseline's.  map : runs the fits (two per split,
    independent; an in-process map, :func:`vfcli.parallel.local_map`), default one after the other; the same errors
    whatever the map.  Returns None when fewer than two groups exist.
    """
    ids = _pick(np.asarray(groups), max_splits)
    if len(ids) < 2:
        return None
    model = getattr(baseline, "model", None)
    ext_problem = baseline.problem if extended_problem is None else extended_problem

    def fit(item):
        """(held-out error, theta) of one model fitted without group g; the error None where the extension's fit
        switched it off (the baseline's error is then its)."""
        g, extend = item
        held = np.flatnonzero(groups == g)
        keep = np.ones(len(groups), bool)
        keep[held] = False
        if not extend:
            b = joint_fit(baseline.problem, baseline.x, None, baseline.f0_hz, keep=keep,
                          max_iterations=max_iterations, model=model, stated=False, frozen=True)
            return prediction_error(baseline, b.displacements, held), None
        e = joint_fit(ext_problem, extended.x, candidate, baseline.f0_hz, theta0=extended.theta, keep=keep,
                      max_iterations=max_iterations, model=model, stated=False, frozen=True)
        off = switched_off(candidate, e.theta)
        return (None if off else prediction_error(baseline, e.displacements, held)), np.asarray(e.theta, float)

    got = list((map or builtins.map)(fit, [(g, extend) for g in ids for extend in (False, True)]))
    base_err = [got[2 * k][0] for k in range(len(ids))]
    ext_err = [b if e is None else e for b, (e, _) in zip(base_err, got[1::2])]
    thetas = [t for _, t in got[1::2]]
    return HeldOutError("cycles", "mm/s", np.array(base_err), np.array(ext_err), np.array(thetas, float))


def across_instruments(baseline, candidate, extended: RefitResult, groups: np.ndarray,
                       max_iterations: int = 4, extended_problem=None, map=None) -> HeldOutError | None:
    """Fit camera + gap + pressure, predict the vertical velocity, per cycle group (module docstring).

    extended_problem, map : as :func:`leave_cycles_out`'s (here two fits: the baseline's and the extension's).
    Returns None when fewer than two groups exist or no compared pixel carries a vertical velocity.
    """
    ids = np.unique(np.asarray(groups)[np.asarray(groups) >= 0])
    if len(ids) < 2:
        return None
    if not any(np.any(fr.v_both[:, 2] != 0) for fr in baseline.frames if fr.m_both.shape[0]):
        return None
    model = getattr(baseline, "model", None)

    def fit(extend: bool):
        """(per-group vertical errors, theta) of the camera-only fit; the errors None where the extension's fit
        switched it off."""
        if not extend:
            problem = baseline.problem.with_weights(component_weights=CAMERA_ONLY)
            b = joint_fit(problem, baseline.x, None, baseline.f0_hz, max_iterations=max_iterations, model=model,
                          stated=False, frozen=True)
            return [prediction_error(baseline, b.displacements, np.flatnonzero(groups == g), (2,)) for g in ids], None
        problem = (baseline.problem if extended_problem is None else extended_problem).with_weights(
            component_weights=CAMERA_ONLY)
        e = joint_fit(problem, extended.x, candidate, baseline.f0_hz, theta0=extended.theta,
                      max_iterations=max_iterations, model=model, stated=False, frozen=True)
        if switched_off(candidate, e.theta):
            return None, np.asarray(e.theta, float)
        return ([prediction_error(baseline, e.displacements, np.flatnonzero(groups == g), (2,)) for g in ids],
                np.asarray(e.theta, float))

    (base_err, _), (ext_err, theta) = (map or builtins.map)(fit, [False, True])
    return HeldOutError("instruments", "mm/s", np.array(base_err),
                        np.array(base_err if ext_err is None else ext_err), np.asarray(theta, float)[None])
