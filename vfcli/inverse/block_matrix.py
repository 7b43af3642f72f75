"""Symmetric matrices that are block diagonal after a permutation, and their SPD solve.

The Gauss-Newton Hessian of E (:mod:`vfcli.inverse.linearization`) has one block per
group of control values whose loads move different folds; the posterior covariance
(:mod:`vfcli.inverse.uncertainty`) keeps the same blocks.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.workspace import Workspace


@dataclass(frozen=True)
class BlockMatrix:
    """A symmetric (n, n) matrix that is block diagonal after a permutation.

    indices[k] : (n_k,) int, the rows/columns of block k (disjoint, together all n).
    blocks[k] : (n_k, n_k) float64.

    The free force fields of independent folds give one block per fold (a fold's
    loads move only that fold); a shared load model gives one block.
    """

    n: int
    indices: tuple
    blocks: tuple

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        out = np.zeros((self.n,) + v.shape[1:])
        for idx, b in zip(self.indices, self.blocks):
            out[idx] = b @ v[idx]
        return out

    def diagonal(self) -> np.ndarray:
        out = np.zeros(self.n)
        for idx, b in zip(self.indices, self.blocks):
            out[idx] = np.diag(b)
        return out

    def dense(self) -> np.ndarray:
        out = np.zeros((self.n, self.n))
        for idx, b in zip(self.indices, self.blocks):
            out[np.ix_(idx, idx)] = b
        return out

    def plus(self, other: sp.spmatrix | np.ndarray, scale: float = 1.0) -> BlockMatrix:
        """``self + scale * other`` for a matrix ``other`` with no entries between blocks."""
        other = sp.csr_matrix(other)
        blocks = tuple(b + scale * other[idx][:, idx].toarray() for idx, b in zip(self.indices, self.blocks))
        total = sum(float(np.abs(other[idx][:, idx]).sum()) for idx in self.indices)
        if not np.isclose(total, float(np.abs(other).sum()), rtol=1e-12, atol=0.0):
            raise ValueError("the added matrix couples different blocks")
        return BlockMatrix(self.n, self.indices, blocks)

    def solve(self, rhs: np.ndarray, shift: np.ndarray | None = None,
              workspace: Workspace | None = None) -> np.ndarray:
        """``(self + diag(shift))^-1 rhs`` per block (:func:`spd_solve`); rhs (n,) or (n, k)."""
        rhs = np.asarray(rhs, dtype=float)
        out = np.zeros_like(rhs)
        for idx, b in zip(self.indices, self.blocks):
            out[idx] = spd_solve(b, rhs[idx], None if shift is None else shift[idx], workspace)
        return out


def spd_solve(a: np.ndarray, rhs: np.ndarray, shift: np.ndarray | None = None,
              workspace: Workspace | None = None) -> np.ndarray:
    """``(a + diag(shift))^-1 rhs`` for a symmetric positive (semi-)definite (n, n) ``a`` by Cholesky
    (least squares if singular).

    ``a`` is copied into a work array of ``workspace`` (a new one when omitted) and factorised
    there.  (A float32 factorisation with float64 refinement was measured no faster with this
    machine's OpenBLAS: 0.40 s against 0.35 s at n = 3450.)
    """
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    ws = workspace if workspace is not None else Workspace()
    work = ws.array("cholesky", a.shape, order="F")    # LAPACK's layout: factorised without another copy
    np.copyto(work, a)
    if shift is not None:
        work.flat[::len(work) + 1] += shift
    try:
        return cho_solve(cho_factor(work, lower=True, overwrite_a=True, check_finite=False), rhs, check_finite=False)
    except LinAlgError:
        work = np.array(a, dtype=float)
        if shift is not None:
            work.flat[::len(work) + 1] += shift
        return np.linalg.lstsq(work, rhs, rcond=None)[0]
