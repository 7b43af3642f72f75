"""The glottal cycle from the gap area: f0, the cycle and phase of every frame, and its four phases.

The phase is locked to the glottal area waveform A(t): a cycle starts where A rises through
half its range (``A_min + 0.5 (A_max - A_min)``, linearly interpolated between frames), and the
phase grows linearly (0 to 1) from one such crossing to the next.  The four phases of a cycle
are read from the area's level and slope:

* ``closed`` : A below 15 % of its range above the minimum (closed, or as closed as it gets);
* ``open`` : A above 85 % of its range (around the widest opening);
* ``opening`` / ``closing`` : between the two, A rising / falling.

Whole cycles (between two consecutive crossings) are the units of replication of the noise
floor (:mod:`vfcli.diagnose.noise`); :func:`floor_cycles` and :func:`floor_cycle_ids` pick the ones
it is measured on around a fitted window.

An area that opens twice in a cycle (a smaller second opening after a partial closure: folds with mass
or in contact) rises through half its range twice, and its crossings alone give twice f0 (blind panel
seed 2007: 240 Hz for a recording at 120 Hz, so the steady-state candidates worked at the wrong
harmonics).  The recorded subglottal pressure's f0 (``/sync``, the same for every frame) settles it:
given ``f0_hz``, a crossing less than :data:`MIN_PERIOD_SHARE` of its period after the last kept one is
the same cycle's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: names of the four phases, in the order of :attr:`Cycles.phase_name`
PHASE_NAMES = ("opening", "open", "closing", "closed")
#: area levels (fraction of the range above the minimum) below which a frame is closed, above which open
CLOSED_LEVEL, OPEN_LEVEL = 0.15, 0.85
#: with a known f0, upward crossings closer than this share of its period belong to one cycle
MIN_PERIOD_SHARE = 0.75


class TooFewCycles(ValueError):
    """The recording holds too few whole glottal cycles for what was asked (a property of the data)."""


@dataclass(frozen=True)
class Cycles:
    """Glottal cycles of a recording.

    f0_hz : fundamental frequency, 1 / the median cycle length, Hz.
    phase : (F,) cycle phase of each frame, cycles, continuous (frame in cycle k has phase in [k, k + 1));
        extrapolated with 1 / f0 before the first and after the last crossing.
    cycle : (F,) index of the whole cycle each frame lies in (0-based), -1 outside whole cycles.
    phase_name : (F,) index into :data:`PHASE_NAMES` of each frame.
    """

    f0_hz: float
    phase: np.ndarray
    cycle: np.ndarray
    phase_name: np.ndarray

    @property
    def n_cycles(self) -> int:
        """Number of whole cycles."""
        return int(self.cycle.max() + 1) if self.cycle.size and self.cycle.max() >= 0 else 0


def _smooth(a: np.ndarray, width: int) -> np.ndarray:
    if width < 2:
        return a
    k = np.ones(width) / width
    pad = np.pad(a, (width // 2, width - 1 - width // 2), mode="edge")
    return np.convolve(pad, k, mode="valid")


def glottal_cycles(area: np.ndarray, dt: float, f0_hz: float | None = None) -> Cycles:
    """The cycles of the glottal area waveform (module docstring).

    Parameters
    ----------
    area : (F,) glottal area at uniformly spaced frames, mm^2 (any unit).
    dt : frame interval, s.
    f0_hz : the recording's f0 from another signal (the subglottal pressure, ``/sync``), Hz, or None:
        crossings closer than :data:`MIN_PERIOD_SHARE` of its period are one cycle's.

    Raises
    ------
    TooFewCycles
        Fewer than two upward crossings (not even one whole cycle), or a flat area.
    ValueError
        ``area`` is not (F,) finite with F >= 4.
    """
    a = np.asarray(area, dtype=float)
    if a.ndim != 1 or a.size < 4 or not np.all(np.isfinite(a)):
        raise ValueError(f"the glottal area must be (F,) finite with F >= 4, got shape {a.shape}")
    lo, hi = np.percentile(a, 1), np.percentile(a, 99)
    if not hi > lo:
        raise TooFewCycles("the glottal area is flat: no glottal cycle")
    level = (a - lo) / (hi - lo)
    # upward crossings of the half level, with hysteresis (0.4 / 0.6) against noise
    ups: list[float] = []
    armed = level[0] < 0.4
    for i in range(1, a.size):
        if level[i] < 0.4:
            armed = True
        if armed and level[i - 1] < 0.5 <= level[i]:
            ups.append(i - 1 + (0.5 - level[i - 1]) / (level[i] - level[i - 1]))
            armed = False
    if f0_hz is not None and np.isfinite(f0_hz) and f0_hz > 0:
        gap = MIN_PERIOD_SHARE / (float(f0_hz) * dt)        # frames
        kept: list[float] = []
        for u in ups:
            if not kept or u - kept[-1] >= gap:
                kept.append(u)
        ups = kept
    if len(ups) < 2:
        raise TooFewCycles(f"the glottal area rises through half its range {len(ups)} time(s): "
                         "no whole glottal cycle in the recording")
    ups_arr = np.asarray(ups)
    period = float(np.median(np.diff(ups_arr)))          # frames
    idx = np.arange(a.size, dtype=float)
    knots_t = np.concatenate([[ups_arr[0] - period * (1 + ups_arr[0] // period)], ups_arr,
                              [ups_arr[-1] + period * (1 + (a.size - ups_arr[-1]) // period)]])
    knots_p = np.concatenate([[-(1 + ups_arr[0] // period)], np.arange(len(ups_arr), dtype=float),
                              [len(ups_arr) - 1 + 1 + (a.size - ups_arr[-1]) // period]])
    phase = np.interp(idx, knots_t, knots_p)
    cycle = np.floor(phase).astype(int)
    cycle[(idx < ups_arr[0]) | (idx >= ups_arr[-1])] = -1
    slope = np.gradient(_smooth(level, max(1, int(round(period / 20)))))
    name = np.where(slope > 0, 0, 2)
    name[level >= OPEN_LEVEL] = 1
    name[level < CLOSED_LEVEL] = 3
    return Cycles(1.0 / (period * dt), phase, cycle, name.astype(int))


def whole_cycles(area: np.ndarray, dt: float, f0_hz: float | None = None) -> int:
    """Whole glottal cycles :func:`glottal_cycles` counts in ``area`` (0 when it finds none or the area is flat)."""
    try:
        return glottal_cycles(area, dt, f0_hz).n_cycles
    except TooFewCycles:
        return 0


def too_few_advice(area: np.ndarray, dt: float, f0_hz: float | None = None) -> str:
    """What to do when the glottal area holds too few whole cycles: record longer, unless the subglottal
    pressure says the frames span at least two more whole cycles than the area shows (the gap was missed).

    area : (F,) glottal area per frame, mm^2.  dt : frame interval, s.  f0_hz : the subglottal pressure's f0
    (``/sync``), Hz, or None/NaN (then both are said).
    """
    a = np.asarray(area, dtype=float)
    found = int(np.count_nonzero(a > 0))
    gap = (f"the glottal gap was found in {found} of {a.size} frames, and a slit narrower than about two pixels is "
           "not found (check the gap `vfcli report` outlines; more pixels per mm resolve it, a higher flow.threshold "
           "(counts) finds it but too wide)")
    longer = "record longer (more glottal cycles around the run's window)"
    if f0_hz is None or not np.isfinite(f0_hz) or f0_hz <= 0:
        return f"{longer}, or, if the recording does hold them, {gap}"
    spans = a.size * dt * float(f0_hz)              # cycles of the pressure in these frames
    counted = whole_cycles(a, dt, f0_hz)
    if np.floor(spans) - 1 >= counted + 2:          # at least floor(spans) - 1 of them are whole
        return (f"the subglottal pressure (f0 {f0_hz:.4g} Hz) spans {spans:.1f} cycles in these {a.size} frames "
                f"and the glottal area shows {counted} whole one(s): {gap}")
    return longer


#: whole glottal cycles on each side of the window the noise floor uses at most (bounds time and memory)
MAX_FLOOR_CYCLES = 32


def floor_frames(cycles: Cycles, window: np.ndarray, max_cycles: int = MAX_FLOOR_CYCLES) -> slice:
    """The frames the noise floor uses: whole cycles from ``max_cycles`` before the window's to
    ``max_cycles`` after it (cut at integer phases, so the cycles inside stay whole)."""
    first = np.floor(cycles.phase[window[0]]) - max_cycles
    last = np.floor(cycles.phase[window[-1]]) + max_cycles + 1
    inside = np.flatnonzero((cycles.phase >= first) & (cycles.phase < last))
    return slice(int(inside[0]), int(inside[-1]) + 1)


def floor_cycles(cycles: Cycles, window: np.ndarray) -> tuple[slice, Cycles, np.ndarray]:
    """(frames, their cycles, (frames,) bool the window's among them): what the noise floor is measured on
    (:func:`floor_frames`) for the window's frames ``window``."""
    if window[-1] >= len(cycles.phase):
        raise ValueError(f"window frames {window[0]}..{window[-1]} run past the recording ({len(cycles.phase)})")
    span = floor_frames(cycles, window)
    around = Cycles(cycles.f0_hz, cycles.phase[span], cycles.cycle[span], cycles.phase_name[span])
    exclude = np.zeros(span.stop - span.start, bool)
    exclude[window - span.start] = True
    return span, around, exclude


def floor_cycle_ids(cycles: Cycles, exclude: np.ndarray | None = None) -> np.ndarray:
    """(n,) the whole cycles the noise floor is measured on: those with no ``exclude`` frame while at
    least 3 remain, else all of them (see :func:`cycle_floor`).

    Raises
    ------
    TooFewCycles
        Fewer than 2 whole cycles."""
    ids = np.unique(cycles.cycle[cycles.cycle >= 0])
    if exclude is not None:
        hit = np.unique(cycles.cycle[np.asarray(exclude, bool) & (cycles.cycle >= 0)])
        kept = np.setdiff1d(ids, hit)
        if len(kept) >= 3:
            ids = kept
    if len(ids) < 2:
        raise TooFewCycles(f"{len(ids)} whole glottal cycle(s) in the recording: the noise floor needs at least 2")
    return ids
