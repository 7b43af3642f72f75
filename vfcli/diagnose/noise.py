"""The noise floor of a residual, estimated from the recording itself.

Two sources, added as variances (:class:`NoiseFloor`):

* **cycle-to-cycle variation** (:func:`cycle_floor`): the measured signal, averaged over a
  region per frame, is cut into whole glottal cycles (:mod:`vfcli.diagnose.cycles`); in each
  cycle it is reduced to the same statistics Locate computes on the residual (mean per phase
  of the cycle; cosine and sine coefficient per harmonic of f0).  The periodic motion is the
  same in every cycle, so the scatter of these statistics across cycles is the noise a single
  cycle's statistic carries, with ``n_cycles - 1`` degrees of freedom (cosine and sine pooled:
  ``2 (n_cycles - 1)``).  The motion common to all cycles is removed first
  (:func:`periodic_template`), so that the frames' sampling of it does not count as noise.  Cycles are the units of replication: correlation within a cycle
  is allowed for.
* **the vibrometer's noise above the band of motion** (:func:`ldv_noise_density`,
  :func:`ldv_known_variance`): the vertical velocity of the field is the vibrometer's
  phase-averaged waveform, the same in every video cycle, so its noise does not show as
  cycle-to-cycle variation.  Its level is read from the raw records where the motion has no
  content (frequencies above max(fs / 4, 12 f0)): a white density P ((mm/s)^2/Hz) averaged
  over T = n_cycles / f0 s of record gives a cosine (or sine) coefficient of variance P / T and
  a mean over a phase interval of width w (cycles) of variance P / (2 T w); a region with n
  scan points averages n of them.  This part is treated as known (infinite degrees of freedom).
"""
from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.signal import welch

from vfcli.diagnose.cycles import PHASE_NAMES, Cycles, floor_cycle_ids
from vfcli.diagnose.harmonics import design, fit_harmonics


@dataclass(frozen=True)
class NoiseFloor:
    """Noise of one cycle's statistics, per region r and component c.

    bin_var : (R, C, 4) variance of one cycle's mean over a phase of the cycle (:data:`PHASE_NAMES`).
    bin_dof : (R, C, 4) its degrees of freedom (whole cycles - 1; 0: not estimable).
    frames_per_bin : (4,) mean number of frames per phase in one whole cycle.
    harm_var : (R, C, K) variance of one cycle's cosine or sine coefficient of harmonic k (pooled).
    harm_dof : (R, C, K) its degrees of freedom (2 (whole cycles - 1)).
    harm_scale : (K,) the one-cycle least-squares factor (:func:`vfcli.diagnose.harmonics.fit_harmonics`).
    known_bin_var, known_harm_var : (R, C, 4) and (R, C, K) known variance (vibrometer), added as is.
    n_cycles : whole cycles used.
    """

    bin_var: np.ndarray
    bin_dof: np.ndarray
    frames_per_bin: np.ndarray
    harm_var: np.ndarray
    harm_dof: np.ndarray
    harm_scale: np.ndarray
    known_bin_var: np.ndarray
    known_harm_var: np.ndarray
    n_cycles: int

    def with_known(self, known_bin_var: np.ndarray, known_harm_var: np.ndarray) -> "NoiseFloor":
        """The same floor with known variances (R, C, 4) and (R, C, K) added to the current ones."""
        return NoiseFloor(self.bin_var, self.bin_dof, self.frames_per_bin, self.harm_var, self.harm_dof,
                          self.harm_scale, self.known_bin_var + known_bin_var,
                          self.known_harm_var + known_harm_var, self.n_cycles)


