"""Cycle phase of a periodic pressure signal: a harmonic template with a smooth phase.

Model of one record (samples y_s at times t_s, any unit)::

    y(t) = g * W(phi(t)) + baseline(t) + noise
    W(phi) = Re sum_{h=1..H} c_h exp(2 pi i h phi)        (unit RMS, c_1 real > 0)
    phi(t) = sum_k theta_k B_k(t / T)                    (cycles; B = clamped B-splines)

``W`` is the *pressure template*, ``g`` a gain, ``baseline`` a quadratic in time (offset and
slow drift), ``phi`` the cycle phase: cycle k spans ``phi`` in [k, k+1) and ``phi`` = 0 mod 1
is the maximum of the template's fundamental (the gauge ``c_1`` real and positive). The
phase is a cubic B-spline with a knot every ``knot_cycles`` cycles, so a slow f0 drift
within a record is followed; cycle-to-cycle jitter faster than the knot spacing is averaged.

* :func:`fit_free_phase` fits everything (template included) to one record, alternating the
  linear least-squares solve for the harmonics with Gauss-Newton steps on the phase. Used
  for the video's pressure (which defines the template) and by :func:`estimate_f0`.
* :func:`track_phase` fits many records of equal length at once, started from the video's
  template: gain, baseline and phase, and (``mode="fundamental"``, the default) the
  harmonics h >= 2 of each record, with phase 0 pinned to each record's own fundamental
  maximum; or (``mode="template"``) the video's template kept whole. Either way phase 0 is
  the same point of the cycle in every record, whatever its gain and offset (a positive
  gain is assumed: an inverted channel is rejected). See :mod:`vfcli.sync.gauss_newton`.

Gauss-Newton is batched over records (chunks of ``CHUNK`` rows) and fits a strided subset of
the samples (every ``stride``-th, keeping ``SAMPLES_PER_HARMONIC`` = 8 samples per period
of the highest harmonic). The records are first averaged over the ``2 (stride // 2) + 1`` samples centred on each
(:func:`prefiltered`: zero phase, so no delay; the highest harmonic keeps 97 % of its amplitude, the lower ones more).
Strided without it, the fit saw the whole white noise of the skipped samples (session 28, RMS timing error of
tests/test_sync.py's 374-point fixture 1.57 -> 0.77 us; widened rigs 1111, 1112, 1114, 1120: 0.98 -> 0.49,
6.08 -> 1.55, 0.76 -> 0.44, 2.94 -> 2.41 us). The first and last ``stride // 2`` samples are left as they are: an
average reflected at the record's ends moved 47 of 1111's 374 points by about -6 us (the offset is read at the
record's start). The fit's quality (:func:`_quality`, the rejection thresholds) is still measured on the unaveraged
samples.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from vfcli.config import SyncConfig
from vfcli.sync.gauss_newton import (
    CHUNK,
    MODES,
    curvature_penalty,
    evaluate_template,
    gauss_newton,
    gram,
    linear_part,
)

log = logging.getLogger(__name__)

#: Degree of the baseline polynomial (offset + slow drift).
BASELINE_DEGREE = 2


@dataclass(frozen=True)
class PressureTemplate:
    """One cycle of the reference waveform, as a harmonic series.

    Attributes
    ----------
    coeffs : (H,) complex
        ``W(phi) = Re sum_h coeffs[h-1] exp(2 pi i h phi)``; unit RMS, ``coeffs[0]`` real > 0.
    """

    coeffs: np.ndarray

    @property
    def n_harmonics(self) -> int:
        return int(self.coeffs.size)

    def __call__(self, phi: np.ndarray) -> np.ndarray:
        """Template value at phase ``phi`` (cycles), same shape as ``phi``, unit RMS."""
        return evaluate_template(self.coeffs, np.asarray(phi, dtype=float))[0]


@dataclass
class PhaseTracks:
    """Cycle phase of N records of equal length, as B-splines of time.

    Attributes
    ----------
    knots : (K + degree + 1,) float
        Knot vector in normalised time u = (t - t_start) / duration, clamped on [0, 1].
    degree : int
        Spline degree.
    theta : (N, K) float
        Spline coefficients, cycles.
    t_start, duration : float
        Time of the first sample and of the last minus the first, s.
    f0_hz : (N,) float
        Mean frequency over the record: slope of the least-squares line through phi(t), Hz.
    drift_rate_per_s : (N,) float
        Linear trend of the instantaneous frequency divided by f0, 1/s.
    gain : (N,) float
        Gain g of the template in each record (record units per unit-RMS template).
    quality : (N,) float
        Correlation between the record (baseline removed) and ``W(phi(t))``, in [0, 1].
    """

    knots: np.ndarray
    degree: int
    theta: np.ndarray
    t_start: float
    duration: float
    f0_hz: np.ndarray
    drift_rate_per_s: np.ndarray
    gain: np.ndarray
    quality: np.ndarray

    def phase_at(self, t: np.ndarray) -> np.ndarray:
        """Phase (cycles) at times ``t`` (M,) s -> (N, M)."""
        u = (np.asarray(t, dtype=float) - self.t_start) / self.duration
        spl = BSpline(self.knots, self.theta.T, self.degree, extrapolate=True)
        return np.asarray(spl(u)).T

    def frequency_at(self, t: np.ndarray) -> np.ndarray:
        """Instantaneous frequency (Hz) at times ``t`` (M,) s -> (N, M)."""
        u = (np.asarray(t, dtype=float) - self.t_start) / self.duration
        spl = BSpline(self.knots, self.theta.T, self.degree, extrapolate=True).derivative()
        return np.asarray(spl(u)).T / self.duration


def phase_basis(u: np.ndarray, n_intervals: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Clamped B-spline design matrix on [0, 1].

    Returns ``basis`` (S, K) with K = n_intervals + degree, and the knot vector.
    """
    inner = np.linspace(0.0, 1.0, n_intervals + 1)
    knots = np.concatenate([np.zeros(degree), inner, np.ones(degree)])
    uu = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    basis = BSpline.design_matrix(uu, knots, degree).toarray()
    return basis, knots


