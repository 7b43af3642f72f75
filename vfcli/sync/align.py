"""Phase-locked synchronisation of sequential LDV epochs onto the video's time base.

Each LDV point is measured in its own epoch; the subglottal pressure recorded beside each
epoch (the *reference channel*) and beside the video is the common clock.

Method
------
1. **Video phase reference** (:func:`video_phase_reference`): a harmonic template
   ``W(phi)`` and a smooth cycle phase ``phi_v(t)`` are fitted to the video's pressure
   (:func:`vfcli.sync.phase.fit_free_phase`). Phase 0 mod 1 is the maximum of the pressure's
   fundamental; cycle k spans ``phi`` in [k, k + 1); ``phi_v(first frame)`` lies in [0, 1).
2. **Epoch phase** (:func:`vfcli.sync.phase.track_phase`): every LDV reference record gets
   its own smooth phase ``phi_e(tau)``, gain and quadratic baseline, started from the
   video's template. With ``phase_reference="fundamental"`` (default) phase 0 is the maximum
   of the record's own fundamental and its higher harmonics are free; with ``"template"``
   the video's whole waveform is fitted. Gain and offset (Pa or volts, DC, slow drift) do
   not matter; both channels must have the same polarity (an inverted one is rejected).
3. **Phase-locked averaging** (:func:`phase_average_at`): for each frame time t the epoch
   times ``tau_k`` with ``phi_e(tau_k) = phi_v(t) mod 1`` are found in *every* cycle k of
   the epoch (inverse of the monotonic phase by linear interpolation between samples), the
   velocity is interpolated there (Keys cubic convolution at 50 kHz) and averaged over the
   cycles (NaN samples, e.g. speckle dropouts, are skipped). For speed the average is taken
   on a grid of phases at least as fine as the LDV samples (512 per cycle at 150 Hz) and
   interpolated periodically (Keys cubic) to the frames' phases. The result is a
   phase-averaged, noise-reduced cycle sampled on the video's frame times: it removes
   cycle-to-cycle variation, which a single-cycle match would keep, in exchange for
   sqrt(n_cycles) less noise (chosen: the FEM inversion wants the periodic motion).

Choices, by measurement (tests/test_sync.py fixture: 0.2 s epochs at 50 kHz, f0 150 Hz,
+-1.5% between epochs, 2% pressure noise, slow drift; RMS error of the mapped epoch times)
---------------------------------------------------------------------------------------------
* Phase model: cubic B-spline, knots every 2 cycles, curvature penalty 0.1: 1.4 us
  (template reference); 1.6 us when f0 wobbles by 0.2% with a 50 ms period. Knots every 4
  cycles with a strong penalty reach 0.9 us on slow drift but 14 us on the 50 ms wobble;
  knots every 2 cycles without penalty give 1.7 us (noisier record ends).
* Fit on every 6th sample (``SAMPLES_PER_HARMONIC`` = 8 per period of the highest template
  harmonic): 1.5 us for 0.7 s CPU per 100 points (fundamental reference); 16 per period:
  1.0 us, 1.9 s; every sample: 0.7 us, 4.2 s. The noise-limited error scales as
  sqrt(stride).
* The strided fit averages the samples it skips first (session 28, :func:`vfcli.sync.phase.prefiltered`): every
  figure of this list about halves (374 points 1.57 -> 0.77 us); the figures here are from before it.
* Phase reference: the fundamental costs a little noise (1.6 us vs 1.4 us for the whole
  template on identical waveforms) but is unbiased when the waveform's harmonics change
  between recordings: with 2% / 5% random changes of harmonics 2.. the template reference
  gives 3.8 / 8.9 us, the fundamental 1.6 / 1.6 us.

Per-point outputs
-----------------
``offset_s``: epoch time (s from the epoch's first sample) of the first instant whose phase
equals the video's phase at the first frame. ``f0_hz``: the epoch's mean f0 (slope of the
least-squares line through its phase). ``drift``: ``f0_hz / f0_video - 1``.
``drift_rate_per_s``: relative f0 trend within the epoch. ``quality``: correlation (in
[0, 1]) between the epoch's reference (baseline removed) and the video's template at the
fitted phase. A point is not ``ok`` (and its aligned velocity is NaN) when its reference has
non-finite samples, is constant or too short for ``min_cycles`` cycles, has no periodicity
(quality < ``NO_PERIODICITY_QUALITY`` = 0.5), an f0 more than ``max_f0_deviation`` (5%) from
the video's, a negative gain, a quality below ``min_quality`` (default 0.9; an inverted
channel lands here), or no finite velocity at some frame's phase.
"""
from __future__ import annotations

