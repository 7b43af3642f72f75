"""The typed reader of /optimize/<run>: one optimisation run as one frozen value
(for report, export and diagnose)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vfcli.store.reader import StoreReader

#: The per-iteration series of a run (``history_<key>`` datasets).
HISTORY_KEYS = ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "n_evals")


@dataclass(frozen=True)
class OptimizeRun:
    """A stored optimisation run.

    Attributes
    ----------
    name : str
        The run's name (``/optimize/<name>``).
    sim_time : (F + 1,) float64
        Model times, s.
    displacements : (F + 1, N, 3) float32
        Reconstructed vertex displacements, mm.
    std : (F + 1, N, 3) float32 or None
        Standard deviation of each displacement component, mm (None: optimize.uncertainty off).
    controls : (P,) float64
        Final control values, Pa.
    parameter_names : (P,) str
        Name of each control value.
    history : dict of (I,) arrays
        :data:`HISTORY_KEYS` -> the series over the iterations (``total``: E, 1; ``wall_time``: s).
    attrs : dict
        The stage's attributes (setup, loads, camera pose, convergence, uncertainty summary,
        provenance).
    """

    name: str
    sim_time: np.ndarray
    displacements: np.ndarray
    std: np.ndarray | None
    controls: np.ndarray
    parameter_names: np.ndarray
    history: dict[str, np.ndarray]
    attrs: dict[str, Any]


def run_names(reader: StoreReader) -> list[str]:
    """Names of the complete optimisation runs in the store."""
    return [run for run in reader.runs("optimize") if reader.has_stage("optimize", run)]


def read_optimize_run(reader: StoreReader, run: str) -> OptimizeRun:
    """/optimize/<run> (:class:`vfcli.errors.MissingStageError` when absent or incomplete)."""
    g = reader.group("optimize", run)
    attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in g.attrs.items()}
    std = reader.read("optimize", "displacement_std", run) if "displacement_std" in g else None
    history = {k: reader.read("optimize", f"history_{k}", run) for k in HISTORY_KEYS if f"history_{k}" in g}
    return OptimizeRun(run, reader.read("optimize", "sim_time", run), reader.read("optimize", "displacements", run),
                       std, reader.read("optimize", "controls", run),
                       np.asarray(reader.read("optimize", "parameter_names", run)), history, attrs)