def greville(knots: np.ndarray, degree: int) -> np.ndarray:
    """Greville abscissae: coefficients at these reproduce a linear function exactly."""
    n_coef = knots.size - degree - 1
    if degree == 0:
        return 0.5 * (knots[:-1] + knots[1:])
    return np.array([knots[j + 1: j + degree + 1].mean() for j in range(n_coef)])


def baseline_basis(n: int, degree: int = BASELINE_DEGREE) -> np.ndarray:
    """Legendre polynomials on [-1, 1] over n samples -> (n, degree + 1)."""
    x = np.linspace(-1.0, 1.0, n)
    return np.polynomial.legendre.legvander(x, degree)


#: Weight of the curvature (third-derivative) penalty on the phase spline (see
#: :func:`vfcli.sync.gauss_newton.gauss_newton`);
#: chosen by measurement: 0.1 with knots every 2 cycles follows an f0 modulation of period
#: 50 ms and halves the noise at the record ends. The value is sync.smooth's default (vfcli/config.py).
DEFAULT_SMOOTH = SyncConfig().smooth
#: Samples kept per period of the highest template harmonic when striding the fit.
SAMPLES_PER_HARMONIC = 8.0
#: Template harmonics above the last one reaching this fraction of the largest are dropped.
MIN_HARMONIC_FRACTION = 3e-3


