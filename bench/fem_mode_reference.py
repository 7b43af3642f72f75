"""The eigenfrequency reference of tests/test_fem.py, recomputed from the repository.

One clamped M5 fold (the default M5Params: D = 8 mm, L = 15 mm; E = 4.4 kPa, nu = 0.499,
rho = 1070 kg/m^3), P2 elements through ``vfcli.model.fem.ElasticModel.modes``, on a sequence of
refined meshes; each of the six lowest frequencies is extrapolated to h -> 0 by fitting
f(h) = f0 + c h^r (Richardson with the observed order r, from the three finest meshes). The
meshes are not nested (tetgen, arcs resampled per size), so a frequency that no longer falls
monotonically has reached the meshes' own scatter: then f0 is the finest mesh's value.

Output (2 cores, 2026-11; 24 min, mostly the 0.85 mm mesh)::

    target edge 1.50 mm (mean 1.321 mm): 49.21, 72.59, 84.08, 85.83, 95.88, 98.35 Hz
    target edge 1.20 mm (mean 1.042 mm): 49.04, 72.39, 83.84, 85.59, 95.61, 98.09 Hz
    target edge 1.00 mm (mean 0.860 mm): 48.92, 72.26, 83.70, 85.49, 95.48, 97.97 Hz
    target edge 0.85 mm (mean 0.724 mm): 48.93, 72.32, 83.71, 85.44, 95.43, 97.93 Hz
    observed order r per mode: nan, nan, nan, 3.35, 3.66, 5.94
    extrapolated f0 (Hz):      48.9, 72.3, 83.7, 85.4, 95.4, 97.9
    default mesh vs f0 (%):    +0.56, +0.38, +0.45, +0.53, +0.55, +0.45

Prints the frequencies per mesh, the observed order, the extrapolated f0 and the relative
difference of the default mesh (1.5 mm, what the test computes) from f0.

Reproduce::

    .venv/bin/python bench/fem_mode_reference.py [--edges 1.5 1.2 1.0 0.85]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vfcli.model.fem import ElasticModel  # noqa: E402
from vfcli.model.m5 import M5Params  # noqa: E402
from vfcli.model.mesh import build_mesh  # noqa: E402

N_MODES = 6


def fold_frequencies(edge_mm: float, n_modes: int = N_MODES) -> tuple[np.ndarray, float]:
    """(n_modes,) lowest eigenfrequencies of fold 1, Hz, and the mesh's actual mean edge, mm."""
    mesh = build_mesh(M5Params(), target_edge_mm=edge_mm)
    freqs, _ = ElasticModel(mesh).modes(n_modes, fold=1)
    p = mesh.nodes[mesh.tets]
    edges = np.concatenate([np.linalg.norm(p[:, i] - p[:, j], axis=1) for i in range(4) for j in range(i + 1, 4)])
    return freqs, float(edges.mean())


def extrapolate(h: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """(f0, r) with f = f0 + c h^r through three points (h descending); r = nan and f0 = f[-1]
    when the differences change sign (no monotone convergence to extrapolate)."""
    (h1, h2, h3), (f1, f2, f3) = h[-3:], f[-3:]
    d12, d23 = f1 - f2, f2 - f3
    if d12 * d23 <= 0:
        return float(f3), float("nan")

    def g(r):  # (h1^r - h2^r) / (h2^r - h3^r) = d12 / d23
        return (h1 ** r - h2 ** r) / (h2 ** r - h3 ** r) - d12 / d23

    try:
        r = brentq(g, 0.2, 12.0)
    except ValueError:
        return float(f3), float("nan")
    c = d23 / (h2 ** r - h3 ** r)
    return float(f3 - c * h3 ** r), float(r)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edges", type=float, nargs="+", default=[1.5, 1.2, 1.0, 0.85])
    args = ap.parse_args()
    rows, hs = [], []
    for e in sorted(args.edges, reverse=True):
        t0 = time.perf_counter()
        f, h = fold_frequencies(e)
        rows.append(f)
        hs.append(h)
        print(f"target edge {e:.2f} mm (mean {h:.3f} mm): " + ", ".join(f"{x:.2f}" for x in f)
              + f" Hz  [{time.perf_counter() - t0:.0f} s]", flush=True)
    f = np.array(rows)
    h = np.array(hs)
    ref = [extrapolate(h, f[:, k]) for k in range(f.shape[1])]
    f0 = np.array([r[0] for r in ref])
    print("observed order r per mode: " + ", ".join(f"{r[1]:.2f}" for r in ref))
    print("extrapolated f0 (Hz):      " + ", ".join(f"{x:.1f}" for x in f0))
    print("default mesh vs f0 (%):    " + ", ".join(f"{x:+.2f}" for x in 100 * (f[0] / f0 - 1)))
    print("finest mesh vs f0 (%):     " + ", ".join(f"{x:+.2f}" for x in 100 * (f[-1] / f0 - 1)))


if __name__ == "__main__":
    main()