import logging

import numpy as np

from vfcli.config import SyncConfig
from vfcli.errors import InputDataError
from vfcli.sync.average import invert_monotonic, matched_times, phase_average_at
from vfcli.sync.f0 import F_RANGE, check_signal, coarse_f0, estimate_f0
from vfcli.sync.rate import check_ldv_rate, scan_explains_video, scan_f0
from vfcli.sync.phase import (
    PhaseTracks,
    PressureTemplate,
    fit_free_phase,
    n_intervals_for,
    track_phase,
)
from vfcli.sync.types import EpochAlignment, SyncResult, VideoPhase

#: The defaults of every setting below are the [sync] config's (one source, vfcli/config.py).
_D = SyncConfig()

__all__ = [
    "estimate_f0", "phase_track", "VideoPhase", "SyncResult", "EpochAlignment",
    "video_phase_reference", "epoch_phase_tracks", "matched_times", "phase_average_at",
    "align_epoch", "sync_scan", "PressureTemplate", "PhaseTracks", "NO_PERIODICITY_QUALITY",
    "invert_monotonic",
]

log = logging.getLogger(__name__)

#: Below this quality a reference is reported as "no periodicity" rather than "low quality".
NO_PERIODICITY_QUALITY = 0.5


def video_phase_reference(
    video_pressure: np.ndarray, fs: float, t0: float, frame_times: np.ndarray, *,
    f_range: tuple[float, float] = F_RANGE, n_harmonics: int = _D.n_harmonics,
    knot_cycles: float = _D.knot_cycles, smooth: float = _D.smooth, source: str = "video pressure",
) -> VideoPhase:
    """Template and phase of the video's pressure, evaluated at the frame times.

    Parameters
    ----------
    video_pressure : (S,) float
        Pressure beside the video, any unit, at ``fs`` Hz; sample j is at video time
        ``t0 + j / fs`` s (t = 0 at the first frame).
    frame_times : (n_frames,) float
        Video frame times, s (e.g. ``k / fps``); must lie within the pressure record.
    f_range : (2,) float
        f0 search range, Hz.
    n_harmonics : int
        Template harmonics.
    knot_cycles : float
        Phase-spline knot spacing, cycles.
    smooth : float
        Curvature penalty of the phase spline (see :mod:`vfcli.sync.phase`).

    Raises
    ------
    InputDataError
        The pressure is not usable (non-finite, constant, too short, not periodic, f0 out
        of range) or does not cover the frames.
    """
    y = np.asarray(video_pressure, dtype=float)
    frame_times = np.asarray(frame_times, dtype=float)
    if y.ndim != 1:
        raise InputDataError(f"expected a 1-D pressure signal, got shape {y.shape}", source)
    t_end = t0 + (y.size - 1) / fs
    tol = 0.5 / fs
    if frame_times.size == 0:
        raise InputDataError("no frame times", source)
    if frame_times.min() < t0 - tol or frame_times.max() > t_end + tol:
        raise InputDataError(
            f"the pressure record ({t0:.6f}-{t_end:.6f} s) does not cover the frame times "
            f"({frame_times.min():.6f}-{frame_times.max():.6f} s): check the video's frame rate (the file's, or "
            "camera.fps_hz) and frame range (ingest_hsc.first_frame, n_frames) against the pressure file", source)
    # the spline phase (not estimate_f0's constant f0) so that a drifting f0 still fits
    track, template = phase_track(y, fs, t0=t0, f_range=f_range, n_harmonics=n_harmonics,
                                  knot_cycles=knot_cycles, smooth=smooth, source=source)
    f0 = float(track.f0_hz[0])
    duration = (y.size - 1) / fs
    if not (f_range[0] * 0.99 <= f0 <= f_range[1] * 1.01):
        raise InputDataError(
            f"f0 {f0:.2f} Hz lies outside the search range {f_range[0]}-{f_range[1]} Hz", source)
    if duration * f0 < 2.0:
        raise InputDataError(
            f"too short: {duration * 1e3:.1f} ms holds fewer than 2 cycles at f0 = {f0:.1f} Hz; sync needs "
            f"a video (and its pressure record) of at least 2 cycles ({2e3 / f0:.1f} ms)", source)
    phase = track.phase_at(frame_times)[0]
    shift = np.floor(phase[0])
    track.theta = track.theta - shift
    phase = phase - shift
    return VideoPhase(template=template, track=track, f0_hz=f0, frame_times=frame_times,
                      frame_phase=phase, quality=float(track.quality[0]))


