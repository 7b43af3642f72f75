"""The bootstrap calibration (:mod:`vfcli.diagnose.calibrate`) on a fitted run and its recording.

Builds, on the rows of :meth:`vfcli.diagnose.candidate.Baseline.measure_linear` (motion rows, then
gap rows):

* the candidates' efficient score directions ``Omega A_c``, ``A_c`` the measurement columns of
  ``dU_c - dU/dx H_LL^-1 H_Lc`` (:func:`vfcli.diagnose.candidates.blocks.screen_run_columns`), Omega the
  objective's row weights (:func:`row_weights`: the motion term's exact weights, the gap term's
  quadratic majoriser at the baseline);
* the pool of noise stretches (:func:`pool_stretches`): the window moved by whole glottal cycles
  (k = +-1, +-2, ... cycles, disjoint from the window), the measured velocity read there at the
  window frames' phases (linear interpolation between frames) on the window's compared pixels, in
  model axes; the periodic template is their mean, each stretch's deviation from it is one
  realisation of the window's noise.  The gap rows get no resampled noise (their noise is left to
  the model-error part);
* the systematic residual ``s = r - (window's measured velocity - template)`` with the part the
  loads can make removed (one Gauss-Newton projection), then the part all candidates together
  explain removed and its energy (objective metric) restored to that of s, moved cyclically by
  every whole number of frames (:func:`shifted`).

Memory: a handful of vectors of the motion rows (3 per compared pixel and frame) per candidate
parameter; the recording is read one stretch at a time.
"""
from __future__ import annotations

import builtins
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vfcli.camera.pose import model_axes_velocity
from vfcli.diagnose.calibrate import (DEFAULT_REPLICATES, Calibration, NullParts, ScoreBasis, calibrate,
                                      quadrature_scores)
from vfcli.diagnose.cycles import Cycles, TooFewCycles, floor_cycle_ids, floor_cycles, glottal_cycles
from vfcli.inverse.stencil import stencil_scatter
from vfcli.inverse.terms.motion import frame_adjoint

#: noise stretches used at most on each side of the window (time and memory stay bounded)
MAX_POOL_STRETCHES = 8


@dataclass(frozen=True)
class RunCalibration:
    """calibration : the bootstrap result.  names : candidate names, in its order.
    naive_p : (C,) the uncalibrated score test's p-values (chi2, white noise of the estimated scale).
    information : per candidate, (p_c, p_c) ``I_c`` of its efficient columns (:class:`vfcli.diagnose.calibrate.ScoreBasis`)."""

    calibration: Calibration
    names: tuple[str, ...]
    naive_p: np.ndarray
    information: tuple = ()


def row_weights(baseline) -> np.ndarray:
    """(n_rows,) Omega: the Gauss-Newton weight of each measurement row in the objective E.

    Motion rows of frame f, component c: ``2 w_motion w_c / (F N_f)`` (E's motion term is exactly
    ``sum Omega r^2 / 2`` over them); gap rows: ``2 w_gap / (F n_sil l^2 (1 + q0^2))``, the curvature of
    the arctan's quadratic majoriser at the baseline (q0 = (d / l)^2, d the row's residual in mm).
    """
    p = baseline.problem
    st = p.settings
    cw = np.asarray(st.component_weights, dtype=float)
    out = [np.tile(cw * (2.0 * st.motion_weight / (p.n_frames * fr.n_norm)), fr.m_both.shape[0])
           for fr in baseline.frames]
    d = baseline.gap_residual()
    q = (d / st.gap_length_mm) ** 2
    n_sil = 2.0 * max(len(p.rays), 1)
    out.append(2.0 * st.gap_weight / (p.n_frames * n_sil * st.gap_length_mm ** 2 * (1.0 + q * q)))
    return np.concatenate(out)


def motion_adjoint(baseline, s: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n_params,) ``J_L^T Omega s`` over the motion rows of s (the gap rows are left out)."""
    p = baseline.problem
    g = np.zeros_like(baseline.displacements)
    at = 0
    for f, fr in enumerate(baseline.frames):
        n = 3 * fr.m_both.shape[0]
        gv, gu = frame_adjoint(fr, (s[at:at + n] * weights[at:at + n]).reshape(-1, 3))
        stencil_scatter(g, p.stencil[f], gv / p.dt)
        if gu is not None:
            g[f] += gu
        at += n
    return p.response.adjoint(g, p.sim_times, baseline.x)


def project_out_loads(baseline, model, s: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n_rows,) s minus the measurement change of its (ridge-regularised) Gauss-Newton load fit."""
    dx = model.hessian.solve(motion_adjoint(baseline, s, weights))
    du = model.linearization.apply(dx)
    return s - baseline.measure_linear(du[..., None])[:, 0]


