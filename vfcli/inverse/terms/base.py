"""A term of the error E: its value, exact frozen gradient and Gauss-Newton Hessian, in one class.

E is the sum of its weighted terms (:class:`vfcli.inverse.problem.Problem` holds the
list).  A term is one of two kinds:

* a **data term** depends on the vertex displacements U (F + 1, N, 3) at the simulated
  times (motion, gap).  Its gradient is accumulated with respect to U and taken to the
  control values by the response's adjoint once for all terms.  Its Gauss-Newton
  Hessian is given in the Kronecker form the linearised response allows
  (:class:`KronBlocks`, :meth:`Term.kron_blocks`).
* a **prior term** depends on the control values x directly (ridge, a physics
  penalty).  Its gradient is with respect to x; its Hessian is a sparse
  (n_params, n_params) matrix (:meth:`Term.hessian_matrix`) that must not couple
  control values of different Hessian blocks.

A new term is one subclass of :class:`Term` added to the problem's ``terms``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class Terms:
    """Value of E and its weighted terms: ``total = motion + gap + ridge + sum(extra.values())``.

    extra : {name: weighted value} of terms other than motion, gap and ridge.
    """

    total: float
    motion: float
    gap: float
    ridge: float = 0.0
    extra: Mapping[str, float] = field(default_factory=dict)

    @classmethod
    def from_parts(cls, parts: Mapping[str, float]) -> Terms:
        """Terms from {name: weighted value}, summed in the given order."""
        total = 0.0
        for v in parts.values():
            total = total + v
        named = {k: parts.get(k, 0.0) for k in ("motion", "gap", "ridge")}
        return cls(float(total), float(named["motion"]), float(named["gap"]), float(named["ridge"]),
                   {k: float(v) for k, v in parts.items() if k not in named})

    def as_dict(self) -> dict[str, float]:
        """{"total", "motion", "gap", "ridge", *extra}: the figures a stage prints and stores."""
        return {"total": self.total, "motion": self.motion, "gap": self.gap, "ridge": self.ridge, **self.extra}


@dataclass
class Evaluation:
    """What the terms share when E is evaluated at x with frozen frames.

    problem : :class:`vfcli.inverse.problem.Problem`.
    x : (n_params,) control values.
    disp : (F + 1, N, 3) vertex displacements at the simulated times, mm.
    frames : the frozen frames (:meth:`vfcli.inverse.problem.Problem.freeze`).
    grad_disp : (F + 1, N, 3) dE/dU accumulated by data terms (per mm), or None (no gradient).
    grad_x : (n_params,) dE/dx accumulated by prior terms, or None.
    """

    problem: object
    x: np.ndarray
    disp: np.ndarray
    frames: list
    grad_disp: np.ndarray | None = None
    grad_x: np.ndarray | None = None

    @property
    def wants_grad(self) -> bool:
        return self.grad_disp is not None


@dataclass
class KronBlocks:
    """A Gauss-Newton Hessian as ``sum_k kron(outers[k], blocks[k])`` per block group.

    blocks : one (K, S_g, S_g) array per spatial group g (spatial index major, float64).
    outers : (K, n_time, n_time) the time factors (zeros where a frame adds nothing).
    n_residuals : scalar residuals behind it (3 per compared pixel for the motion term).

    Filled in place by :meth:`Term.kron_blocks` (arrays from the fit's workspace, zeroed).
    """

    blocks: list
    outers: np.ndarray
    n_residuals: int = 0


class Term:
    """Base class of a term of E (module docstring).

    Subclasses set ``name`` and implement :meth:`value` and either :meth:`kron_blocks`
    (data terms) or :meth:`hessian_matrix` (prior terms).
    """

    #: key of the term in :class:`Terms` (motion, gap, ridge or an extra name)
    name: str = ""
    #: True: a function of the displacements (data); False: a function of x only (prior)
    data: bool = True

    def weight(self, settings) -> float:
        """The term's weight (from :class:`vfcli.inverse.problem.ObjectiveSettings`; dimension 1/[term])."""
        return float(getattr(settings, f"{self.name}_weight"))

    def value(self, ev: Evaluation) -> float:
        """Weighted value at ``ev.x``; adds the weighted gradient to ``ev.grad_disp`` / ``ev.grad_x``
        when they are given."""
        raise NotImplementedError

    def n_kron(self, problem, n_lin_terms: int) -> int:
        """Number of Kronecker pairs :meth:`kron_blocks` fills (data terms)."""
        return 0

    def kron_blocks(self, ev: Evaluation, lin, groups: list[np.ndarray], out: KronBlocks) -> None:
        """Fill ``out`` (``n_kron`` pairs) with the term's Gauss-Newton Hessian at ``ev``.

        lin : :class:`vfcli.model.response.base.Linearization` at ``ev.x`` and the simulated times.
        groups : (S_g,) spatial index arrays (:func:`vfcli.inverse.linearization.spatial_groups`).
        """

    def hessian_matrix(self, ev: Evaluation) -> sp.spmatrix | None:
        """(n_params, n_params) sparse weighted Hessian of a prior term, or None."""
        return None


class FrameTerm(Term):
    """A data term with one Gauss-Newton block per frame and linearisation term pair (motion, gap)."""

    def n_kron(self, problem, n_lin_terms: int) -> int:
        return problem.n_frames * n_lin_terms ** 2 if self.weight(problem.settings) else 0


def term_pairs(n_terms: int) -> list[tuple[int, int]]:
    """(j, k) index pairs of a product of two sums of ``n_terms`` terms, (0, 0) first."""
    return [(j, k) for j in range(n_terms) for k in range(n_terms)]


def pair_outers(rows: np.ndarray) -> np.ndarray:
    """(J * J, t, t) ``outer(rows[j], rows[k])`` for every pair of :func:`term_pairs` in its order; rows (J, t)."""
    n, t = rows.shape
    return (rows[:, None, :, None] * rows[None, :, None, :]).reshape(n * n, t, t)


@dataclass(frozen=True)
class GroupedLinearization:
    """A response's linearisation split by block group, as the Gauss-Newton terms use it.

    spatial[j][g] : (N, 3, S_g) C-contiguous R_j restricted to group g's spatial patterns.
    full[j] : (N, 3, S) R_j.  temporal[j] : (T, n_time) B_j at the simulated times.
    groups : (S_g,) spatial indices per group.  moved[g] : (N,) bool, the vertices of the folds group g moves.
    """

    spatial: list
    full: list
    temporal: list
    groups: list
    moved: list

    @property
    def n_terms(self) -> int:
        return len(self.full)

    @property
    def n_time(self) -> int:
        return int(self.temporal[0].shape[1])


def group_linearization(lin, groups: list[np.ndarray], vertex_fold: np.ndarray) -> GroupedLinearization:
    """Split ``lin`` (:class:`vfcli.model.response.base.Linearization`) by the spatial ``groups``.

    vertex_fold : (N,) fold (0 or 1) of each vertex.
    """
    spatial = [[np.ascontiguousarray(t.spatial[:, :, g]) for g in groups] for t in lin.terms]
    moved = []
    for gi in range(len(groups)):
        size = np.zeros(len(vertex_fold))
        for per_term in spatial:
            size = np.maximum(size, np.abs(per_term[gi]).max(axis=(1, 2)))
        moved.append(np.isin(vertex_fold, np.unique(vertex_fold[size > 0])))
    return GroupedLinearization(spatial, [t.spatial for t in lin.terms], [t.temporal for t in lin.terms],
                                list(groups), moved)