def phase_track(
    p: np.ndarray, fs: float, *, t0: float = 0.0, template: PressureTemplate | None = None,
    f_range: tuple[float, float] = F_RANGE, n_harmonics: int = _D.n_harmonics,
    knot_cycles: float = _D.knot_cycles, smooth: float = _D.smooth,
    phase_reference: str = _D.phase_reference, source: str = "pressure signal",
) -> tuple[PhaseTracks, PressureTemplate]:
    """Cycle phase of one pressure record (any unit), as a smooth spline of time.

    Parameters
    ----------
    p : (S,) float
        Pressure, at ``fs`` Hz; sample j at time ``t0 + j / fs`` s.
    template : PressureTemplate, optional
        Reference waveform (e.g. ``VideoPhase.template``); without one, the record's own
        template is fitted and returned.

    Returns
    -------
    track : PhaseTracks
        One row: ``track.phase_at(t)[0]`` is the phase in cycles (phase 0 mod 1 = the
        fundamental's maximum), ``track.f0_hz[0]`` the mean f0.
    template : PressureTemplate
        The template used or fitted.

    Raises
    ------
    InputDataError
        Non-finite, constant, too short or not periodic.
    """
    y = np.asarray(p, dtype=float)
    if y.ndim != 1:
        raise InputDataError(f"expected a 1-D pressure signal, got shape {y.shape}", source)
    check_signal(y, fs, f_range, source)
    f_coarse, psi = coarse_f0(y, fs, f_range)
    n_int = n_intervals_for((y.size - 1) / fs, float(f_coarse[0]), knot_cycles)
    if template is None:
        fit = fit_free_phase(y, fs, float(f_coarse[0]), float(psi[0]), n_intervals=n_int,
                             degree=3, n_harmonics=n_harmonics, t_start=t0, smooth=smooth)
        track, template = fit.tracks, fit.template
    else:
        track = track_phase(y[None], fs, template, f_coarse, psi, n_intervals=n_int, degree=3,
                            t_start=t0, smooth=smooth, mode=phase_reference)
    if not track.quality[0] >= NO_PERIODICITY_QUALITY:
        raise InputDataError(
            f"no periodicity: correlation {track.quality[0]:.2f} between the signal and its "
            f"periodic fit (need {NO_PERIODICITY_QUALITY})", source)
    return track, template