@dataclass(frozen=True)
class FrameLayout:
    """The rows of a baseline laid out as frames x slots (a slot: one pixel and component, or one ray and side).

    slot : (n_rows,) the slot of each row; frame : (n_rows,) its frame.  n_slots : R.
    """

    slot: np.ndarray
    frame: np.ndarray
    n_slots: int
    n_frames: int

    @classmethod
    def of(cls, baseline) -> "FrameLayout":
        pix = [fr.pix_both for fr in baseline.frames]
        union = np.unique(np.concatenate(pix)) if pix else np.zeros(0, int)
        slots, frames = [], []
        for f, p in enumerate(pix):
            at = np.searchsorted(union, p)
            slots.append((3 * at[:, None] + np.arange(3)).ravel())
            frames.append(np.full(3 * len(p), f))
        gap_keys: dict = {}
        gs, gf = [], []
        for f, fr in enumerate(baseline.frames):
            for side, (rays, _edge, _tgt) in enumerate(fr.sil):
                for r in np.asarray(rays).ravel():
                    gs.append(gap_keys.setdefault((side, float(r)), len(gap_keys)))
                    gf.append(f)
        n_motion = 3 * len(union)
        slot = np.concatenate(slots + [n_motion + np.asarray(gs, dtype=int)])
        frame = np.concatenate(frames + [np.asarray(gf, dtype=int)])
        return cls(slot, frame, n_motion + len(gap_keys), len(baseline.frames))

    def to_frames(self, v: np.ndarray) -> np.ndarray:
        """(F, R, ...) the rows v (n_rows, ...) in their slots, 0 where a frame has no such row."""
        out = np.zeros((self.n_frames, self.n_slots) + v.shape[1:])
        out[self.frame, self.slot] = v
        return out

    def to_rows(self, x: np.ndarray) -> np.ndarray:
        """(n_rows, ...) the rows of a (F, R, ...) layout."""
        return x[self.frame, self.slot]


def quadrature(layout: FrameLayout, v: np.ndarray) -> np.ndarray:
    """(n_rows,) the rows v with every frequency of the window turned by a quarter period (Hilbert transform over
    the window's frames, cyclic), the zero frequency dropped."""
    x = np.fft.rfft(layout.to_frames(v), axis=0) * -1j
    x[0] = 0.0
    return layout.to_rows(np.fft.irfft(x, n=layout.n_frames, axis=0))


def frames_at_phase(cycles: Cycles, phase: np.ndarray) -> np.ndarray:
    """(n,) fractional frame index of the recording where the cycle phase is ``phase`` (n,) cycles."""
    idx = np.arange(len(cycles.phase), dtype=float)
    return np.interp(phase, cycles.phase, idx, left=np.nan, right=np.nan)


def pool_shifts(cycles: Cycles, window: np.ndarray, max_each_side: int = MAX_POOL_STRETCHES) -> list[int]:
    """Whole-cycle shifts k != 0 whose stretch (the window's phases + k) lies inside the recording, nearest first."""
    ph = cycles.phase[window]
    lo, hi = float(cycles.phase[0]), float(cycles.phase[-1])
    out = []
    for k in range(1, max_each_side + 1):
        for kk in (-k, k):
            if ph.min() + kk >= lo and ph.max() + kk <= hi - 1e-9:
                out.append(kk)
    return out


def calibration_shifts(cycles: Cycles, window: np.ndarray) -> list[int]:
    """:func:`pool_shifts`, at least 3 of them (the calibration's noise stretches).

    Raises
    ------
    vfcli.diagnose.cycles.TooFewCycles
        Fewer than 3 whole-cycle stretches of the window's length inside the recording."""
    shifts = pool_shifts(cycles, window)
    if len(shifts) < 3:
        raise TooFewCycles(f"{len(shifts)} stretch(es) of the window's length at whole cycles from it inside the "
                           "recording: the calibration needs at least 3")
    return shifts


def stretch_motion(baseline, rec, cycles: Cycles, window: np.ndarray, k: int) -> np.ndarray:
    """(n_motion_rows,) the measured velocity (model axes, mm/s) of the stretch k cycles from the window, at the
    window frames' phases and compared pixels (linear interpolation between frames), NaN where not valid."""
    p = baseline.problem
    pos = frames_at_phase(cycles, cycles.phase[window] + k)
    i0 = np.floor(pos).astype(int)
    a = pos - i0
    first, last = int(i0.min()), int(min(i0.max() + 2, len(cycles.phase)))
    v = np.array(rec.velocity[first:last], dtype=np.float64)
    v[..., :2] = model_axes_velocity(v[..., :2], rec.velocity_rotation_deg, p.camera.rotation_deg)
    v[~np.asarray(rec.valid[first:last], bool)] = np.nan
    v = v.reshape(v.shape[0], -1, 3)
    out = []
    for f, fr in enumerate(baseline.frames):
        j = i0[f] - first
        j1 = min(j + 1, v.shape[0] - 1)
        out.append(((1 - a[f]) * v[j, fr.pix_both] + a[f] * v[j1, fr.pix_both]).ravel())
    return np.concatenate(out)


