"""The gap term of E: simulated against measured silhouettes on the lateral rays.

With the frozen silhouette edge of each ray and fold (:meth:`vfcli.inverse.problem.Problem.freeze`),
the crossing s (lateral px) of the edge with the ray, its target m, ``d = (s - m) / px_per_mm``
(mm) and the length scale l (``gap_length_mm``)::

    E_gap = gap_weight / F * sum_f (1 / (2 n_rays)) sum_rays sum_folds arctan((d / l)^2)

The sum runs over the frozen rays: a ray the camera sees closed is left out of a frame where the simulated folds
overlap on it (:func:`closed_rays_kept`, ``optimize.gap_closed_rays = "overlap-allowed"``), as the frozen raster is
chosen at the linearisation point.

``"overlap-bounded"`` leaves such a ray out only while the overlap o (px) is within the widest opening the camera
measured in the window, B (:func:`widest_opening`): a fold that oscillates linearly about a mean opening w0 >= 0 with
amplitude A overlaps the other by at most A - w0 <= w0 + A, the widest opening it reaches. Beyond B the excess is
the model's own state, not a noisy silhouette, and is charged without saturation (:func:`closed_rays_excess`): each
fold's target is its own silhouette moved back by half the excess, and the row costs ``(d / l)^2`` instead of
``arctan((d / l)^2)``, so a frame's excess rows sum to ``(o - B)^2 / (2 (k l)^2)`` (k px per mm) at the
linearisation point, and the frozen form majorises that function of the folds' positions elsewhere.

Gauss-Newton
------------
``arctan(q)``, ``q = (d / l)^2``, is concave in q, so
``arctan(q) <= arctan(q0) + (q - q0) / (1 + q0^2)``: a quadratic majoriser in d whose
curvature ``2 / ((1 + q0^2) l^2)`` is used, with d linearised in the control values
(rows ``dd/dC`` per linearisation term j, :func:`gap_rows`)::

    H_f = sum_{j,k} (Q_j,f^T diag(curv) Q_k,f) (x) (B_j(t_f) B_k(t_f)^T)
"""
from __future__ import annotations

import numpy as np

from vfcli.camera.silhouette import crossing_with_gradient
from vfcli.inverse.terms.base import Evaluation, FrameTerm, GroupedLinearization, KronBlocks, pair_outers, term_pairs

#: what a ray the camera sees closed asks of the simulated silhouettes (``optimize.gap_closed_rays``)
CLOSED_RAYS = ("overlap-allowed", "meet", "overlap-bounded")


def widest_opening(lo: np.ndarray, hi: np.ndarray, rays: np.ndarray) -> float:
    """The widest opening the camera measured, px: the largest ``hi - lo`` over the frames and ``rays``.

    lo, hi : (F, n_rays_img) measured silhouettes, lateral px (NaN where none).  rays : (n,) ray indices.
    Returns 0.0 when no ray of any frame has both silhouettes.
    """
    w = np.asarray(hi, float)[:, rays] - np.asarray(lo, float)[:, rays]
    w = w[np.isfinite(w)]
    return float(w.max()) if w.size else 0.0


def closed_rays_excess(simulated: list, lo: np.ndarray, hi: np.ndarray, bound_px: float) -> tuple[list, list]:
    """:func:`closed_rays_kept`, and the closed rays where the simulated folds overlap by more than ``bound_px``.

    Returns
    -------
    kept : ``simulated`` without the closed rays where the folds overlap (as :func:`closed_rays_kept`).
    excess : [(rays, edge, target px), (rays, edge, target px)] per fold side: the closed rays where the overlap o
        exceeds ``bound_px``, each fold's target its own silhouette moved back by (o - bound_px) / 2 (the rows the
        gap term charges quadratically, module docstring).
    """
    (r0, e0, s0), (r1, e1, s1) = simulated
    i0, i1, over = _closed_overlap(simulated, lo, hi)
    beyond = over > bound_px                               # NaN (not closed) compares unequal
    half = 0.5 * (over[beyond] - bound_px)
    excess = [(r0[i0][beyond], e0[i0][beyond], s0[i0][beyond] - half),
              (r1[i1][beyond], e1[i1][beyond], s1[i1][beyond] + half)]
    return _without(simulated, r0[i0][over >= 0]), excess


