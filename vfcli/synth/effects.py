"""The true motion of the phantom folds: the baseline physics plus one hidden effect.

Baseline: quasi-static linear elasticity of two symmetric M5 folds, clamped fixture faces, no
collision, loaded by the aerodynamic pressure of :mod:`vfcli.synth.aero`. The load is periodic
at f0 and given over one cycle by coefficients ``c (P, J)`` of the load patterns (inferior
uniform pressure, medial hat patterns), sampled at the phases ``arange(P) / P``.

Each effect is simulated in full, as its own physics, not as a shortcut:

``none``
    ``K u(t) = F(t)``.
``inertia``
    ``M u'' + K (1 + i eta_s) u = F``, steady state, harmonic by harmonic (a direct complex
    sparse solve per harmonic, checked against a dense solve in tests/test_synth.py). ``eta_s``
    is a small structural loss factor (0.02) that keeps resonances bounded; the mean load's
    response is static. Strength: density factor (1 = 1070 kg/m^3).
``damping``
    Kelvin-Voigt viscoelasticity with the elastic Poisson ratio, ``K (u + beta u') = F``:
    each harmonic of the quasi-static response is multiplied by ``1 / (1 + i k omega beta)``.
    Strength: the loss factor ``omega0 beta`` at f0.
``contact``
    The folds collide at the midplane and cannot interpenetrate: at every phase the
    quasi-static response plus contact forces ``lambda >= 0`` on the medial nodes solves the
    linear complementarity problem ``g + G lambda >= 0, lambda . (g + G lambda) = 0``
    (``G`` the compliance of the candidate nodes, exact with one factorisation).
    Strength: factor on the medial adduction (how hard the folds are pressed together).
``asymmetry``
    The left fold is softer: ``E_left = (1 - s) E_right`` with the same load on both.

All effects but asymmetry are symmetric, so fold 1 is solved and fold 0 is its mirror image.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_factor, solve_triangular
from scipy.optimize import nnls

from vfcli.config import SynthConfig, literal_choices
from vfcli.model.fem import ElasticModel
from vfcli.model.mesh import TAG_FIXTURE, TAG_INFERIOR, TAG_MEDIAL, TAG_SUPERIOR
from vfcli.synth import aero

#: The hidden effects a phantom can carry: synth.effect's values but 'random' (which draws one of these)
EFFECTS = tuple(e for e in literal_choices(SynthConfig, "effect") if e != "random")

#: default strength of each effect and its documented range
DEFAULT_STRENGTH = {"none": 0.0, "inertia": 1.0, "damping": 0.2, "contact": 1.0, "asymmetry": 0.2}
STRENGTH_RANGE = {"none": (0.0, 0.0), "inertia": (0.25, 2.0), "damping": (0.05, 0.5),
                  "contact": (0.5, 2.0), "asymmetry": (0.05, 0.4)}
STRUCTURAL_LOSS = 0.02


@dataclass
class LoadPatterns:
    """Load vectors of the phantom's pressure patterns and their static responses.

    Attributes
    ----------
    loads : (n_dofs, J) load vectors (1 Pa on column 0: inferior; columns 1..: medial hats).
    static : (J, N, 3) vertex displacement responses, mm per Pa.
    grid : the medial hat grid.
    """

    loads: np.ndarray
    static: np.ndarray
    grid: aero.MedialGrid


def load_patterns(model: ElasticModel, grid: aero.MedialGrid) -> LoadPatterns:
    """Assemble the pattern loads (both folds alike) and solve them once."""
    q = model.quadrature
    inf = model.quadrature_mask(tags=[TAG_INFERIOR])
    med = model.quadrature_mask(tags=[TAG_MEDIAL])
    f_inf = model.pressure_operator(inf) @ np.ones(int(inf.sum()))
    hats = aero.hat_weights(grid, q.positions[med, 0], q.positions[med, 2])
    f_med = (model.pressure_operator(med) @ hats).toarray()
    loads = np.column_stack([f_inf, f_med])
    static = model.vertex_displacements(model.solve(loads))
    return LoadPatterns(loads, static, grid)


def right_medial_nodes(model: ElasticModel) -> np.ndarray:
    """Vertex indices on the medial surface of fold 1."""
    mesh = model.mesh
    faces = mesh.faces[(mesh.face_tag == TAG_MEDIAL) & (mesh.face_fold == 1)]
    return np.unique(faces)


def aerodynamic_coefficients(
    patterns: LoadPatterns,
    half_width0: np.ndarray,
    width_op: sp.csr_matrix,
    p_sub: np.ndarray,
    closed_fraction: float,
    n_iter: int = 30,
    medial_drive: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, float]:
    """Load coefficients over one cycle, consistent with the glottal shape they produce.

    Parameters
    ----------
    patterns : the load patterns.
    half_width0 : (G,) rest half-width of the channel at the hat nodes (no adduction), mm.
    width_op : (G, N) map from vertex y-displacements to half-width change.
    p_sub : (P,) subglottal pressure over one cycle, Pa.
    closed_fraction : fraction of the cycle in which the glottis is fully closed; sets the
        medial adduction (how far each fold is pressed past the midplane at rest).
    medial_drive : None (the Bernoulli profile scales p_sub), or ``f(p_sub (P,), opening (P,) mm)
        -> (P,) Pa``, the pressure the profile scales (the widened panel's own intraglottal
        waveform, :class:`vfcli.synth.widened.LoadDistribution`).

    Returns
    -------
    c : (P, J) load coefficients (Pa) of the patterns.
    adduction_mm : shift of each fold towards the midplane at rest, mm.
    """
    n_x, n_z = patterns.grid.shape
    resp = width_op @ patterns.static[:, :, 1].T  # (G, J) half-width per unit coefficient
    c = np.column_stack([p_sub, np.outer(p_sub, np.ones(resp.shape[1] - 1))])
    adduction = 0.0
    for _ in range(n_iter):
        half = half_width0[None] + c @ resp.T  # (P, G) without adduction
        opening = half.reshape(-1, n_x, n_z).min(axis=2)[:, 1:-1].max(axis=1)  # widest slice's narrowest point
        adduction = float(np.quantile(opening, closed_fraction))
        prof = aero.bernoulli_profile(2 * (half - adduction).reshape(-1, n_x, n_z)).reshape(len(p_sub), -1)
        drive = p_sub if medial_drive is None else medial_drive(p_sub, opening - adduction)
        c_new = np.column_stack([p_sub, drive[:, None] * prof])
        if np.max(np.abs(c_new - c)) < 1e-3 * np.max(np.abs(p_sub)):
            c = c_new
            break
        c = 0.5 * (c + c_new)
    return c, adduction


def band_limit(c: np.ndarray, n_harmonics: int) -> np.ndarray:
    """Keep the mean and the first ``n_harmonics`` harmonics of periodic samples (P, ...)."""
    spec = np.fft.rfft(c, axis=0)
    spec[n_harmonics + 1:] = 0
    return np.fft.irfft(spec, n=c.shape[0], axis=0)


def _harmonics(c: np.ndarray) -> np.ndarray:
    return np.fft.rfft(c, axis=0)


def _from_harmonics(spec: np.ndarray, p: int) -> np.ndarray:
    return np.fft.irfft(spec, n=p, axis=0)


def quasi_static(patterns: LoadPatterns, c: np.ndarray) -> np.ndarray:
    """(P, N, 3) vertex displacements of the baseline, mm."""
    return np.tensordot(c, patterns.static, axes=(1, 0))


def kelvin_voigt(patterns: LoadPatterns, c: np.ndarray, loss_factor: float) -> np.ndarray:
    """Quasi-static Kelvin-Voigt response: harmonic k scaled by 1 / (1 + i k loss_factor)."""
    p = c.shape[0]
    spec = _harmonics(c)
    k = np.arange(spec.shape[0])
    spec = spec / (1.0 + 1j * k * loss_factor)[:, None]
    return quasi_static(patterns, _from_harmonics(spec, p))


def _fold_blocks(model: ElasticModel, fold: int) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
    """(K_ff, M_ff, free DOFs, vertex DOFs (3, N_k), vertex node ids) of one fold, fold-local."""
    f = model.folds[fold]
    o = model.offsets
    m = model.mass[o[fold]:o[fold + 1], o[fold]:o[fold + 1]]
    free = f.free
    return f.stiffness[free][:, free].tocsc(), m[free][:, free].tocsc(), free, f.vertex_dofs, f.nodes


def _mirror_fold1(model: ElasticModel, u1: np.ndarray) -> np.ndarray:
    """(..., N, 3) displacements of both folds from fold 1's (..., N1, 3) by mirror symmetry."""
    f0, f1 = model.folds
    out = np.zeros(u1.shape[:-2] + (model.mesh.n_nodes, 3), dtype=u1.dtype)
    out[..., f1.nodes, :] = u1
    mirrored = u1 * np.array([1.0, -1.0, 1.0])
    # node i of fold 0 mirrors node i + N/2 of fold 1 (vfcli.model.mesh construction)
    half = model.mesh.n_nodes // 2
    out[..., f1.nodes - half, :] = mirrored
    return out


