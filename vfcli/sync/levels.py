"""Do the video and the scan come from the same operating point? The pressure levels beside each.

The rig records the subglottal pressure beside the video and beside every scan point, and sync only
locks their phases: a scan recorded at another mean pressure (another operating point, or another
recording's files put together) aligns perfectly and yields a fit about 50 % off on the inferior surface with
exit 0. The levels themselves tell: the mean of the pressure and its swing (the RMS of its oscillating
part), each over whole glottal cycles, beside the video against beside the scan's points.

A rig holds its pressure within a few percent over the minutes of a scan; a change of operating point is a
step of 10 % or more (labs step their pressure by about 100 Pa around 300-1000 Pa). :data:`LEVEL_TOLERANCE`
sits between, a judgement, not a fit to phantoms (theirs agree to 0.06 %); the scan's own spread between
points (:data:`SPREAD_FACTOR` standard deviations) widens it for a rig that drifts more.
"""
from __future__ import annotations

import numpy as np

#: Largest relative difference of the mean pressure, or of its swing, beside the video and beside the scan.
LEVEL_TOLERANCE = 0.10
#: ... widened to this many standard deviations of the scan points' own levels.
SPREAD_FACTOR = 4.0


def cycle_levels(x: np.ndarray, fs: float, f0_hz: float) -> tuple[float, float] | None:
    """(mean, swing) of a pressure record over its whole glottal cycles from the start: the mean and the RMS
    of the oscillating part, in the record's unit; None when it holds no whole cycle.

    x : (n,) samples at ``fs`` Hz; f0_hz : the glottal f0.
    """
    if not (np.isfinite(f0_hz) and f0_hz > 0):
        return None
    n_cycles = int(np.floor(len(x) / fs * f0_hz))
    if n_cycles < 1:
        return None
    seg = np.asarray(x[: int(round(n_cycles * fs / f0_hz))], dtype=float)
    return float(seg.mean()), float(seg.std())


def level_mismatch(video: tuple[float, float], points: np.ndarray) -> list[tuple[str, float, float, float, float]]:
    """Which level differs beside the video and beside the scan beyond the tolerance (module doc).

    video : (mean, swing) beside the video, Pa.  points : (P, 2) the same beside each aligned scan point, Pa.
    Returns ``(name, video value, scan median, scan min, scan max)`` for "mean" and/or "swing" (empty: they agree).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    out = []
    if len(pts) == 0:
        return out
    for k, name in enumerate(("mean", "swing")):
        scan = float(np.median(pts[:, k]))
        tol = max(LEVEL_TOLERANCE * max(abs(scan), abs(video[k])), SPREAD_FACTOR * float(pts[:, k].std()))
        if not abs(video[k] - scan) <= tol:
            out.append((name, float(video[k]), scan, float(pts[:, k].min()), float(pts[:, k].max())))
    return out
