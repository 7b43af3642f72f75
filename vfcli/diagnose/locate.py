"""Locate: the residual decomposed by where, when, component and harmonic, judged against noise.

The residual of a fitted window, averaged per frame over each region (where), is reduced to

* its mean over each phase of the glottal cycle (when: :data:`vfcli.diagnose.cycles.PHASE_NAMES`),
* its cosine and sine coefficients on each harmonic k of f0 (least squares over the window,
  :mod:`vfcli.diagnose.harmonics`),

per component.  Each statistic is judged against the noise floor (:mod:`vfcli.diagnose.noise`):
the window's statistic carries the variance of one cycle's, scaled by how much of the cycle
the window holds (``frames per phase in a cycle / frames in the window``; the least-squares
factor of the window over one cycle's for the harmonics), plus the known vibrometer part.
Under the null (the residual is noise) a phase mean m gives ``m^2 / var ~ F(1, nu)`` and a
harmonic ``(a^2 + b^2) / (2 var) ~ F(2, nu)``, nu the cycle-based degrees of freedom
(Welch-Satterthwaite when a known part is added).  The p-value of every part is reported with
its Holm-adjusted value over all parts (family-wise false-alarm rate ``alpha``), and
``ratio = sqrt(F)``: the residual's size in units of the noise floor.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import f as f_dist

from vfcli.diagnose.cycles import PHASE_NAMES
from vfcli.diagnose.harmonics import fit_harmonics
from vfcli.diagnose.noise import NoiseFloor, _quiet

#: effective degrees of freedom standing for "known" (no estimation error)
_INF_DOF = 1e6


@dataclass(frozen=True)
class Decomposition:
    """The decomposition of one residual family (motion or gap) over R regions and C components.

    bin_mean, bin_sd, bin_dof, bin_p : (R, C, 4) mean residual per phase of the cycle, the noise
        floor's standard deviation of that mean, its degrees of freedom and the p-value.
    harm_amp, harm_phase, harm_sd, harm_dof, harm_p : (R, C, K) amplitude A_k (units of the residual) and
        phase theta_k (rad) of harmonic k (residual ~ A_k cos(2 pi k phi + theta_k)), the standard deviation of
        a cosine (or sine) coefficient, degrees of freedom and p-value.
    region_names, component_names : (R,), (C,) text.  units : of the residual.
    window_cycles : glottal cycles the window spans (harmonics are tested from :data:`MIN_HARMONIC_CYCLES`).
    """

    bin_mean: np.ndarray
    bin_sd: np.ndarray
    bin_dof: np.ndarray
    bin_p: np.ndarray
    harm_amp: np.ndarray
    harm_phase: np.ndarray
    harm_sd: np.ndarray
    harm_dof: np.ndarray
    harm_p: np.ndarray
    region_names: tuple[str, ...]
    component_names: tuple[str, ...]
    units: str
    window_cycles: float = float("nan")

    @property
    def bin_ratio(self) -> np.ndarray:
        """(R, C, 4) |mean| / sd."""
        with _quiet():
            return np.abs(self.bin_mean) / self.bin_sd

    @property
    def harm_ratio(self) -> np.ndarray:
        """(R, C, K) amplitude / (sqrt 2 sd) = sqrt(F)."""
        with _quiet():
            return self.harm_amp / (np.sqrt(2.0) * self.harm_sd)


def _satterthwaite(cycle_var: np.ndarray, cycle_dof: np.ndarray, known_var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    total = cycle_var + known_var
    with _quiet():
        dof = np.where(cycle_var > 0, total ** 2 / (cycle_var ** 2 / cycle_dof), _INF_DOF)
    return total, np.minimum(dof, _INF_DOF)


#: the glottal cycles a window must span for its residual's harmonics of f0 to be tested: over a part of a cycle
#: the harmonics are nearly collinear (a 12-frame window of 0.14 cycle gave a 2nd harmonic of 2.8e6 mm/s, where the
#: measured speed peaked at 1218 mm/s), so their amplitudes say nothing about the residual's frequency content
MIN_HARMONIC_CYCLES = 0.9


def decompose(residual: np.ndarray, phase: np.ndarray, phase_name: np.ndarray, floor: NoiseFloor,
              region_names: tuple[str, ...], component_names: tuple[str, ...], units: str) -> Decomposition:
    """Decompose a window's region-mean residual and test every part against ``floor`` (module docstring).

    Parameters
    ----------
    residual : (F, R, C) measured minus simulated, region mean per frame (NaN: region unseen).
    phase : (F,) cycle phase of each frame, cycles.  phase_name : (F,) index into PHASE_NAMES.
    floor : the noise floor of these R regions and C components (same K harmonics).
    """
    y = np.asarray(residual, dtype=float)
    f, r, c = y.shape
    nb, k = len(PHASE_NAMES), floor.harm_var.shape[-1]
    bin_mean = np.full((r, c, nb), np.nan)
    bin_var = np.full((r, c, nb), np.nan)
    for b in range(nb):
        inb = np.asarray(phase_name) == b
        if not inb.any():
            continue
        with _quiet():
            bin_mean[..., b] = np.nanmean(y[inb], axis=0)
        m_w = np.sum(np.isfinite(y[inb]), axis=0)                               # (R, C) frames seen
        with _quiet():
            bin_var[..., b] = floor.bin_var[..., b] * floor.frames_per_bin[b] / np.where(m_w > 0, m_w, np.nan)
    bin_total, bin_dof = _satterthwaite(bin_var, floor.bin_dof, floor.known_bin_var)
    a, s, scale = fit_harmonics(np.asarray(phase, float) - np.floor(np.nanmin(phase)), y, k)   # (K, R, C)
    a, s, scale = (np.moveaxis(v, 0, -1) for v in (a, s, scale))                  # (R, C, K)
    ratio = scale / floor.harm_scale[None, None, :]
    harm_total, harm_dof = _satterthwaite(floor.harm_var * ratio, floor.harm_dof,
                                          floor.known_harm_var * np.maximum(ratio, 1.0))
    with _quiet():
        f_bin = bin_mean ** 2 / bin_total
        f_harm = (a ** 2 + s ** 2) / (2.0 * harm_total)
        bin_p = f_dist.sf(f_bin, 1, bin_dof)
        harm_p = f_dist.sf(f_harm, 2, harm_dof)
    ph = np.asarray(phase, float)
    steps = np.diff(ph)
    span = float(np.nanmax(ph) - np.nanmin(ph) + (np.nanmedian(steps) if steps.size else 0.0))
    bad_b = ~(np.isfinite(f_bin) & (bin_dof > 0))
    bad_h = ~(np.isfinite(f_harm) & (harm_dof > 0)) | (span < MIN_HARMONIC_CYCLES)
    bin_p[bad_b] = np.nan
    harm_p[bad_h] = np.nan
    return Decomposition(bin_mean, np.sqrt(bin_total), bin_dof, bin_p, np.hypot(a, s), np.arctan2(-s, a),
                         np.sqrt(harm_total), harm_dof, harm_p, tuple(region_names), tuple(component_names), units,
                         span)


@dataclass(frozen=True)
class Hotspot:
    """One part of the residual.

    family : "motion" or "gap".  kind : "phase" (mean over a phase of the cycle) or "harmonic".
    region, component : indices into the family's names.  index : phase index or harmonic number k (1-based).
    size : |mean| or amplitude (units of the family).  ratio : size in units of the noise floor (sqrt F).
    p_value : the part's p-value.  p_adjusted : Holm-adjusted over every part of every family.
    peak_phase : for a harmonic, the phase (index) whose mean residual is largest in units of the floor.
    """

    family: str
    kind: str
    region: int
    component: int
    index: int
    size: float
    ratio: float
    p_value: float
    p_adjusted: float
    peak_phase: int = -1


@dataclass(frozen=True)
class Located:
    """What Locate found.

    families : {"motion": Decomposition, "gap": Decomposition} (a family may be absent).
    hotspots : every tested part, ranked (:func:`rank_hotspots`).
    alpha : family-wise false-alarm rate the Holm adjustment controls.
    f0_hz, n_cycles : the window's fundamental and the whole cycles of the noise floor.
    """

    families: dict[str, Decomposition]
    hotspots: list[Hotspot]
    alpha: float
    f0_hz: float
    n_cycles: int

    @property
    def significant(self) -> list[Hotspot]:
        """The hotspots above the noise floor at the family-wise level alpha."""
        return [h for h in self.hotspots if h.p_adjusted <= self.alpha]


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error), same shape as p (NaN stays NaN)."""
    p = np.asarray(p, dtype=float)
    out = np.full(p.shape, np.nan)
    ok = np.isfinite(p)
    q = p[ok]
    m = q.size
    if not m:
        return out
    order = np.argsort(q)
    adj = np.maximum.accumulate((m - np.arange(m)) * q[order])
    res = np.empty(m)
    res[order] = np.minimum(adj, 1.0)
    out[ok] = res
    return out


