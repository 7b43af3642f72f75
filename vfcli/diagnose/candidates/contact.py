"""Collision of the folds at the midplane: no interpenetration, enforced by contact forces.

The baseline is linear and knows no collision: under a load that presses the folds together its
medial surfaces pass through the midplane y = 0 (fold 0 lives at y < 0, fold 1 at y > 0).  With
contact, each fold's surface vertices near its medial edge (the contact nodes, within
:data:`CONTACT_BAND_MM` of the rest medial plane) are pushed back by forces ``lambda >= 0`` along y,
the unilateral (rigid-contact) problem of the linear folds at every time t (an LCP)::

    g(t) = g0(t) + G lambda(t) >= 0,   lambda(t) >= 0,   lambda(t) . g(t) = 0

with ``g0 = s (y_rest + u0_y)`` the baseline's distance of each contact node from the midplane on
its own side (s = -1 on fold 0, +1 on fold 1; negative where it crossed) and ``G`` the compliance
of the contact nodes (separation change per unit push, mm per Pa mm^2; the folds are separate
bodies, so G is block diagonal).  It is solved as the bounded least-squares problem
``min 1/2 lambda^T G lambda + g0^T lambda, lambda >= 0`` (scipy's NNLS on the Cholesky factor).

Parameter (:class:`Contact`): ``theta``, the share of the rigid-contact correction switched on,

    U(theta) = U0 + theta K^-1 N^T lambda(U0)        (N^T: the y forces at the contact nodes)

theta = 0 is the baseline (no contact), theta = 1 the exact rigid contact of the linear folds at the
midplane (no interpenetration left); the change is linear in theta, so the column
``dU/dtheta = K^-1 N^T lambda(U0)`` is exact and :meth:`Contact.extension` is exact at theta = 1 (in
between it is a blend, not a compliant-contact law).  lambda(U0) is continuous and piecewise linear
in U0 (smooth enough for Gauss-Newton in the loads).  Where the baseline's folds never cross the
midplane the column is exactly zero: the term does not act and there is no evidence for it.

Signature and evidence: clipping at closure.  The recording's gap silhouette is closed while the
folds of the no-contact fit cross the midplane (:meth:`Contact.overlap`, :meth:`Contact.evidence`,
e.g. "the folds of the no-contact fit cross the midplane by up to 0.3 mm during the closed phase").
The superior-surface velocity changes little (the reference note: about 0.2 % at 0.13 mm of
prevented overlap); the evidence sits in the closure phase, the medial edge and the gap rows.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, solve_triangular
from scipy.optimize import nnls

from vfcli.diagnose.candidates.base import DisplacementTerm
from vfcli.diagnose.candidates.inertia import term_model
from vfcli.model.mesh import TAG_FIXTURE, TAG_MEDIAL, TAG_SUPERIOR

log = logging.getLogger(__name__)

#: contact nodes: surface vertices (medial, superior) within this distance of the fold's rest medial plane, mm
CONTACT_BAND_MM = 1.0
#: a crossing below this is no crossing (round-off of the solves), mm
CROSSING_TOL_MM = 1e-6
#: a recorded frame is "closed" when its gap area is at most this share of the window's largest
CLOSED_AREA_SHARE = 0.02


@dataclass(frozen=True)
class ContactNodes:
    """The contact nodes of a mesh.

    nodes : (n_c,) vertex indices.  side : (n_c,) -1 on fold 0 (y < 0), +1 on fold 1.
    ydof : (n_c,) global y DOF of each node in the elastic model.
    """

    nodes: np.ndarray
    side: np.ndarray
    ydof: np.ndarray


def contact_nodes(model, band_mm: float = CONTACT_BAND_MM) -> ContactNodes:
    """The surface vertices of both folds (medial and superior faces, not on the fixture) within
    ``band_mm`` of each fold's rest medial plane (module docstring)."""
    mesh = model.mesh
    fixture = np.unique(mesh.faces[mesh.face_tag == TAG_FIXTURE])
    nodes, side, ydof = [], [], []
    for k, sign in ((0, -1.0), (1, 1.0)):
        near = (mesh.face_fold == k) & np.isin(mesh.face_tag, [TAG_MEDIAL, TAG_SUPERIOR])
        cand = np.setdiff1d(np.unique(mesh.faces[near]), fixture)
        dist = sign * mesh.nodes[cand, 1]
        cand = cand[dist < dist.min() + band_mm]
        fold = model.folds[k]
        local = np.searchsorted(fold.nodes, cand)
        if not np.array_equal(fold.nodes[local], cand):
            raise RuntimeError(f"contact nodes of fold {k} are not vertices of its elastic model")
        nodes.append(cand)
        side.append(np.full(len(cand), sign))
        ydof.append(fold.vertex_dofs[1, local] + model.offsets[k])
    return ContactNodes(np.concatenate(nodes), np.concatenate(side), np.concatenate(ydof))


