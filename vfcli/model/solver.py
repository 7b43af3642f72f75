"""Sparse direct solvers for symmetric positive definite systems, behind one interface.

Backends
--------
- ``"splu"``: scipy SuperLU with a symmetric ordering (always available).
- ``"cholespy"``: CHOLMOD Cholesky from the self-contained ``cholespy`` wheel.
- ``"pypardiso"``: Intel MKL PARDISO (``pip install pypardiso``, optional extra).
- ``"auto"``: the fastest installed one, in the order given by :data:`AUTO_ORDER`
  (measured with bench/bench_fem.py, see docs/benchmarks.md).

Usage: ``fac = factorize(A, "auto"); X = fac.solve(B)`` with ``B`` of shape
``(n,)`` or ``(n, k)``; the factorisation is computed once and reused.

Threads (the diagnosis's refits, :func:`vfcli.parallel.local_map`) may solve with one factorisation at once:
SuperLU is thread-safe (SuperLU 5, scipy releases the GIL in its solves); CHOLMOD's solve writes its
Common and its work array and PARDISO's its handle, so those two solve one call at a time (a lock).
"""
from __future__ import annotations

import importlib.util
import logging
import threading
from typing import Protocol

import numpy as np
import scipy.sparse as sp


log = logging.getLogger(__name__)

BACKENDS = ("splu", "cholespy", "pypardiso")
#: preference of ``"auto"``, fastest first (docs/benchmarks.md, "Mesh and FEM")
AUTO_ORDER = ("pypardiso", "cholespy", "splu")


class Factorization(Protocol):
    """A factorised SPD matrix: ``solve(B)`` returns ``A^-1 B``."""

    backend: str
    shape: tuple[int, int]

    def solve(self, b: np.ndarray) -> np.ndarray: ...


def available_backends() -> list[str]:
    """Names of the installed backends (``"splu"`` always)."""
    out = ["splu"]
    for name in ("cholespy", "pypardiso"):
        if importlib.util.find_spec(name) is not None:
            out.append(name)
    return out


def resolve_backend(backend: str) -> str:
    """Turn ``"auto"`` into an installed backend name; check explicit names."""
    avail = available_backends()
    if backend == "auto":
        return next(b for b in AUTO_ORDER if b in avail)
    if backend not in BACKENDS:
        raise ValueError(f"unknown solver backend {backend!r}; choose one of auto, {', '.join(BACKENDS)}")
    if backend not in avail:
        raise ValueError(f"solver backend {backend!r} is not installed (pip install {backend}); use 'auto' or 'splu'")
    return backend


class _SuperLU:
    backend = "splu"

    def __init__(self, a: sp.spmatrix) -> None:
        from scipy.sparse.linalg import splu

        self.shape = a.shape
        self._lu = splu(sp.csc_matrix(a), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                        options={"SymmetricMode": True})

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._lu.solve(np.asarray(b, dtype=np.float64))


class _Cholespy:
    backend = "cholespy"

    def __init__(self, a: sp.spmatrix) -> None:
        from cholespy import CholeskySolverD, MatrixType

        self.shape = a.shape
        c = sp.csr_matrix(a)
        c.sort_indices()
        self._solver = CholeskySolverD(a.shape[0], c.indptr.astype(np.int32), c.indices.astype(np.int32),
                                       c.data.astype(np.float64), MatrixType.CSR)
        self._lock = threading.Lock()        # one solve at a time: it writes the solver's own work array

    def solve(self, b: np.ndarray) -> np.ndarray:
        rhs = np.ascontiguousarray(b, dtype=np.float64)
        x = np.empty_like(rhs)
        with self._lock:
            self._solver.solve(rhs, x)
        return x


class _Pardiso:
    backend = "pypardiso"

    def __init__(self, a: sp.spmatrix) -> None:
        from pypardiso import PyPardisoSolver

        self.shape = a.shape
        self._a = sp.triu(sp.csr_matrix(a), format="csr")
        self._a.sort_indices()
        self._solver = PyPardisoSolver(mtype=2)  # real symmetric positive definite
        self._solver.set_statistical_info_off()
        self._solver.factorize(self._a)
        self._lock = threading.Lock()        # one solve at a time: it sets the handle's phase

    def solve(self, b: np.ndarray) -> np.ndarray:
        rhs = np.asarray(b, dtype=np.float64)
        with self._lock:
            x = self._solver.solve(self._a, rhs)
        return x.reshape(rhs.shape)


_IMPL = {"splu": _SuperLU, "cholespy": _Cholespy, "pypardiso": _Pardiso}


def factorize(a: sp.spmatrix, backend: str = "auto") -> Factorization:
    """Factorise a sparse SPD matrix once.

    Parameters
    ----------
    a : (n, n) sparse, symmetric positive definite.
    backend : ``"auto"`` or one of :data:`BACKENDS`.

    Returns
    -------
    Factorization with ``solve(b)``, ``b`` of shape (n,) or (n, k).
    """
    name = resolve_backend(backend)
    log.debug("factorising %d x %d (nnz %d) with %s", a.shape[0], a.shape[1], a.nnz, name)
    return _IMPL[name](a)