def _solve_complex(a: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray:
    """``a^-1 rhs`` for a complex symmetric sparse ``a`` (one harmonic's dynamic stiffness).

    SuperLU with a symmetric ordering and no pivoting (8 s for 32k DOFs, where the default column
    ordering took 20 s); checked by its residual, with partial pivoting as the fallback.
    """
    from scipy.sparse.linalg import splu

    x = splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}).solve(rhs)
    if np.linalg.norm(a @ x - rhs) > 1e-8 * np.linalg.norm(rhs):
        x = splu(a).solve(rhs)
    return x


def harmonic_response(
    model: ElasticModel,
    patterns: LoadPatterns,
    c: np.ndarray,
    f0_hz: float,
    loss: float = STRUCTURAL_LOSS,
) -> np.ndarray:
    """Steady-state dynamic response (P, N, 3), mm: ``(K (1 + i loss) - (k w)^2 M) u_k = F c_k``
    for every harmonic k >= 1 of the load coefficients ``c (P, J)``, the mean ``K u_0 = F c_0``.

    Solved directly, one sparse complex LU per harmonic with content, on fold 1 (fold 0 is its
    mirror image).  A reduced space is not enough here: the load-dependent Ritz space of the loads
    (8 Krylov blocks about w = 0) that this function used until session 21 missed the 2nd to 4th
    harmonics of f0 = 120 Hz by 68-194 % on a widened phantom whose folds have dozens of modes below
    them (tests/test_synth.py).
    """
    p = c.shape[0]
    spec = _harmonics(c)  # (K+1, J)
    k_ff, m_ff, free, vertex_dofs, nodes = _fold_blocks(model, 1)
    rows = model.offsets[1] + free
    f1 = patterns.loads[rows]  # (n_free, J)
    fold1 = model.folds[1]
    out = np.zeros((spec.shape[0], len(nodes), 3), dtype=complex)
    out[0] = np.tensordot(spec[0], patterns.static[:, nodes], axes=(0, 0))
    floor = 1e-12 * np.abs(spec).max()
    for k in range(1, spec.shape[0]):
        if np.abs(spec[k]).max() <= floor:
            continue
        omega = 2 * np.pi * f0_hz * k
        a = (k_ff * (1 + 1j * loss) - omega**2 * m_ff).tocsc()
        x = np.zeros(fold1.n_dofs, dtype=complex)
        x[free] = _solve_complex(a, f1 @ spec[k])
        out[k] = x[vertex_dofs].T
    u1 = np.fft.irfft(out, n=p, axis=0)
    return _mirror_fold1(model, u1)


