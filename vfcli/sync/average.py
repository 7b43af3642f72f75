"""Phase-locked averaging: epoch times of given phases, and cycle-averaged velocity.

Pure numpy helpers of :mod:`vfcli.sync.align`: invert an epoch's monotonic phase (sampled at the
LDV samples) at target phases in every cycle, interpolate the velocity there (Keys cubic
convolution, a = -1/2) and average over the cycles.
"""
from __future__ import annotations

import numpy as np


def matched_times(
    epoch_phase: np.ndarray, fs: float, target_phase: np.ndarray, margin: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Epoch times at which a monotonic phase equals each target phase modulo 1.

    Parameters
    ----------
    epoch_phase : (S,) float
        Epoch phase at its samples (sample j at j / fs s), cycles, increasing.
    target_phase : (M,) float
        Phases to find (only their value mod 1 matters), cycles.
    margin : int
        Samples to keep clear of the ends (for the interpolation kernel).

    Returns
    -------
    times : (M, C) float
        Epoch time (s) of the match in each of the C candidate cycles.
    valid : (M, C) bool
        Match lies inside the epoch (away from its ends by ``margin`` samples).
    """
    ph = np.asarray(epoch_phase, dtype=float)
    frac = np.mod(np.asarray(target_phase, dtype=float), 1.0)
    k_first = np.floor(ph[0])
    k_last = np.floor(ph[-1])
    cycles = np.arange(k_first, k_last + 1)
    targets = cycles[None, :] + frac[:, None]
    # start each cycle's search from a straight line between the cycle's boundaries
    bounds = np.interp(np.append(cycles, k_last + 1.0), ph, np.arange(ph.size, dtype=float))
    start = bounds[None, :-1] + frac[:, None] * np.diff(bounds)[None, :]
    samples = invert_monotonic(ph, targets, start=start)
    valid = (targets >= ph[margin]) & (targets <= ph[-1 - margin])
    return samples / fs, valid


def invert_monotonic(ph: np.ndarray, targets: np.ndarray, n_iter: int = 6,
                     start: np.ndarray | None = None) -> np.ndarray:
    """Fractional sample index where the increasing sequence ``ph`` (S,) equals ``targets``.

    Piecewise-linear inverse (same as ``np.interp(targets, ph, arange(S))``, clamped at the
    ends), found by Newton steps on the bracketing sample from ``start`` (default: a
    straight line through the ends): O(1) per target for a nearly linear phase.
    """
    n = ph.size
    if start is None:
        slope = (ph[-1] - ph[0]) / (n - 1)
        start = (targets - ph[0]) / slope
    x = np.clip(start, 0.0, n - 1.0)
    for _ in range(n_iter):
        i = np.clip(np.floor(x).astype(np.int64), 0, n - 2)
        d = ph[i + 1] - ph[i]
        x_new = np.clip(i + (targets - ph[i]) / d, 0.0, n - 1.0)
        if np.array_equal(np.clip(np.floor(x_new).astype(np.int64), 0, n - 2), i):
            return x_new
        x = x_new
    # fall back for strongly non-linear phases
    return np.interp(targets, ph, np.arange(n, dtype=float))


def _keys_cubic(v: np.ndarray, x: np.ndarray, periodic: bool = False) -> np.ndarray:
    """Keys (a = -0.5) cubic convolution of samples v (S,) at fractional indices x (any).

    ``periodic``: v is one period (index S is index 0); otherwise indices are clamped.
    """
    i = np.floor(x).astype(int)
    s = x - i
    if periodic:
        n = v.size
        i = np.mod(i, n)
        vm, v0, v1, v2 = v[i - 1], v[i], v[(i + 1) % n], v[(i + 2) % n]
        return v0 + 0.5 * s * (v1 - vm + s * (2.0 * vm - 5.0 * v0 + 4.0 * v1 - v2
                                              + s * (3.0 * (v0 - v1) + v2 - vm)))
    i = np.clip(i, 1, v.size - 3)
    vm, v0, v1, v2 = v[i - 1], v[i], v[i + 1], v[i + 2]
    return v0 + 0.5 * s * (v1 - vm + s * (2.0 * vm - 5.0 * v0 + 4.0 * v1 - v2
                                          + s * (3.0 * (v0 - v1) + v2 - vm)))


def phase_average_at(
    velocity: np.ndarray, epoch_phase: np.ndarray, fs: float, target_phase: np.ndarray,
    n_grid: int | None = None,
) -> tuple[np.ndarray, int]:
    """Cycle-averaged velocity at given phases.

    The velocity is interpolated (Keys cubic convolution) at ``n_grid`` equally spaced
    phases in every cycle of the epoch and averaged over the cycles; the averaged cycle is
    then interpolated periodically (Keys cubic) at the target phases. With the default grid
    (a power of two >= the samples per cycle) the grid is at least as fine as the samples.
    ``n_grid=0`` skips the grid and averages directly at every target phase (exact, slower).

    Parameters
    ----------
    velocity : (S,) float
        Epoch velocity, at ``fs`` Hz (NaN samples are skipped).
    epoch_phase : (S,) float
        Epoch phase at the samples, cycles.
    target_phase : (M,) float
        Phases (mod 1), cycles.
    n_grid : int, optional
        Phase grid points per cycle.

    Returns
    -------
    mean : (M,) float
        Mean over the cycles of the velocity at each phase (NaN where no finite sample).
    n_cycles : int
        Full cycles in the epoch.
    """
    v = np.asarray(velocity, dtype=float)
    samples_per_cycle = (epoch_phase.size - 1) / max(epoch_phase[-1] - epoch_phase[0], 1e-9)
    if n_grid is None:
        n_grid = int(2 ** np.ceil(np.log2(max(samples_per_cycle, 64.0))))
    direct = n_grid == 0
    phases = np.asarray(target_phase, dtype=float) if direct else np.arange(n_grid) / n_grid
    times, valid = matched_times(epoch_phase, fs, phases)
    vals = np.where(valid, _keys_cubic(v, times * fs), np.nan)
    count = np.sum(np.isfinite(vals), axis=1)
    with np.errstate(invalid="ignore"):
        mean = np.where(count > 0, np.nansum(vals, axis=1) / np.maximum(count, 1), np.nan)
    if not direct:
        x = np.mod(np.asarray(target_phase, dtype=float), 1.0) * n_grid
        mean = _keys_cubic(mean, x, periodic=True)
    n_cyc = int(np.floor(epoch_phase[-1 - 2]) - np.ceil(epoch_phase[2]))
    return mean, max(n_cyc, 0)