def separation(rest: np.ndarray, disp: np.ndarray, cn: ContactNodes) -> np.ndarray:
    """(T, n_c) distance of each contact node from the midplane on its own side, mm (negative: crossed).

    rest : (N, 3) rest positions, mm.  disp : (T, N, 3) displacements, mm.
    """
    return cn.side[None] * (rest[cn.nodes, 1][None] + disp[:, cn.nodes, 1])


def solve_contact(g0: np.ndarray, compliance: np.ndarray) -> np.ndarray:
    """(T, n_c) contact forces (Pa mm^2, >= 0) of the rigid-contact LCP (module docstring).

    g0 : (T, n_c) separations without contact, mm.  compliance : (n_c, n_c) G, mm per Pa mm^2, SPD.
    """
    g0 = np.atleast_2d(np.asarray(g0, dtype=float))
    lam = np.zeros_like(g0)
    crossed = np.flatnonzero((g0 < -CROSSING_TOL_MM).any(axis=1))
    if not len(crossed):
        return lam
    chol, _ = cho_factor(compliance, lower=True)
    low = np.tril(chol)
    for t in crossed:
        # min 1/2 l^T G l + g0^T l, l >= 0  <=>  min |L^T l + L^-1 g0|^2, l >= 0 (G = L L^T)
        rhs = -solve_triangular(low, g0[t], lower=True)
        lam[t], _ = nnls(low.T, rhs, maxiter=50 * g0.shape[1])
    return lam