def epoch_phase_tracks(
    reference: np.ndarray, fs: float, video: VideoPhase, *,
    f_range: tuple[float, float] = F_RANGE, knot_cycles: float = _D.knot_cycles,
    min_cycles: float = _D.min_cycles, smooth: float = _D.smooth,
    phase_reference: str = _D.phase_reference,
) -> tuple[PhaseTracks, np.ndarray]:
    """Phase tracks of P reference records against the video's template.

    Parameters
    ----------
    reference : (P, S) float
        Reference-channel records (any unit), at ``fs`` Hz, epoch time 0 at sample 0.

    Returns
    -------
    tracks : PhaseTracks
        P rows (NaN coefficients for rows rejected before fitting).
    reason : (P,) object
        '' or why the row was rejected before fitting (non-finite, constant, too short).
    """
    ref = np.atleast_2d(np.asarray(reference, dtype=float))
    n_pts, n = ref.shape
    reason = np.full(n_pts, "", dtype=object)
    finite = np.all(np.isfinite(ref), axis=1)
    reason[~finite] = "non-finite samples in the reference pressure"
    const = finite & (np.ptp(np.where(finite[:, None], ref, 0.0), axis=1) == 0.0)
    reason[const] = "no periodicity: constant reference pressure"
    duration = (n - 1) / fs
    if duration * video.f0_hz < min_cycles or n < 16:
        reason[reason == ""] = (f"too short: {duration * 1e3:.1f} ms < {min_cycles} cycles "
                                f"at {video.f0_hz:.1f} Hz")
    good = np.flatnonzero(reason == "")
    f_init, psi = np.full(n_pts, np.nan), np.full(n_pts, np.nan)
    if good.size:
        f_init[good], psi[good] = coarse_f0(ref[good], fs, f_range)
    n_int = n_intervals_for(duration, video.f0_hz, knot_cycles)
    if good.size:
        tr = track_phase(ref[good], fs, video.template, f_init[good], psi[good],
                         n_intervals=n_int, degree=3, smooth=smooth, mode=phase_reference)
        n_k = tr.theta.shape[1]
    else:
        tr, n_k = None, n_int + 3
    knots = tr.knots if tr is not None else np.concatenate(
        [np.zeros(3), np.linspace(0.0, 1.0, n_int + 1), np.ones(3)])

    def full(a: np.ndarray | None, shape=()) -> np.ndarray:
        out = np.full((n_pts,) + shape, np.nan)
        if a is not None:
            out[good] = a
        return out

    tracks = PhaseTracks(
        knots=knots, degree=3, theta=full(None if tr is None else tr.theta, (n_k,)),
        t_start=0.0, duration=duration,
        f0_hz=full(None if tr is None else tr.f0_hz),
        drift_rate_per_s=full(None if tr is None else tr.drift_rate_per_s),
        gain=full(None if tr is None else tr.gain),
        quality=np.nan_to_num(full(None if tr is None else tr.quality)),
    )
    return tracks, reason


def align_epoch(
    reference: np.ndarray, velocity: np.ndarray, fs_ldv: float, video: VideoPhase, *,
    f_range: tuple[float, float] = F_RANGE, knot_cycles: float = _D.knot_cycles,
    max_f0_deviation: float = _D.max_drift, min_quality: float = _D.min_quality, min_cycles: float = _D.min_cycles,
    smooth: float = _D.smooth, phase_reference: str = _D.phase_reference,
) -> EpochAlignment:
    """Align one LDV epoch onto the video's frame times (options as in :func:`sync_scan`).

    Parameters
    ----------
    reference, velocity : (S,) float
        The epoch's reference pressure (any unit) and velocity, at ``fs_ldv`` Hz.
    video : VideoPhase
        From :func:`video_phase_reference`.

    Returns
    -------
    EpochAlignment
        ``aligned_w`` (n_frames,) on ``video.frame_times``; NaN when not ``ok``.
    """
    if np.ndim(reference) != 1 or np.shape(reference) != np.shape(velocity):
        raise InputDataError(
            f"reference {np.shape(reference)} and velocity {np.shape(velocity)} must be "
            "equal 1-D epochs", "ldv")
    res = _align_all(np.asarray(reference, float)[None], np.asarray(velocity, float)[None],
                     fs_ldv, video, f_range=f_range, knot_cycles=knot_cycles,
                     max_f0_deviation=max_f0_deviation, min_quality=min_quality,
                     min_cycles=min_cycles, smooth=smooth, phase_reference=phase_reference)
    return EpochAlignment(
        offset_s=float(res.offset_s[0]), f0_hz=float(res.f0_hz[0]), drift=float(res.drift[0]),
        drift_rate_per_s=float(res.drift_rate_per_s[0]), quality=float(res.quality[0]),
        aligned_w=res.aligned_w[0], n_cycles=int(res.n_cycles[0]), ok=bool(res.ok[0]),
        reason=str(res.reason[0]))


