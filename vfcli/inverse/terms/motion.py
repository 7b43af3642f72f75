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

The surface sliding under the pixels (``ObjectiveSettings.motion_slide``)
-------------------------------------------------------------------------
M_f holds each pixel's barycentrics fixed: a material point.  E evaluated with a fresh raster
(a line search) compares the pixel y with the surface point under it after the step; to first
order in the step, with delta(y) = M_f dU(t_f) the (x, y) displacement of the point the frozen
raster saw (mm) and A the camera's (2, 2) matrix (px/mm)::

    v_bar_new(y) = v_bar(y - A delta(y)) = v_bar(y) - K_y delta(y),    K_y = (grad_s v_bar) A   (3, 2), 1/s

with grad_s v_bar the (3, 2) image gradient of the interpolated velocity on the pixel's triangle
(:class:`Slide`, frozen at the linearisation point like M_f).  With motion_slide the frozen
residual is ``r_f = M_f V_f - v_f - K (M_f (U(t_f) - U0(t_f)))``: the same at the linearisation
point U0, still linear in U, and its gradient is E's directional derivative as a line search
sees it (where no pixel changes its triangle).  The Gauss-Newton blocks then have 2J terms per
frame: ``(M_f R_j / dt) (x) db_j,f`` and ``(-K M_f R_j) (x) B_j(t_f)``.
"""
from __future__ import annotations

from dataclasses import dataclass

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


@dataclass(frozen=True)
class Slide:
    """How the velocity a frozen frame's compared pixels see changes when the surface slides under them.

    gradient : (m, 3, 2) K = (grad_s v_bar) A per rasterised triangle, 1/s: grad_s v_bar (3, 2) is the image
        gradient (mm/s per px) of the velocity interpolated on the triangle, A the camera's (2, 2) px per mm;
        a displacement delta (mm, model x and y) of the surface point under a pixel changes the velocity
        seen there by ``-K delta``.
    triangle : (n_both,) each compared pixel's index into ``gradient``.
    ref : (n_both, 2) model (x, y) displacement of the surface point under each pixel at the freeze, mm.
    offset : (n_both, 3) ``K ref``, mm/s (computed from the others when not given).
    """

    gradient: np.ndarray
    triangle: np.ndarray
    ref: np.ndarray
    offset: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.offset is None:
            object.__setattr__(self, "offset", self.apply(self.ref))

    @classmethod
    def at(cls, camera, positions: np.ndarray, triangles: np.ndarray, visible_triangle: np.ndarray,
           velocity: np.ndarray, ref: np.ndarray) -> Slide:
        """From the frame's deformed vertices (N, 3) mm, its rasterised triangles (K, 3), each compared pixel's
        index (n,) into them, the vertex velocity (N, 3) mm/s and ``ref`` (n, 2) mm.  K is computed for every
        rasterised triangle (a few thousand: cheaper than finding the visible ones); a triangle with no screen
        area (never visible) gets K = 0."""
        tri = np.asarray(triangles, dtype=np.int64)                            # (m, 3)
        scr = camera.project(np.asarray(positions, float)[tri.ravel()]).reshape(-1, 3, 2)
        e1, e2 = scr[:, 1] - scr[:, 0], scr[:, 2] - scr[:, 0]
        area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            g1 = np.stack([e2[:, 1], -e2[:, 0]], axis=1) / area2[:, None]     # grad of vertex 1's weight, 1/px
            g2 = np.stack([-e1[:, 1], e1[:, 0]], axis=1) / area2[:, None]
            grads = np.stack([-(g1 + g2), g1, g2], axis=1)                      # (m, 3 vertices, 2)
        grads[~np.isfinite(grads)] = 0.0
        grad_v = np.einsum("mjc,mjs->mcs", np.asarray(velocity, float)[tri], grads)   # (m, 3, 2) mm/s per px
        return cls(grad_v @ camera.matrix, np.asarray(visible_triangle, dtype=np.int64), np.asarray(ref, float))

    def apply(self, delta: np.ndarray) -> np.ndarray:
        """(n_both, 3) ``K delta`` for (n_both, 2) displacements delta, mm/s."""
        k = self.gradient[self.triangle]
        return k[:, :, 0] * delta[:, :1] + k[:, :, 1] * delta[:, 1:2]

    def transpose(self, rows: np.ndarray) -> np.ndarray:
        """(n_both, 2) ``K^T rows`` for (n_both, 3) rows."""
        k = self.gradient[self.triangle]
        return np.stack([np.sum(k[:, :, 0] * rows, axis=1), np.sum(k[:, :, 1] * rows, axis=1)], axis=1)

    def emptied(self) -> Slide:
        """No compared pixel."""
        return Slide(self.gradient, self.triangle[:0], self.ref[:0], self.offset[:0])


def frame_change(frame, velocity: np.ndarray, disp: np.ndarray) -> np.ndarray:
    """(n_both, 3) the linear part of a frozen frame's simulated velocity at its compared pixels, mm/s.

    frame : a frozen frame (:meth:`vfcli.inverse.problem.Problem.freeze`).
    velocity : (N, 3) vertex velocity (or its change) at the frame time, mm/s.
    disp : (N, 3) vertex displacements (or their change) at the frame time, mm (used with ``frame.slide`` only).
    Returns ``M V`` without the slide, ``M V - K (M U)[:, :2]`` with it (module docstring).
    """
    out = frame.m_both @ velocity
    if frame.slide is not None:
        out -= frame.slide.apply(frame.m_both @ disp[:, :2])
    return out


def frame_prediction(frame, velocity: np.ndarray, disp: np.ndarray) -> np.ndarray:
    """(n_both, 3) the simulated velocity a frozen frame's compared pixels see, mm/s (``velocity``, ``disp``: the
    model's at the frame time, as :func:`frame_change`; with the slide relative to the freeze's displacement)."""
    out = frame_change(frame, velocity, disp)
    if frame.slide is not None:
        out += frame.slide.offset
    return out


def frame_residual(frame, velocity: np.ndarray, disp: np.ndarray) -> np.ndarray:
    """(n_both, 3) simulated minus measured velocity of a frozen frame's compared pixels, mm/s
    (:func:`frame_prediction` minus ``frame.v_both``)."""
    return frame_prediction(frame, velocity, disp) - frame.v_both


def frame_adjoint(frame, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The transpose of :func:`frame_change`: (N, 3) per unit velocity and, with the slide, (N, 3) per unit
    displacement (None without it), for (n_both, 3) row values."""
    gv = frame.m_both.T @ rows
    if frame.slide is None:
        return gv, None
    gu = np.zeros_like(gv)
    gu[:, :2] = -(frame.m_both.T @ frame.slide.transpose(rows))
    return gv, gu