def _closed_overlap(simulated: list, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i0, i1, o): indices into each fold's rays of the rays both folds cross, and the overlap o (px) of the
    simulated folds there, NaN where the camera does not see the ray closed (NaN targets compare unequal)."""
    (r0, _, s0), (r1, _, s1) = simulated
    common, i0, i1 = np.intersect1d(r0, r1, assume_unique=True, return_indices=True)
    return i0, i1, np.where(hi[common] == lo[common], s0[i0] - s1[i1], np.nan)


def _without(simulated: list, drop: np.ndarray) -> list:
    """``simulated`` with the rays ``drop`` removed from both folds (the same list when there are none)."""
    if not drop.size:
        return simulated
    (r0, e0, s0), (r1, e1, s1) = simulated
    k0, k1 = ~np.isin(r0, drop), ~np.isin(r1, drop)
    return [(r0[k0], e0[k0], s0[k0]), (r1[k1], e1[k1], s1[k1])]


def closing_targets(simulated: list, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The measured silhouettes ``lo``, ``hi`` (n_rays,) with each closed ray on which the simulated folds leave a gap
    targeted at that gap's middle: the camera says the folds meet there, not where.

    The measured silhouettes of a closed ray are both the last known opening location (the paper's fallback), a
    guess of where the seam lies. Under the rules that leave a closed ray out where the simulated folds overlap,
    a gap that closes away from that guess cost ``2 arctan((m - t)^2 / l^2)`` as its width went to zero (m its
    meeting point, t the guess) and nothing once the folds overlapped by a hair: E jumped there. On a panel
    contact recording (seed 2009) the contact refit started at full contact, where every contact node sits on the
    midplane, and any step that raised the contact share opened those rays: its gap term jumped by 5 % (E by
    1.9e-3) at a step of 1e-7, and the refit kept no step (docs/benchmarks.md, "Session 53: closed rays close where
    they stand"). Targeted at the middle, the two rows are ``-w / 2`` and ``+w / 2`` (w the simulated width): zero as
    the gap closes, so E is continuous where the folds start to overlap. Returns copies.
    """
    i0, i1, over = _closed_overlap(simulated, lo, hi)
    lo, hi = np.array(lo, dtype=float, copy=True), np.array(hi, dtype=float, copy=True)
    opened = over < 0                                       # NaN (not closed) compares unequal
    rays = simulated[0][0][i0][opened]
    middle = 0.5 * (simulated[0][2][i0][opened] + simulated[1][2][i1][opened])
    lo[rays] = middle
    hi[rays] = middle
    return lo, hi


def closed_rays_kept(simulated: list, lo: np.ndarray, hi: np.ndarray) -> list:
    """The simulated silhouettes of one frame without the rays the camera sees closed where the folds overlap.

    A superior view cannot see one fold pass behind the other: a ray it sees closed says only that the folds meet
    or overlap there. The linear-elastic model has no contact, so its folds overlap in the closed phase as the
    recorded folds do when pressed together (their closed phase is a contact, the model's an overlap). Where the
    simulated folds overlap on a closed ray, the ray says nothing more and is left out; where they leave a gap the
    ray is kept and the simulated gap is asked to close where it stands (:func:`closing_targets`). Open rays are all
    kept.

    Parameters
    ----------
    simulated : [(rays, edge, s), (rays, edge, s)] of :meth:`vfcli.inverse.problem.Problem.silhouettes` for the
        fold at smaller lateral px (s its medial-most crossing, px) and the one at larger.
    lo, hi : (n_rays,) measured silhouettes of the frame, lateral px (equal on a closed ray, NaN where none).

    Returns
    -------
    The same list with the closed, overlapping rays removed from both folds.
    """
    i0, _, over = _closed_overlap(simulated, lo, hi)
    return _without(simulated, simulated[0][0][i0][over >= 0])


