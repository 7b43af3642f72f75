"""The Gauss-Newton model of the paper's error E around a frozen raster.

For a frozen raster (:meth:`vfcli.inverse.problem.Problem.freeze`) every data term of E
is a function of the vertex displacements, and the response's linearisation
(:meth:`vfcli.model.response.base.Response.linearize`) writes their change as a sum of
separable terms ``dU(t) = sum_j R_j dC B_j(t)`` (x = C.ravel(), spatial index major).
Each term of E (:mod:`vfcli.inverse.terms`) then gives its Gauss-Newton Hessian as a sum
of Kronecker products of (n_spatial, n_spatial) blocks with (n_time, n_time) time factors,
for example the motion term of frame f::

    r_f = (M_f / dt) sum_k s_fk U(t_k) - v_f          (s_f: the frame-time stencil, vfcli.inverse.stencil)
    d^2/dx^2 |r_f|^2 = 2 sum_{j,k} (R_j^T M_f^T M_f R_k) (x) (db_j,f db_k,f^T),   db_j,f = sum_k s_fk B_j(t_k)

so the full (n_params, n_params) Hessian is one contraction of the stacked blocks with
the stacked outer products.  A quasi-static response has one term (R, b(t)), for which
the model is exact for the motion term; a response with J terms costs J^2 blocks per frame.

The gap term contributes the curvature of a quadratic majoriser of its arctan, the
ridge its exact Hessian.  Together:

    E(x + s) ~ E(x) + g^T s + 1/2 s^T H s

with g the exact frozen gradient.  :func:`gauss_newton_model` builds (E, g, H); the
Levenberg-Marquardt optimiser (:mod:`vfcli.inverse.optimizers.levenberg_marquardt`) and
the uncertainty of the reconstruction (:mod:`vfcli.inverse.uncertainty`) use it.
Work arrays come from the caller's :class:`vfcli.inverse.workspace.Workspace` (the fit's).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vfcli.inverse.block_matrix import BlockMatrix
from vfcli.inverse.problem import Problem
from vfcli.inverse.terms import Evaluation, KronBlocks, Terms
from vfcli.inverse.terms.base import group_linearization
from vfcli.inverse.workspace import Workspace
from vfcli.model.response.base import Linearization


@dataclass(frozen=True)
class QuadraticModel:
    """E around x: value, exact gradient, Gauss-Newton Hessian.

    terms : E and its terms at x.
    grad : (n,) exact frozen-raster gradient, per unit x.
    hessian : (n, n) :class:`BlockMatrix`, symmetric positive semi-definite Gauss-Newton Hessian of E.
    data_hessian : the part of ``hessian`` that comes from the data terms (motion, gap; without
        the prior terms such as the ridge), for uncertainty and effective degrees of freedom.
    n_motion : number of scalar motion residuals (3 per pixel valid in both).
    linearization : the response's dU/dx at x and the simulated times (None for a model built
        without a response), for propagating a covariance to displacements.
    """

    terms: Terms
    grad: np.ndarray
    hessian: BlockMatrix
    data_hessian: BlockMatrix
    n_motion: int
    linearization: Linearization | None = None


def spatial_groups(basis: np.ndarray, vertex_fold: np.ndarray) -> list[np.ndarray]:
    """Spatial load patterns grouped so that patterns of different groups move different folds.

    Parameters
    ----------
    basis : (N, 3, S) vertex displacement per unit spatial control value (or the largest
        magnitude over several linearisation terms).
    vertex_fold : (N,) fold (0 or 1) of each vertex.

    Returns
    -------
    One (S_g,) index array per group: one group per fold when every pattern moves a
    single fold (independent free fields), else a single group.
    """
    size = np.abs(basis).max(axis=1)                                # (N, S)
    tol = 1e-9 * max(float(size.max()), 1e-300)
    moves = np.stack([size[vertex_fold == k].max(axis=0, initial=0.0) > tol for k in (0, 1)], axis=1)
    if np.any(moves.all(axis=1)):
        return [np.arange(basis.shape[2])]
    return [g for g in (np.flatnonzero(moves[:, 0]), np.flatnonzero(~moves[:, 0])) if g.size]


def _kron_sum(blocks: np.ndarray, outer: np.ndarray, workspace: Workspace) -> np.ndarray:
    """``sum_k kron(outer[k], blocks[k])`` for (K, S, S) blocks and (K, T, T) outers -> (T S, T S).

    Time-major (row ``t * S + s``): the transpose below then moves contiguous rows of S
    values, which is several times faster than the spatial-major ``kron(blocks, outer)``.
    """
    k, s, _ = blocks.shape
    t = outer.shape[1]
    h = np.matmul(outer.reshape(k, t * t).T, blocks.reshape(k, s * s), out=workspace.array("kron", (t * t, s * s)))
    out = np.empty((t * s, t * s))
    np.copyto(out.reshape(t, s, t, s), h.reshape(t, t, s, s).transpose(0, 2, 1, 3))
    return out


def gauss_newton_model(problem: Problem, x: np.ndarray, frames: list | None = None,
                       disp: np.ndarray | None = None, workspace: Workspace | None = None) -> QuadraticModel:
    """(E, exact gradient, Gauss-Newton Hessian) of ``problem`` at ``x`` for the raster of x.

    Parameters
    ----------
    problem : :class:`vfcli.inverse.problem.Problem` (its response is used through
        ``linearize`` only; its terms give the blocks).
    x : (n_params,) control values.
    frames : frozen rasters at x (from ``problem.freeze(x)``); computed when omitted.
    disp : (F + 1, N, 3) displacements at x, mm (saves recomputing them).
    workspace : work arrays of the caller (a fit's); a fresh one when omitted.
    """
    ws = workspace if workspace is not None else Workspace()
    x = np.asarray(x, dtype=float)
    u = problem.displacements(x) if disp is None else disp
    frames = problem.freeze(x, u) if frames is None else frames
    terms, grad = problem.frozen_value_and_grad(x, frames)
    lin = problem.response.linearize(x, problem.sim_times)
    if lin.n_vertices != problem.mesh.n_nodes or lin.n_spatial * lin.n_time != problem.n_params:
        raise ValueError(f"the response's linearization ({lin.n_vertices} vertices, {lin.n_spatial} x "
                         f"{lin.n_time} controls) does not match the problem ({problem.mesh.n_nodes} vertices, "
                         f"{problem.n_params} controls)")
    vertex_fold = np.zeros(problem.mesh.n_nodes, dtype=int)
    vertex_fold[problem.mesh.fold_nodes(1)] = 1
    size = lin.terms[0].spatial if len(lin.terms) == 1 else np.max([np.abs(t.spatial) for t in lin.terms], axis=0)
    groups = spatial_groups(size, vertex_fold)
    grouped = group_linearization(lin, groups, vertex_fold)
    ev = Evaluation(problem, x, u, frames)
    counts = [t.n_kron(problem, len(lin.terms)) if t.data else 0 for t in problem.terms]
    n_kron = sum(counts)
    stacks = [ws.array(f"stack{i}", (n_kron, len(g), len(g))) for i, g in enumerate(groups)]
    for stack in stacks:
        stack.fill(0.0)
    outers = np.zeros((n_kron, lin.n_time, lin.n_time))
    n_res = {}
    at = 0
    for term, count in zip(problem.terms, counts):
        if count:
            part = KronBlocks([stack[at:at + count] for stack in stacks], outers[at:at + count])
            term.kron_blocks(ev, grouped, groups, part)
            n_res[term.name] = part.n_residuals
        at += count
    n_t = lin.n_time
    # block row t * S_g + s is control value (g[s], t), i.e. x[g[s] * n_t + t] (x = C.ravel(), C (S, n_time))
    indices = tuple((g[None, :] * n_t + np.arange(n_t)[:, None]).ravel() for g in groups)
    data = BlockMatrix(problem.n_params, indices, tuple(_kron_sum(stack, outers, ws) for stack in stacks))
    hess = data
    for term in problem.terms:
        if not term.data:
            extra = term.hessian_matrix(ev)
            if extra is not None:
                hess = hess.plus(extra)
    return QuadraticModel(terms, grad, hess, data, int(n_res.get("motion", 0)), lin)
