"""CSV tables of an export: run summaries and the velocities at the vibrometer points."""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

RUN_COLUMNS = ["run", "setup", "loads", "method", "iterations", "E_start", "E_final", "wall_time_s", "fit_time_s", "converged",
               "n_frames", "t_start_s", "t_end_s", "inferior_uncertainty_rel", "superior_uncertainty_rel"]


def write_runs(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """One row per run with the RUN_COLUMNS (missing values left empty)."""
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, RUN_COLUMNS, restval="", extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    return Path(path)


def write_ldv(path: str | Path, ldv_px: np.ndarray, grid: np.ndarray, aligned: np.ndarray, times: np.ndarray,
              measured: np.ndarray, simulated: dict[str, np.ndarray], dropout: np.ndarray | None = None,
              used: np.ndarray | None = None) -> Path:
    """Long table, one row per vibrometer point and frame time.

    ldv_px : (P, 2) screen (col, row) px; grid : (P, 2) scan (row, col); aligned : (P,) bool;
    times : (F,) s; measured : (P, F) vertical velocity, mm/s; simulated : run -> (F, P) mm/s (NaN: not simulated);
    dropout : (P,) bool, the point's signal drops out (spikes, a frozen stretch: flagged at ingest, kept);
    used : (P,) bool, the point enters the vertical velocity field (aligned, no dropout). Without them the
    columns are left out.
    """
    extra = [(name, np.asarray(v, bool)) for name, v in (("dropout", dropout), ("used_by_fields", used))
             if v is not None]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["point", "grid_row", "grid_col", "screen_col_px", "screen_row_px", "aligned",
                    *[name for name, _ in extra], "time_s", "measured_vz_mm_per_s",
                    *[f"run_{n}_vz_mm_per_s" for n in simulated]])
        for p in range(len(ldv_px)):
            flags = [bool(v[p]) for _, v in extra]
            for j, t in enumerate(times):
                w.writerow([p, grid[p, 0], grid[p, 1], f"{ldv_px[p, 0]:.2f}", f"{ldv_px[p, 1]:.2f}", bool(aligned[p]),
                            *flags, f"{t:.7f}", f"{measured[p, j]:.6g}",
                            *[f"{s[j, p]:.6g}" for s in simulated.values()]])
    return Path(path)