def pool_stretches(baseline, rec, cycles: Cycles, window: np.ndarray, shifts: list[int]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(template (n_motion_rows,), stretches (K, n_motion_rows) float32) the measured motion rows of every
    stretch (NaN where not valid) and their mean at each row (the periodic template)."""
    stack = np.stack([stretch_motion(baseline, rec, cycles, window, k).astype(np.float32) for k in shifts])
    with np.errstate(invalid="ignore"):
        count = np.sum(np.isfinite(stack), axis=0)
        template = np.where(count > 0, np.nansum(stack, axis=0, dtype=np.float64) / np.maximum(count, 1), np.nan)
    return template, stack


def calibrate_run(candidates, baseline, rec, cycles: Cycles, window: np.ndarray, tests, columns, model,
                  n_replicates: int = DEFAULT_REPLICATES, seed: int = 0, map: Callable = builtins.map
                  ) -> RunCalibration:
    """Calibrated screening of ``candidates`` at a fitted run (module docstring).

    tests, columns, model : from :func:`vfcli.diagnose.candidates.blocks.screen_run_columns` (the naive
    score tests, the efficient displacement columns (F + 1, N, 3, p_c) per candidate, the Gauss-Newton model).
    rec : :class:`vfcli.diagnose.run.Recording`; cycles, window : the recording's cycles and the window's frames.

    Raises
    ------
    vfcli.diagnose.cycles.TooFewCycles
        Fewer than 3 whole-cycle stretches of the recording outside the window.
    """
    shifts = calibration_shifts(cycles, window)
    omega = row_weights(baseline)
    cols = [baseline.measure_linear(c) for c in columns]
    basis = ScoreBasis([omega[:, None] * c for c in cols], [c.T @ (omega[:, None] * c) for c in cols],
                       [bool(t.identifiability.identifiable) for t in tests],
                       [bool(getattr(c, "one_sided", False)) for c in candidates])
    r = baseline.residual_vector()
    n_motion = baseline.n_motion_rows
    template, stack = pool_stretches(baseline, rec, cycles, window, shifts)
    noise = []
    for row in stack:
        dev = np.zeros_like(r)
        dev[:n_motion] = np.nan_to_num(row - template)
        noise.append(basis.scores(dev))
    del stack
    own = np.zeros_like(r)
    own[:n_motion] = np.nan_to_num(baseline.measured_motion() - template)
    s = project_out_loads(baseline, model, r - own, omega)
    layout = FrameLayout.of(baseline)
    q = quadrature_scores(layout.to_frames(s), [layout.to_frames(w) for w in basis.weights])
    # the loads absorbed the part of the model error they can make; its quarter-period turn is missing from
    # s, so the quadrature under-counts each column's lean by the share of its own turn the loads can make
    at = 0
    for c in cols:
        for j in range(c.shape[1]):
            h = quadrature(layout, c[:, j])
            kept = float(np.sum(omega * project_out_loads(baseline, model, h, omega) ** 2))
            q[:, at] /= np.sqrt(max(kept / max(float(np.sum(omega * h ** 2)), 1e-300), 0.05))
            at += 1
    model_error = q
    parts = NullParts(np.stack(noise), model_error)
    cal = calibrate(basis, r, parts, n_replicates, seed, map)
    return RunCalibration(cal, tuple(c.name for c in candidates), np.array([t.p_value for t in tests]),
                          tuple(basis.information))


def uncalibrated_reason(area: np.ndarray, dt: float, f0_hz: float | None, first: int, n_frames: int) -> str | None:
    """Why :func:`vfcli.diagnose.run.diagnose_run` cannot decide on the window ``first .. first + n_frames - 1`` of a recording
    whose glottal area is ``area`` ((F,), frames ``dt`` s apart): its own checks, on the area alone (no whole
    cycle; fewer than 2 for the noise floor; fewer than 3 stretches for the calibration), or None.
    f0_hz : the subglottal pressure's f0 (``/sync``), Hz, or None."""
    try:
        cycles = glottal_cycles(np.asarray(area, float), dt, f0_hz)
        window = np.arange(first, first + n_frames)
        _, around, exclude = floor_cycles(cycles, window)
        floor_cycle_ids(around, exclude)
        calibration_shifts(cycles, window)
    except TooFewCycles as exc:
        return str(exc)
    return None
