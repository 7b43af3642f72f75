"""What the candidate terms share: the base class and time derivatives of the baseline.

A candidate term (:class:`vfcli.diagnose.candidate.Candidate`) here is one small class per
physics the baseline left out.  Most act through the vertex displacements: a subclass of
:class:`DisplacementTerm` gives ``dU/dtheta`` (F + 1, N, 3, n_params) at the baseline fit with the
term switched off (theta = 0), and the base class turns it into Jacobian columns of the
predicted measurement through :meth:`vfcli.diagnose.candidate.Baseline.measure_linear`.
"""
from __future__ import annotations

import numpy as np

#: weights and offsets of the 5-point central differences (exact for polynomials of degree <= 4 / 5)
_STENCILS = {1: (np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0, np.arange(-2, 3)),
             2: (np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / 12.0, np.arange(-2, 3))}


def time_derivative(fn, times: np.ndarray, order: int, step_s: float) -> np.ndarray:
    """``order``-th time derivative of ``fn(times)`` by 5-point central differences.

    Parameters
    ----------
    fn : callable (T,) s -> (T, ...) array (e.g. a response's ``displacements(x, .)`` or a load
        model's ``time_basis``).
    times : (T,) s.
    order : 1 or 2.
    step_s : difference step h, s.  The stencil is exact for polynomials of degree <= 4 (order 1)
        and <= 5 (order 2), e.g. the Bernstein time bases; a measured signal interpolated linearly
        (the subglottal pressure) is differentiated at the scale of h.

    Returns
    -------
    Same shape as ``fn(times)``, per s^order.
    """
    weights, offsets = _STENCILS[int(order)]
    t = np.asarray(times, dtype=float)
    out = 0.0
    for w, o in zip(weights, offsets):
        if w:
            out = out + w * np.asarray(fn(t + o * step_s))
    return out / step_s ** order


def derivative_step(baseline) -> float:
    """The difference step of a baseline: half its frame interval, s."""
    return 0.5 * float(baseline.problem.dt)


def fold_vertices(baseline, fold: int) -> np.ndarray:
    """(N,) bool: the vertices of fold 0 (left) or 1 (right)."""
    mesh = baseline.problem.mesh
    out = np.zeros(mesh.n_nodes, bool)
    out[mesh.fold_nodes(fold)] = True
    return out


class DisplacementTerm:
    """A candidate acting on the vertex displacements (module docstring).

    Subclasses set ``name``, ``parameter_names``, ``signature`` and implement
    :meth:`displacement_jacobian`.
    """

    name: str = ""
    parameter_names: tuple[str, ...] = ()
    signature: str = ""
    #: only a positive parameter is physical (one parameter): a one-sided calibrated test
    one_sided: bool = False
    #: the parameter's value at the effect's physical full strength, and what it means (one parameter; None:
    #: no such value): the decision says when the recording could not show even that much
    #: (:func:`vfcli.diagnose.calibrate.smallest_detectable`)
    full_value: float | None = None
    full_meaning: str = ""

    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    def displacement_jacobian(self, baseline) -> np.ndarray:
        """(F + 1, N, 3, n_params) vertex displacement change (mm) per unit parameter at theta = 0,
        at ``baseline.problem.sim_times``."""
        raise NotImplementedError

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) change of the vertex displacements (mm) from the baseline's with the term at
        parameters ``theta`` (n_params,), at ``baseline.problem.sim_times``, for the baseline's controls
        ``baseline.x``.  Default: the linear term ``displacement_jacobian(baseline) @ theta``; a term whose
        effect is not linear in theta overrides it with the exact change (the confirmation refit,
        :mod:`vfcli.diagnose.refit`, fits theta of any size)."""
        return self.displacement_jacobian(baseline) @ np.asarray(theta, dtype=float)

    def jacobian(self, baseline) -> np.ndarray:
        """(n_rows, n_params) Jacobian of the predicted measurement at the baseline
        (:meth:`vfcli.diagnose.candidate.Baseline.measure_linear`)."""
        return baseline.measure_linear(self.displacement_jacobian(baseline))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(self.parameter_names)})"
