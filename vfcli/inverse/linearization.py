"""The Gauss-Newton model of the paper's error E around a frozen raster.

For a frozen raster (:meth:`vfcli.inverse.problem.Problem.freeze`) the motion term of E is
an exact quadratic in the control values x, because the vertex displacements are
linear in x (``U(t) = R C b(t)``, :mod:`vfcli.model.response.quasi_static`) and the per-pixel simulated
velocity is linear in them.  Its Hessian has a Kronecker structure per frame f::

    r_f = (M_f / dt) (U(t_{f+1}) - U(t_f)) - v_f  = P_f C db_f,     P_f = M_f R / dt
    d^2/dx^2 |r_f|^2 = 2 (P_f^T P_f) (x) (db_f db_f^T),   db_f = b(t_{f+1}) - b(t_f)

(``x = C.ravel()``, spatial index major), so the full (n_params, n_params) Hessian is
one contraction of per-frame (n_spatial, n_spatial) blocks with (n_time, n_time)
outer products, and ``P_f^T P_f = R^T (M_f^T M_f) R`` only involves the vertices
seen in frame f.

The gap term ``arctan(q)``, ``q = (d / l)^2``, is concave in q, so
``arctan(q) <= arctan(q0) + (q - q0) / (1 + q0^2)``: a quadratic majoriser in d whose
curvature ``2 / ((1 + q0^2) l^2)`` we use (d is linear in the two end vertices of the
frozen silhouette edge up to the crossing parameter, which we linearise).  The ridge
term is exactly quadratic.  Together:

    E(x + s) ~ E(x) + g^T s + 1/2 s^T H s

with g the exact frozen gradient.  :func:`gauss_newton_model` builds (E, g, H); the
Levenberg-Marquardt optimiser (:mod:`vfcli.inverse.optimizers.base`, ``method="gauss-newton"``) and
the uncertainty of the reconstruction (:mod:`vfcli.inverse.uncertainty`) use it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.problem import Problem, Terms
from vfcli.camera.silhouette import crossing_with_gradient


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

    def solve(self, rhs: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
        """``(self + diag(shift))^-1 rhs`` per block (:func:`spd_solve`)."""
        rhs = np.asarray(rhs, dtype=float)
        out = np.zeros_like(rhs)
        for idx, b in zip(self.indices, self.blocks):
            out[idx] = spd_solve(b, rhs[idx], None if shift is None else shift[idx])
        return out


_SCRATCH: dict[str, np.ndarray] = {}


def scratch(name: str, shape: tuple[int, ...], order: str = "C") -> np.ndarray:
    """A reusable uninitialised float64 work array (one per ``name``, replaced when the shape changes).

    The Gauss-Newton model and the Levenberg-Marquardt solve need several 70-100 MB
    temporaries per iteration (n = 3450 per block for the 5x5x15 setup); the kernel's
    page faults on fresh memory of that size cost as much as the arithmetic on it.  The
    caller must be done with the array before asking for the same name again.
    """
    buf = _SCRATCH.get(name)
    if buf is None or buf.shape != tuple(shape) or not buf.flags[f"{order}_CONTIGUOUS"]:
        buf = _SCRATCH[name] = np.empty(shape, order=order)
    return buf


def spd_solve(a: np.ndarray, rhs: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
    """``(a + diag(shift))^-1 rhs`` for a symmetric positive (semi-)definite (n, n) ``a`` by Cholesky
    (least squares if singular).

    ``a`` is copied into a reused work array (:func:`scratch`) and factorised there.  (A
    float32 factorisation with float64 refinement was measured no faster with this
    machine's OpenBLAS: 0.40 s against 0.35 s at n = 3450.)
    """
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    work = scratch("cholesky", a.shape, order="F")    # LAPACK's layout: factorised without another copy
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


@dataclass(frozen=True)
class QuadraticModel:
    """E around x: value, exact gradient, Gauss-Newton Hessian.

    terms : E and its terms at x.
    grad : (n,) exact frozen-raster gradient, per unit x.
    hessian : (n, n) :class:`BlockMatrix`, symmetric positive semi-definite Gauss-Newton Hessian of E.
    data_hessian : the part of ``hessian`` that comes from the data (motion and gap
        terms; without the ridge), for uncertainty and effective degrees of freedom.
    n_motion : number of scalar motion residuals (3 per pixel valid in both).
    """

    terms: Terms
    grad: np.ndarray
    hessian: BlockMatrix
    data_hessian: BlockMatrix
    n_motion: int


def spatial_groups(basis: np.ndarray, vertex_fold: np.ndarray) -> list[np.ndarray]:
    """Spatial load patterns grouped so that patterns of different groups move different folds.

    Parameters
    ----------
    basis : (N, 3, S) vertex displacement per unit spatial control value.
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


def _kron_sum(blocks: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """``sum_k kron(outer[k], blocks[k])`` for (K, S, S) blocks and (K, T, T) outers -> (T S, T S).

    Time-major (row ``t * S + s``): the transpose below then moves contiguous rows of S
    values, which is several times faster than the spatial-major ``kron(blocks, outer)``.
    """
    k, s, _ = blocks.shape
    t = outer.shape[1]
    h = np.matmul(outer.reshape(k, t * t).T, blocks.reshape(k, s * s), out=scratch("kron", (t * t, s * s)))
    out = np.empty((t * s, t * s))
    np.copyto(out.reshape(t, s, t, s), h.reshape(t, t, s, s).transpose(0, 2, 1, 3))
    return out


def seen_vertex_gram(m_both: sp.csr_matrix) -> tuple[np.ndarray, sp.csr_matrix]:
    """The vertices a frame's pixels see and ``M^T M`` restricted to them.

    m_both : (n_pix, N) csr interpolation rows of the pixels valid in both.
    Returns seen (n_seen,) int vertex indices and (n_seen, n_seen) csr ``M_s^T M_s``.
    """
    m = m_both.tocsc()
    seen = np.flatnonzero(np.diff(m.indptr))
    ms = m[:, seen]
    return seen, (ms.T @ ms).tocsr()


def motion_block(seen: np.ndarray, gram: sp.csr_matrix, basis: np.ndarray,
                 vertices: np.ndarray | None = None,
                 weights: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """``sum_c w_c R_c^T M^T M R_c`` for one frame.

    Parameters
    ----------
    seen, gram : from :func:`seen_vertex_gram`.
    basis : (N, 3, S) vertex displacement per unit spatial control value, mm.
    vertices : (N,) bool, the only vertices ``basis`` moves (saves work; default all).
    weights : (3,) weight w_c of each velocity component (``ObjectiveSettings.component_weights``).

    Returns
    -------
    (S, S) float64, mm^2 per (unit control)^2.
    """
    out = np.zeros((basis.shape[2], basis.shape[2]))
    keep = np.ones(seen.size, bool) if vertices is None else vertices[seen]
    if not keep.any():
        return out
    k = gram[keep][:, keep] if not keep.all() else gram
    for c in range(3):
        if weights[c]:
            r = basis[seen[keep], c, :]
            out += weights[c] * (r.T @ (k @ r))
    return out


def gap_rows(problem: Problem, positions: np.ndarray, sil: list, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linearised silhouette residuals of one frame.

    Parameters
    ----------
    problem : the Problem (camera, fold edges, ray axis).
    positions : (N, 3) deformed vertices at the frame, mm.
    sil : the frame's frozen silhouettes (:class:`vfcli.inverse.problem._Frame` ``.sil``).
    basis : (N, 3, S) response basis, mm per unit control.

    Returns
    -------
    q_rows : (n_rows, S) d(silhouette px)/d(spatial control).
    dist : (n_rows,) simulated minus measured silhouette, px.
    """
    scr = problem.camera.project(positions)
    p = problem.camera.matrix
    rows, dists = [], []
    for side, (rays, edge, tgt) in enumerate(sil):
        if rays.size == 0:
            continue
        ee = problem.fold_edges[problem.fold_order[side]][edge]
        s, d0, d1 = crossing_with_gradient(scr, ee, rays, problem.ray_comp)
        dists.append(s - tgt)
        # screen px per mm of (x, y) displacement of each end vertex; z does not move the silhouette
        rows.append(np.einsum("rc,rcs->rs", d0 @ p, basis[ee[:, 0], :2, :])
                    + np.einsum("rc,rcs->rs", d1 @ p, basis[ee[:, 1], :2, :]))
    s = basis.shape[2]
    if not rows:
        return np.zeros((0, s)), np.zeros(0)
    return np.concatenate(rows), np.concatenate(dists)


def gauss_newton_model(problem: Problem, x: np.ndarray, frames: list | None = None,
                       disp: np.ndarray | None = None) -> QuadraticModel:
    """(E, exact gradient, Gauss-Newton Hessian) of ``problem`` at ``x`` for the raster of x.

    Parameters
    ----------
    problem : :class:`vfcli.inverse.problem.Problem` whose response has ``basis_`` (N, 3, S)
        and ``time_basis(times)`` (T, n_time) (:class:`vfcli.model.response.quasi_static.QuasiStaticResponse`).
    x : (n_params,) control values.
    frames : frozen rasters at x (from ``problem.freeze(x)``); computed when omitted.
    disp : (F + 1, N, 3) displacements at x (saves recomputing them).
    """
    x = np.asarray(x, dtype=float)
    st = problem.settings
    u = problem.displacements(x) if disp is None else disp
    frames = problem.freeze(x, u) if frames is None else frames
    terms, grad = problem.frozen_value_and_grad(x, frames)
    basis = problem.response.basis_
    b = problem.response.time_basis(problem.sim_times)              # (F + 1, n_time)
    n_f, n_t = problem.n_frames, b.shape[1]
    vertex_fold = np.zeros(problem.mesh.n_nodes, dtype=int)
    vertex_fold[problem.mesh.fold_nodes(1)] = 1
    groups = spatial_groups(basis, vertex_fold)
    scale_px = problem.camera.px_per_mm * st.gap_length_mm
    n_sil = 2.0 * max(len(problem.rays), 1)
    n_terms = 2 * n_f
    stacks = [scratch(f"stack{i}", (n_terms, len(g), len(g))) for i, g in enumerate(groups)]
    for stack in stacks:
        stack.fill(0.0)
    group_basis = [np.ascontiguousarray(basis[:, :, g]) for g in groups]
    moved = [np.isin(vertex_fold, np.unique(vertex_fold[np.abs(bg).max(axis=(1, 2)) > 0])) for bg in group_basis]
    outers = np.zeros((n_terms, n_t, n_t))
    n_motion = 0
    for f, fr in enumerate(frames):
        if st.motion_weight:
            db = b[f + 1] - b[f]
            w = 2.0 * st.motion_weight / (n_f * fr.n_norm * problem.dt ** 2)
            seen, gram = seen_vertex_gram(fr.m_both)
            for stack, bg, mv in zip(stacks, group_basis, moved):
                stack[2 * f] = motion_block(seen, gram, bg, mv, st.component_weights)
                stack[2 * f] *= w
            outers[2 * f] = np.outer(db, db)
            n_motion += 3 * fr.m_both.shape[0]
        if st.gap_weight:
            q_rows, dist = gap_rows(problem, problem.mesh.nodes + u[f], fr.sil, basis)
            if len(dist):
                q = (dist / scale_px) ** 2
                curv = (st.gap_weight / (n_f * n_sil)) * 2.0 / ((1.0 + q * q) * scale_px ** 2)
                for stack, g in zip(stacks, groups):
                    qg = q_rows[:, g]
                    rows = np.flatnonzero(np.any(qg != 0.0, axis=1))   # the silhouettes of the group's folds
                    qg = qg[rows]
                    stack[2 * f + 1] = qg.T @ (curv[rows, None] * qg)
                outers[2 * f + 1] = np.outer(b[f], b[f])
    # block row t * S_g + s is control value (g[s], t), i.e. x[g[s] * n_t + t] (x = C.ravel(), C (S, n_time))
    indices = tuple((g[None, :] * n_t + np.arange(n_t)[:, None]).ravel() for g in groups)
    data = BlockMatrix(problem.n_params, indices, tuple(_kron_sum(stack, outers) for stack in stacks))
    hess = data.plus(problem.penalty, 2.0 * st.ridge_weight / problem.n_params) if st.ridge_weight else data
    return QuadraticModel(terms, grad, hess, data, n_motion)
