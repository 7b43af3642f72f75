"""Writers of LDV scans: the Polytec PSV UFF layout (via pyuff), vfcli CSV and MAT.

The UFF writer produces what :func:`vfcli.io.ldv.read.read_ldv` and pyuff read:
dataset 151 (header), 164 (units), 2411 (geometry, node numbers = scan point
numbers) and one dataset 58 per point and channel (velocity
'Response Time Trace' / 'Vib  Velocity', reference 'Reference Time Trace' /
'Ref1  Pressure'), even abscissa, double precision.

pyuff's ``UFF.write_sets`` rescans the whole file after every dataset (749
records take minutes); here the datasets are written with pyuff's own
per-dataset writers into one file opened in append mode, geometry first, and
the file is scanned once, by the reader. NaN/Inf is refused (pyuff would
write it as 0.0).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from vfcli.errors import ConfigError
from vfcli.io.ldv.read import MM_PER_UNIT, MM_S_PER_UNIT, LdvScan

logger = logging.getLogger(__name__)

#: UFF specific data type codes used in dataset 58 records.
_SPEC_TIME, _SPEC_VELOCITY, _SPEC_PRESSURE, _SPEC_GENERAL = 17, 11, 15, 1


def _check_scan(scan: LdvScan) -> tuple[int, int]:
    p = scan.node_ids.size
    v = np.asarray(scan.velocity_mm_s)
    if v.ndim != 2 or v.shape[0] != p or v.shape[1] < 2:
        raise ConfigError(f"velocity must be (P={p}, S>=2), got {v.shape}")
    if np.asarray(scan.coords_mm).shape != (p, 3):
        raise ConfigError(f"coords_mm must be ({p}, 3)")
    if np.unique(scan.node_ids).size != p:
        raise ConfigError("node ids must be unique")
    arrays = [("velocity", v), ("coords", scan.coords_mm)]
    if scan.reference is not None:
        if np.asarray(scan.reference).shape != v.shape:
            raise ConfigError("reference must have the velocity's shape")
        arrays.append(("reference", scan.reference))
    if scan.t0 is not None:
        arrays.append(("t0", scan.t0))
    for name, a in arrays:
        if not np.isfinite(np.asarray(a, dtype=np.float64)).all():
            raise ConfigError(f"{name} has NaN/Inf values: refusing to write (pyuff would "
                              "store them as 0.0)")
    if not scan.fs > 0:
        raise ConfigError(f"fs must be > 0, got {scan.fs}")
    return v.shape


def write_ldv_uff(
    path: str | Path,
    scan: LdvScan,
    velocity_unit: str = "m/s",
    length_unit: str = "m",
    binary: bool = True,
    velocity_id2: str = "Vib  Velocity",
    reference_id2: str = "Ref1  Pressure",
    units_record: bool = True,
) -> Path:
    """Write a scan as a PSV-style UFF file (overwrites ``path``).

    Parameters
    ----------
    scan : LdvScan
        ``node_ids``, ``coords_mm``, ``velocity_mm_s``, ``fs`` and optionally
        ``reference`` (written with unit label ``reference_unit``) and ``t0``.
    velocity_unit : str
        Unit the velocity is stored in (m/s, as PSV exports, or mm/s ...).
    length_unit : str
        Unit of the stored coordinates; recorded in dataset 164.
    binary : bool
        Binary 58 records (exact doubles, default) or ASCII (12 significant digits).
    units_record : bool
        False omits dataset 164, as some exports do: the file then does not state
        ``length_unit`` (the coordinates are still stored in it).

    Returns
    -------
    Path
    """
    from pyuff.datasets.dataset_58 import _write58
    from pyuff.datasets.dataset_151 import _write151
    from pyuff.datasets.dataset_164 import _write164
    from pyuff.datasets.dataset_2411 import _write2411

    n_pts, n_s = _check_scan(scan)
    if velocity_unit not in MM_S_PER_UNIT or length_unit not in MM_PER_UNIT:
        raise ConfigError(f"unknown unit {velocity_unit!r} or {length_unit!r}")
    v_div = MM_S_PER_UNIT[velocity_unit]
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.unlink(missing_ok=True)
    xyz = np.asarray(scan.coords_mm, dtype=np.float64) / MM_PER_UNIT[length_unit]
    nodes = np.asarray(scan.node_ids).astype(np.int64)
    with open(p, "at", encoding="utf-8") as fh:
        _write151(fh, {"type": 151, "model_name": p.stem, "description": "vfcli LDV scan",
                       "db_app": "vfcli", "program": "vfcli"})
        if units_record:
            _write164(fh, {"type": 164, "units_code": 1, "units_description": "SI",
                           "length": 1e3 / MM_PER_UNIT[length_unit],  # SI = file / length
                           "force": 1.0, "temp": 1.0, "temp_offset": 273.15})
        _write2411(fh, {"type": 2411, "node_nums": nodes, "def_cs": np.zeros(n_pts, int),
                        "disp_cs": np.zeros(n_pts, int), "color": np.ones(n_pts, int),
                        "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
    t0 = np.zeros(n_pts) if scan.t0 is None else np.asarray(scan.t0, dtype=np.float64)
    vel = np.asarray(scan.velocity_mm_s, dtype=np.float64)
    base = np.arange(n_s) / scan.fs
    channels = [("Response Time Trace", velocity_id2, vel, v_div, velocity_unit,
                 _SPEC_VELOCITY)]
    if scan.reference is not None:
        unit = scan.reference_unit or "NONE"
        channels.append(("Reference Time Trace", reference_id2,
                         np.asarray(scan.reference, dtype=np.float64), 1.0, unit,
                         _SPEC_PRESSURE if unit.lower() in ("pa", "kpa") else _SPEC_GENERAL))
    fh = None if binary else open(p, "at", encoding="utf-8")
    try:
        for i in range(n_pts):
            for id1, id2, data, scale, unit, spec in channels:  # scale: file unit -> mm/s
                dset = {
                    "type": 58, "binary": int(binary), "func_type": 1,
                    "id1": id1, "id2": id2, "id3": "", "id4": "", "id5": "",
                    "rsp_node": int(nodes[i]), "rsp_dir": 3, "ref_node": 0, "ref_dir": 0,
                    "rsp_ent_name": "NONE", "ref_ent_name": "NONE",
                    "abscissa_spacing": 1, "abscissa_inc": 1.0 / scan.fs,
                    "abscissa_spec_data_type": _SPEC_TIME, "abscissa_axis_lab": "Time",
                    "abscissa_axis_units_lab": "s",
                    "ordinate_spec_data_type": spec, "ordinate_axis_lab": id2.split()[-1],
                    "ordinate_axis_units_lab": unit, "orddenom_spec_data_type": 0,
                    "data": data[i] / scale,
                    "x": t0[i] + base,
                }
                if binary:
                    # pyuff's binary branch closes the handle and reopens the file by
                    # name, so each record gets its own append handle.
                    _write58(open(p, "at", encoding="utf-8"), dset, "add", _filename=str(p))
                else:
                    _write58(fh, dset, "add", _filename=str(p))
    finally:
        if fh is not None:
            fh.close()
    logger.info("wrote %d points x %d channels x %d samples to %s", n_pts, len(channels), n_s,
                p)
    return p


def write_ldv_csv(path: str | Path, scan: LdvScan) -> Path:
    """Write a scan in vfcli's LDV CSV layout (see :mod:`vfcli.io.ldv.read`), mm and mm/s.

    Values are written with 17 significant digits (exact round trip).
    """
    n_pts, n_s = _check_scan(scan)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    t0 = np.zeros(n_pts) if scan.t0 is None else np.asarray(scan.t0, dtype=np.float64)
    head = (f"# fs = {float(scan.fs)!r}\n# velocity_unit = mm/s\n"
            f"# reference_unit = {scan.reference_unit or 'Pa'}\n# length_unit = mm\n"
            "node,x,y,z,channel,t0," + ",".join(f"s{k}" for k in range(n_s)) + "\n")
    chans = [("velocity", scan.velocity_mm_s)]
    if scan.reference is not None:
        chans.append(("reference", scan.reference))
    with open(p, "w", encoding="utf-8") as fh:
        fh.write(head)
        for name, data in chans:
            data = np.asarray(data, dtype=np.float64)
            for i in range(n_pts):
                x, y, z = np.asarray(scan.coords_mm, dtype=np.float64)[i].tolist()
                fh.write(f"{int(scan.node_ids[i])},{x!r},{y!r},{z!r},{name},{float(t0[i])!r},")
                fh.write(",".join(map(repr, data[i].tolist())))
                fh.write("\n")
    return p


def write_ldv_mat(path: str | Path, scan: LdvScan) -> Path:
    """Write a scan as a MATLAB v5 .mat file in the layout :mod:`vfcli.io.ldv.read` reads."""
    from scipy.io import savemat

    _check_scan(scan)
    d = {"node_ids": np.asarray(scan.node_ids, dtype=np.int64),
         "coords": np.asarray(scan.coords_mm, dtype=np.float64),
         "velocity": np.asarray(scan.velocity_mm_s, dtype=np.float64),
         "fs": float(scan.fs), "length_unit": "mm", "velocity_unit": "mm/s",
         "reference_unit": scan.reference_unit or "Pa"}
    if scan.reference is not None:
        d["reference"] = np.asarray(scan.reference, dtype=np.float64)
    if scan.t0 is not None:
        d["t0"] = np.asarray(scan.t0, dtype=np.float64)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    savemat(p, d)
    return p
