"""The confirmation refit's small case: the pressure-load case of tests/_candidates_case.py with data that carry a
candidate at a known theta (tests/test_diagnose_refit.py, tests/test_diagnose_refit_inertia.py)."""
from __future__ import annotations

import dataclasses

import numpy as np

from _candidates_case import CAMERA, SETTINGS, pressure_case
from vfcli.diagnose.candidate import Baseline
from vfcli.inverse.problem import Problem, synthesize_measurement


class _Shown:
    """A response that shows fixed displacements at the case's simulated times (the data's truth)."""

    def __init__(self, response, disp, times):
        self._r, self._disp, self._times = response, disp, times

    def displacements(self, x, t):
        assert np.allclose(t, self._times)
        return self._disp

    def __getattr__(self, name):
        return getattr(self._r, name)


def case_with(candidate, theta, noise_mm_s: float = 0.0, seed: int = 0, n_frames: int = 12) -> Baseline:
    """The pressure case (``n_frames`` per cycle) whose data carry ``candidate`` at ``theta`` (+ white noise
    on the velocity), as a Baseline at the case's true loads (theta = 0: the baseline's start)."""
    b0 = pressure_case(n_frames, 4)
    p0 = b0.problem
    disp = b0.displacements + candidate.extension(b0, np.asarray(theta, float))
    meas = synthesize_measurement(p0.mesh, CAMERA, _Shown(p0.response, disp, p0.sim_times), p0.meas.times, b0.x,
                                  SETTINGS)
    if noise_mm_s:
        rng = np.random.default_rng(seed)
        meas = dataclasses.replace(meas, velocity=meas.velocity + rng.normal(0, noise_mm_s, meas.velocity.shape))
    base = Baseline.at(Problem(p0.mesh, CAMERA, p0.response, meas, SETTINGS), b0.x, b0.f0_hz)
    base.model = b0.model
    return base