def gap_rows(problem, positions: np.ndarray, sil: list, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linearised silhouette residuals of one frame.

    Parameters
    ----------
    problem : the :class:`vfcli.inverse.problem.Problem` (camera, fold edges, ray axis).
    positions : (N, 3) deformed vertices at the frame, mm.
    sil : the frame's frozen silhouettes (``Problem.freeze(x)[f].sil``).
    basis : (N, 3, S) vertex displacement per unit spatial control value, mm.

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


class GapTerm(FrameTerm):
    """``gap_weight * E_gap`` (module docstring), dimensionless times the weight."""

    name = "gap"

    @staticmethod
    def _n_sil(problem) -> float:
        return 2.0 * max(len(problem.rays), 1)

    def value(self, ev: Evaluation) -> float:
        p = ev.problem
        st = p.settings
        weight = self.weight(st)
        if not weight:
            return 0.0
        n_f, n_sil, ell = p.n_frames, self._n_sil(p), st.gap_length_mm
        gap = 0.0
        scale = p.camera.px_per_mm * ell
        for f, fr in enumerate(ev.frames):
            scr = p.camera.project(p.mesh.nodes + ev.disp[f])
            rows = [(side, row, False) for side, row in enumerate(fr.sil)]
            rows += [(side, row, True) for side, row in enumerate(fr.excess)]
            for side, (rays, edge, tgt), quadratic in rows:
                if rays.size == 0:
                    continue
                ee = p.fold_edges[p.fold_order[side]][edge]
                s, d0, d1 = crossing_with_gradient(scr, ee, rays, p.ray_comp)
                q = ((s - tgt) / scale) ** 2
                gap += np.sum(q if quadratic else np.arctan(q)) / n_sil
                if ev.wants_grad:
                    # d arctan(q)/ds (or dq/ds), q = ((s - m) / (k l))^2
                    dphi = 2.0 * (s - tgt) / scale ** 2
                    if not quadratic:
                        dphi /= 1.0 + q * q
                    dphi *= weight / (n_f * n_sil)
                    gs = np.zeros((len(scr), 2))
                    np.add.at(gs, ee[:, 0], dphi[:, None] * d0)
                    np.add.at(gs, ee[:, 1], dphi[:, None] * d1)
                    ev.grad_disp[f, :, :2] += gs @ p.camera.matrix
        return weight * gap / n_f

    def kron_blocks(self, ev: Evaluation, lin: GroupedLinearization, groups: list[np.ndarray],
                    out: KronBlocks) -> None:
        p = ev.problem
        st = p.settings
        weight = self.weight(st)
        if not weight:
            return
        scale_px = p.camera.px_per_mm * st.gap_length_mm
        pairs = term_pairs(lin.n_terms)
        # every term's basis side by side: a frame's crossings are found once, not once per term
        bases = np.concatenate(lin.full, axis=2)                          # (N, 3, n_terms * S)
        for f, fr in enumerate(ev.frames):
            pos = p.mesh.nodes + ev.disp[f]
            q_r, dist = gap_rows(p, pos, fr.sil, bases)
            q_x, dist_x = gap_rows(p, pos, fr.excess, bases)
            if not len(dist) + len(dist_x):
                continue
            q_rows = np.split(np.concatenate([q_r, q_x]), len(lin.full), axis=1)
            q = (dist / scale_px) ** 2
            # the arctan's majoriser on the silhouette rows, the quadratic's own curvature on the excess rows
            curv = (weight / (p.n_frames * self._n_sil(p))) * 2.0 / (np.append(1.0 + q * q, np.ones(len(dist_x)))
                                                                       * scale_px ** 2)
            for stack, g in zip(out.blocks, groups):
                qg = [qr[:, g] for qr in q_rows]
                # the silhouettes of the group's folds
                rows = np.flatnonzero(np.any(np.any([qj != 0.0 for qj in qg], axis=0), axis=1)) if len(qg) > 1 \
                    else np.flatnonzero(np.any(qg[0] != 0.0, axis=1))
                # every pair's block from one product of the terms' rows side by side
                q_all = np.hstack([qj[rows] for qj in qg])
                n_s = qg[0].shape[1]
                blocks = (q_all.T @ (curv[rows, None] * q_all)).reshape(len(qg), n_s, len(qg), n_s)
                for i, (j, k) in enumerate(pairs):
                    stack[f * len(pairs) + i] = blocks[j, :, k, :]
            out.outers[f * len(pairs):(f + 1) * len(pairs)] = pair_outers(np.stack([b[f] for b in lin.temporal]))