def prefiltered(y: np.ndarray, stride: int) -> np.ndarray:
    """(..., S) ``y`` averaged over the ``2 (stride // 2) + 1`` samples centred on each, the first and last
    ``stride // 2`` left as they are: the anti-alias filter of the strided fit (module docstring).  ``stride`` 1:
    ``y`` itself."""
    from scipy.ndimage import uniform_filter1d

    size = 2 * (int(stride) // 2) + 1
    if size <= 1:
        return y
    out = uniform_filter1d(y, size, axis=-1, mode="reflect")
    h = size // 2
    out[..., :h] = y[..., :h]
    out[..., -h:] = y[..., -h:]
    return out


def auto_stride(fs: float, f0_max: float, n_harmonics: int) -> int:
    """Sample stride keeping ``SAMPLES_PER_HARMONIC`` samples per period of the highest harmonic."""
    return max(1, int(fs / (SAMPLES_PER_HARMONIC * n_harmonics * f0_max)))


def _quality(y: np.ndarray, base: np.ndarray, beta: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Correlation of (y - baseline) with W(phi), clipped to [0, 1]; rows."""
    r = y - beta @ np.ascontiguousarray(base.T)
    r = r - r.mean(axis=1, keepdims=True)
    wc = w - w.mean(axis=1, keepdims=True)
    num = np.einsum("ns,ns->n", r, wc)
    den = np.sqrt(np.einsum("ns,ns->n", r, r) * np.einsum("ns,ns->n", wc, wc))
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(den > 0, num / den, 0.0)
    return np.clip(np.nan_to_num(q), 0.0, 1.0)


def _fit_harmonics(y: np.ndarray, phi: np.ndarray, base: np.ndarray, n_harmonics: int):
    """Linear LS of y (S,) on baseline + harmonics of phi (S,) -> (coeffs (H,) complex, beta)."""
    h = np.arange(1, n_harmonics + 1)
    arg = 2.0 * np.pi * phi[:, None] * h[None, :]
    a = np.concatenate([base, np.cos(arg), np.sin(arg)], axis=1)
    ata = gram(a)
    ata += 1e-12 * np.trace(ata) * np.eye(ata.shape[0])
    x = np.linalg.solve(ata, y @ a)
    d = base.shape[1]
    return x[d:d + n_harmonics] - 1j * x[d + n_harmonics:], x[:d]


def _gauge(coeffs: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Rotate so c_1 is real > 0 and scale to unit RMS; returns (coeffs, phase shift, rms).

    With ``phi_new = phi + shift`` and ``coeffs_new``, W_new(phi_new) * rms = W_old(phi).
    """
    psi1 = float(np.angle(coeffs[0]))
    h = np.arange(1, coeffs.size + 1)
    rot = coeffs * np.exp(-1j * h * psi1)
    rms = float(np.sqrt(np.sum(np.abs(rot) ** 2) / 2.0))
    return rot / rms, psi1 / (2.0 * np.pi), rms


def truncate_harmonics(coeffs: np.ndarray, fraction: float = MIN_HARMONIC_FRACTION) -> np.ndarray:
    """Drop the trailing harmonics smaller than ``fraction`` of the largest (noise fits)."""
    mag = np.abs(coeffs)
    keep = np.flatnonzero(mag >= fraction * mag.max())
    return coeffs[: keep[-1] + 1].copy()


def _drift_rate(tracks_f: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Slope of a straight-line fit of f(t) rows, divided by their mean -> 1/s."""
    tc = t - t.mean()
    slope = (tracks_f - tracks_f.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
    return slope / tracks_f.mean(axis=1)


@dataclass
class FreeFit:
    """Result of :func:`fit_free_phase`: the track (N = 1) and the fitted template."""

    tracks: PhaseTracks
    template: PressureTemplate

    @property
    def f0_hz(self) -> float:
        return float(self.tracks.f0_hz[0])

    @property
    def quality(self) -> float:
        return float(self.tracks.quality[0])


def n_intervals_for(duration: float, f0: float, knot_cycles: float) -> int:
    """Spline intervals for a record of ``duration`` s at ``f0`` Hz (>= 1)."""
    return max(1, int(round(duration * f0 / knot_cycles)))


def fit_free_phase(
    y: np.ndarray, fs: float, f_init: float, psi_init: float, *,
    n_intervals: int, degree: int = 3, n_harmonics: int = SyncConfig().n_harmonics, t_start: float = 0.0,
    stride: int | None = None, n_outer: int = 5, smooth: float = DEFAULT_SMOOTH,
) -> FreeFit:
    """Fit template and smooth phase to one record.

    Parameters
    ----------
    y : (S,) float
        Record, any unit, sampled at ``fs`` Hz; first sample at ``t_start`` s.
    f_init, psi_init : float
        Starting f0 (Hz) and fundamental phase at the first sample (rad), e.g. from
        :func:`vfcli.sync.f0.coarse_f0`.
    n_intervals, degree : int
        Phase spline: intervals over the record and degree (1 interval, degree 1 = constant f0).
    n_harmonics : int
        Harmonics of the template (capped at 0.45 fs / f0).

    Returns
    -------
    FreeFit
        Phase track (gauged: phase 0 = maximum of the fundamental) and unit-RMS template.
    """
    y = np.asarray(y, dtype=float)
    n = y.size
    duration = (n - 1) / fs
    n_h = max(1, min(n_harmonics, int(0.45 * fs / f_init)))
    if stride is None:
        stride = auto_stride(fs, 1.1 * f_init, n_h)
    idx = np.arange(0, n, stride)
    u = idx / (n - 1)
    basis, knots = phase_basis(u, n_intervals, degree)
    base = baseline_basis(n)[idx]
    raw = y[idx]
    ys = prefiltered(y, stride)[idx]
    theta = psi_init / (2.0 * np.pi) + f_init * duration * greville(knots, degree)
    coeffs = np.zeros(n_h, dtype=complex)
    for _ in range(n_outer):
        coeffs, _ = _fit_harmonics(ys, basis @ theta, base, n_h)
        coeffs, shift, _ = _gauge(coeffs)
        theta = theta + shift
        prev = theta
        th, _, _ = gauss_newton(ys[None], basis, base, coeffs, theta[None], n_iter=4,
                                smooth=smooth, pen=curvature_penalty(knots, degree))
        theta = th[0]
        if np.max(np.abs(theta - prev)) < 1e-9:
            break
    coeffs, _ = _fit_harmonics(ys, basis @ theta, base, n_h)
    coeffs, shift, _ = _gauge(coeffs)
    theta = theta + shift
    phi = basis @ theta
    w, _ = evaluate_template(coeffs, phi)
    g, beta, _ = linear_part(ys[None], w[None, None], base)
    g = g[:, 0]
    q = _quality(raw[None], base, beta, w[None])
    tracks = _make_tracks(knots, degree, theta[None], t_start, duration, g, q, idx / fs)
    return FreeFit(tracks=tracks, template=PressureTemplate(truncate_harmonics(coeffs)))


def _make_tracks(knots, degree, theta, t_start, duration, gain, quality, t_rel) -> PhaseTracks:
    tracks = PhaseTracks(knots=knots, degree=degree, theta=theta, t_start=t_start,
                         duration=duration, f0_hz=np.zeros(theta.shape[0]),
                         drift_rate_per_s=np.zeros(theta.shape[0]), gain=gain, quality=quality)
    phi = tracks.phase_at(t_start + t_rel)
    tc = t_rel - t_rel.mean()
    tracks.f0_hz = (phi - phi.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
    f_inst = tracks.frequency_at(t_start + t_rel)
    tracks.drift_rate_per_s = _drift_rate(f_inst, t_rel)
    return tracks


def track_phase(
    y: np.ndarray, fs: float, template: PressureTemplate, f_init: np.ndarray,
    psi_init: np.ndarray, *, n_intervals: int, degree: int = 3, t_start: float = 0.0,
    stride: int | None = None, n_iter: int = 8, smooth: float = DEFAULT_SMOOTH,
    mode: str = "fundamental",
) -> PhaseTracks:
    """Phase of N records of equal length against a fixed template.

    Parameters
    ----------
    y : (N, S) float
        Records (any unit, each its own gain and offset), sampled at ``fs`` Hz, finite.
    template : PressureTemplate
        Reference waveform (e.g. from the video's pressure, :func:`fit_free_phase`).
    f_init, psi_init : (N,) float
        Starting f0 (Hz) and fundamental phase at the first sample (rad).
    n_intervals, degree : int
        Phase spline (shared by all records).
    mode : {"fundamental", "template"}
        Phase reference: ``"fundamental"`` (default) pins phase 0 to each record's own
        fundamental maximum, its higher harmonics free (robust to waveform-shape changes
        between records); ``"template"`` fits the video's whole template (all harmonics
        fixed relative to each other). See :mod:`vfcli.sync.gauss_newton`.

    Returns
    -------
    PhaseTracks
        N tracks; phase 0 mod 1 is the fundamental maximum (= the template's phase 0).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    y = np.atleast_2d(np.asarray(y, dtype=float))
    n_rows, n = y.shape
    f_init = np.asarray(f_init, dtype=float)
    duration = (n - 1) / fs
    coeffs = template.coeffs
    if stride is None:
        stride = auto_stride(fs, 1.1 * float(np.max(f_init)), template.n_harmonics)
    idx = np.arange(0, n, stride)
    basis, knots = phase_basis(idx / (n - 1), n_intervals, degree)
    base = baseline_basis(n)[idx]
    raw = y[:, idx]
    ys = prefiltered(y, stride)[:, idx]
    t_rel = idx / fs
    theta = (np.asarray(psi_init)[:, None] / (2.0 * np.pi)
             + f_init[:, None] * duration * greville(knots, degree)[None, :])
    basis_t = np.ascontiguousarray(basis.T)
    theta = theta + _best_shift(ys, theta @ basis_t, base, coeffs)[:, None]
    theta, x, beta = gauss_newton(ys, basis, base, coeffs, theta, mode=mode, n_iter=n_iter,
                                  smooth=smooth, pen=curvature_penalty(knots, degree))
    # gain of the template: its fundamental's amplitude is coeffs[0] (real > 0)
    gain = x[:, 0] if mode == "template" else x[:, 0] / coeffs[0].real
    quality = np.zeros(n_rows)
    for lo in range(0, n_rows, CHUNK):
        sl = slice(lo, min(lo + CHUNK, n_rows))
        w, _ = evaluate_template(coeffs, theta[sl] @ basis_t)
        quality[sl] = _quality(raw[sl], base, beta[sl], w)
    return _make_tracks(knots, degree, theta, t_start, duration, gain, quality, t_rel)


def _best_shift(ys: np.ndarray, phi: np.ndarray, base: np.ndarray, coeffs: np.ndarray,
                n_grid: int = 128) -> np.ndarray:
    """Constant phase shift (cycles) maximising the correlation with the template; rows."""
    resid = ys - (ys @ base) @ np.linalg.pinv(base)
    e1 = np.exp(-2j * np.pi * phi)
    eh = np.ones_like(e1)
    proj = np.zeros((ys.shape[0], coeffs.size), dtype=complex)
    for h in range(coeffs.size):
        eh = eh * e1
        proj[:, h] = np.einsum("ns,ns->n", resid, eh)
    grid = np.arange(n_grid) / n_grid - 0.5
    hh = np.arange(1, coeffs.size + 1)
    rot = np.exp(-2j * np.pi * grid[:, None] * hh[None, :]) * np.conj(coeffs)[None, :]
    score = (proj @ rot.T).real
    return grid[np.argmax(score, axis=1)]
