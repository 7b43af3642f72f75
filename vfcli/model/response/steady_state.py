"""A quasi-static response extended by the periodic steady state of mass and damping: a Response.

The extended model of the folds under a load model's controls ``x`` (n_params,) is

    U(x, t) = U0(x, t) + Re sum_k [H_k(rho, tau, eta) - H_k(0, 0, eta)] L C beta_k e^{i k w0 t}

with U0 the quasi-static response (:class:`vfcli.model.response.quasi_static.QuasiStaticResponse`),
``H_k = (c K - rho (k w0)^2 M)^-1``, ``c = (1 + i eta)(1 + i k w0 tau)`` the transfer of the
harmonic k of f0 (:class:`vfcli.model.response.modal.ModalReduction`, units mm, Pa, s), L the load
model's spatial loads, C its control matrix (n_spatial, n_time) and ``beta_k`` (n_time,) the
harmonics of f0 of the load model's time basis, fitted once over ``fit_times`` (the run's window,
:func:`vfcli.model.response.modal.harmonic_fit`).  At ``rho = tau = 0`` the change vanishes: the
extended model is the baseline.  The change is the periodic steady state of the window's load
(its harmonics up to ``n_harmonics``) with the mass (density factor ``rho``) and the Kelvin-Voigt
retardation ``tau`` switched on, minus the same without them, at the structural loss ``eta``.

For fixed (rho, tau, eta) it is linear in x and implements
:class:`vfcli.model.response.base.Response` exactly: its linearisation has the quasi-static term
and two separable terms per harmonic (the real and imaginary parts), so a problem
(:class:`vfcli.inverse.problem.Problem`) with this response refits the loads *with* the dynamics
(the confirmation refit of the inertia and damping candidates, :mod:`vfcli.diagnose.refit`).
"""
from __future__ import annotations

import numpy as np

from vfcli.model.response.base import Linearization, SeparableTerm
from vfcli.model.response.modal import harmonic_fit


def change_transfers(reduction, omegas: np.ndarray, density: float, retardation_s: float, loss: float) -> np.ndarray:
    """(K, N, 3, S) complex ``[H(rho, tau, eta) - H(0, 0, eta)] L`` at each angular frequency of ``omegas`` (K,)
    rad/s, mm per unit load pattern, from the modal reduction.

    One product with the reduction's vertex modes for every frequency and both the real and imaginary parts: the
    modes (r, N, 3) are the large operand (the complete expansion of a 2.5 mm mesh: 6960 modes of 438 surface
    vertices, 73 MB), read once instead of twice per frequency (docs/benchmarks.md, "Session 73: the install, and
    the steady state's transfers in one product")."""
    omegas = np.atleast_1d(np.asarray(omegas, dtype=float))
    d = np.stack([reduction.modal_factors(w, density, retardation_s, loss) - reduction.modal_factors(w, 0.0, 0.0, loss)
                  for w in omegas])                                              # (K, r) complex
    modes = reduction.vertex_modes_                                              # (r, N, 3) real
    flat = modes.reshape(len(modes), -1).T                                       # (3N, r), no complex copy
    w = d[:, :, None] * reduction.modal_loads_[None]                             # (K, r, S) complex
    k, r, n_s = w.shape
    rhs = np.concatenate([w.real, w.imag]).transpose(1, 0, 2).reshape(r, 2 * k * n_s)
    out = (flat @ rhs).reshape(-1, 2, k, n_s)                                    # (3N, re/im, K, S)
    return (out[:, 0] + 1j * out[:, 1]).transpose(1, 0, 2).reshape(k, modes.shape[1], 3, n_s)


