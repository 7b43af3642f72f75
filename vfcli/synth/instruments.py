"""Phantom instrument models: subglottal pressure, scanning LDV epochs, pressure references.

Everything is a pure function of its arguments and an explicit, seeded
``numpy.random.Generator``: the same seed gives the same bytes.

Phase convention: the phantom's motion is periodic in the *cycle phase*
``phase`` (cycles, period 1); the pressure that drives it is
``PressureWaveform.at_phase(phase)``.  Time maps to phase through the
fundamental frequency, ``phase(t) = phase0 + integral_0^t f0(t') dt'``.  The
video, each LDV epoch and each epoch's pressure reference share this phase, so
the truth of an epoch is the phase at its first sample (and its f0).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.interpolate import CubicSpline

from vfcli.camera.raster import raycast_points

#: a function giving the true vertical surface velocity (mm/s, NaN where no
#: surface) at scan points ``(P, 2)`` mm for cycle phases ``(P, S)``: returns (P, S)
TrueVelocity = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class PressureWaveform:
    """One cycle of subglottal pressure: mean plus a few harmonics.

    ``p(phase) = mean_pa * (1 + amplitude_rel * g(phase))`` with
    ``g = sum_k a_k cos(2 pi k phase + phi_k) / s``, normalised so that
    ``(max g - min g) / 2 = 1``: the half peak-to-peak swing is ``amplitude_rel * mean_pa``.

    mean_pa : mean subglottal pressure, Pa.
    amplitude_rel : half peak-to-peak swing relative to the mean.
    harmonics : relative amplitudes a_k of harmonics k = 1, 2, ...
    phases_rad : phases phi_k, radians (same length as ``harmonics``).
    """

    mean_pa: float = 800.0
    amplitude_rel: float = 0.45
    harmonics: tuple[float, ...] = (1.0, 0.45, 0.2, 0.08)
    phases_rad: tuple[float, ...] = (0.0, -0.6, -1.4, -2.1)

    def __post_init__(self) -> None:
        if len(self.harmonics) != len(self.phases_rad) or not self.harmonics:
            raise ValueError("pressure harmonics and phases_rad must be non-empty and of equal length")
        if not (np.all(np.isfinite(self.harmonics)) and np.any(np.asarray(self.harmonics) != 0)):
            raise ValueError(f"pressure harmonics must be finite and not all zero, got {self.harmonics}")
        if self.amplitude_rel < 0 or not np.isfinite(self.mean_pa):
            raise ValueError("pressure amplitude_rel must be >= 0 and mean_pa finite")
        grid = np.arange(8192) / 8192
        g = self._raw(grid)
        object.__setattr__(self, "_scale", 0.5 * (g.max() - g.min()))

    def _raw(self, phase: np.ndarray) -> np.ndarray:
        ph = np.asarray(phase, dtype=float)
        out = np.zeros_like(ph)
        for k, (a, p) in enumerate(zip(self.harmonics, self.phases_rad), start=1):
            out += a * np.cos(2 * np.pi * k * ph + p)
        return out

    def harmonic_amplitudes_pa(self) -> np.ndarray:
        """(n_harmonics,) amplitude of each harmonic, Pa."""
        return self.mean_pa * self.amplitude_rel * np.abs(np.asarray(self.harmonics)) / self._scale

    def at_phase(self, phase_cycles: np.ndarray) -> np.ndarray:
        """Pressure (Pa) at cycle phases (any shape, cycles)."""
        return self.mean_pa * (1.0 + self.amplitude_rel * self._raw(phase_cycles) / self._scale)


def cycle_phase(t: np.ndarray, f0_hz: float | np.ndarray, phase0: float = 0.0) -> np.ndarray:
    """Cycle phase (cycles, unwrapped) ``phase0 + integral_0^t f0``.

    t : (S,) increasing times, s.
    f0_hz : scalar, or (S,) the fundamental at each time (a slow drift); the
        integral is trapezoidal from t[0], with f0 taken constant before t[0].
    phase0 : phase at t = 0, cycles.
    """
    tt = np.asarray(t, dtype=float)
    f0 = np.asarray(f0_hz, dtype=float)
    if f0.ndim == 0:
        return phase0 + f0 * tt
    if f0.shape != tt.shape or tt.ndim != 1:
        raise ValueError(f"f0_hz must be a scalar or shaped like t {tt.shape}, got {f0.shape}")
    steps = 0.5 * (f0[1:] + f0[:-1]) * np.diff(tt)
    return phase0 + f0[0] * tt[0] + np.concatenate([[0.0], np.cumsum(steps)])


def subglottal_pressure(t: np.ndarray, f0_hz: float | np.ndarray,
                        waveform: PressureWaveform = PressureWaveform(), phase0: float = 0.0) -> np.ndarray:
    """Subglottal pressure (Pa) at times t (s): periodic at f0 (or drifting, see :func:`cycle_phase`)."""
    return waveform.at_phase(cycle_phase(t, f0_hz, phase0))


def slow_f0_drift(t: np.ndarray, f0_hz: float, rel_amplitude: float, timescale_s: float,
                  rng: np.random.Generator) -> np.ndarray:
    """A smooth random f0(t) (Hz): f0 times (1 + r(t)), |r| <= rel_amplitude.

    r is a sum of four sinusoids with periods around ``timescale_s`` (random
    periods in [0.5, 2] x timescale, random phases), scaled so its largest
    excursion over t is ``rel_amplitude``.
    """
    tt = np.asarray(t, dtype=float)
    periods = timescale_s * rng.uniform(0.5, 2.0, size=4)
    phases = rng.uniform(0, 2 * np.pi, size=4)
    r = np.sum(np.sin(2 * np.pi * tt[:, None] / periods + phases), axis=1)
    peak = np.abs(r).max()
    return f0_hz * (1.0 + rel_amplitude * r / (peak if peak > 0 else 1.0))


@dataclass(frozen=True, eq=False)
class PressureRecord:
    """A pressure channel and the phase it was generated with.

    t : (S,) s; phase_cycles : (S,) unwrapped cycle phase; true_pa : (S,) the
    driving pressure; measured_pa : (S,) with sensor noise.
    """

    t: np.ndarray
    phase_cycles: np.ndarray
    true_pa: np.ndarray
    measured_pa: np.ndarray

    def phase_at(self, times: np.ndarray) -> np.ndarray:
        """Cycle phase at arbitrary times within the record (e.g. the video frames), cycles."""
        return np.interp(np.asarray(times, dtype=float), self.t, self.phase_cycles)


def video_pressure(duration_s: float, fs_hz: float, f0_hz: float | Callable[[np.ndarray], np.ndarray],
                   waveform: PressureWaveform, phase0: float, noise_pa: float,
                   rng: np.random.Generator) -> PressureRecord:
    """The pressure recorded beside the video, from t = 0 (first frame) for ``duration_s``.

    f0_hz : constant f0, or a function of time (s) -> f0 (Hz) for a drifting f0
        (e.g. ``lambda t: slow_f0_drift(t, 120, 0.005, 0.3, rng)``).
    noise_pa : white sensor noise, Pa RMS.
    The phantom must be driven with ``true_pa`` and rendered at
    ``record.phase_at(frame_index / fps)``.
    """
    n = int(round(duration_s * fs_hz))
    if n < 2:
        raise ValueError(f"video pressure needs at least 2 samples, got duration {duration_s} s at {fs_hz} Hz")
    t = np.arange(n) / fs_hz
    f0 = f0_hz(t) if callable(f0_hz) else f0_hz
    phase = cycle_phase(t, f0, phase0)
    true = waveform.at_phase(phase)
    return PressureRecord(t, phase, true, true + noise_pa * rng.standard_normal(n))


def ldv_scan_grid(bounds_mm: tuple[float, float, float, float], n_x: int, n_y: int, jitter_rel: float,
                  rotation_deg: float, rng: np.random.Generator) -> np.ndarray:
    """Scan points of the vibrometer, camera frame, mm: (n_x * n_y, 2) ``(x, y)``.

    A regular n_x (along x) by n_y (along y) grid spanning ``bounds_mm = (x0, x1, y0, y1)``,
    rotated by ``rotation_deg`` about the centre of the bounds, each point moved
    by Gaussian jitter of ``jitter_rel`` times the grid spacing (per axis).
    Point ``i * n_y + j`` is grid column i (x), row j (y).
    """
    x0, x1, y0, y1 = map(float, bounds_mm)
    if n_x < 2 or n_y < 2 or x1 <= x0 or y1 <= y0:
        raise ValueError(f"LDV grid needs n_x, n_y >= 2 and non-empty bounds, got {n_x} x {n_y} over {bounds_mm}")
    gx, gy = np.meshgrid(np.linspace(x0, x1, n_x), np.linspace(y0, y1, n_y), indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    spacing = np.array([(x1 - x0) / (n_x - 1), (y1 - y0) / (n_y - 1)])
    pts = pts + jitter_rel * spacing * rng.standard_normal(pts.shape)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    th = np.deg2rad(rotation_deg)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return (pts - centre) @ rot.T + centre


@dataclass(frozen=True)
class LdvSettings:
    """The scanning vibrometer session (defaults: physical-setup.md; [est] values configurable).

    fs_hz : sample rate, Hz.  epoch_s : duration of one point's epoch, s.
    pause_s : (min, max) random pause between epochs, s (mirror moves, averaging).
    f0_step_rel : std of the relative f0 random-walk step between epochs.
    f0_drift_rel : bound of the relative f0 excursion (reflected random walk).
    noise_rel : white noise std relative to the RMS of the true signal over all points.
    dropout_fraction : fraction of points with a dropout (spikes or flat runs).
    pressure_noise_pa : white noise of the pressure reference, Pa RMS.
    spike_window_s : 0, spikes anywhere in the epoch; > 0, a burst: all of a point's spikes
        within one window of this length, s.
    gap_noise_rel : 0, the signal through the gap is the noise floor; > 0, signal loss there:
        white noise of this std relative to the true signal's RMS (the widened panel).
    """

    fs_hz: float = 50_000.0
    epoch_s: float = 0.1
    pause_s: tuple[float, float] = (0.05, 0.5)
    f0_step_rel: float = 0.003
    f0_drift_rel: float = 0.01
    noise_rel: float = 0.01
    dropout_fraction: float = 0.02
    pressure_noise_pa: float = 2.0
    spike_window_s: float = 0.0
    gap_noise_rel: float = 0.0

    def __post_init__(self) -> None:
        if self.fs_hz <= 0 or self.epoch_s * self.fs_hz < 2:
            raise ValueError("LDV fs_hz must be > 0 and an epoch must hold at least 2 samples")
        if not 0 <= self.dropout_fraction <= 1 or self.noise_rel < 0 or self.f0_drift_rel < 0:
            raise ValueError("LDV dropout_fraction must be in [0, 1], noise_rel and f0_drift_rel >= 0")

    @property
    def n_samples(self) -> int:
        return int(round(self.epoch_s * self.fs_hz))


#: dropout kinds in :attr:`LdvTruth.dropout_kind`
DROPOUT_NONE, DROPOUT_SPIKES, DROPOUT_FLAT = 0, 1, 2


@dataclass(frozen=True, eq=False)
class LdvTruth:
    """What generated each epoch (for scoring the sync stage).

    start_phase : (P,) cycle phase at the epoch's first sample, in [0, 1).
    start_time_s : (P,) session time of the first sample, s.
    f0_hz : (P,) fundamental during the epoch, Hz.
    velocity : (P, S) true vertical velocity at the point, mm/s (NaN: no surface there).
    pressure : (P, S) true pressure, Pa.
    noise_std : std of the LDV white noise, mm/s.
    dropout_kind : (P,) int, DROPOUT_NONE / DROPOUT_SPIKES / DROPOUT_FLAT.
    dropout_mask : (P, S) bool, samples corrupted by a dropout.
    """

    start_phase: np.ndarray
    start_time_s: np.ndarray
    f0_hz: np.ndarray
    velocity: np.ndarray
    pressure: np.ndarray
    noise_std: float
    dropout_kind: np.ndarray
    dropout_mask: np.ndarray

    def video_time_s(self, video_f0_hz: float, video_phase0: float = 0.0) -> np.ndarray:
        """(P,) earliest video time (s, in [0, 1/f0)) with the same phase as each epoch's start."""
        return np.mod(self.start_phase - video_phase0, 1.0) / video_f0_hz


