"""Result types of :mod:`vfcli.sync.align` (plain dataclasses of numpy arrays)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vfcli.sync.phase import PhaseTracks, PressureTemplate


@dataclass
class VideoPhase:
    """The video's phase reference.

    Attributes
    ----------
    template : PressureTemplate
        Unit-RMS harmonic template of the video's pressure; phase 0 = fundamental maximum.
    track : PhaseTracks
        Phase of the video's pressure (N = 1), times in the video's time base (s).
    f0_hz : float
        Mean f0 of the video's pressure record, Hz.
    frame_times : (n_frames,) float
        Video frame times, s.
    frame_phase : (n_frames,) float
        Phase at the frame times, cycles; ``frame_phase[0]`` in [0, 1).
    quality : float
        Correlation of the video's pressure with its own template fit.
    """

    template: PressureTemplate
    track: PhaseTracks
    f0_hz: float
    frame_times: np.ndarray
    frame_phase: np.ndarray
    quality: float


@dataclass
class SyncResult:
    """Synchronisation of P LDV points onto n_frames video frames.

    Attributes
    ----------
    offset_s : (P,) float
        Epoch time (s from the epoch's first sample) whose phase equals the first frame's.
    f0_hz : (P,) float
        Mean f0 of each epoch's reference, Hz.
    drift : (P,) float
        ``f0_hz / f0_video_hz - 1``.
    drift_rate_per_s : (P,) float
        Linear trend of the epoch's instantaneous f0 divided by its mean, 1/s.
    quality : (P,) float
        Correlation of each reference with the video's template at the fitted phase, [0, 1].
    aligned_w : (P, n_frames) float
        Phase-averaged LDV velocity on the video frame times (velocity units); NaN if not ok.
    n_cycles : (P,) int
        Cycles of the epoch averaged (full cycles covered).
    ok : (P,) bool
        Point aligned.
    reason : (P,) str
        Why a point is not ok ('' when ok).
    f0_video_hz : float
        Video's mean f0, Hz.
    video_phase : (n_frames,) float
        Video phase at the frame times, cycles.
    template : (H,) complex
        Video's pressure template (phase reference), see :class:`PressureTemplate`.
    tracks : PhaseTracks or None
        Epoch phase tracks (all P rows; rows of points rejected before fitting are NaN).
    """

    offset_s: np.ndarray
    f0_hz: np.ndarray
    drift: np.ndarray
    drift_rate_per_s: np.ndarray
    quality: np.ndarray
    aligned_w: np.ndarray
    n_cycles: np.ndarray
    ok: np.ndarray
    reason: np.ndarray
    f0_video_hz: float
    video_phase: np.ndarray
    template: np.ndarray
    tracks: PhaseTracks | None = None


@dataclass
class EpochAlignment:
    """One point's alignment (the fields of :class:`SyncResult` for one row)."""

    offset_s: float
    f0_hz: float
    drift: float
    drift_rate_per_s: float
    quality: float
    aligned_w: np.ndarray
    n_cycles: int
    ok: bool
    reason: str