def inertia(model: ElasticModel, patterns: LoadPatterns, c: np.ndarray, f0_hz: float) -> np.ndarray:
    """The inertia effect: steady-state response with the mass of the folds (P, N, 3), mm."""
    return harmonic_response(model, patterns, c, f0_hz)


def contact(model: ElasticModel, patterns: LoadPatterns, c: np.ndarray, rest_nodes: np.ndarray) -> np.ndarray:
    """Quasi-static response with unilateral contact at the midplane y = 0 (P, N, 3), mm.

    ``rest_nodes`` are the rest positions including the adduction (fold 1 at y >= -adduction).
    """
    mesh = model.mesh
    free_resp = quasi_static(patterns, c)
    f1 = model.folds[1]
    near = (mesh.face_fold == 1) & np.isin(mesh.face_tag, [TAG_MEDIAL, TAG_SUPERIOR])
    cand = np.setdiff1d(np.unique(mesh.faces[near]), np.unique(mesh.faces[mesh.face_tag == TAG_FIXTURE]))
    lo = rest_nodes[cand, 1].min()
    cand = cand[rest_nodes[cand, 1] < lo + 1.0]  # within 1 mm of the medial edge
    # unit +y point forces at the candidate vertices of fold 1 (fold-local vertex DOFs)
    local = np.searchsorted(f1.nodes, cand)
    ydof = f1.vertex_dofs[1, local] + model.offsets[1]
    rhs = sp.csr_matrix((np.ones(len(cand)), (ydof, np.arange(len(cand)))), shape=(model.n_dofs, len(cand))).toarray()
    resp = model.vertex_displacements(model.solve(rhs))  # (n_c, N, 3)
    g_mat = resp[:, cand, 1].T  # compliance: y at cand per unit force at cand
    g_mat = 0.5 * (g_mat + g_mat.T)
    chol, _ = cho_factor(g_mat, lower=True)
    l_mat = np.tril(chol)
    out = free_resp.copy()
    for i in range(c.shape[0]):
        gap = rest_nodes[cand, 1] + free_resp[i, cand, 1]
        if gap.min() >= 0:
            continue
        # min 1/2 l^T G l + g^T l, l >= 0  <=>  nnls(L^T, -L^-1 g)
        rhs_i = -solve_triangular(l_mat, gap, lower=True)
        lam, _ = nnls(l_mat.T, rhs_i, maxiter=50 * len(cand))
        out[i] += np.tensordot(lam, resp, axes=(0, 0))
    # fold 0 mirrors fold 1
    return _mirror_fold1(model, out[:, f1.nodes])


def asymmetric(patterns: LoadPatterns, c: np.ndarray, model: ElasticModel, softening: float) -> np.ndarray:
    """Quasi-static response with the left fold's modulus scaled by (1 - softening)."""
    u = quasi_static(patterns, c)
    left = np.zeros(model.mesh.n_nodes, bool)
    left[model.folds[0].nodes] = True
    return np.where(left[None, :, None], u / (1.0 - softening), u)
