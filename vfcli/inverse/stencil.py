"""The model's velocity at the frame times: which simulated displacements, with which weights.

The measured velocity of frame f belongs to the frame time t_f: :func:`vfcli.flow.optical_flow.flow_stream`
attributes the mean of the two midpoint flows around frame k to t_k (and extrapolates
``1.5 f(k + 1/2) - 0.5 f(k + 3/2)`` at a recording's first frame), and the vibrometer is synced onto the
frame times.  The model is simulated at the F + 1 times t_0 .. t_F (:attr:`vfcli.inverse.problem.
Problem.sim_times`); its velocity at t_f is the same combination of its own midpoint differences::

    f = 0:          (-1.5 U_0 + 2 U_1 - 0.5 U_2) / dt          (1.5 d_1/2 - 0.5 d_3/2)
    0 < f < F:      (U_{f+1} - U_{f-1}) / (2 dt)               (0.5 d_f-1/2 + 0.5 d_f+1/2)

both second order in dt at t_f.  The forward difference ``(U_{f+1} - U_f) / dt`` of the paper's v-bar is the
velocity at t_f + dt/2: compared with frame-time data it put the model half a frame ahead of the
recording (E 40 % above its value with the model delayed by dt/2 on the demo phantom; docs/diagnose.md).
"""
from __future__ import annotations

import numpy as np


def frame_velocity_stencil(n_frames: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """Per frame f of ``n_frames`` (>= 2): (indices into the F + 1 simulated times, weights), the model's
    velocity at t_f being ``sum_k w_k U[idx_k] / dt`` (module docstring)."""
    n = int(n_frames)
    if n < 2:
        raise ValueError(f"the frame-time velocity needs at least 2 frames, got {n}")
    out = [(np.array([0, 1, 2]), np.array([-1.5, 2.0, -0.5]))]
    out += [(np.array([f - 1, f + 1]), np.array([-0.5, 0.5])) for f in range(1, n)]
    return tuple(out)


def stencil_apply(u: np.ndarray, stencil: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``sum_k w_k u[idx_k]`` of one frame's stencil over the first axis of u (e.g. (F + 1, N, 3) mm -> (N, 3))."""
    idx, w = stencil
    return np.tensordot(w, np.asarray(u)[idx], axes=1)


def stencil_scatter(out: np.ndarray, stencil: tuple[np.ndarray, np.ndarray], value: np.ndarray) -> None:
    """The adjoint of :func:`stencil_apply`: ``out[idx_k] += w_k * value`` for one frame's stencil (in place)."""
    idx, w = stencil
    for k, wk in zip(idx, w):
        out[k] += wk * value