def cycle_floor(series: np.ndarray, cycles: Cycles, n_harmonics: int,
                exclude: np.ndarray | None = None) -> NoiseFloor:
    """Cycle-to-cycle noise floor of a measured series (module docstring).

    Parameters
    ----------
    series : (F, R, C) measured values per frame, region and component (NaN: region unseen at that frame).
    cycles : the recording's cycles (F frames).
    n_harmonics : K.
    exclude : (F,) bool frames whose whole cycles are left out (the fitted window, so the floor is
        independent of the residual it judges), honoured while at least 3 whole cycles remain.

    Raises
    ------
    TooFewCycles
        Fewer than 2 whole cycles: no cycle-to-cycle variation can be measured.
    """
    y = np.asarray(series, dtype=float)
    f, r, c = y.shape
    if len(cycles.cycle) != f:
        raise ValueError(f"series has {f} frames, cycles {len(cycles.cycle)}")
    ids = floor_cycle_ids(cycles, exclude)
    nb, k = len(PHASE_NAMES), n_harmonics
    y = y - periodic_template(y, cycles, np.isin(cycles.cycle, ids))
    means = np.full((len(ids), r, c, nb), np.nan)
    counts = np.zeros((len(ids), nb))
    cos = np.full((len(ids), k, r, c), np.nan)
    sin = np.full((len(ids), k, r, c), np.nan)
    scales = np.full((len(ids), k), np.nan)
    for i, cyc in enumerate(ids):
        sel = cycles.cycle == cyc
        yc = y[sel]
        names = cycles.phase_name[sel]
        for b in range(nb):
            inb = names == b
            counts[i, b] = inb.sum()
            if inb.any():
                with _quiet():
                    means[i, ..., b] = np.nanmean(yc[inb], axis=0)
        phase = cycles.phase[sel] - cyc
        a, s, sc = fit_harmonics(phase, yc, k)
        cos[i], sin[i] = a, s
        scales[i] = np.nanmedian(sc.reshape(k, -1), axis=1) if np.isfinite(sc).any() else np.nan
    n_bin = np.sum(np.isfinite(means), axis=0)
    with _quiet():
        bin_var = np.nanvar(means, axis=0, ddof=1)
        dev = np.concatenate([cos - np.nanmean(cos, axis=0), sin - np.nanmean(sin, axis=0)], axis=0)
        n_h = np.sum(np.isfinite(cos), axis=0)                                   # (K, R, C)
        harm_var = np.nansum(dev ** 2, axis=0) / np.maximum(2 * (n_h - 1), 1)
    bin_dof = np.maximum(n_bin - 1, 0).astype(float)
    harm_dof = np.maximum(2 * (n_h - 1), 0).astype(float)
    bin_var = np.where(bin_dof > 0, bin_var, np.nan)
    harm_var = np.where(harm_dof > 0, harm_var, np.nan)
    return NoiseFloor(bin_var, bin_dof, counts.mean(axis=0), np.moveaxis(harm_var, 0, -1),
                      np.moveaxis(harm_dof, 0, -1), np.nanmedian(scales, axis=0),
                      np.zeros((r, c, nb)), np.zeros((r, c, k)), int(len(ids)))


def periodic_template(y: np.ndarray, cycles: Cycles, frames: np.ndarray) -> np.ndarray:
    """(F, R, C) the motion common to every cycle: a Fourier series in the cycle phase fitted to ``frames``.

    Removing it leaves the cycle-to-cycle variation unchanged (it is the same in every cycle) but
    removes the scatter a strongly varying motion gives to a phase mean when the frames fall at
    other phases in each cycle.  Harmonics up to a third of the frames per cycle (at most 30).
    """
    per_cycle = np.sum(frames) / max(len(np.unique(cycles.cycle[frames])), 1)
    k = int(np.clip(per_cycle // 3, 1, 30))
    a, b, _ = fit_harmonics(cycles.phase[frames], y[frames], k)
    if not np.isfinite(a).any():
        return np.zeros_like(y)
    x = design(cycles.phase, k)[:, 1:]                                        # (F, 2K)
    coef = np.concatenate([np.nan_to_num(a), np.nan_to_num(b)], axis=0)      # (2K, R, C)
    return np.einsum("fk,k...->f...", x, coef)


@contextmanager
def _quiet():
    """numpy's warnings about all-NaN slices, silenced (NaN is the intended answer)."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def ldv_noise_density(velocity: np.ndarray, fs_hz: float, f0_hz: float, used: np.ndarray | None = None) -> float:
    """White noise density of the vibrometer records above the band of motion, (mm/s)^2/Hz (one-sided).

    velocity : (P, S) raw records, mm/s.  fs_hz : sampling rate.  f0_hz : fundamental.
    used : (P,) bool points to use (aligned, no dropout); default all.
    Median over points of the mean Welch density above max(fs / 4, 12 f0); NaN when that band is empty.
    """
    v = np.asarray(velocity, dtype=float)
    if used is not None:
        v = v[np.asarray(used, bool)]
    v = v[np.all(np.isfinite(v), axis=1)] if v.size else v
    if v.shape[0] == 0 or v.shape[1] < 64:
        return float("nan")
    f, p = welch(v, fs=fs_hz, nperseg=min(1024, v.shape[1]), axis=-1)
    band = f > max(fs_hz / 4.0, 12.0 * f0_hz)
    if not band.any():
        return float("nan")
    return float(np.median(p[:, band].mean(axis=1)))


def ldv_known_variance(density: float, record_s: float, points_per_region: np.ndarray, component: int,
                       n_components: int, bin_width_cycles: np.ndarray, n_harmonics: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Known variance the vibrometer's noise adds to the statistics of one component (module docstring).

    density : P, (mm/s)^2/Hz.  record_s : T, seconds of record averaged per point (n_cycles / f0).
    points_per_region : (R,) scan points on each region (0 counts as 1: the spline extrapolates the nearest).
    component : index of the vertical component.  bin_width_cycles : (4,) width of each phase, cycles.

    Returns (R, C, 4) and (R, C, K) variances, zero outside ``component``; zero when density is NaN.
    """
    n = np.maximum(np.asarray(points_per_region, float), 1.0)
    r = len(n)
    bins = np.zeros((r, n_components, len(bin_width_cycles)))
    harm = np.zeros((r, n_components, n_harmonics))
    if not (np.isfinite(density) and record_s > 0):
        return bins, harm
    w = np.maximum(np.asarray(bin_width_cycles, float), 1e-3)
    bins[:, component, :] = density / (2.0 * record_s * w[None, :]) / n[:, None]
    harm[:, component, :] = density / record_s / n[:, None]
    return bins, harm
