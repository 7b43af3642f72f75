"""Flag LDV scan points whose velocity signal drops out (pure numpy).

Speckle dropout of a laser vibrometer shows as isolated spikes (the decoder
loses the carrier and outputs a large jump) or as flat runs (the output
holds a value or falls to zero). Points are flagged, never deleted.

Thresholds are robust (median / MAD), per point, so they scale with each
point's own amplitude and noise and are not tuned to any one file:

* spike: a sample whose deviation from the point's median exceeds
  ``amp_k`` robust standard deviations of the signal (sigma = 1.4826 MAD)
  **and** whose jump from a neighbour exceeds ``jump_k`` robust standard
  deviations of the first difference. A pure sinusoid peaks at about 1 sigma,
  Gaussian noise over 10^4-10^5 samples at about 4.5 sigma, so defaults 6 and
  10 leave clean signals unflagged while dropout spikes (tens of sigma) are caught.
* flat run: at least ``flat_s`` seconds (default 1 ms, at least 5 samples) of
  consecutive samples that do not change by more than ``1e-9`` sigma. Real
  vocal-fold motion (>= 50 Hz) never rests that long within a quantisation
  step at LDV sampling rates; a held or zeroed output does.
* dead: the whole signal is constant (MAD and spread zero).
"""
from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826


def _longest_true_run(mask: np.ndarray) -> tuple[int, int]:
    """(length, start) of the longest run of True in a 1-D bool array."""
    if not mask.any():
        return 0, 0
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    starts, stops = edges[0::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(stops[k] - starts[k]), int(starts[k])


def detect_dropouts(
    velocity: np.ndarray,
    fs: float,
    amp_k: float = 6.0,
    jump_k: float = 10.0,
    flat_s: float = 1e-3,
) -> tuple[np.ndarray, list[str]]:
    """Flag scan points whose signal shows dropout spikes or flat runs.

    Parameters
    ----------
    velocity : (P, S) float
        Velocity per point, any unit.
    fs : float
        Sampling rate, Hz.
    amp_k, jump_k : float
        Spike thresholds in robust standard deviations (see module docstring).
    flat_s : float
        Shortest flat run flagged, s (and at least 5 samples).

    Returns
    -------
    flags : (P,) bool
        True where the point's signal drops out.
    reasons : list of P str
        Why each point was flagged ("" when not flagged).
    """
    v = np.asarray(velocity, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"velocity must be (P, S), got shape {v.shape}")
    n_pts, n_s = v.shape
    flags = np.zeros(n_pts, bool)
    reasons = [""] * n_pts
    if n_s < 3:
        return flags, reasons
    med = np.median(v, axis=1, keepdims=True)
    dev = np.abs(v - med)
    sig = MAD_TO_SIGMA * np.median(dev, axis=1, keepdims=True)
    dv = np.diff(v, axis=1)
    dmed = np.median(dv, axis=1, keepdims=True)
    dsig = MAD_TO_SIGMA * np.median(np.abs(dv - dmed), axis=1, keepdims=True)
    tiny = np.finfo(float).tiny
    with np.errstate(over="ignore"):  # a frozen (zero-MAD) signal: z = inf is the intended "huge"
        amp_z = dev / np.maximum(sig, tiny)
        jz = np.abs(dv - dmed) / np.maximum(dsig, tiny)
    jump_at = np.zeros_like(v, dtype=bool)          # sample touches a big jump
    big = jz > jump_k
    jump_at[:, :-1] |= big
    jump_at[:, 1:] |= big
    spikes = (amp_z > amp_k) & jump_at & (sig > 0)
    spread = np.ptp(v, axis=1)
    still = np.abs(dv) <= 1e-9 * np.maximum(sig, np.maximum(spread[:, None], tiny))
    min_run = max(5, int(np.ceil(flat_s * fs)))
    for i in range(n_pts):
        why = []
        if spread[i] == 0:
            why.append("dead: constant signal")
        else:
            n_spk = int(spikes[i].sum())
            if n_spk:
                k = int(np.argmax(spikes[i]))
                why.append(f"{n_spk} spike sample(s) > {amp_k:g} robust sd and jump > "
                           f"{jump_k:g} robust sd (first at t = {k / fs:.6g} s)")
            run, start = _longest_true_run(still[i])
            if run + 1 >= min_run:
                why.append(f"flat run of {run + 1} samples ({(run + 1) / fs * 1e3:.3g} ms) at "
                           f"t = {start / fs:.6g} s")
        if why:
            flags[i] = True
            reasons[i] = "; ".join(why)
    return flags, reasons
