"""A response whose load lags the one its load model describes by a fixed time: a Response.

    U(x, t) = U_base(x, t - d)

with ``U_base`` any response (the quasi-static response of the pressure load, whose time basis is the
recorded subglottal pressure) and ``d`` the delay, s.  It is linear in x at fixed d and implements
:class:`vfcli.model.response.base.Response` exactly: the base's displacements, adjoint and linearisation
at the times ``t - d``.  The intraglottal pressure that drives the folds is not the subglottal pressure
the sensor records: it lags it (the widened phantoms draw 0-0.1 cycles, vfcli/synth/widened.py), and a
timing error of the synchronisation shifts it the same way.  For small d the change is ``-d U_base'(t)``,
the same as a Kelvin-Voigt retardation time's (:class:`vfcli.diagnose.candidates.damping.
KelvinVoigtDamping`): a lag of the motion behind the pressure does not say by itself which of the two it is.
"""
from __future__ import annotations

import numpy as np


class DelayedResponse:
    """The ``base`` response with its load delayed by ``delay_s`` seconds (module docstring).

    Parameters
    ----------
    base : a :class:`vfcli.model.response.base.Response` with a ``load_model``.
    delay_s : the delay d, s (negative: the load leads).
    """

    def __init__(self, base, delay_s: float) -> None:
        self.base, self.load_model, self.delay_s = base, base.load_model, float(delay_s)
        self.n_vertices = int(base.n_vertices)
        if hasattr(base, "basis_"):
            self.basis_ = base.basis_

    @property
    def n_params(self) -> int:
        return self.base.n_params

    def _shifted(self, times: np.ndarray) -> np.ndarray:
        return np.atleast_1d(np.asarray(times, dtype=float)) - self.delay_s

    def displacements(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, N, 3) vertex displacements, mm: the base's at ``times - delay_s``."""
        return self.base.displacements(x, self._shifted(times))

    def change(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, N, 3) the delay's change alone (mm): ``displacements - base.displacements``."""
        return self.displacements(x, times) - self.base.displacements(x, np.atleast_1d(np.asarray(times, float)))

    def adjoint(self, g: np.ndarray, times: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """(n_params,) gradient of ``sum(g * displacements(x, times))`` with respect to x, g (T, N, 3)."""
        return self.base.adjoint(g, self._shifted(times), x)

    def linearize(self, x: np.ndarray | None, times: np.ndarray):
        """dU/dx: the base's linearisation at the shifted times (exact)."""
        return self.base.linearize(x, self._shifted(times))

    def penalty_operator(self):
        """The base response's ridge matrix Omega."""
        return self.base.penalty_operator()
