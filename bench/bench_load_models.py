"""## Load models side by side on `none` phantoms: error of the unseen inferior surface vs stated uncertainty.

For each seed: `vfcli synth --effect none`, the pipeline up to `mesh` through the real CLI,
then `vfcli optimize` with three load models on the same window:

* `free`: the paper's literal force field (``--setup``, no bound on the loads);
* `free-regularised`: the same field with the Tikhonov term (size + smoothness) whose
  weight the L-curve chooses (vfcli/inverse/regularization.py);
* `pressure`: shared normal pressure tied to the recorded subglottal pressure, ridge by
  the L-curve (vfcli/model/loads/pressure.py).

Reported per run: inferior-surface RMS displacement error relative to the RMS true
displacement (the inferior surface is never observed), the stated uncertainty (RMS posterior
standard deviation relative to the RMS reconstructed displacement, vfcli/inverse/uncertainty.py),
the coverage of the stated 90 % intervals over inferior nodes x components x frames, the
chosen ridge weight and the wall time.

Reproduce::

    .venv/bin/python bench/bench_load_models.py [--seeds 1 2 3] [--setup 3x3x10-two-sided] [--workdir /tmp/vf_loads]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _runner import vfcli  # noqa: E402
from vfcli.model.mesh import FoldMesh  # noqa: E402
from vfcli.synth.scoring import interval_coverage, relative_rms_error, side_truth  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.store import Store, read_truth  # noqa: E402

MODELS = {
    "free (paper)": ["--loads", "free"],
    "free-regularised": ["--loads", "free-regularised"],
    "pressure": ["--loads", "pressure"],
}


def pipeline(work: Path, seed: int) -> tuple[Path, Path]:
    raw, store = work / f"seed{seed}" / "raw", work / f"seed{seed}" / "rec.h5"
    if not store.exists():
        vfcli("synth", raw, "--seed", seed, "--effect", "none")
        vfcli("ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms",
              "--config", raw / "recording.toml")
        vfcli("ingest-ldv", store, raw / "scan.uff")
        vfcli("sync", store)
        vfcli("flow", store)
        vfcli("mesh", store)
    return store, raw


def score(store: Path, raw: Path, run: str) -> dict[str, float]:
    t, _ = read_truth(raw / "truth.h5")
    truth_mesh = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    with Store(store).read() as r:
        mesh = read_mesh(r)
        disp = r.read("optimize", "displacements", run).astype(float)[:-1]
        std = r.read("optimize", "displacement_std", run).astype(float)[:-1]
        sim_time = r.read("optimize", "sim_time", run)
        attrs = r.attrs("optimize", run)
        wall = float(r.read("optimize", "history_wall_time", run)[-1])
    true = t["frames/displacement"][np.searchsorted(t["frames/time"], sim_time[:-1] - 1e-9)].astype(float)
    nodes, ref = side_truth(mesh.uv, mesh.node_side, truth_mesh.uv, truth_mesh.node_side, true, 1)
    est, sd = disp[:, nodes], std[:, nodes]
    return {"error": relative_rms_error(est, ref),
            "stated": float(np.sqrt(np.mean(sd ** 2)) / np.sqrt(np.mean(est ** 2))),
            "coverage": interval_coverage(est, sd, ref),
            "ridge": float(attrs["ridge_weight"]), "wall": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--setup", default="3x3x10-two-sided")
    ap.add_argument("--workdir", default="/tmp/vf_loads")
    args = ap.parse_args()
    work = Path(args.workdir)
    rows = []
    for seed in args.seeds:
        store, raw = pipeline(work, seed)
        for name, opts in MODELS.items():
            run = name.split()[0].replace("-", "_")
            setup = ["--setup", args.setup] if name != "pressure" else []
            t0 = time.perf_counter()
            vfcli("optimize", store, "--run", run, *setup, *opts, "--force")
            s = score(store, raw, run)
            s["total_wall"] = time.perf_counter() - t0
            rows.append((seed, name, s))
            print(seed, name, {k: round(v, 4) for k, v in s.items()}, flush=True)
    print(f"\n| seed | load model | inferior error | stated uncertainty | 90 % interval coverage | ridge weight (1/Pa^2) "
          f"| fit time (s) | command time (s) |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for seed, name, s in rows:
        print(f"| {seed} | {name} | {100 * s['error']:.1f}% | {100 * s['stated']:.1f}% | {100 * s['coverage']:.0f}% "
              f"| {s['ridge']:.2g} | {s['wall']:.0f} | {s['total_wall']:.0f} |")


if __name__ == "__main__":
    main()