def sync_scan(
    video_pressure: np.ndarray, fs_video_p: float, t0_video_p: float,
    frame_times: np.ndarray, ldv_reference: np.ndarray, ldv_velocity: np.ndarray,
    fs_ldv: float, *, f_range: tuple[float, float] = F_RANGE,
    n_harmonics: int = _D.n_harmonics, knot_cycles: float = _D.knot_cycles, max_f0_deviation: float = _D.max_drift,
    min_quality: float = _D.min_quality, min_cycles: float = _D.min_cycles, smooth: float = _D.smooth,
    phase_reference: str = _D.phase_reference, source: str = "video pressure", ldv_source: str = "ldv",
) -> SyncResult:
    """Synchronise all LDV epochs of a scan onto the video's frame times.

    Parameters
    ----------
    video_pressure : (S_v,) float
        Pressure recorded with the video, any unit, at ``fs_video_p`` Hz; sample j at video
        time ``t0_video_p + j / fs_video_p`` s.
    frame_times : (n_frames,) float
        Frame times in the video's time base, s (``k / fps``).
    ldv_reference : (P, S) float
        Reference-channel pressure of each epoch (any unit, gain and offset free), at
        ``fs_ldv`` Hz.
    ldv_velocity : (P, S) float
        LDV velocity of each epoch (any unit, e.g. mm/s), same sampling.
    f_range : (2,) float
        f0 search range, Hz.
    n_harmonics : int
        Harmonics of the pressure template.
    knot_cycles : float
        Knot spacing of the phase splines, cycles (slow drift is followed, faster jitter
        averaged).
    max_f0_deviation : float
        Largest accepted ``|f0_epoch / f0_video - 1|``.
    min_quality : float
        Smallest accepted correlation between a reference and the template, in [0, 1].
    min_cycles : float
        Shortest usable epoch, cycles.
    smooth : float
        Curvature penalty of the phase splines (0.1; see :mod:`vfcli.sync.phase`).
    phase_reference : {"fundamental", "template"}
        What phase 0 of an epoch is: the maximum of its own pressure fundamental, its
        harmonics free (default: robust to waveform-shape changes between recordings), or
        the best fit of the video's whole template waveform (see :mod:`vfcli.sync.gauss_newton`).
    source : str
        Name of the video's pressure (file) for error messages.
    ldv_source : str
        Name of the scan (file) for error messages.

    Returns
    -------
    SyncResult

    Raises
    ------
    InputDataError
        The video's pressure is unusable, the LDV arrays have mismatched shapes, or the
        epochs agree on an f0 that contradicts the scan's stated sampling rate
        (:func:`vfcli.sync.rate.check_ldv_rate`).
    """
    _check_settings(f_range, knot_cycles, max_f0_deviation, min_quality, min_cycles, smooth,
                    phase_reference)
    ref = np.asarray(ldv_reference, dtype=float)
    vel = np.asarray(ldv_velocity, dtype=float)
    if ref.ndim != 2 or ref.shape != vel.shape:
        raise InputDataError(
            f"LDV reference {ref.shape} and velocity {vel.shape} must both be (points, samples)",
            ldv_source)
    video = _video_reference(video_pressure, fs_video_p, t0_video_p, frame_times, ref, fs_ldv,
                             f_range=f_range, n_harmonics=n_harmonics, knot_cycles=knot_cycles,
                             smooth=smooth, max_drift=max_f0_deviation, source=source)
    check_ldv_rate(video.f0_hz, ref, fs_ldv, f_range=f_range, max_drift=max_f0_deviation, source=ldv_source)
    return _align_all(ref, vel, fs_ldv, video, f_range=f_range, knot_cycles=knot_cycles,
                      max_f0_deviation=max_f0_deviation, min_quality=min_quality,
                      min_cycles=min_cycles, smooth=smooth, phase_reference=phase_reference)


