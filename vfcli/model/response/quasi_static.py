"""Linear (quasi-static) response of the folds to a load model (paper, section 3.3).

The displacement is linear in the control values: with one factorisation of K,

    R = V K^-1 L S            (3 N, n_spatial)  vertex displacement per spatial pattern
    U(t) = R @ C @ b(t)       (3 N,)            at any time, for C (n_spatial, n_time)

(V picks the vertex DOFs, row ``3 i + c`` = vertex i, component c, mm).  R is
computed once (all right-hand sides at once, in chunks); afterwards a whole
trajectory is a small dense product, and its adjoint (needed for exact
gradients) is the transposed product.

It implements :class:`vfcli.model.response.base.Response`; its linearisation is
exact and has one separable term (R, b(t)).  Any other implementation of that
protocol (a response with inertia and damping, a contact response) can replace it
in :class:`vfcli.inverse.problem.Problem`.
"""
from __future__ import annotations

import functools
import logging

import numpy as np
import scipy.sparse as sp

from vfcli.model.loads.force_field import LoadModel
from vfcli.model.response.base import Linearization, SeparableTerm
from vfcli.parallel import Mapper, serial_map

log = logging.getLogger(__name__)


def _basis_block(model, vop, rhs) -> np.ndarray:
    """(3 N, k) vertex displacements, mm, under the (n_dofs, k) loads ``rhs`` (dense or sparse):
    one batch of the basis solves (a module-level function, so a process pool can run it)."""
    rhs = rhs.toarray() if sp.issparse(rhs) else rhs
    return vop @ model.solve(rhs)


class QuasiStaticResponse:
    """Vertex displacements of a static linear-elastic model under a load model.

    Parameters
    ----------
    model : :class:`vfcli.model.fem.ElasticModel` (factorised on first use).
    load_model : :class:`vfcli.model.loads.force_field.LoadModel`.
    chunk : right-hand sides solved per batch (bounds the (n_dofs, chunk) work array).
    map : a :class:`vfcli.parallel.Mapper` that runs the batches' solves (they are
        independent) and returns their results in order; default one after the other. A thread
        pool's ``map`` (the factorisation's solves release the GIL) or a Dask client's
        (:func:`vfcli.batch.cluster.client_map`; the model pickles without its factorisation,
        which each worker redoes) spreads them; the basis is the same whatever the map.

    Attributes
    ----------
    basis_ : (N, 3, n_spatial) float64, vertex displacement (mm) per unit spatial
        control value (the matrix R, reshaped).
    """

    def __init__(self, model, load_model: LoadModel, chunk: int = 64,
                 map: Mapper | None = None) -> None:
        self.load_model = load_model
        self.n_vertices = int(model.mesh.n_nodes)
        loads = load_model.spatial_loads(model)
        loads = loads.tocsc() if sp.issparse(loads) else np.asarray(loads, dtype=float)
        if loads.shape != (model.n_dofs, load_model.n_spatial):
            raise ValueError(f"load model gave loads of shape {loads.shape}, expected "
                              f"({model.n_dofs}, {load_model.n_spatial})")
        vop = model.vertex_operator()
        out = np.empty((3 * self.n_vertices, load_model.n_spatial))
        spans = [(a, min(a + chunk, load_model.n_spatial)) for a in range(0, load_model.n_spatial, chunk)]
        if map is not None and hasattr(model, "factorize"):
            model.factorize()  # once here, not by racing threads of a pool
        solved = (serial_map if map is None else map)(
            functools.partial(_basis_block, model, vop), [loads[:, a:b] for a, b in spans])
        for (a, b), block in zip(spans, solved, strict=True):
            out[:, a:b] = block
        self.basis_ = out.reshape(self.n_vertices, 3, load_model.n_spatial)
        self._flat = out
        log.debug("response basis: %d vertices x %d spatial patterns", self.n_vertices, load_model.n_spatial)

    @property
    def n_params(self) -> int:
        return self.load_model.n_params

    def time_basis(self, times: np.ndarray) -> np.ndarray:
        """(T, n_time) time basis of the load model at ``times`` (s): ``U(t) = R C time_basis(t)``."""
        return np.atleast_2d(self.load_model.time_basis(times))

    def displacements(self, x: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Vertex displacements at ``times``.

        Parameters
        ----------
        x : (n_params,) control values (``C.ravel()``).
        times : (T,) s.

        Returns
        -------
        (T, N, 3) float64, mm.
        """
        c = self.load_model.control_matrix(x)
        b = self.load_model.time_basis(times)  # (T, n_time)
        u = self._flat @ (c @ b.T)  # (3N, T)
        return u.T.reshape(len(b), self.n_vertices, 3)

    def adjoint(self, g: np.ndarray, times: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """Gradient with respect to x of ``sum(g * displacements(x, times))``.

        Parameters
        ----------
        g : (T, N, 3) sensitivities dE/dU, per mm.
        times : (T,) s.
        x : ignored (the response is linear).

        Returns
        -------
        (n_params,) float64.
        """
        b = self.load_model.time_basis(times)  # (T, n_time)
        g2 = np.asarray(g, dtype=float).reshape(len(b), -1)  # (T, 3N)
        return (self._flat.T @ (g2.T @ b)).ravel()

    def linearize(self, x: np.ndarray | None, times: np.ndarray) -> Linearization:
        """dU/dx (exact, independent of x): one term, R = :attr:`basis_` and B = :meth:`time_basis`."""
        return Linearization((SeparableTerm(self.basis_, self.time_basis(times)),))

    def penalty_operator(self):
        """(n_params, n_params) sparse Omega of the ridge term: the load model's, identity if it has none."""
        if hasattr(self.load_model, "penalty_operator"):
            return self.load_model.penalty_operator()
        return sp.identity(self.n_params, format="csr")
