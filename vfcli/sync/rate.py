"""Is the vibrometer's stated sampling rate the rate its samples were taken at?

A scan file states its sampling interval (UFF ``abscissa_inc``, CSV ``# fs``, MAT ``fs``). A
wrong but plausible rate (25 kHz written for 50 kHz) passes every range check, and then every
epoch's f0 comes out off by the same factor: sync rejects all points ("f0 ... is -50 % from the
video's") and the recording is lost without a word about why. What fixes the true rate is the
pressure recorded beside each vibrometer point: its fundamental, measured on the vibrometer's
time base, must match the fundamental of the pressure recorded with the video (sync's premise:
one sustained phonation). A rate off by a factor ``k`` moves the apparent f0 by ``k``, so

    implied rate = stated rate * f0_video / f0_reference.

:func:`check_ldv_rate` refuses a scan whose points agree among themselves on an f0 that is
further from the video's than sync would accept (``sync.max_drift``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.errors import InputDataError
from vfcli.sync.f0 import coarse_f0

#: Epochs whose reference f0 is measured (evenly spread over the scan); enough for a robust median.
N_PROBE = 32
#: The f0 search range is widened by this factor both ways, so that a rate off by up to this
#: factor still gives a measurable apparent f0 (rates further off fail the range checks of
#: vfcli/io/limits.py or the search finds no consistent f0, which sync reports per point).
WIDEN = 4.0
#: Fewest cycles of the apparent f0 an epoch must hold for its f0 to count (a count of cycles does not
#: depend on the stated rate; shorter epochs give no reliable f0, and sync flags them "too short").
MIN_CYCLES = 2.0
#: Fraction of the probed epochs that must agree (within ``max_drift``) on the apparent f0.
MIN_AGREEING = 0.5
#: Largest fraction of the probed epochs whose f0 may match the video's for the rate to be called
#: wrong: when more match, the stated rate explains them and the others are sync's to reject.
MAX_MATCHING = 0.1


def apparent_reference_f0(reference: np.ndarray, fs: float, f_range: tuple[float, float]) -> np.ndarray:
    """f0 of the reference channels of up to :data:`N_PROBE` epochs at the stated rate, Hz.

    Parameters
    ----------
    reference : (P, S) float
        Reference pressure of each epoch (any unit), sampled at ``fs`` Hz.
    fs : float
        Stated sampling rate, Hz.
    f_range : (2,) float
        f0 search range, Hz (widened by :data:`WIDEN` both ways, capped below Nyquist).

    Returns
    -------
    (n,) float
        Apparent f0 of each probed epoch with a finite estimate, Hz (empty when none has).
    """
    ref = np.atleast_2d(np.asarray(reference, dtype=float))
    rows = np.unique(np.linspace(0, ref.shape[0] - 1, min(N_PROBE, ref.shape[0])).round().astype(int))
    ref = ref[rows]
    ref = ref[np.all(np.isfinite(ref), axis=1)]
    lo, hi = f_range[0] / WIDEN, min(f_range[1] * WIDEN, 0.45 * fs)
    if ref.shape[0] == 0 or ref.shape[1] < 8 or not lo < hi:
        return np.zeros(0)
    f0, _ = coarse_f0(ref, fs, (lo, hi))
    return f0[np.isfinite(f0)]


def scan_f0(reference: np.ndarray, fs: float, f_range: tuple[float, float], max_drift: float) -> float | None:
    """The f0 the scan's reference channels agree on at the stated rate, Hz (None: no agreement).

    The median apparent f0 of the probed epochs (:func:`apparent_reference_f0`) when at least
    :data:`MIN_AGREEING` of them lie within ``max_drift`` of it and the epochs hold at least
    :data:`MIN_CYCLES` cycles of it.
    """
    f0s = apparent_reference_f0(reference, fs, f_range)
    if f0s.size == 0:
        return None
    med = float(np.median(f0s))
    if np.mean(np.abs(f0s / med - 1.0) <= max_drift) < MIN_AGREEING:
        return None
    if np.asarray(reference).shape[-1] / fs * med < MIN_CYCLES:
        return None
    return med


def harmonic_r2(p: np.ndarray, fs: float, f0: float, n_harmonics: int) -> float:
    """Share of a signal's variance (after a quadratic baseline) that harmonics of ``f0`` explain, in [0, 1].

    Parameters
    ----------
    p : (S,) float, any unit, sampled at ``fs`` Hz.  f0 : Hz.  n_harmonics : harmonics fitted
        (capped below 0.45 fs).

    Returns
    -------
    float
        R^2 of the least-squares fit of ``sum_h a_h cos(2 pi h f0 t) + b_h sin(...)`` to the
        detrended signal (0 for a constant signal or an f0 that is not finite and positive).
    """
    y = np.asarray(p, dtype=float)
    t = np.linspace(-1.0, 1.0, y.size)
    base = np.column_stack([np.ones_like(t), t, t * t])
    y = y - base @ np.linalg.lstsq(base, y, rcond=None)[0]
    total = float(y @ y)
    n_h = min(int(n_harmonics), int(0.45 * fs / f0)) if np.isfinite(f0) and f0 > 0 else 0
    if total <= 0 or n_h < 1:
        return 0.0
    ts = np.arange(y.size) / fs
    arg = 2 * np.pi * f0 * np.outer(ts, np.arange(1, n_h + 1))
    a = np.column_stack([base, np.cos(arg), np.sin(arg)])
    resid = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
    return float(np.clip(1.0 - (resid @ resid) / total, 0.0, 1.0))


#: The scan's f0 is taken for the video's when its harmonics leave less than this share of the
#: residual variance that the harmonics of the video's own estimate leave (see
#: :func:`scan_explains_video`).
BETTER_RESIDUAL = 0.5


def scan_explains_video(video_pressure: np.ndarray, fs: float, f0_video: float | None, f0_scan: float,
                        n_harmonics: int) -> bool:
    """The scan's f0 explains the video's pressure clearly better than the video's own f0 estimate.

    A video pressure of one or two cycles gives no reliable f0 of its own (the harmonic-sum
    estimate wants about 4 cycles, vfcli/sync/f0.py): 12 ms videos (1.4 cycles at 120 Hz) of
    widened phantoms gave 361 Hz (3 x 120) and 52.5 Hz. The harmonics of the true f0 explain the
    record; those of a harmonic (3 f0) do not. A wrong sampling rate of the scan instead makes the
    scan's apparent f0 a fraction (or multiple) of the true one: a sub-harmonic explains the video no
    better than the video's own right estimate, a multiple worse, so the rate check still applies.

    Returns
    -------
    bool
        ``harmonic_r2(scan f0) >= 0.5`` and its residual share is below :data:`BETTER_RESIDUAL` times the
        video estimate's (any share when the video gave no estimate, ``f0_video`` None).
    """
    r2_scan = harmonic_r2(video_pressure, fs, f0_scan, n_harmonics)
    if r2_scan < 0.5:
        return False
    if f0_video is None:
        return True
    r2_own = harmonic_r2(video_pressure, fs, f0_video, n_harmonics)
    return (1.0 - r2_scan) < BETTER_RESIDUAL * (1.0 - r2_own)


def check_ldv_rate(f0_video_hz: float, reference: np.ndarray, fs: float, *, f_range: tuple[float, float],
                   max_drift: float, source: str | Path) -> None:
    """Refuse a scan whose stated rate the pressure contradicts.

    Parameters
    ----------
    f0_video_hz : float
        f0 of the pressure recorded with the video, Hz.
    reference : (P, S) float
        The scan's reference pressure per epoch, sampled at the stated ``fs`` Hz.
    fs : float
        The scan's stated sampling rate, Hz.
    f_range : (2,) float
        sync's f0 search range, Hz.
    max_drift : float
        Largest relative f0 difference sync accepts (``sync.max_drift``).
    source : str or Path
        The scan file, named in the message.

    Raises
    ------
    InputDataError
        When the epochs hold at least :data:`MIN_CYCLES` cycles, at least :data:`MIN_AGREEING`
        of the probed epochs agree (within ``max_drift`` of their median) on an apparent f0 more
        than ``max_drift`` away from ``f0_video_hz``, and at most :data:`MAX_MATCHING` of them
        match the video's f0; the message names the stated rate and the rate the data imply.
    """
    if not (np.isfinite(f0_video_hz) and f0_video_hz > 0):
        return
    f0s = apparent_reference_f0(reference, fs, f_range)
    if f0s.size == 0:
        return
    med = float(np.median(f0s))
    agree = np.abs(f0s / med - 1.0) <= max_drift
    ratio = med / f0_video_hz
    matching = np.abs(f0s / f0_video_hz - 1.0) <= max_drift
    n_cycles = np.asarray(reference).shape[-1] / fs * med
    if (abs(ratio - 1.0) <= max_drift or agree.mean() < MIN_AGREEING or matching.mean() > MAX_MATCHING
            or n_cycles < MIN_CYCLES):
        return
    implied = fs / ratio
    raise InputDataError(
        f"the stated vibrometer sampling rate {fs:g} Hz contradicts the recording: at that rate the "
        f"reference pressure's f0 is {med:.1f} Hz ({int(agree.sum())} of {f0s.size} epochs probed) against "
        f"{f0_video_hz:.1f} Hz in the video's pressure: either the file's sampling rate is wrong (the data imply "
        f"{implied:.0f} Hz: correct it) or the scan and the video were phonated at different f0 (another operating "
        f"point, or files of different recordings), which one fit cannot join", source)
