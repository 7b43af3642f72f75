"""Shared helpers of the benchmarks: run the real CLI, time a callable, a phantom's truth on a fit's nodes."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def vfcli(*args) -> float:
    """Run ``vfcli ARGS -q`` in a subprocess (as a user does); wall time in s. Exits on failure."""
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args), "-q"], capture_output=True,
                         text=True, cwd=ROOT)
    if res.returncode:
        raise SystemExit(f"vfcli {args[0]} failed: {res.stderr}")
    return time.perf_counter() - t


def best(fn: Callable[[], object], repeat: int) -> float:
    """Smallest wall time of ``repeat`` calls of ``fn``, s."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


#: truth.h5 datasets of the phantom's own mesh.
TRUTH_MESH_KEYS = ("nodes", "tets", "tet_fold", "faces", "face_tag", "face_fold", "uv", "node_side")


def side_truth_at(truth_h5: Path, mesh, sim_time: np.ndarray, side: int = 1,
                  rotation_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The phantom's true displacements on one side of a fit's mesh at the fit's window times.

    truth_h5 : the phantom's truth.h5.  mesh : the fit's :class:`vfcli.model.mesh.FoldMesh`.
    sim_time : (T,) s, the window's frame times.  side : 1 inferior, 2 superior.
    rotation_deg : the fit's camera rotation (its ``camera_rotation_deg``); when it is half a turn off the
        phantom's, the truth is given in the fit's frame (:func:`vfcli.synth.scoring.half_turned`).

    Returns (nodes, ref): the fit's node indices scored and their true displacements (T, n, 3), mm
    (:func:`vfcli.synth.scoring.side_truth`).
    """
    from vfcli.model.mesh import FoldMesh
    from vfcli.store.truth import read_truth
    from vfcli.synth.scoring import half_turned, pose_half_turned, side_truth

    t, a = read_truth(truth_h5, ["frames/time", "frames/displacement"] + [f"mesh/{k}" for k in TRUTH_MESH_KEYS])
    tm = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    true = t["frames/displacement"][np.searchsorted(t["frames/time"], np.asarray(sim_time) - 1e-9)].astype(float)
    phantom = (tm.uv, tm.node_side, true)
    if rotation_deg is not None and pose_half_turned(rotation_deg, float(a["camera_rotation_deg"])):
        phantom = half_turned(*phantom)
    return side_truth(mesh.uv, mesh.node_side, *phantom, side)
