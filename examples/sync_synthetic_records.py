"""Synchronise sequential vibrometer records onto a video's time base, with the library alone.

A laser-Doppler vibrometer measures one scan point at a time, each in its own recording
(epoch); the subglottal pressure recorded beside each epoch and beside the video is the common
clock. Here everything is synthetic: a glottal-like pressure cycle (six harmonics) at 150 Hz
beside a 20 ms high-speed video (10 kHz), and 12 epochs of 0.2 s at 50 kHz, each with its own
f0 (up to 1.5 % off the video's), start phase, reference gain and offset, and 2 % pressure noise;
the velocity of each point is its own two-harmonic waveform of the same cycle phase.
``vfcli.sync.align.sync_scan`` maps every frame to the matching instants of every cycle of each
epoch and averages the velocity there; the truth on the frame times is known.

Run: ``python examples/sync_synthetic_records.py`` (a few seconds). tests/test_examples.py checks
``VELOCITY_ERROR_REL`` (relative RMS error of the aligned velocity on the frame times).
"""
from __future__ import annotations

import numpy as np

from vfcli.sync.align import sync_scan

FS, FPS, F0_HZ, N_POINTS = 50_000.0, 10_000.0, 150.0, 12
rng = np.random.default_rng(0)
harmonics = np.array([1.0, 0.5, 0.3, 0.15, 0.08, 0.04]) * 160.0 * np.exp(2j * np.pi * rng.uniform(size=6))


def pressure(phase: np.ndarray) -> np.ndarray:
    """Pa at cycle phase ``phase`` (cycles): 800 Pa mean and the harmonics above."""
    k = np.arange(1, harmonics.size + 1)
    return 800.0 + (harmonics * np.exp(2j * np.pi * np.asarray(phase)[..., None] * k)).real.sum(axis=-1)


# the video: its pressure from t0 = -2 ms at 50 kHz, and the frame times
t0 = -0.002
t_video = t0 + np.arange(int(0.2 * FS)) / FS
phase0_video = rng.uniform()
noise_pa = 0.02 * np.sqrt(np.sum(np.abs(harmonics) ** 2) / 2)
video_pressure = pressure(phase0_video + F0_HZ * t_video) + noise_pa * rng.standard_normal(t_video.size)
frame_times = np.arange(200) / FPS

# the epochs: reference channel (volts: gain and offset of their own) and velocity (mm/s)
t = np.arange(int(0.2 * FS)) / FS
f0 = F0_HZ * (1 + rng.uniform(-0.015, 0.015, N_POINTS))
start = rng.uniform(0, 100, N_POINTS)
amp = rng.uniform(100, 300, (N_POINTS, 2)) * np.exp(2j * np.pi * rng.uniform(size=(N_POINTS, 2)))
phase = start[:, None] + f0[:, None] * t[None]
reference = (pressure(phase) + noise_pa * rng.standard_normal(phase.shape)) / 250.0 + 0.3
velocity = (amp[:, :1] * np.exp(2j * np.pi * phase) + amp[:, 1:] * np.exp(4j * np.pi * phase)).real
velocity += 0.01 * velocity.std() * rng.standard_normal(velocity.shape)

result = sync_scan(video_pressure, FS, t0, frame_times, reference, velocity, FS)

# the truth: each point's waveform at the video's phase at every frame
phase_frames = phase0_video + F0_HZ * frame_times
truth = (amp[:, :1] * np.exp(2j * np.pi * phase_frames) + amp[:, 1:] * np.exp(4j * np.pi * phase_frames)).real
N_OK = int(result.ok.sum())
VELOCITY_ERROR_REL = float(np.sqrt(np.mean((result.aligned_w - truth) ** 2) / np.mean(truth ** 2)))

if __name__ == "__main__":
    print(f"{N_OK} of {N_POINTS} epochs aligned; velocity on the frame times: relative RMS error "
          f"{100 * VELOCITY_ERROR_REL:.2f} %")
