"""Can the data tell a candidate term from the baseline?  Its information after the load model's.

With whitened Jacobians (rows divided by their noise standard deviation) of the predicted
measurement, J_c (m, p) of a candidate's parameters and J_L (m, q) of the load model's control
values at the baseline fit, the candidate's Fisher information once the loads are free to
compensate is the Schur complement

    I_c|L = J_c^T (I - P_L) J_c,        P_L = J_L J_L^+   the projector onto the load columns

(the loads unbounded: what any load of the model could absorb, at any cost).  Normalised by the
candidate's own information ``I_c = J_c^T J_c``, the eigenvalues of
``D^-1/2 I_c|L D^-1/2`` (D = diag I_c) lie in [0, 1]: the share of the term's signal the load
model cannot mimic, in its least visible direction (:attr:`Identifiability.residual_fraction`).
A share at round-off level means the load model absorbs the term: the verdict is "not
identifiable with this load model", never "absent".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a residual share below this is round-off of the projection: the load model absorbs the term
ABSORBED_FRACTION = 1e-9
#: singular values of the whitened load Jacobian below this share of the largest are not load directions
RANK_RTOL = 1e-10


@dataclass(frozen=True)
class Identifiability:
    """residual_fraction : smallest eigenvalue of the normalised information after the loads, in [0, 1].
    information : (p, p) I_c|L, per unit parameter^2 (whitened).  own_information : (p, p) I_c.
    identifiable : residual_fraction above :data:`ABSORBED_FRACTION`."""

    residual_fraction: float
    information: np.ndarray
    own_information: np.ndarray

    @property
    def identifiable(self) -> bool:
        return bool(self.residual_fraction > ABSORBED_FRACTION)

    def words(self, name: str, load_model: str) -> str:
        if not self.identifiable:
            return f"{name}: not identifiable with the {load_model} load model (the loads absorb it)"
        return (f"{name}: identifiable with the {load_model} load model "
                f"({100 * self.residual_fraction:.3g} % of its signal cannot be absorbed)")


def load_basis(jl: np.ndarray, rtol: float = RANK_RTOL) -> np.ndarray:
    """(m, rank) orthonormal basis of the column space of the whitened load Jacobian jl (m, q)."""
    jl = np.asarray(jl, dtype=float)
    if jl.shape[1] == 0:
        return np.zeros((jl.shape[0], 0))
    q, r = np.linalg.qr(jl)                          # Householder: backward stable, also when jl is rank deficient
    u, s, _ = np.linalg.svd(r)
    return q @ u[:, s > rtol * max(float(s[0]), 1e-300)]


def project_out(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(I - Q Q^T) a`` for an orthonormal q (m, r) and a (m,) or (m, p), reorthogonalised once."""
    a = np.asarray(a, dtype=float)
    for _ in range(2):
        a = a - q @ (q.T @ a)
    return a


def identifiability(jc: np.ndarray, jl: np.ndarray | None = None, q: np.ndarray | None = None) -> Identifiability:
    """How much of a candidate's information survives the load model (module docstring).

    Parameters
    ----------
    jc : (m, p) whitened Jacobian of the candidate's parameters.
    jl : (m, q) whitened Jacobian of the load model's control values (or give ``q``).
    q : (m, r) orthonormal load basis from :func:`load_basis` (reuse it over candidates).
    """
    jc = np.asarray(jc, dtype=float).reshape(len(jc), -1)
    q = load_basis(jl) if q is None else q
    perp = project_out(jc, q)
    own = jc.T @ jc
    info = perp.T @ perp
    d = np.sqrt(np.maximum(np.diag(own), 1e-300))
    normalised = info / np.outer(d, d)
    frac = float(np.linalg.eigvalsh(0.5 * (normalised + normalised.T)).min()) if own.any() else 0.0
    return Identifiability(max(frac, 0.0), info, own)
