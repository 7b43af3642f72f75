"""The model's velocity at the frame times (vfcli.inverse.stencil) against an analytic motion.

The measured velocity of frame f belongs to t_f (flow_stream's midpoint flows averaged around the frame);
the model's must too.  For U(t) = sin(w t) sampled at the F + 1 simulated times, the stencil's velocity at
t_f converges to w cos(w t_f) at second order in dt, at every frame including the first; the paper's
forward difference (U_{f+1} - U_f) / dt, which the motion term used before session 10, converges only at
first order there, being the velocity half a frame later (its error at t_f + dt/2 is second order).
"""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.inverse.stencil import frame_velocity_stencil, stencil_apply

W = 2 * np.pi * 120.0          # rad/s, f0 of the phantoms


def _errors(frames_per_cycle: int) -> tuple[float, float, float]:
    """(max error of the stencil at t_f, of the forward difference at t_f, of the forward difference at
    t_f + dt/2), relative to w, over 2 cycles."""
    dt = 1.0 / (120.0 * frames_per_cycle)
    n = 2 * frames_per_cycle
    t = 0.001 + dt * np.arange(n + 1)                      # the F + 1 simulated times
    u = np.sin(W * t)[:, None, None] * np.ones((1, 2, 3))   # (F + 1, N, 3)
    st = frame_velocity_stencil(n)
    v = np.array([stencil_apply(u, st[f])[0, 0] / dt for f in range(n)])
    fwd = (u[1:, 0, 0] - u[:-1, 0, 0]) / dt
    exact = W * np.cos(W * t[:-1])
    mid = W * np.cos(W * (t[:-1] + 0.5 * dt))
    return (float(np.max(np.abs(v - exact))) / W, float(np.max(np.abs(fwd - exact))) / W,
            float(np.max(np.abs(fwd - mid))) / W)


def test_the_frame_velocity_is_second_order_at_the_frame_times_and_the_forward_difference_is_not():
    coarse, fine = _errors(40), _errors(80)
    rate = [np.log2(c / f) for c, f in zip(coarse, fine)]
    assert 1.9 < rate[0] < 2.1, rate                       # the stencil at t_f: second order
    assert 0.9 < rate[1] < 1.1, rate                       # the forward difference at t_f: first order
    assert 1.9 < rate[2] < 2.1, rate                       # ... it is the velocity at t_f + dt/2
    # at 83 frames per cycle (10 kHz, 120 Hz) the forward difference was off by 3.8 % of the amplitude
    assert _errors(83)[1] == pytest.approx(np.pi / 83, rel=0.02)
    assert _errors(83)[0] < 2e-3


def test_the_stencil_needs_two_frames_and_uses_only_simulated_times():
    with pytest.raises(ValueError, match="at least 2 frames"):
        frame_velocity_stencil(1)
    for n in (2, 3, 12):
        st = frame_velocity_stencil(n)
        assert len(st) == n
        for idx, w in st:
            assert idx.min() >= 0 and idx.max() <= n and abs(w.sum()) < 1e-15   # a constant has no velocity
