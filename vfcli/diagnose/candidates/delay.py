"""A delay of the load behind the recorded subglottal pressure (or of the sync): one time, the same at every harmonic.

The pressure load model ties the load in time to the recorded subglottal pressure p_s(t).  The pressure
that drives the folds lags it (the intraglottal flow), and an error of the synchronisation shifts the
camera against the pressure the same way: the motion is then the baseline's at ``t - d``
(:class:`vfcli.model.response.delayed.DelayedResponse`), a phase lag ``k w0 d`` at harmonic k, linear in
k, with no amplitude lost.  Its column at d = 0 is ``-U0'(t)``, exactly Kelvin-Voigt damping's
(:class:`vfcli.diagnose.candidates.damping.KelvinVoigtDamping`: ``atan(k w0 tau)`` and an amplitude loss
``1 / sqrt(1 + (k w0 tau)^2)``), so the two are told apart only at finite size, by their refitted
profiles (bench/bench_term_profile.py), never by the score test.

This term is the alternative explanation a damping lead must beat; it is not in the screened
family (:data:`vfcli.diagnose.candidates.CANDIDATES`): with the same column as damping it adds nothing
to the score tests.
"""
from __future__ import annotations

import numpy as np

from vfcli.diagnose.candidates.base import DisplacementTerm
from vfcli.diagnose.candidates.damping import MS, KelvinVoigtDamping
from vfcli.model.response.delayed import DelayedResponse


class LoadDelay(DisplacementTerm):
    """The load's delay behind the recorded subglottal pressure, ms (module docstring)."""

    name = "delay"
    parameter_names = ("load_delay_ms",)
    signature = ("the motion lags the recorded subglottal pressure by one time at every harmonic (a phase "
                 "lag linear in frequency, no amplitude lost): the load's own delay, or the sync's timing")

    def __init__(self) -> None:
        self._damping = KelvinVoigtDamping()          # its column at 0 is this term's

    def response(self, baseline, theta: np.ndarray) -> DelayedResponse:
        """The baseline's response with its load delayed by theta[0] ms."""
        return DelayedResponse(baseline.problem.response, MS * float(np.asarray(theta, dtype=float).reshape(-1)[0]))

    def displacement_jacobian(self, baseline) -> np.ndarray:
        """(F + 1, N, 3, 1) dU/dd at d = 0, mm per ms: ``-U0'(t)``, damping's column (module docstring)."""
        return self._damping.displacement_jacobian(baseline)

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) exact change at delay theta[0] ms, at the baseline's loads."""
        return self.response(baseline, theta).change(baseline.x, baseline.problem.sim_times)
