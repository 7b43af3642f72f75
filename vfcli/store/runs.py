"""Typed reader of one optimisation run (/optimize/<run>) for export, report and diagnose.

The typed reader of /mesh is :mod:`vfcli.store.mesh`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vfcli.store.mesh import read_mesh
from vfcli.store.reader import StoreReader

HISTORY_KEYS = ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "n_evals")


@dataclass(frozen=True)
class OptimizeRun:
    """One optimisation run as stored.

    Attributes
    ----------
    name : run name (``/optimize/<name>``).
    sim_time : (T,) s, model times.
    displacements : (T, N, 3) mm, reconstructed vertex displacements (model frame).
    displacement_std : (T, N, 3) mm stated standard deviation, or None when the run has none.
    controls : (P,) Pa, final control values; parameter_names : (P,) their names.
    history : {key: (I,) array} per iteration (HISTORY_KEYS present in the store).
    attrs : the run group's attributes (setup, loads, method, converged, camera pose, px_per_mm, ...).
    config : the optimize/camera/mesh settings the run was made with (parsed config_json).
    digest : the stored group's digest (changes whenever the run is rewritten).
    """

    name: str
    sim_time: np.ndarray
    displacements: np.ndarray
    displacement_std: np.ndarray | None
    controls: np.ndarray
    parameter_names: np.ndarray
    history: dict[str, np.ndarray]
    attrs: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    digest: str = ""

    @property
    def wall_time_s(self) -> float | None:
        """s the whole optimize stage took (setup, fit, stated uncertainty); runs stored before that was
        kept, and diagnose's refits, give their fit's wall time; None when neither is stored."""
        if "stage_time_s" in self.attrs:
            return float(self.attrs["stage_time_s"])
        h = self.history.get("wall_time")
        return float(h[-1]) if h is not None and len(h) else None


def stage_runs(reader: StoreReader, name: str) -> list[str]:
    """Names of the complete runs of a stage with runs (``optimize``, ``diagnose``), sorted."""
    return sorted(run for run in reader.runs(name) if reader.has_stage(name, run))


def run_names(reader: StoreReader) -> list[str]:
    """Names of the complete optimisation runs in the store, sorted."""
    return stage_runs(reader, "optimize")


def _plain(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, bytes):
        return v.decode()
    return v


def read_run(reader: StoreReader, run: str) -> OptimizeRun:
    """The run ``/optimize/<run>`` (MissingStageError, exit 5, when it is absent)."""
    g = reader.group("optimize", run)
    attrs = {k: _plain(v) for k, v in g.attrs.items()}
    std = reader.read("optimize", "displacement_std", run) if "displacement_std" in g else None
    history = {k: np.asarray(reader.read("optimize", f"history_{k}", run)) for k in HISTORY_KEYS
               if f"history_{k}" in g}
    return OptimizeRun(
        name=run,
        sim_time=np.asarray(reader.read("optimize", "sim_time", run), dtype=float),
        displacements=np.asarray(reader.read("optimize", "displacements", run)),
        displacement_std=None if std is None else np.asarray(std),
        controls=np.asarray(reader.read("optimize", "controls", run), dtype=float),
        parameter_names=np.asarray(reader.read("optimize", "parameter_names", run)),
        history=history,
        attrs=attrs,
        config=json.loads(attrs.get("config_json", "{}") or "{}"),
        digest=str(attrs.get("digest", "")),
    )


__all__ = ["HISTORY_KEYS", "OptimizeRun", "read_mesh", "read_run", "run_names", "stage_digests", "stage_runs"]


def stage_digests(reader: StoreReader) -> dict[str, str]:
    """``{group path: digest}`` of every complete stage group in the store."""
    out = {}
    for path in reader.stage_paths():
        parts = path.strip("/").split("/")
        name, run = parts[0], (parts[1] if len(parts) > 1 else None)
        if reader.has_stage(name, run):
            out[path] = reader.digest(name, run)
    return out
