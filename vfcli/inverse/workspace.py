"""Reusable work arrays of one fit.

The Gauss-Newton model and the Levenberg-Marquardt solve need several 70-100 MB
temporaries per iteration (n = 3450 per block for the 5x5x15 setup); the kernel's page
faults on fresh memory of that size cost as much as the arithmetic on it, so a fit
reuses them across iterations.  They belong to the fit that asks for them (one
:class:`Workspace` per :func:`vfcli.inverse.optimizers.base.fit`), never to the
process: two fits in two threads (a Dask worker's threads) each have their own.
"""
from __future__ import annotations

import numpy as np


class Workspace:
    """Named uninitialised float64 work arrays, reused while their shape stays the same.

    Not thread-safe on its own: one workspace serves one fit (one thread) at a time.

    Examples
    --------
    >>> ws = Workspace()
    >>> a = ws.array("kron", (2, 3))
    >>> ws.array("kron", (2, 3)) is a, ws.array("kron", (3, 2)) is a
    (True, False)
    """

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], order: str = "C") -> np.ndarray:
        """An uninitialised float64 array of ``shape`` (replaced when the shape or order changes).

        The caller must be done with the array before asking for the same ``name`` again.
        """
        buf = self._arrays.get(name)
        if buf is None or buf.shape != tuple(shape) or not buf.flags[f"{order}_CONTIGUOUS"]:
            buf = self._arrays[name] = np.empty(shape, order=order)
        return buf

    @property
    def nbytes(self) -> int:
        """Bytes held by the work arrays."""
        return sum(a.nbytes for a in self._arrays.values())
