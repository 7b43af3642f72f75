"""`vfcli mesh`: build the M5 model of both folds and store it in /mesh."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.store import StageWriter, StoreReader
from vfcli.store.signals import killable
from vfcli.stages.base import RunContext, StageResult, run_stage, stage_config_json

log = logging.getLogger(__name__)


def run_mesh(ctx: RunContext, preview: str | Path | None = None) -> StageResult:
    """Mesh the folds (unless /mesh is up to date) and optionally render a preview PNG.

    The meshing libraries are imported only when /mesh is written (an up-to-date call stays cheap)."""
    cfg = ctx.config.mesh

    def body(_reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        from vfcli.model.m5 import m5_params_from
        from vfcli.model.mesh import build_mesh, dihedral_angles_deg

        with killable():  # tetgen's C code does not return to Python's signal handlers until it is done
            log.info("mesh: tetgen meshes the folds (target edge %g mm)", cfg.target_edge_mm)
            mesh = build_mesh(m5_params_from(cfg), cfg.target_edge_mm, cfg.min_ratio, cfg.min_dihedral_deg)
        for key, arr in mesh.to_arrays().items():
            s.put(key, arr)
        volumes = [mesh.fold_volume(0), mesh.fold_volume(1)]
        smallest = dihedral_angles_deg(mesh.nodes, mesh.tets).min(axis=1)      # (M,) each tet's smallest angle
        s.set_attrs(
            youngs_modulus_pa=cfg.youngs_modulus_pa,
            poisson_ratio=cfg.poisson_ratio,
            density_kg_m3=cfg.density_kg_m3,
            fold_volume_mm3=np.array(volumes),
            min_dihedral_deg=float(smallest.min()),
        )
        return {
            "nodes": int(mesh.n_nodes),
            "tets": int(len(mesh.tets)),
            "volume_mm3": round(float(sum(volumes)), 2),
            "min_dihedral_deg": round(float(smallest.min()), 1),
            # tetgen's sliver removal works towards the target, it does not bound the angles (at the defaults 56 of
            # 7352 tets stay below 15 deg, inside the folds as next to their surface): say how many
            "min_dihedral_target_deg": cfg.min_dihedral_deg,
            "tets_below_target": int(np.count_nonzero(smallest < cfg.min_dihedral_deg)),
        }

    result = run_stage(ctx, "mesh", config_json=stage_config_json("mesh", ctx.config), body=body)
    if preview is not None:
        from vfcli.model.preview import render_mesh_png
        from vfcli.store.mesh import read_mesh

        with ctx.store.read() as r:
            mesh = read_mesh(r)
        render_mesh_png(mesh, preview)
        result.summary["preview"] = str(preview)
    return result
