"""Kelvin-Voigt damping: a retardation time tau of the tissue, ``K (u + tau u') = F``.

Switched on from the quasi-static baseline ``K u0 = F``, the displacement is
``u = u0 - tau u0' + O(tau^2)`` for any load history, so

    dU/dtau = -U0'(t)        (the baseline's own velocity, per ms of tau)

per harmonic k of f0 a factor ``1 / (1 + i k w0 tau)``: a phase lag growing with frequency and
an amplitude loss growing with it (:class:`vfcli.model.response.modal.ModalReduction` gives the
full steady state at any tau).  A load model whose time profile is free (a Bernstein basis,
closed under d/dt) absorbs it exactly; only a load tied in time to the measured subglottal
pressure leaves the lag visible (the reference note "What superior-surface data can and cannot
reveal").
"""
from __future__ import annotations

import numpy as np

from vfcli.diagnose.candidates.base import DisplacementTerm, derivative_step, time_derivative
from vfcli.model.response.modal import harmonic_fit
from vfcli.model.response.steady_state import SteadyStateResponse

#: parameter unit: the column is per millisecond of retardation time
MS = 1e-3


class KelvinVoigtDamping(DisplacementTerm):
    """Kelvin-Voigt retardation time tau (ms), one parameter."""

    name = "damping"
    parameter_names = ("retardation_time_ms",)
    signature = ("a phase lag of the motion behind the load that grows with frequency "
                 "(harmonic k delayed by atan(k w0 tau)), and amplitude lost at the higher harmonics")
    #: a retardation time is positive: a lead in the motion (tau < 0) is no damping
    one_sided = True
    #: retardation times (ms) the profile screening and the confirmation refit's start scan try: loss
    #: factors ``2 pi f0 tau`` of 0.04-0.6 at 120 Hz (0.05-0.85 at 170 Hz), around silicone's estimated
    #: 0.1-0.3 (the reference's physical setup); a loss factor far beyond 0.2 is not linear in tau
    start_values = (0.05, 0.1, 0.2, 0.4, 0.8)
    #: the score test's column at tau = 0 is also the column of a load that lags the recorded pressure and
    #: is linear in tau only while ``k w0 tau`` is small at the harmonics that carry the motion: the
    #: diagnosis also profiles E over :attr:`start_values` with the loads refitted under the viscoelastic
    #: steady state (:mod:`vfcli.diagnose.profile`; the blind panel's damping phantoms 2008 and 2013, which
    #: the calibrated score test misses, fit 66 and 76 % better at their best value, docs/benchmarks.md "Session 12")
    profile_screening = True

    def __init__(self, model=None, modal=None) -> None:
        """model : the FEM model (default: the baseline's).  modal : an :class:`Inertia` whose modal reduction
        this term shares (built once per baseline for both), default its own."""
        from vfcli.diagnose.candidates.inertia import Inertia

        self._modal = modal if modal is not None else Inertia(model)   # its modal reduction and steady state

    def reduction(self, baseline, map=None):
        """The modal reduction the steady state uses (:meth:`Inertia.reduction`, built once per baseline; map: its
        factorisations', :class:`vfcli.model.response.modal.ModalReduction`)."""
        return self._modal.reduction(baseline, self._modal.n_harmonics, map=map)

    def displacement_jacobian(self, baseline) -> np.ndarray:
        """(F + 1, N, 3, 1) dU/dtau at tau = 0, mm per ms: ``-U0'(t)``.  For a load tied to a recorded
        signal (``measured_time_basis``, the pressure load) and a known f0 the velocity of the harmonics
        of f0 of the load over the window (the derivative of :meth:`extension` at 0: differences would
        differentiate the recorded pressure's sensor noise, as for :class:`Inertia`'s column)."""
        p = baseline.problem
        load_model = getattr(p.response, "load_model", None)
        if (np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0 and getattr(load_model, "measured_time_basis", False)
                and hasattr(p.response, "basis_")):
            t = p.sim_times
            beta = harmonic_fit(load_model.time_basis(t), t, baseline.f0_hz, self._modal.n_harmonics)
            w0 = 2 * np.pi * baseline.f0_hz
            k = np.arange(beta.shape[0])
            rate = np.real((np.exp(1j * w0 * np.outer(t, k)) * (1j * k * w0)) @ (beta @ load_model.control_matrix(baseline.x).T))
            vel = np.einsum("ncs,ts->tnc", p.response.basis_, rate)              # (T, N, 3) mm/s
            return (-MS * vel)[..., None]
        vel = time_derivative(lambda t: p.response.displacements(baseline.x, t), p.sim_times, 1,
                              derivative_step(baseline))
        return (-MS * vel)[..., None]

    def response(self, baseline, theta: np.ndarray) -> SteadyStateResponse:
        """The extended response at retardation time theta[0] (ms): the baseline's quasi-static response plus
        the steady-state change of the viscoelastic folds (each harmonic k of f0 times ``1 / (1 + i k w0 tau)``
        per mode, massless, no structural loss), from the modal reduction of :class:`Inertia` (built once);
        linear in the loads, so the confirmation refit fits the loads with the damping's lag (exact
        x-columns, :mod:`vfcli.diagnose.refit`) instead of the elastic model's."""
        tau_s = MS * float(np.asarray(theta, dtype=float).reshape(-1)[0])
        p = baseline.problem
        return SteadyStateResponse(p.response, self.reduction(baseline),
                                   baseline.f0_hz, p.sim_times, retardation_s=tau_s,
                                   n_harmonics=self._modal.n_harmonics)

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """Exact change at retardation time theta[0] (ms): :meth:`response`'s steady-state change at the
        baseline's loads."""
        if not (np.isfinite(baseline.f0_hz) and baseline.f0_hz > 0):
            raise ValueError(f"the damping steady state needs the baseline's f0, got {baseline.f0_hz!r}")
        return self.response(baseline, theta).change(baseline.x, baseline.problem.sim_times)