class Contact(DisplacementTerm):
    """Collision of the folds at the midplane (rigid contact of the linear folds), one parameter:
    the share theta of the contact correction switched on (0: none, 1: no interpenetration).

    Parameters
    ----------
    model : the baseline's :class:`vfcli.model.fem.ElasticModel` (default: ``baseline.model``, else a
        default-material model of its mesh; the correction of a rigid contact does not depend on E).
    band_mm : width of the contact band at the medial edge, mm.
    """

    name = "contact"
    parameter_names = ("contact_share",)
    signature = ("clipping at closure: the recording's glottis is closed while the folds of the no-contact "
                 "fit cross the midplane (they would interpenetrate), the medial edge moving on where the "
                 "recorded one stops")
    #: contact only pushes the folds apart: a negative share (pulling them through) is no contact
    one_sided = True
    full_value = 1.0
    full_meaning = "rigid contact, no interpenetration"
    #: the confirmation refit's starting values (:mod:`vfcli.diagnose.refit`): none and full contact.  Not
    #: profiled (no ``profile_screening``): the profile at full contact with the loads refitted named a null
    #: of the blind panel as readily as a contact phantom (docs/diagnose.md, "A contact profile at full contact")
    start_values = (0.0, 1.0)

    def __init__(self, model=None, band_mm: float = CONTACT_BAND_MM) -> None:
        self.model = model
        self.band_mm = float(band_mm)
        self._own: tuple = (None, None)               # (mesh, default model)
        self._ops: tuple = (None, None, None, None)   # (model, ContactNodes, compliance, (n_c, N, 3) unit pushes)

    def operators(self, baseline) -> tuple:
        """(model, :class:`ContactNodes`, compliance G (n_c, n_c)) of the baseline's model (cached with the unit
        pushes' displacements, :meth:`correction_of_units`: one solve per contact node, in chunks)."""
        model = term_model(self, baseline)
        if self._ops[0] is not model:
            cn = contact_nodes(model, self.band_mm)
            g = np.empty((len(cn.nodes), len(cn.nodes)))
            units = np.empty((len(cn.nodes), model.mesh.n_nodes, 3))
            for a in range(0, len(cn.nodes), 256):             # unit y pushes, in chunks
                cols = np.arange(a, min(a + 256, len(cn.nodes)))
                rhs = np.zeros((model.n_dofs, len(cols)))
                rhs[cn.ydof[cols], np.arange(len(cols))] = cn.side[cols]
                u = model.solve(rhs)
                g[:, cols] = cn.side[:, None] * u[cn.ydof]
                units[cols] = model.vertex_displacements(u).reshape(len(cols), -1, 3)
            self._ops = (model, cn, 0.5 * (g + g.T), units)
        return self._ops[:3]

    def separation(self, baseline, disp: np.ndarray | None = None) -> np.ndarray:
        """(T, n_c) distance of each contact node from the midplane on its side, mm, for ``disp``
        (T, N, 3) (default: the baseline's displacements); negative where the fold crossed it."""
        _, cn, _ = self.operators(baseline)
        disp = baseline.displacements if disp is None else disp
        return separation(baseline.problem.mesh.nodes, disp, cn)

    def forces(self, baseline) -> np.ndarray:
        """(F + 1, n_c) rigid-contact forces at the baseline (Pa mm^2, >= 0, along each fold's outward y)."""
        _, _, g = self.operators(baseline)
        return solve_contact(self.separation(baseline), g)

    def correction(self, baseline, lam: np.ndarray) -> np.ndarray:
        """(T, N, 3) displacement (mm) of the contact forces ``lam`` (T, n_c): their sum over the unit pushes'
        displacements (:meth:`correction_of_units`; the folds are linear)."""
        return np.tensordot(np.asarray(lam, dtype=float), self._unit_pushes(baseline), axes=(1, 0))

    def pullback(self, baseline, grad: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(T, N, 3) gradient with respect to the baseline's displacements U0 of ``sum(grad * U)``, U the
        extended model's displacements ``U0 + extension(U0, theta)`` and ``grad`` (T, N, 3) a gradient
        with respect to U (e.g. dE/dU): the chain rule through the contact forces, so that a refit of the
        loads under contact steps with E's exact gradient.

        On each time's active set A (the nodes pushed, ``lambda > 0``) the forces are
        ``lambda_A = -G_AA^-1 g0_A`` with ``g0 = s (y_rest + U0_y)``, so ``dU = dU0 - theta W_A G_AA^-1 S_A
        dU0_y,A`` (W_A: the displacement per unit push at A) and the pullback subtracts
        ``theta S_A G_AA^-1 W_A^T grad`` from grad's y at A.  Exact where the active set does not change
        (lambda is piecewise linear in U0).
        """
        _, cn, g = self.operators(baseline)
        lam = self.forces(baseline)
        th = float(np.asarray(theta, dtype=float).reshape(-1)[0])
        out = np.array(grad, dtype=float, copy=True)
        for t in np.flatnonzero(np.any(lam > 0, axis=1)):
            active = np.flatnonzero(lam[t] > 0)
            push = self.correction_of_units(baseline, active)            # (n_a, N, 3)
            w = push.reshape(len(active), -1) @ np.asarray(grad[t], float).ravel()
            z = np.linalg.solve(g[np.ix_(active, active)], w)
            out[t, cn.nodes[active], 1] -= th * cn.side[active] * z
        return out

    def correction_of_units(self, baseline, which: np.ndarray) -> np.ndarray:
        """(k, N, 3) displacement (mm) of a unit push (Pa mm^2, along the fold's outward y) at each contact
        node ``which`` (k,) (indices into the contact nodes), cached per model with :meth:`operators`."""
        return self._unit_pushes(baseline)[np.asarray(which)]

    def _unit_pushes(self, baseline) -> np.ndarray:
        """(n_c, N, 3) displacement (mm) of a unit push at every contact node (:meth:`operators`' cache)."""
        self.operators(baseline)
        return self._ops[3]

    def displacement_jacobian(self, baseline) -> np.ndarray:
        return self.correction(baseline, self.forces(baseline))[..., None]

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """(F + 1, N, 3) change of the displacements at share ``theta[0]``: theta times the rigid-contact
        correction of the baseline's displacements (exact at theta = 1; module docstring)."""
        return self.displacement_jacobian(baseline)[..., 0] * float(np.asarray(theta, dtype=float).reshape(-1)[0])

    # ------------------------------------------------------------ evidence
    def overlap(self, baseline) -> np.ndarray:
        """(F + 1,) deepest crossing of the midplane by either fold of the baseline at each time, mm (0: none)."""
        return np.maximum(-self.separation(baseline).min(axis=1), 0.0)

    def evidence(self, baseline, closed: np.ndarray | None = None) -> str:
        """Plain words: how far the folds of the no-contact fit cross the midplane, in the frames where
        the recording's glottis is closed and where it is open.

        closed : (F,) bool, the frames the recording shows closed (default :func:`closed_frames`).
        """
        depth = self.overlap(baseline)[:-1]                 # at the frame times
        closed = closed_frames(baseline.problem.meas) if closed is None else np.asarray(closed, bool)
        if not np.any(depth > CROSSING_TOL_MM):
            closest = float(self.separation(baseline).min())
            return (f"the folds of the no-contact fit never cross the midplane (closest {closest:.2g} mm from it)")
        parts = []
        for mask, when in ((closed, "during the closed phase"), (~closed, "while the glottis is open")):
            if mask.any():
                d = float(depth[mask].max())
                n = int(np.sum(depth[mask] > CROSSING_TOL_MM))
                parts.append(f"by up to {d:.2g} mm {when} ({n} of {int(mask.sum())} frames)" if n
                             else f"not at all {when} ({int(mask.sum())} frames)")
        return "the folds of the no-contact fit cross the midplane " + "; ".join(parts)

    def missing_signature(self, baseline, closed: np.ndarray | None = None) -> str:
        """Why the no-contact fit's crossing of the midplane is not collision's signature ("" when it is).

        Collision acts at closure: a no-contact fit that had to cross the midplane to match a closed glottis crosses
        while the recording shows it closed, and less while it is open.  A crossing the fit holds at every time, open
        or closed, is its rest shape and mounting (what the offset candidate reads), not a collision, and a refit
        with contact then pushes the folds back by a constant: a finding of "contact" from it names the wrong physics
        (fresh null 2348: 0.337 mm on average while closed, 0.329 mm while open, 0.33 mm in every frame; refit share
        0.183 confirmed, docs/benchmarks.md "Session 77").  Missing when (in the frames at the frame times):

        * the recording shows no closed frame in the window, or the fit does not cross while it is closed;
        * the fit crosses no deeper on average while the recording is closed than while it is open;
        * the crossing that comes with the closure (the closed frames' mean depth less the window's shallowest) is
          smaller than the crossing that stays (the window's shallowest depth): most of it is the rest shape.

        The last rule's bound (half the closed phase's crossing) is the definition of "most", not a value fitted to
        recordings: on the fresh nulls and the blind panel's contact recordings measured in session 76 the crossing
        that comes with the closure was within 0.02 mm of nothing on a crossing of 0.03-0.63 mm, which any bound
        would have read alike.

        closed : (F,) bool, the frames the recording shows closed (default :func:`closed_frames`).
        """
        depth = self.overlap(baseline)[:-1]
        closed = closed_frames(baseline.problem.meas) if closed is None else np.asarray(closed, bool)
        if not closed.any():
            return "the recording shows the glottis closed in no frame of the window, so no crossing comes with a closure"
        shut = float(depth[closed].mean())
        if shut <= CROSSING_TOL_MM:
            return "the folds of the no-contact fit do not cross the midplane while the recording shows the glottis closed"
        if (~closed).any() and shut <= float(depth[~closed].mean()):
            return (f"the folds of the no-contact fit cross the midplane no deeper while the glottis is closed "
                    f"({shut:.2g} mm on average) than while it is open ({float(depth[~closed].mean()):.2g} mm): the "
                    "crossing does not come with the closure")
        stays = float(depth.min())
        if shut - stays < stays:
            return (f"the folds of the no-contact fit cross the midplane by {stays:.2g} mm at every time of the window, "
                    f"open or closed, and by {shut:.2g} mm on average while closed: most of the crossing is the fit's "
                    "rest shape (its mounting, the offset candidate's reading), not a collision at closure")
        return ""


def closed_frames(meas) -> np.ndarray:
    """(F,) bool: the frames whose recorded gap area is at most :data:`CLOSED_AREA_SHARE` of the
    window's largest (from the gap masks, else from the silhouettes: no ray with a target)."""
    if getattr(meas, "gap", None) is not None:
        area = np.asarray(meas.gap, bool).reshape(len(meas.gap), -1).sum(axis=1).astype(float)
        return area <= CLOSED_AREA_SHARE * max(float(area.max(initial=0.0)), 1.0)
    return np.all(np.isnan(meas.gap_lo), axis=1) & np.all(np.isnan(meas.gap_hi), axis=1)
