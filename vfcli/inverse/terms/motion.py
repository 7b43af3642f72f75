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
from vfcli.inverse.terms.base import Evaluation, FrameTerm, GroupedLinearization, KronBlocks, pair_outers, term_pairs


def seen_vertex_gram(m_both: sp.csr_matrix) -> tuple[np.ndarray, sp.csr_matrix]:
    """The vertices a frame's pixels see and ``M^T M`` restricted to them.

    m_both : (n_pix, N) csr interpolation rows of the pixels valid in both.
    Returns seen (n_seen,) int vertex indices and (n_seen, n_seen) csr ``M_s^T M_s``.
    """
    m = m_both.tocsc()
    seen = np.flatnonzero(np.diff(m.indptr))
    ms = m[:, seen]
    return seen, (ms.T @ ms).tocsr()


def motion_blocks(seen: np.ndarray, gram: sp.csr_matrix, bases: list[np.ndarray],
                  vertices: np.ndarray | None = None,
                  weights: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """``sum_c w_c R_j,c^T M^T M R_k,c`` for one frame and every pair (j, k) of linearisation terms.

    Parameters
    ----------
    seen, gram : from :func:`seen_vertex_gram`.
    bases : J arrays (N, 3, S), R_j: vertex displacement per unit spatial control value of each term, mm.
    vertices : (N,) bool, the only vertices the bases move (saves work; default all).
    weights : (3,) weight w_c of each velocity component (``ObjectiveSettings.component_weights``).

    Returns
    -------
    (J, J, S, S) float64, mm^2 per (unit control)^2.

    The J terms' columns side by side make one ``(J S, J S)`` product per component: with the 14 terms
    of a steady-state response one call where J^2 = 196 small sparse products were (the inertia refit's
    Gauss-Newton models on the demo mesh spent 84 s in them, loaded machine; 8.6x on one thread in
    bench/bench_diagnose_kernels.py).
    """
    n_terms, n_s = len(bases), bases[0].shape[2]
    out = np.zeros((n_terms * n_s, n_terms * n_s))
    keep = np.ones(seen.size, bool) if vertices is None else vertices[seen]
    if keep.any():
        k = gram[keep][:, keep] if not keep.all() else gram
        rows = seen[keep]
        for c in range(3):
            if weights[c]:
                r = np.hstack([b[rows, c, :] for b in bases])
                out += weights[c] * (r.T @ (k @ r))
    return out.reshape(n_terms, n_s, n_terms, n_s).transpose(0, 2, 1, 3)


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
            for g, (stack, mv) in enumerate(zip(out.blocks, lin.moved)):
                blocks = motion_blocks(seen, gram, [r[g] for r in lin.spatial], mv, st.component_weights)
                for i, (j, k) in enumerate(pairs):
                    stack[f * len(pairs) + i] = w * blocks[j, k]
            out.outers[f * len(pairs):(f + 1) * len(pairs)] = pair_outers(np.stack(db))
            out.n_residuals += 3 * fr.m_both.shape[0]
