"""The applied surface load of a run, as a traction (Pa) at the mesh nodes, for the ParaView export.

The load model is rebuilt from the settings the run stored (optimize.loads, setup, tie_folds,
pressure shapes; vfcli/model/loads) with its final control values; the traction at the facet
quadrature points is averaged (area-weighted) onto each facet's three nodes. Nodes off the
loaded surfaces get zero.
"""
from __future__ import annotations

import numpy as np

from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec
from vfcli.model.loads.pressure import PressureLoad, band_limited
from vfcli.model.mesh import FoldMesh


def node_traction(mesh: FoldMesh, quad, traction: np.ndarray) -> np.ndarray:
    """(T, N, 3) Pa: quadrature-point tractions (T, Q, 3) averaged onto the facets' nodes by area weight."""
    t_n = traction.shape[0]
    out = np.zeros((t_n, mesh.n_nodes, 3))
    wsum = np.zeros(mesh.n_nodes)
    nodes = mesh.faces[quad.face]                                   # (Q, 3)
    for c in range(3):
        np.add.at(wsum, nodes[:, c], quad.weights)
        for k in range(t_n):
            np.add.at(out[k], nodes[:, c], quad.weights[:, None] * traction[k])
    return out / np.maximum(wsum, 1e-30)[None, :, None]


def applied_traction(mesh: FoldMesh, optimize_cfg: dict, mesh_cfg: dict, controls: np.ndarray, sim_time: np.ndarray,
                     pressure: tuple[np.ndarray, np.ndarray] | None = None, f0_hz: float = float("nan")) -> np.ndarray:
    """(T, N, 3) Pa: the surface traction a run applied at each model time.

    optimize_cfg / mesh_cfg : the run's stored ``optimize`` and ``mesh`` settings (dicts).
    controls : (P,) the run's final control values.  sim_time : (T,) s.
    pressure : (times s, Pa) recorded subglottal pressure (needed when optimize.loads = 'pressure'), band-limited as
        the run did (its ``pressure_band_harmonics`` of ``f0_hz``, the video's f0 from /sync; a run that does not
        state it used the record as it is).
    """
    t_range = (float(sim_time[0]), float(sim_time[-1]))
    model = ElasticModel(mesh, mesh_cfg.get("youngs_modulus_pa", 4400.0), mesh_cfg.get("poisson_ratio", 0.499),
                         mesh_cfg.get("density_kg_m3", 1070.0))
    quad = model.quadrature
    if optimize_cfg.get("loads", "pressure") in ("free", "free-regularised"):
        field = ForceField(ForceFieldSpec.from_name(optimize_cfg["setup"], tie_folds=bool(optimize_cfg.get("tie_folds"))),
                           t_range)
        traction = field.tractions(model, controls, sim_time)
    else:
        if pressure is None:
            raise ValueError("a pressure-load run needs the recorded pressure")
        n_z, n_x = optimize_cfg.get("pressure_medial_shapes", (3, 2))
        p_rec = band_limited(pressure[0], pressure[1], f0_hz, optimize_cfg.get("pressure_band_harmonics"))
        load = PressureLoad(pressure[0], p_rec, t_range, time_degree=optimize_cfg.get("pressure_time_degree", 4),
                            medial_z=n_z, medial_x=n_x,
                            inferior_linear_x=bool(optimize_cfg.get("pressure_inferior_linear", False)))
        mask, values = load.shape_values(quad)
        p = load.amplitudes(controls, sim_time) @ values.T                 # (T, Q_sel) Pa
        traction = np.zeros((len(sim_time), len(quad), 3))
        traction[:, mask] = -p[..., None] * quad.normals[mask][None]
    return node_traction(mesh, quad, traction)
