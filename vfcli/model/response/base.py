"""What the inverse problem needs from a response of the folds to its control values.

A response maps the control values ``x`` (n_params,) to vertex displacements at any
times.  The objective (:mod:`vfcli.inverse.problem`), the Gauss-Newton model
(:mod:`vfcli.inverse.linearization`) and the uncertainty (:mod:`vfcli.inverse.uncertainty`)
use it through the methods of :class:`Response` only.

Linearisation
-------------
``linearize(x, times)`` gives dU/dx at x as a sum of separable terms::

    dU(t) ~= sum_j R_j dC B_j(t)        R_j (N, 3, S),  B_j (T, n_time),  dx = dC.ravel(), dC (S, n_time)

(spatial index major, as the load models lay out x).  A quasi-static response is
exactly one term (``U(t) = R C b(t)``, R its basis and b the load model's time basis).
A response whose displacement is a filtered or delayed copy of the load (inertia,
damping) is linear with one or a few terms; a nonlinear one (contact) gives the
tangent at x.  The Gauss-Newton model keeps its Kronecker structure term pair by term
pair, so its cost grows with the square of the number of terms.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class SeparableTerm:
    """One term ``R C B(t)`` of a linearised response.

    spatial : (N, 3, S) float64 R, vertex displacement (mm) per unit spatial control value.
    temporal : (T, n_time) float64 B, dimensionless weights of the n_time control values at the T times.
    """

    spatial: np.ndarray
    temporal: np.ndarray


@dataclass(frozen=True)
class Linearization:
    """dU/dx of a response at some x, at T times: ``dU(t) = sum_j R_j dC B_j(t)``.

    terms : one or more :class:`SeparableTerm` with the same S, n_time and T.
    """

    terms: tuple[SeparableTerm, ...]

    def __post_init__(self) -> None:
        if not self.terms:
            raise ValueError("a linearization needs at least one term")
        shapes = {(t.spatial.shape[2], t.temporal.shape[1], t.temporal.shape[0], t.spatial.shape[:2])
                  for t in self.terms}
        if len(shapes) != 1 or any(t.spatial.ndim != 3 or t.spatial.shape[1] != 3 or t.temporal.ndim != 2
                                   for t in self.terms):
            raise ValueError(f"linearization terms must share (N, 3, S) and (T, n_time) shapes, got "
                             f"{[(t.spatial.shape, t.temporal.shape) for t in self.terms]}")

    @property
    def n_spatial(self) -> int:
        return int(self.terms[0].spatial.shape[2])

    @property
    def n_time(self) -> int:
        return int(self.terms[0].temporal.shape[1])

    @property
    def n_vertices(self) -> int:
        return int(self.terms[0].spatial.shape[0])

    def apply(self, dx: np.ndarray) -> np.ndarray:
        """(T, N, 3) displacement change (mm) for a control change dx (n_params,)."""
        dc = np.asarray(dx, dtype=float).reshape(self.n_spatial, self.n_time)
        out = 0.0
        for t in self.terms:
            r = t.spatial.reshape(-1, self.n_spatial)                   # (3N, S)
            out = out + (r @ (dc @ t.temporal.T)).T                     # (T, 3N)
        return np.asarray(out).reshape(-1, self.n_vertices, 3)


@runtime_checkable
class Response(Protocol):
    """The response of the folds to control values ``x`` (module docstring).

    n_params : number of control values, ``S * n_time``.  n_vertices : N.
    """

    @property
    def n_params(self) -> int: ...

    @property
    def n_vertices(self) -> int: ...

    def displacements(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """(T, N, 3) vertex displacements, mm, at ``times`` (T,) s for controls ``x`` (n_params,)."""
        ...

    def adjoint(self, g: np.ndarray, times: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """(n_params,) gradient with respect to x (at ``x``) of ``sum(g * displacements(x, times))``, g (T, N, 3)."""
        ...

    def linearize(self, x: np.ndarray, times: np.ndarray) -> Linearization:
        """dU/dx at x and ``times`` (T,) s as separable terms (module docstring)."""
        ...

    def penalty_operator(self) -> sp.spmatrix:
        """(n_params, n_params) sparse PSD matrix Omega of the ridge term ``x^T Omega x / n``."""
        ...
