"""## Where the stated uncertainty is too wide: its shape against the error, per component and by size (issue 15).

For each kept store of ``bench/bench_unseen.py --keep DIR`` (run ``default`` fitted with
``optimize.uncertainty``), against the phantom's truth on the inferior surface:

* the Spearman rank correlation of the stated sd and the error (RMS over the window, per node and
  component, leaving out those stated exactly 0): does the stated sd rank the error right;
* the coverage of the 90 % intervals and the ratio RMS error / RMS sd in each quartile of the stated sd;
* per component (model x longitudinal, y lateral, z vertical): RMS error, RMS stated sd, coverage.

Reproduce::

    .venv/bin/python bench/bench_unseen.py 304 309 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_uncertainty_shape.py DIR/seed304 DIR/seed309
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from _runner import side_truth_at  # noqa: E402

from vfcli.store import Store  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.store.runs import read_run  # noqa: E402


def shape(work: Path) -> str:
    """One markdown row of the figures of a kept store (module docstring)."""
    with Store(work / "recording.h5").read() as r:
        stored = read_run(r, "default")
        mesh = read_mesh(r)
    nodes, ref = side_truth_at(work / "raw" / "truth.h5", mesh, stored.sim_time[:-1],
                               rotation_deg=float(stored.attrs["camera_rotation_deg"]))
    est = np.asarray(stored.displacements, float)[:-1][:, nodes]
    sd = np.asarray(stored.displacement_std, float)[:-1][:, nodes]
    err = np.abs(est - ref)
    inside = err <= 1.645 * sd
    e_nc, s_nc = np.sqrt(np.mean(err ** 2, axis=0)).ravel(), np.sqrt(np.mean(sd ** 2, axis=0)).ravel()
    cov_nc = inside.mean(axis=0).ravel()
    zero = s_nc <= 1e-9                       # stated exactly 0 (a node the fit does not move in that component)
    e_nc, s_nc, cov_nc = e_nc[~zero], s_nc[~zero], cov_nc[~zero]
    quartile = np.minimum((4 * np.argsort(np.argsort(s_nc, kind="stable")) // len(s_nc)), 3)   # rank quartiles
    rms = lambda a: float(np.sqrt(np.mean(np.asarray(a) ** 2)))  # noqa: E731
    by_q = " / ".join(f"{100 * cov_nc[quartile == q].mean():.1f} %, {rms(e_nc[quartile == q]) / max(rms(s_nc[quartile == q]), 1e-300):.2f}"
                      for q in range(4))
    by_c = " / ".join(f"{rms(err[..., c]):.4f}, {rms(sd[..., c]):.4f}, {100 * inside[..., c].mean():.1f} %" for c in range(3))
    return f"| {work.name} | {spearmanr(e_nc, s_nc).correlation:.2f} | {by_q} | {by_c} | {int(zero.sum())} of {zero.size} |"


def main() -> None:
    print("| store | Spearman (error, sd) | coverage, error / sd by quartile of the sd (smallest first) | "
          "error (mm), sd (mm), coverage: x / y / z | node-components stated 0 (left out of the first two) |")
    print("| --- | ---: | --- | --- | ---: |")
    for w in sys.argv[1:]:
        print(shape(Path(w)), flush=True)


if __name__ == "__main__":
    main()
