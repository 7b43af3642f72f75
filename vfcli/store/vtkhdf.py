"""Write a transient VTKHDF unstructured grid (ParaView 5.12+, VTK 9.3+, pyvista).

VTK's own vtkHDFWriter writes the connectivity again at every step once the points move;
this writer stores the tetrahedra once and indexes the moving points and the point data
per step (VTKHDF 2.x "Steps" group: one partition described once, every step's PartOffsets,
CellOffsets and ConnectivityIdOffsets are 0, its PointOffsets and PointDataOffsets advance by
the number of nodes). Spec:
https://docs.vtk.org/en/latest/vtk_file_formats/vtkhdf_file_format/
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

VTK_TETRA = 10


def write_transient_tets(path: str | Path, points: np.ndarray, tets: np.ndarray, times: np.ndarray,
                         point_data: dict[str, np.ndarray]) -> None:
    """Write moving tetrahedra as one transient VTKHDF file.

    Parameters
    ----------
    points : (T, N, 3) node positions at each step (mm).
    tets : (C, 4) node indices, the same at every step.
    times : (T,) time of each step (s).
    point_data : name -> (T, N) or (T, N, k) values per step.
    """
    points = np.asarray(points, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    n_t, n_p = points.shape[:2]
    n_c = len(tets)
    tmp = Path(path).with_name(Path(path).name + ".tmp")
    with h5py.File(tmp, "w") as f:
        g = f.create_group("VTKHDF")
        g.attrs["Version"] = np.array([2, 0], dtype=np.int64)   # transient UnstructuredGrid: VTK 9.3+ / ParaView 5.12+
        g.attrs.create("Type", np.bytes_("UnstructuredGrid"), dtype=h5py.string_dtype("ascii", len("UnstructuredGrid")))
        g.create_dataset("NumberOfPoints", data=np.array([n_p], np.int64))
        g.create_dataset("NumberOfCells", data=np.array([n_c], np.int64))
        g.create_dataset("NumberOfConnectivityIds", data=np.array([4 * n_c], np.int64))
        g.create_dataset("Points", data=points.reshape(n_t * n_p, 3), compression="gzip", compression_opts=4)
        g.create_dataset("Connectivity", data=tets.ravel())
        g.create_dataset("Offsets", data=np.arange(0, 4 * n_c + 1, 4, dtype=np.int64))
        g.create_dataset("Types", data=np.full(n_c, VTK_TETRA, np.uint8))
        pd = g.create_group("PointData")
        g.create_group("CellData")
        g.create_group("FieldData")
        steps = g.create_group("Steps")
        steps.attrs["NSteps"] = np.int64(n_t)
        steps.create_dataset("Values", data=np.asarray(times, dtype=np.float64))
        steps.create_dataset("PartOffsets", data=np.zeros(n_t, np.int64))
        steps.create_dataset("NumberOfParts", data=np.ones(n_t, np.int64))
        steps.create_dataset("PointOffsets", data=np.arange(n_t, dtype=np.int64) * n_p)
        steps.create_dataset("CellOffsets", data=np.zeros(n_t, np.int64))
        steps.create_dataset("ConnectivityIdOffsets", data=np.zeros(n_t, np.int64))
        pdo = steps.create_group("PointDataOffsets")
        steps.create_group("CellDataOffsets")
        steps.create_group("FieldDataOffsets")
        for name, values in point_data.items():
            v = np.asarray(values, dtype=np.float32)
            if v.shape[:2] != (n_t, n_p):
                raise ValueError(f"point data {name!r}: shape {v.shape}, expected ({n_t}, {n_p}, ...)")
            pd.create_dataset(name, data=v.reshape(n_t * n_p, *v.shape[2:]), compression="gzip", compression_opts=4)
            pdo.create_dataset(name, data=np.arange(n_t, dtype=np.int64) * n_p)
    tmp.replace(path)
