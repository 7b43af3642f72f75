"""The reconstructed motion of a run as ParaView time series: the point data, and the .pvd + .vtu
collection (the transient VTKHDF file is written by vfcli/store/vtkhdf.py, HDF5 being the store's).

Point data per step (units in the array names, ParaView shows them as they are):
``displacement_mm`` (N, 3), ``displacement_magnitude_mm``, ``velocity_mm_per_s`` (N, 3, central
differences of the displacements over the model times), ``displacement_std_mm`` (N, 3, the
stated standard deviation, when the run has one) and ``surface_load_Pa`` (N, 3, the applied
surface traction averaged onto the nodes, zero off the loaded surfaces; vfcli/export/loads.py), and ``fold`` (0 the left
fold, 1 the right; the same at every step). Points are the deformed positions
(rest + displacement, mm), so ParaView's time slider plays the motion without a filter.
"""
from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from vfcli.model.mesh import FoldMesh


def motion_fields(times: np.ndarray, displacements: np.ndarray, std: np.ndarray | None = None,
                  load: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Point data of every step.

    times : (T,) s; displacements : (T, N, 3) mm; std : (T, N, 3) mm or None; load : (T, N, 3) Pa or None.
    Returns name -> (T, N) or (T, N, 3) float32.
    """
    d = np.asarray(displacements, dtype=np.float64)
    out = {"displacement_mm": d, "displacement_magnitude_mm": np.linalg.norm(d, axis=2)}
    out["velocity_mm_per_s"] = np.gradient(d, np.asarray(times, dtype=float), axis=0) if len(times) > 1 else np.zeros_like(d)
    if std is not None:
        out["displacement_std_mm"] = np.asarray(std, dtype=np.float64)
    if load is not None:
        out["surface_load_Pa"] = np.asarray(load, dtype=np.float64)
    return {k: v.astype(np.float32) for k, v in out.items()}


def write_pvd(path: str | Path, mesh: FoldMesh, times: np.ndarray, displacements: np.ndarray,
              fields: dict[str, np.ndarray]) -> list[Path]:
    """A ``.pvd`` collection of one ``.vtu`` per step (in ``<stem>/``), for readers older than VTKHDF 2."""
    import pyvista as pv

    path = Path(path)
    folder = path.with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    cells = {pv.CellType.TETRA: np.asarray(mesh.tets, dtype=np.int64)}
    written, entries = [], []
    for k, t in enumerate(np.asarray(times, dtype=float)):
        grid = pv.UnstructuredGrid(cells, (mesh.nodes + displacements[k]).astype(np.float64))
        for name, v in fields.items():
            grid.point_data[name] = v[k]
        grid.point_data["fold"] = node_fold(mesh)
        vtu = folder / f"step_{k:04d}.vtu"
        grid.save(vtu, binary=True)
        written.append(vtu)
        entries.append(f'    <DataSet timestep="{t:.9g}" group="" part="0" file={quoteattr(f"{folder.name}/{vtu.name}")}/>')
    path.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
                    "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return [path, *written]


def node_fold(mesh: FoldMesh) -> np.ndarray:
    """(N,) int32 the fold of each node: 0 the left (y < 0), 1 the right, as in the store's /mesh."""
    fold = np.zeros(mesh.n_nodes, np.int32)
    fold[mesh.fold_nodes(1)] = 1
    return fold