class SteadyStateResponse:
    """The quasi-static ``base`` response plus the steady-state change of mass and damping (module docstring).

    Parameters
    ----------
    base : the run's quasi-static response (``load_model``, ``linearize``, ``penalty_operator``).
    reduction : :class:`vfcli.model.response.modal.ModalReduction` of the run's model and the load
        model's spatial loads.
    f0_hz : fundamental, Hz (finite, > 0).
    fit_times : (T,) s over which the time basis's harmonics are fitted (the run's ``sim_times``).
    density : density factor rho (1: the model's own density).
    retardation_s : Kelvin-Voigt retardation time tau, s.
    loss : structural loss factor eta (both the extended and the reference steady state).
    n_harmonics : harmonics of f0 kept.
    """

    def __init__(self, base, reduction, f0_hz: float, fit_times: np.ndarray, density: float = 0.0,
                 retardation_s: float = 0.0, loss: float = 0.0, n_harmonics: int = 6) -> None:
        if not (np.isfinite(f0_hz) and f0_hz > 0):
            raise ValueError(f"the steady-state response needs a positive f0, got {f0_hz!r}")
        self.base, self.load_model = base, base.load_model
        self.n_vertices = int(base.n_vertices)
        self.f0_hz, self.density, self.retardation_s, self.loss = float(f0_hz), float(density), \
            float(retardation_s), float(loss)
        fit_times = np.asarray(fit_times, dtype=float)
        self.beta = harmonic_fit(self.load_model.time_basis(fit_times), fit_times, self.f0_hz,
                                 int(n_harmonics))                             # (K + 1, n_time) complex
        w0 = 2 * np.pi * self.f0_hz
        self.delta = change_transfers(reduction, w0 * np.arange(self.beta.shape[0]), self.density,
                                      self.retardation_s, self.loss)          # (K + 1, N, 3, S) complex

    @property
    def n_params(self) -> int:
        return self.base.n_params

    def linearize(self, x: np.ndarray | None, times: np.ndarray) -> Linearization:
        """dU/dx (exact, independent of x): the base's terms, then per harmonic k of f0 the terms
        ``(Re Delta_k, Re(beta_k e^{ikw0t}))`` and ``(-Im Delta_k, Im(beta_k e^{ikw0t}))`` (k = 0: the first only)."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        terms = list(self.base.linearize(x, times).terms)
        w0 = 2 * np.pi * self.f0_hz
        for k in range(self.beta.shape[0]):
            e = np.exp(1j * k * w0 * times)[:, None] * self.beta[k][None, :]   # (T, n_time)
            terms.append(SeparableTerm(np.ascontiguousarray(self.delta[k].real), np.ascontiguousarray(e.real)))
            if k:
                terms.append(SeparableTerm(np.ascontiguousarray(-self.delta[k].imag), np.ascontiguousarray(e.imag)))
        return Linearization(tuple(terms))

    def change(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, N, 3) the steady-state change alone (mm): ``displacements - base.displacements``."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        c = self.load_model.control_matrix(np.asarray(x, dtype=float))       # (S, n_time)
        w0 = 2 * np.pi * self.f0_hz
        out = np.zeros((len(times), self.n_vertices, 3))
        for k in range(self.beta.shape[0]):
            u_k = self.delta[k] @ (c @ self.beta[k])                          # (N, 3) complex
            out += np.real(np.exp(1j * k * w0 * times)[:, None, None] * u_k[None])
        return out

    def displacements(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, N, 3) vertex displacements, mm, at ``times`` (T,) s for controls ``x`` (n_params,)."""
        return self.base.displacements(x, times) + self.change(x, times)

    def adjoint(self, g: np.ndarray, times: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """(n_params,) gradient of ``sum(g * displacements(x, times))`` with respect to x, g (T, N, 3)."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        out = np.asarray(self.base.adjoint(g, times, x), dtype=float).reshape(
            self.load_model.n_spatial, self.load_model.n_time)
        g = np.asarray(g, dtype=float)
        w0 = 2 * np.pi * self.f0_hz
        for k in range(self.beta.shape[0]):
            # d/dC of sum_t Re(e_t * <g_t, Delta C beta>) = Re(sum_t e_t Delta^T g_t) beta^T
            gk = np.tensordot(np.exp(1j * k * w0 * times), g, axes=(0, 0))                 # (N, 3) complex
            z = np.einsum("nc,ncs->s", gk, self.delta[k])                                     # (S,) complex
            out += np.real(np.outer(z, self.beta[k]))
        return out.ravel()

    def penalty_operator(self):
        """The base response's ridge matrix Omega."""
        return self.base.penalty_operator()