@dataclass(frozen=True, eq=False)
class LdvScan:
    """A simulated vibrometer scan.

    points_mm : (P, 2) scan points, camera frame (model x, y), mm.
    fs_hz : sample rate, Hz.
    velocity : (P, S) measured vertical velocity, mm/s (line of sight, +z up).
    pressure : (P, S) measured pressure reference, Pa.
    truth : :class:`LdvTruth`.
    """

    points_mm: np.ndarray
    fs_hz: float
    velocity: np.ndarray
    pressure: np.ndarray
    truth: LdvTruth


def _session_phases(n: int, settings: LdvSettings, f0_hz: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start times (s), start phases (cycles, [0, 1)) and f0 (Hz) of n sequential epochs."""
    lo, hi = settings.pause_s
    gaps = settings.epoch_s + rng.uniform(lo, hi, size=n)
    start = np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    r = np.empty(n)
    r[0] = rng.uniform(-settings.f0_drift_rel, settings.f0_drift_rel) if settings.f0_drift_rel else 0.0
    steps = settings.f0_step_rel * rng.standard_normal(n)
    bound = settings.f0_drift_rel
    for i in range(1, n):                      # reflected random walk (n ~ 374: cheap)
        v = r[i - 1] + steps[i]
        if bound > 0:
            v = bound - np.abs(np.mod(v + bound, 4 * bound) - 2 * bound) if abs(v) > bound else v
        else:
            v = 0.0
        r[i] = v
    f0 = f0_hz * (1.0 + r)
    phase0 = rng.uniform()
    # f0 is held from one epoch's start to the next
    phase = phase0 + np.concatenate([[0.0], np.cumsum(f0[:-1] * np.diff(start))])
    return start, np.mod(phase, 1.0), f0


def _apply_dropouts(meas: np.ndarray, rms: float, settings: LdvSettings,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt a few points in place: spikes (speckle) or flat runs (signal loss)."""
    n_pts, n_s = meas.shape
    kind = np.zeros(n_pts, dtype=np.int64)
    mask = np.zeros(meas.shape, dtype=bool)
    n_drop = int(round(settings.dropout_fraction * n_pts))
    if settings.dropout_fraction > 0:
        n_drop = max(n_drop, 1)
    for p in rng.choice(n_pts, size=n_drop, replace=False):
        if rng.uniform() < 0.5:
            kind[p] = DROPOUT_SPIKES
            window = min(n_s - 6, int(settings.spike_window_s * settings.fs_hz))
            w0 = int(rng.integers(0, n_s - window)) if window > 5 else 0
            for _ in range(int(rng.integers(3, 11))):
                width = int(rng.integers(1, 6))
                s0 = w0 + int(rng.integers(0, window - width)) if window > 5 else int(rng.integers(0, n_s - width))
                meas[p, s0:s0 + width] += rng.choice([-1.0, 1.0]) * rng.uniform(5, 20) * rms
                mask[p, s0:s0 + width] = True
        else:
            kind[p] = DROPOUT_FLAT
            for _ in range(int(rng.integers(1, 4))):
                width = int(min(n_s - 2, rng.uniform(0.002, 0.02) * settings.fs_hz))
                s0 = int(rng.integers(1, n_s - width))
                meas[p, s0:s0 + width] = meas[p, s0 - 1]
                mask[p, s0:s0 + width] = True
    return kind, mask


def simulate_ldv_scan(points_mm: np.ndarray, true_velocity: TrueVelocity, f0_hz: float,
                      waveform: PressureWaveform, settings: LdvSettings,
                      rng: np.random.Generator) -> LdvScan:
    """Record one vibrometer epoch per scan point, each with its pressure reference.

    The epochs are taken one after another in point order over a long session
    (random pauses between them), so each starts at its own cycle phase; f0
    follows a bounded random walk from epoch to epoch (constant within one).
    Noise: white, std ``noise_rel`` x the RMS of the true signal over all points.
    Where the truth is NaN (no surface under the laser) the signal is lost:
    the output is noise around 0.  A few points get dropouts (see :class:`LdvTruth`).

    Parameters
    ----------
    points_mm : (P, 2) scan points (e.g. :func:`ldv_scan_grid`), mm.
    true_velocity : ``f(points (P, 2), phase (P, S)) -> (P, S)`` true vertical velocity,
        mm/s, NaN where no surface (e.g. :class:`PeriodicTable`).
    f0_hz : nominal fundamental of the session, Hz.
    waveform : the pressure cycle (the same one that drives the phantom).
    settings : session settings.
    rng : seeded generator.
    """
    pts = np.asarray(points_mm, dtype=float)
    n_pts, n_s = len(pts), settings.n_samples
    start, phase0, f0 = _session_phases(n_pts, settings, f0_hz, rng)
    phase = phase0[:, None] + f0[:, None] * (np.arange(n_s) / settings.fs_hz)[None, :]
    truth_v = np.asarray(true_velocity(pts, phase), dtype=float)
    if truth_v.shape != phase.shape:
        raise ValueError(f"true_velocity returned {truth_v.shape}, expected {phase.shape}")
    surface = np.isfinite(truth_v)
    rms = float(np.sqrt(np.mean(truth_v[surface] ** 2))) if surface.any() else 0.0
    noise_std = settings.noise_rel * rms
    meas = np.where(surface, truth_v, 0.0) + noise_std * rng.standard_normal(phase.shape)
    kind, mask = _apply_dropouts(meas, rms, settings, rng)
    if settings.gap_noise_rel > 0:      # the beam looks through the gap: no return, the demodulator wanders
        lost = ~surface
        meas[lost] += settings.gap_noise_rel * rms * rng.standard_normal(int(lost.sum()))
        mask |= lost
    p_true = waveform.at_phase(phase)
    p_meas = p_true + settings.pressure_noise_pa * rng.standard_normal(phase.shape)
    truth = LdvTruth(phase0, start, f0, truth_v, p_true, noise_std, kind, mask)
    return LdvScan(pts, settings.fs_hz, meas, p_meas, truth)


class PeriodicTable:
    """True velocity at fixed points from one sampled cycle: a :data:`TrueVelocity`.

    table : (P, M) value at each point for phases ``m / M`` (m = 0 .. M-1), NaN
        where no surface.  Interpolated in phase by a periodic cubic spline; a
        phase between two samples is NaN if either sample is NaN.
    """

    def __init__(self, table: np.ndarray) -> None:
        tab = np.asarray(table, dtype=float)
        if tab.ndim != 2 or tab.shape[1] < 4:
            raise ValueError(f"table must be (P, M) with M >= 4 phases, got {tab.shape}")
        self.n_points, self.n_phases = tab.shape
        self._nan = ~np.isfinite(tab)
        filled = np.where(self._nan, 0.0, tab)
        grid = np.arange(self.n_phases + 1) / self.n_phases
        closed = np.concatenate([filled, filled[:, :1]], axis=1)
        self._coef = CubicSpline(grid, closed, axis=1, bc_type="periodic").c     # (4, M, P)

    def __call__(self, points: np.ndarray, phase: np.ndarray) -> np.ndarray:
        ph = np.asarray(phase, dtype=float)
        if ph.shape[0] != self.n_points:
            raise ValueError(f"phase has {ph.shape[0]} rows, the table has {self.n_points} points")
        q = np.mod(ph, 1.0) * self.n_phases
        k = np.minimum(np.floor(q).astype(np.int64), self.n_phases - 1)
        x = (q - k) / self.n_phases
        p = np.arange(self.n_points).reshape((-1,) + (1,) * (ph.ndim - 1))
        c = self._coef
        out = ((c[0, k, p] * x + c[1, k, p]) * x + c[2, k, p]) * x + c[3, k, p]
        bad = self._nan[p, k] | self._nan[p, (k + 1) % self.n_phases]
        return np.where(bad, np.nan, out)


def vertical_velocity_table(points_xy: np.ndarray, vertices: np.ndarray, velocities: np.ndarray,
                            triangles: np.ndarray) -> np.ndarray:
    """What a vertical laser beam at each scan point sees over one sampled cycle.

    At each phase the beam hits the topmost surface point above (x, y) (whatever
    material is there at that instant, as a real LDV does) and measures its
    vertical velocity.

    Parameters
    ----------
    points_xy : (P, 2) scan points, mm.
    vertices : (M, N, 3) surface vertices at phases m / M, mm.
    velocities : (M, N, 3) vertex velocities at the same phases, mm/s.
    triangles : (K, 3) int surface triangles (both folds).

    Returns
    -------
    (P, M) vertical velocity w, mm/s; NaN where the beam hits no surface.
    Wrap it in :class:`PeriodicTable` to get a :data:`TrueVelocity`.
    """
    verts = np.asarray(vertices, dtype=float)
    vel = np.asarray(velocities, dtype=float)
    if verts.ndim != 3 or vel.shape != verts.shape:
        raise ValueError(f"vertices and velocities must both be (M, N, 3), got {verts.shape} and {vel.shape}")
    pts = np.asarray(points_xy, dtype=float)
    out = np.full((len(pts), len(verts)), np.nan)
    for m in range(len(verts)):
        hits = raycast_points(pts, verts[m], triangles)
        out[hits.visible_index, m] = hits.interpolate_visible(vel[m, :, 2])
    return out
