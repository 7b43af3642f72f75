"""Left-right asymmetry: a stiffness ratio between the folds and a mounting offset per fold.

Stiffness (:class:`StiffnessAsymmetry`)
    The left fold (fold 0) is softer by a fraction s, ``E_left = (1 - s) E_right``, under the
    same load: its displacement scales by ``1 / (1 - s)``, so ``dU/ds = U0`` on fold 0 and 0 on
    fold 1.  (A common stiffness factor of both folds is a load scale that any load model
    absorbs; the ratio is what can be told.)  Signature: a left-right antisymmetric residual in
    phase with the motion, the left fold moving more (s > 0) than the shared load explains.
    A load model with free per-fold loads absorbs it exactly (a per-fold load scale).
Mounting offset (:class:`MountingOffset`)
    Each fold shifted laterally (y) by a constant: ``dU/d(offset_k) = e_y`` on fold k at all
    times.  The velocity does not see a constant shift; the gap silhouettes do (the medial
    edges sit off their fitted places in every frame, also when the glottis is closed).
"""
from __future__ import annotations

import numpy as np

from vfcli.diagnose.candidates.base import DisplacementTerm, fold_vertices


class StiffnessAsymmetry(DisplacementTerm):
    """Softening s of the left fold relative to the right, ``E_left = (1 - s) E_right``; one parameter."""

    name = "asymmetry"
    parameter_names = ("left_softening",)
    signature = ("a left-right antisymmetric residual in phase with the motion: one fold moves more "
                 "than the load shared by both folds explains")

    def displacement_jacobian(self, baseline) -> np.ndarray:
        left = fold_vertices(baseline, 0)
        return np.where(left[None, :, None], baseline.displacements, 0.0)[..., None]

    def extension(self, baseline, theta: np.ndarray) -> np.ndarray:
        """Exact: the left fold's displacement ``U0 / (1 - s)``, a change of ``U0 s / (1 - s)`` there (s < 1)."""
        s = float(np.asarray(theta, dtype=float).reshape(-1)[0])
        if not s < 1.0:
            raise ValueError(f"left_softening must be below 1, got {s}")
        return self.displacement_jacobian(baseline)[..., 0] * (s / (1.0 - s))


class MountingOffset(DisplacementTerm):
    """Lateral (y) mounting offset of each fold, mm; two parameters (left, right)."""

    name = "offset"
    parameter_names = ("offset_y_left_mm", "offset_y_right_mm")
    signature = ("the medial edges sit off their fitted places by a constant in every frame "
                 "(gap silhouettes), with no trace in the velocity")

    def reading(self, theta) -> str:
        """The two offsets read as the folds' mounting, in the lab's terms.

        In the model frame the left fold (fold 0) lies at y < 0 and the right one (fold 1) at y > 0
        (:mod:`vfcli.model.m5`), so offsets ``(l, r)`` (mm, along +y) move the folds ``(l - r) / 2`` each toward the
        midplane (a glottis ``l - r`` narrower at rest than the mesh's: ``mesh.gap_mm``, ``mesh.offset_y_mm``) and the
        pair ``(l + r) / 2`` toward the right fold's side (the midline of the pose: ``camera.offset_px``). A mounting
        the config does not state, or states wrong, reads so (widened phantom 4215 fitted with its folds 0.32 mm
        further apart than they are: one-step estimate +0.18 and -0.18 mm, docs/benchmarks.md "Session 63: frames
        that are not square ...")."""
        left, right = (float(v) for v in np.asarray(theta, dtype=float).reshape(-1)[:2])
        inward, shift = 0.5 * (left - right), 0.5 * (left + right)
        return (f"read as the folds' mounting: each fold {abs(inward):.2f} mm "
                f"{'nearer the midplane' if inward >= 0 else 'further from the midplane'} than the mesh puts it (the "
                f"glottis {2 * abs(inward):.2f} mm {'narrower' if inward >= 0 else 'wider'} at rest: mesh.gap_mm, "
                f"mesh.offset_y_mm), and the pair {abs(shift):.2f} mm toward the "
                f"{'right' if shift >= 0 else 'left'} fold's side (the pose's midline: camera.offset_px)")

    def displacement_jacobian(self, baseline) -> np.ndarray:
        u = baseline.displacements
        out = np.zeros(u.shape + (2,))
        for k in (0, 1):
            out[:, fold_vertices(baseline, k), 1, k] = 1.0
        return out