def triangle_grams(m_both: sp.csr_matrix, triangle: np.ndarray, n_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's vertices (m, 3) and ``sum_p b_p b_p^T`` (m, 3, 3) over its pixels' barycentrics b_p.

    m_both : (n_pix, N) interpolation rows, three entries per row in the triangle's vertex order (as
    :meth:`vfcli.camera.raster.Raster.interpolation_rows` makes them); triangle : (n_pix,) each row's triangle
    (0 .. n_triangles - 1; a triangle without rows gets vertex -1 and zeros).
    """
    cols = m_both.indices.reshape(-1, 3)
    bary = m_both.data.reshape(-1, 3)
    verts = np.full((n_triangles, 3), -1, dtype=np.int64)
    verts[triangle] = cols
    grams = np.empty((n_triangles, 3, 3))
    for j in range(3):
        for k in range(j, 3):
            grams[:, j, k] = grams[:, k, j] = np.bincount(triangle, weights=bary[:, j] * bary[:, k],
                                                          minlength=n_triangles)
    return verts, grams


def motion_slide_blocks(m_both: sp.csr_matrix, slide: Slide, bases: list[np.ndarray],
                        vertices: np.ndarray | None, weights: tuple[float, float, float], dt: float,
                        grams: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The Gauss-Newton blocks of one frame's motion residual with the slide (module docstring).

    The residual's 2J terms are ``X_j = M R_j / dt`` (with the velocity stencil in time) and
    ``Y_j = -K M R_j[:, :2]`` (with B_j(t_f)); returns the (2J, 2J, S, S) blocks
    ``sum_c w_c Z_a,c^T Z_b,c`` over the 2J terms Z (X first), per (unit control)^2 in (mm/s)^2.
    K is constant on a triangle, so every weighted gram ``M^T diag(w) M`` is a sum of the triangles'
    ``sum_p b_p b_p^T`` (:func:`triangle_grams`) weighted per triangle.
    bases, vertices, weights : as :func:`motion_blocks`; dt : frame interval, s; grams : the frame's
    :func:`triangle_grams` (computed when omitted; a frame's block groups share them).
    """
    n_terms, n_s = len(bases), bases[0].shape[2]
    k = n_terms * n_s
    out = np.zeros((2 * k, 2 * k))
    verts, tgram = grams if grams is not None else triangle_grams(m_both, slide.triangle, len(slide.gradient))
    rows = np.unique(verts[verts >= 0])
    if vertices is not None:
        rows = rows[vertices[rows]]
    if rows.size:
        at = np.full(max(m_both.shape[1], 1), -1)
        at[rows] = np.arange(rows.size)
        local = np.where(verts >= 0, at[np.maximum(verts, 0)], -1)          # (m, 3)
        pair = (local[:, :, None] >= 0) & (local[:, None, :] >= 0)           # (m, 3, 3)
        i = np.broadcast_to(local[:, :, None], pair.shape)[pair]
        j = np.broadcast_to(local[:, None, :], pair.shape)[pair]

        def gram(per_triangle: np.ndarray) -> sp.csr_matrix:
            data = (per_triangle[:, None, None] * tgram)[pair]
            return sp.csr_matrix((data, (i, j)), shape=(rows.size, rows.size))

        r = [np.hstack([b[rows, c, :] for b in bases]) for c in range(3)]
        comps = [c for c in range(3) if weights[c]]
        g_k = slide.gradient                                                    # (m, 3, 2)
        plain = gram(np.ones(len(g_k)))
        out[:k, :k] = sum(weights[c] * (r[c].T @ (plain @ r[c])) for c in comps) / dt ** 2
        out[:k, k:] = -sum(r[c].T @ (gram(weights[c] * g_k[:, c, d]) @ r[d]) for c in comps for d in range(2)) / dt
        out[k:, :k] = out[:k, k:].T
        yy = {(d, e): r[d].T @ (gram(sum(weights[c] * g_k[:, c, d] * g_k[:, c, e] for c in comps)) @ r[e])
              for d, e in ((0, 0), (0, 1), (1, 1))}
        out[k:, k:] = yy[0, 0] + yy[0, 1] + yy[0, 1].T + yy[1, 1]
    return out.reshape(2 * n_terms, n_s, 2 * n_terms, n_s).transpose(0, 2, 1, 3)


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

    def n_kron(self, problem, n_lin_terms: int) -> int:
        per = 2 * n_lin_terms if problem.settings.motion_slide else n_lin_terms
        return problem.n_frames * per ** 2 if self.weight(problem.settings) else 0

    def value(self, ev: Evaluation) -> float:
        p = ev.problem
        w = self.weight(p.settings)
        cw = np.asarray(p.settings.component_weights, dtype=float)
        u, n_f = ev.disp, p.n_frames
        motion = 0.0
        for f, fr in enumerate(ev.frames):
            r = frame_residual(fr, p.frame_velocity(u, f), u[f])
            motion += (np.sum(r * r @ cw) + fr.const) / fr.n_norm
            if ev.wants_grad and w:
                gv, gu = frame_adjoint(fr, (r * cw) * (2.0 * w / (n_f * fr.n_norm)))
                stencil_scatter(ev.grad_disp, p.stencil[f], gv / p.dt)
                if gu is not None:
                    ev.grad_disp[f] += gu
        return w * motion / n_f

    def kron_blocks(self, ev: Evaluation, lin: GroupedLinearization, groups: list[np.ndarray],
                    out: KronBlocks) -> None:
        p = ev.problem
        st = p.settings
        weight = self.weight(st)
        if not weight:
            return
        slide = st.motion_slide
        pairs = term_pairs(2 * lin.n_terms if slide else lin.n_terms)
        b = lin.temporal
        for f, fr in enumerate(ev.frames):
            db = [stencil_apply(bj, p.stencil[f]) for bj in b]
            if slide:
                if fr.slide is None:
                    raise ValueError("motion_slide needs frames frozen with it (Problem.freeze)")
                w = 2.0 * weight / (p.n_frames * fr.n_norm)
                db += [bj[f] for bj in b]
                grams = triangle_grams(fr.m_both, fr.slide.triangle, len(fr.slide.gradient))
            else:
                w = 2.0 * weight / (p.n_frames * fr.n_norm * p.dt ** 2)
                seen, gram = seen_vertex_gram(fr.m_both)
            for g, (stack, mv) in enumerate(zip(out.blocks, lin.moved)):
                bases = [r[g] for r in lin.spatial]
                blocks = (motion_slide_blocks(fr.m_both, fr.slide, bases, mv, st.component_weights, p.dt, grams)
                          if slide else motion_blocks(seen, gram, bases, mv, st.component_weights))
                for i, (j, k) in enumerate(pairs):
                    stack[f * len(pairs) + i] = w * blocks[j, k]
            out.outers[f * len(pairs):(f + 1) * len(pairs)] = pair_outers(np.stack(db))
            out.n_residuals += 3 * fr.m_both.shape[0]
