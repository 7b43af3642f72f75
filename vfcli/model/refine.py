"""The run's folds on a finer mesh: how far the fit mesh's discretisation moves a fitted parameter.

A P2 model on a tetgen mesh is slightly stiffer than the folds it discretises: the lowest eigenvalues
(omega^2) of a widened phantom's folds fall by 0.7 % from a 1.5 mm to a 1.25 mm mesh and by another
0.5 % to 1.0 mm (docs/diagnose.md, the *mesh* part of the stated uncertainty).  A term whose parameter
trades against the stiffness (inertia's density factor: the resonances sit at omega^2 ~ K / (rho M))
inherits that bias, and no noise-based interval sees it.  :func:`finer_model` builds the same folds
with edges :data:`REFINEMENT` times shorter; the term compares the two spectra
(:meth:`vfcli.diagnose.candidates.inertia.Inertia.mesh_sd`).
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
