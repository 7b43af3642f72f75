"""The run's folds on a finer mesh: how far the fit mesh's discretisation moves a fitted parameter.

A P2 model on a tetgen mesh is slightly stiffer than the folds it discretises: the lowest eigenvalues
(omega^2) of a widened phantom's folds fall by 0.7 % from a 1.5 mm to a 1.25 mm mesh and by another
0.5 % to 1.0 mm, the modes near 150-250 Hz by 1.1-3.0 % (docs/diagnose.md, the *mesh* part of the stated
uncertainty).  A term whose parameter trades against the stiffness (inertia's density factor: the
resonances sit at omega^2 ~ K / (rho M)) inherits that bias, and no noise-based interval sees it.
:func:`finer_model` builds the same folds with edges :data:`REFINEMENT` times shorter;
:func:`density_shift` says how far the density a fit finds moves between the two
(:meth:`vfcli.diagnose.candidates.inertia.Inertia.mesh_shift`; the diagnosis corrects the estimate by it,
:func:`vfcli.diagnose.confirmation.mesh_corrected`).
"""
from __future__ import annotations

import numpy as np

from vfcli.model.fem import ElasticModel
from vfcli.model.m5 import m5_params_from
from vfcli.model.mesh import build_mesh

#: target edge length of the fit mesh over that of the finer one
REFINEMENT = 1.2


def finer_model(mesh_config, model: ElasticModel, refinement: float = REFINEMENT) -> ElasticModel | None:
    """``model``'s folds and material on a mesh ``refinement`` times finer.

    Parameters
    ----------
    mesh_config : the run's [mesh] settings (:class:`vfcli.config.MeshConfig`: M5 geometry, placement,
        ``target_edge_mm``, tetgen quality bounds), the ones its mesh was built from.
    model : the run's :class:`ElasticModel` (E, nu and density are taken from it).

    Returns None when the material is not uniform (a per-element modulus has no counterpart on another mesh).
    """
    e = np.unique(np.asarray(model.youngs_pa, dtype=float))
    if e.size != 1:
        return None
    mesh = build_mesh(m5_params_from(mesh_config), float(mesh_config.target_edge_mm) / refinement,
                      mesh_config.min_ratio, mesh_config.min_dihedral_deg)
    return ElasticModel(mesh, float(e[0]), model.poisson, model.density_kg_m3)


def density_shift(model: ElasticModel, fine: ElasticModel, forces: np.ndarray, f0_hz: float, density: float,
                  observed: np.ndarray, loss: float = 0.0, band: float = 3.5, modes: tuple[int, int] = (60, 240),
                  folds: tuple[int, ...] = (0, 1)) -> float:
    """Relative density shift delta a fit on ``model``'s mesh makes against ``fine``'s: the density factor the
    fit mesh needs to reproduce, at the observed vertices, the finer mesh's periodic steady state of the same
    loads at ``density`` is about ``density (1 + delta)``.

    In each fold's M-orthonormal modes phi_j (eigenvalue mu_j on the fit mesh) the steady state of harmonic k
    (angular frequency W_k = k 2 pi f0) is ``U_k = sum_j phi_j q_jk / D_jk``, ``q_jk = phi_j^T F_k``,
    ``D_jk = c mu_j - density W_k^2``, ``c = 1 + i loss``.  The finer mesh's eigenvalues are lower,
    ``mu_j / (1 + d_j)`` (``d_j`` from the two sorted spectra: where modes crowd, the ratio of the j-th
    eigenvalues is the local shift of the spectrum however the shapes pair).  To first order the fit mesh's
    stiffer modes change the steady state by ``G = -sum_j phi_j d_j c mu_j q_jk / D_jk^2``; a relative density
    change delta by ``delta H``, ``H = sum_j phi_j density W_k^2 q_jk / D_jk^2``; the loads' overall scale s by
    ``s U``.  delta is the least-squares solution of ``G + delta H + s U = 0`` over all harmonics and the given
    folds (with the same d_j for every mode, delta = d exactly: the scale takes ``1 / (1 + d)``), on the
    observed vertices' displacements (what the gap term sees) and on their velocities ``i W_k U_k`` (the
    camera's motion term); the larger of the two is returned: the fit weighs both, and neither alone
    matched a refit on the finer mesh's data everywhere (tests/test_diagnose_refit_inertia.py; docs/diagnose.md).
    Modes are taken up to ``band`` harmonics of f0 at the density, ``band sqrt(density) f0``, from
    ``modes[0]`` per fold up to ``modes[1]`` (Weyl's law, N(f) ~ f^3, sizes the second eigensolve); the
    modes near the harmonics with load weigh most (on widened phantom 2012 the estimate settled at 2.4
    harmonics).

    Parameters
    ----------
    model, fine : the fit mesh's and a finer mesh's :class:`ElasticModel` of the same folds and material.
    forces : (n_dofs, K + 1) complex one-sided harmonic load vectors on ``model`` (Pa mm^2), column k at k f0.
    f0_hz : Hz.  density : density factor (1 = the models' density).
    observed : (n,) int indices of the vertices the data see (``mesh.nodes`` order).
    loss : structural loss factor eta.  folds : the folds to compare (one suffices for mirror images).

    Returns
    -------
    delta, dimensionless (0.021: the fit mesh's density estimate 2.1 % above the finer mesh's).
    """
    forces = np.asarray(forces)
    rho = float(density)
    w = 2 * np.pi * float(f0_hz) * np.arange(forces.shape[1])
    c = 1.0 + 1j * float(loss)
    cut = float(band) * np.sqrt(max(rho, 0.0)) * float(f0_hz)
    obs = np.asarray(observed, dtype=int)
    cols: dict[str, list] = {"displacement": [], "velocity": []}
    for f in folds:
        k = int(modes[0])
        freqs, shapes = model.modes(k, fold=f)
        if freqs[-1] < cut and k < modes[1]:
            k = int(min(modes[1], np.ceil(1.1 * k * (cut / freqs[-1]) ** 3)))
            freqs, shapes = model.modes(k, fold=f)
        d = (freqs / fine.modes(k, fold=f)[0]) ** 2 - 1.0              # (k,) relative stiffening of the fit mesh
        mu = (2 * np.pi * freqs) ** 2
        q = shapes.T @ forces                                           # (k, K + 1)
        den = c * mu[:, None] - rho * w[None, :] ** 2
        verts = model.vertex_displacements(shapes)[:, obs, :]          # (k, n, 3)
        for modal in (-(c * mu * d)[:, None] * q / den ** 2, rho * w ** 2 * q / den ** 2, q / den):
            u = np.einsum("jnc,jk->knc", verts, modal)                 # (K + 1, n, 3)
            for name, v in (("displacement", u), ("velocity", u * (1j * w)[:, None, None])):
                cols[name].append(np.concatenate([v.real.ravel(), v.imag.ravel()]))
    shifts = []
    for parts in cols.values():
        g, h, u = (np.concatenate(parts[i::3]) for i in range(3))
        shifts.append(float(np.linalg.lstsq(np.stack([h, u], axis=1), -g, rcond=None)[0][0]))
    return max(shifts, key=abs)