def _video_reference(
    video_pressure: np.ndarray, fs_video_p: float, t0_video_p: float, frame_times: np.ndarray,
    ref: np.ndarray, fs_ldv: float, *, f_range: tuple[float, float], n_harmonics: int, knot_cycles: float,
    smooth: float, max_drift: float, source: str,
) -> VideoPhase:
    """:func:`video_phase_reference`, searched near the scan's f0 when that explains the video better.

    A video pressure of one or two cycles gives no reliable f0 of its own: its estimate can be a
    harmonic, and sync then blamed the scan's sampling rate (:func:`vfcli.sync.rate.check_ldv_rate`)
    or called the video too short at a wrong f0. When the video's estimate fails or differs by
    more than ``max_drift`` from the f0 the scan's long epochs agree on
    (:func:`vfcli.sync.rate.scan_f0`), and the scan's f0 explains the video's pressure clearly better
    (:func:`vfcli.sync.rate.scan_explains_video`), the video is fitted again with the f0 search range
    ``scan f0 / (1 + max_drift) .. scan f0 * (1 + max_drift)``; a record under 2 cycles of it is
    refused as too short (InputDataError, naming the length it needs).
    """
    kw = dict(n_harmonics=n_harmonics, knot_cycles=knot_cycles, smooth=smooth, source=source)
    try:
        video, error = video_phase_reference(video_pressure, fs_video_p, t0_video_p, frame_times,
                                             f_range=f_range, **kw), None
    except InputDataError as exc:
        video, error = None, exc
    f_scan = scan_f0(ref, fs_ldv, f_range, max_drift)
    if (f_scan is None or (video is not None and abs(video.f0_hz / f_scan - 1.0) <= max_drift)
            or not scan_explains_video(video_pressure, fs_video_p, None if video is None else video.f0_hz, f_scan,
                                       n_harmonics)):
        if video is None:
            raise error
        return video
    duration = (np.asarray(video_pressure).size - 1) / fs_video_p
    if duration * f_scan < 2.0:
        raise InputDataError(
            f"too short: the pressure recorded with the video ({duration * 1e3:.1f} ms) holds {duration * f_scan:.1f} "
            f"cycles at the f0 the scan's reference pressure agrees on ({f_scan:.1f} Hz); sync needs at least 2 "
            f"cycles: a video and pressure record of at least {2e3 / f_scan:.1f} ms", source)
    log.info("sync: the video's pressure holds %.1f cycles at the scan's f0 %.2f Hz (its own estimate: %s); "
             "searching its f0 near the scan's", duration * f_scan, f_scan,
             "none" if video is None else f"{video.f0_hz:.2f} Hz")
    return video_phase_reference(video_pressure, fs_video_p, t0_video_p, frame_times,
                                 f_range=(f_scan / (1.0 + max_drift), f_scan * (1.0 + max_drift)), **kw)