def rank_hotspots(families: dict[str, Decomposition], alpha: float) -> list[Hotspot]:
    """Every part of every family as a :class:`Hotspot`, Holm-adjusted over all: first the parts above the
    noise floor at the family-wise level ``alpha``, largest ratio first, then the others by p-value."""
    rows = []
    for fam, d in families.items():
        br, hr = d.bin_ratio, d.harm_ratio
        for (ri, ci, b), p in np.ndenumerate(d.bin_p):
            if np.isfinite(p):
                rows.append([fam, "phase", ri, ci, b, abs(d.bin_mean[ri, ci, b]), br[ri, ci, b], p, -1])
        for (ri, ci, kk), p in np.ndenumerate(d.harm_p):
            if np.isfinite(p):
                peak = int(np.nanargmax(br[ri, ci])) if np.isfinite(br[ri, ci]).any() else -1
                rows.append([fam, "harmonic", ri, ci, kk + 1, d.harm_amp[ri, ci, kk], hr[ri, ci, kk], p, peak])
    if not rows:
        return []
    adj = holm(np.array([r[7] for r in rows]))
    spots = [Hotspot(r[0], r[1], int(r[2]), int(r[3]), int(r[4]), float(r[5]), float(r[6]), float(r[7]),
                     float(a), int(r[8])) for r, a in zip(rows, adj)]
    spots.sort(key=lambda h: (0, -h.ratio, h.p_value) if h.p_adjusted <= alpha else (1, h.p_value, -h.ratio))
    return spots
