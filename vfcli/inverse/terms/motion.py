"""The motion term of E: velocity residuals of the pixels seen (paper, section 3.4).

Per frame f, with the frozen interpolation rows M_f (n_both, N) of the compared pixels
(:meth:`vfcli.inverse.problem.Problem.freeze`), the measured velocity v_f (n_both, 3)
mm/s and the component weights w_c::

    r_f = M_f V_f - v_f                                                       (n_both, 3) mm/s

with V_f the model's vertex velocity at the frame time t_f, ``sum_k s_fk U(t_k) / dt`` over the stencil
s_f of :mod:`vfcli.inverse.stencil` (central inside the window; the paper's forward difference is the
velocity half a frame later)
    E_motion = motion_weight / F * sum_f (sum_c w_c |r_f,c|^2 + const_f) / N_f

(const_f: the pixels valid only in the measurement, N_f: the frame's valid pixels).

Gauss-Newton
------------
For a frozen raster r_f is linear in U, and with ``dU(t) = sum_j R_j dC B_j(t)``
(:mod:`vfcli.model.response.base`)::

    J_f = sum_j (M_f R_j / dt) (x) db_j,f^T,        db_j,f = sum_k s_fk B_j(t_k)
    J_f^T J_f = sum_{j,k} (R_j^T M_f^T M_f R_k) (x) (db_j,f db_k,f^T)

so the Hessian is exact (the motion term is quadratic in x for a linear response) and
``R^T M^T M R`` only involves the vertices seen in frame f.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vfcli.inverse.stencil import stencil_apply, stencil_scatter
from vfcli.inverse.terms.base import Evaluation, FrameTerm, GroupedLinearization, KronBlocks, term_pairs


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
                 weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
                 other: np.ndarray | None = None) -> np.ndarray:
    """``sum_c w_c R_c^T M^T M Q_c`` for one frame (Q = R unless ``other`` is given).

    Parameters
    ----------
    seen, gram : from :func:`seen_vertex_gram`.
    basis : (N, 3, S) R, vertex displacement per unit spatial control value, mm.
    vertices : (N,) bool, the only vertices ``basis`` and ``other`` move (saves work; default all).
    weights : (3,) weight w_c of each velocity component (``ObjectiveSettings.component_weights``).
    other : (N, 3, S) Q, a second linearisation term (default R).

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
            q = r if other is None else other[seen[keep], c, :]
            out += weights[c] * (r.T @ (k @ q))
    return out


class MotionTerm(FrameTerm):
    """``motion_weight * E_motion`` (module docstring), (mm/s)^2 times the weight."""

    name = "motion"

    def value(self, ev: Evaluation) -> float:
        p = ev.problem
        w = self.weight(p.settings)
        cw = np.asarray(p.settings.component_weights, dtype=float)
        u, n_f = ev.disp, p.n_frames
        motion = 0.0
        for f, fr in enumerate(ev.frames):
            r = fr.m_both @ p.frame_velocity(u, f) - fr.v_both
            motion += (np.sum(r * r @ cw) + fr.const) / fr.n_norm
            if ev.wants_grad and w:
                gd = (fr.m_both.T @ (r * cw)) * (2.0 * w / (n_f * fr.n_norm * p.dt))
                stencil_scatter(ev.grad_disp, p.stencil[f], gd)
        return w * motion / n_f

    def kron_blocks(self, ev: Evaluation, lin: GroupedLinearization, groups: list[np.ndarray],
                    out: KronBlocks) -> None:
        p = ev.problem
        st = p.settings
        weight = self.weight(st)
        if not weight:
            return
        pairs = term_pairs(lin.n_terms)
        b = lin.temporal
        for f, fr in enumerate(ev.frames):
            db = [stencil_apply(bj, p.stencil[f]) for bj in b]
            w = 2.0 * weight / (p.n_frames * fr.n_norm * p.dt ** 2)
            seen, gram = seen_vertex_gram(fr.m_both)
            for i, (j, k) in enumerate(pairs):
                at = f * len(pairs) + i
                for stack, rj, rk, mv in zip(out.blocks, lin.spatial[j], lin.spatial[k], lin.moved):
                    stack[at] = motion_block(seen, gram, rj, mv, st.component_weights, None if j == k else rk)
                    stack[at] *= w
                out.outers[at] = np.outer(db[j], db[k])
            out.n_residuals += 3 * fr.m_both.shape[0]