def _align_all(
    ref: np.ndarray, vel: np.ndarray, fs: float, video: VideoPhase, *,
    f_range: tuple[float, float] = F_RANGE, knot_cycles: float = _D.knot_cycles,
    max_f0_deviation: float = _D.max_drift, min_quality: float = _D.min_quality, min_cycles: float = _D.min_cycles,
    smooth: float = _D.smooth, phase_reference: str = _D.phase_reference,
) -> SyncResult:
    _check_settings(f_range, knot_cycles, max_f0_deviation, min_quality, min_cycles,
                    smooth, phase_reference)
    n_pts, n = ref.shape
    n_frames = video.frame_times.size
    tracks, reason = epoch_phase_tracks(ref, fs, video, f_range=f_range,
                                        knot_cycles=knot_cycles, min_cycles=min_cycles,
                                        smooth=smooth, phase_reference=phase_reference)
    q = tracks.quality
    drift = tracks.f0_hz / video.f0_hz - 1.0
    fitted = reason == ""
    r = np.where(fitted & (q < NO_PERIODICITY_QUALITY),
                 "no periodicity in the reference pressure", reason)
    r = np.where((r == "") & (np.abs(drift) > max_f0_deviation),
                 [f"f0 {f:.2f} Hz is {100 * d:+.1f}% from the video's {video.f0_hz:.2f} Hz "
                  f"(max {100 * max_f0_deviation:.0f}%)" for f, d in zip(tracks.f0_hz, drift)],
                 r)
    r = np.where((r == "") & (tracks.gain <= 0), "inverted reference polarity", r)
    r = np.where((r == "") & (q < min_quality),
                 [f"low alignment quality {x:.3f} < {min_quality}" for x in q], r)
    reason = np.asarray(r, dtype=object)

    aligned = np.full((n_pts, n_frames), np.nan)
    offset = np.full(n_pts, np.nan)
    n_cyc = np.zeros(n_pts, dtype=int)
    rows = np.flatnonzero(reason == "")
    if rows.size:
        t_samp = np.arange(n) / fs
        target0 = video.frame_phase[:1]
        for lo in range(0, rows.size, 64):
            chunk = rows[lo:lo + 64]
            sub = PhaseTracks(tracks.knots, tracks.degree, tracks.theta[chunk], 0.0,
                              tracks.duration, tracks.f0_hz[chunk],
                              tracks.drift_rate_per_s[chunk], tracks.gain[chunk], q[chunk])
            phases = sub.phase_at(t_samp)
            for j, p in enumerate(chunk):
                ph = phases[j]
                if np.any(np.diff(ph) <= 0):
                    reason[p] = "phase track not monotonic"
                    continue
                aligned[p], n_cyc[p] = phase_average_at(vel[p], ph, fs, video.frame_phase)
                times, valid = matched_times(ph, fs, target0, margin=0)
                offset[p] = times[0][valid[0]][0] if valid[0].any() else np.nan
                if not np.all(np.isfinite(aligned[p])):
                    reason[p] = "no finite velocity at some frame phases"
                    aligned[p] = np.nan
    ok = reason == ""
    log.info("synchronised %d of %d LDV points (video f0 %.3f Hz)", int(ok.sum()), n_pts,
             video.f0_hz)
    return SyncResult(
        offset_s=offset, f0_hz=tracks.f0_hz, drift=drift,
        drift_rate_per_s=tracks.drift_rate_per_s, quality=q, aligned_w=aligned,
        n_cycles=n_cyc, ok=ok, reason=reason.astype(str), f0_video_hz=video.f0_hz,
        video_phase=video.frame_phase, template=video.template.coeffs, tracks=tracks)


def _check_settings(f_range, knot_cycles, max_f0_deviation, min_quality, min_cycles, smooth,
                    phase_reference) -> None:
    """Raise ValueError for out-of-range synchronisation settings (the config validates them first)."""
    if phase_reference not in ("fundamental", "template"):
        raise ValueError(f"sync phase_reference must be 'fundamental' or 'template', "
                          f"got {phase_reference!r}")
    if not (0 < f_range[0] < f_range[1]):
        raise ValueError(f"sync f_range must be 0 < low < high Hz, got {f_range}")
    if not knot_cycles > 0 or not max_f0_deviation > 0 or not min_cycles > 0 or smooth < 0:
        raise ValueError(
            f"sync knot_cycles ({knot_cycles}), max_f0_deviation ({max_f0_deviation}) and "
            f"min_cycles ({min_cycles}) must be > 0, smooth ({smooth}) >= 0")
    if not 0.0 <= min_quality <= 1.0:
        raise ValueError(f"sync min_quality must lie in [0, 1], got {min_quality}")
