"""## Optimize: the paper's three setups on a phantom, scored against truth.h5.

Runs a phantom through `vfcli synth`, `ingest-hsc`, `ingest-ldv`, `sync`, `flow`, `mesh` and
then `vfcli optimize` with the setups 3x3x10 one-sided, 3x3x10 two-sided and 5x5x15
two-sided (L-BFGS with exact gradients), and reports for each: final error E, iterations,
objective evaluations, wall time, and the RMS displacement error of the inferior surface
(which no instrument sees) and of the superior surface, relative to the RMS true
displacement, over the fitted window. Also the time of one exact gradient against one
finite-difference gradient (the paper's method) on the same problem. Writes a combined
convergence plot.

Reproduce::

    .venv/bin/python bench/bench_optimize.py [--store demo/recording.h5 --raw demo/raw] [--iters 60] [--plot docs/optimize_convergence.png]
        [--loads free|pressure|both]

``--loads pressure`` runs the pressure load model instead (``optimize.loads='pressure'``, run name
``pressure``: shared normal pressure on the inferior and medial surfaces tied to the recorded
subglottal pressure, vfcli/model/loads/pressure.py); ``both`` adds it as a row after the three free setups.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.model.mesh import FoldMesh  # noqa: E402
from vfcli.synth.scoring import relative_rms_error, side_truth  # noqa: E402
from vfcli.stages.base import RunContext  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.stages.optimize import problem_of_store  # noqa: E402
from vfcli.store import Store, read_truth  # noqa: E402

SETUPS = ["3x3x10-one-sided", "3x3x10-two-sided", "5x5x15-two-sided"]


def vfcli(*args) -> None:
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args)], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"vfcli {args[0]} failed: {res.stderr}")


def surface_errors(store: Path, raw: Path, run: str) -> tuple[float, float]:
    """(inferior, superior) RMS displacement error / RMS true displacement over the window."""
    t, _ = read_truth(raw / "truth.h5")
    truth_mesh = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    with Store(store).read() as r:
        mesh = read_mesh(r)
        disp = r.read("optimize", "displacements", run).astype(float)
        sim_time = r.read("optimize", "sim_time", run)
    idx = np.searchsorted(t["frames/time"], sim_time[:-1] - 1e-9)
    true = t["frames/displacement"][idx].astype(float)
    out = []
    for side in (1, 2):
        nodes, ref = side_truth(mesh.uv, mesh.node_side, truth_mesh.uv, truth_mesh.node_side, true, side)
        out.append(relative_rms_error(disp[:-1][:, nodes], ref))
    return out[0], out[1]


def gradient_speed(store: Path) -> tuple[float, float, int]:
    """(exact gradient s, finite-difference gradient s (extrapolated from 20 evaluations), n_params)."""
    ctx = RunContext.open(store, None, ["optimize.setup='3x3x10-one-sided'", "optimize.loads='free'"])
    with Store(store).read() as r:
        problem, _ = problem_of_store(r, ctx.config)
    x = np.zeros(problem.n_params)
    problem.value_and_grad(x)
    t = time.perf_counter()
    problem.value_and_grad(x)
    exact = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(20):
        problem.evaluate(x)
    per_eval = (time.perf_counter() - t) / 20
    return exact, per_eval * (problem.n_params + 1), problem.n_params


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="demo/recording.h5")
    ap.add_argument("--raw", default="demo/raw")
    ap.add_argument("--iters", type=int, default=60)
    ap.add_argument("--plot", default="docs/optimize_convergence.png")
    ap.add_argument("--loads", choices=["free", "pressure", "both"], default="free",
                    help="free: the paper's three setups; pressure: the pressure load model; both: all four")
    ap.add_argument("--no-lbfgs", dest="compare_lbfgs", action="store_false",
                    help="skip the L-BFGS comparison row of the 5x5x15 two-sided setup")
    args = ap.parse_args()
    store, raw = Path(args.store), Path(args.raw)
    if not store.is_file() or not (raw / "truth.h5").is_file():
        ap.error(f"no store at {store} or no phantom truth in {raw}: run `make demo` first, or give --store and --raw")
    rows, hist = [], {}
    runs = [(s, s.replace("x", "_"), ["--setup", s]) for s in SETUPS] if args.loads != "pressure" else []
    if args.loads != "pressure" and args.compare_lbfgs:
        runs.append((f"{SETUPS[-1]} (lbfgs)", "lbfgs_5", ["--setup", SETUPS[-1], "--method", "lbfgs"]))
    if args.loads != "free":
        runs.append(("pressure", "pressure", ["--set", "optimize.loads='pressure'"]))
    for setup, run, opts in runs:
        t0 = time.perf_counter()
        vfcli("optimize", store, "--run", run, *opts, "--set", f"optimize.max_iterations={args.iters}", "-q", "--force")
        wall = time.perf_counter() - t0
        with Store(store).read() as r:
            h = {k: r.read("optimize", f"history_{k}", run) for k in ("iteration", "total", "n_evals", "wall_time")}
            attrs = r.attrs("optimize", run)
        hist[setup] = h
        inf, sup = surface_errors(store, raw, run)
        rows.append((setup, attrs["method"], h["total"][-1], int(h["iteration"][-1]), int(h["n_evals"][-1]),
                     bool(attrs["converged"]), float(h["wall_time"][-1]), wall, inf, sup))
    exact, fd, n = gradient_speed(store) if args.loads != "pressure" else (None, None, None)
    print("| setup | method | final E | iterations | evaluations | converged | fit time (s) | command time (s) "
          "| inferior error | superior error |")
    print("| --- | --- | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: |")
    for setup, method, e, it, ne, conv, fit_s, wall, inf, sup in rows:
        print(f"| {setup} | {method} | {e:.4g} | {it} | {ne} | {'yes' if conv else 'no'} | {fit_s:.0f} | {wall:.0f} "
              f"| {100 * inf:.0f}% | {100 * sup:.0f}% |")
    if exact is not None:
        print(f"\nOne gradient, 3x3x10 one-sided ({n} control values): exact {exact:.2f} s, "
              f"finite differences {fd:.0f} s (from 20 timed evaluations): {fd / exact:.0f}x")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110, sharey=True)
    for setup, h in hist.items():
        axes[0].semilogy(h["iteration"], h["total"], label=setup)
        axes[1].semilogy(h["wall_time"], h["total"], label=setup)
    axes[0].set_xlabel("iteration")
    axes[1].set_xlabel("wall time (s)")
    axes[0].set_ylabel("error E")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.plot)
    print(f"\nConvergence plot: {args.plot}\nReproduce: `.venv/bin/python bench/bench_optimize.py --iters {args.iters} --loads {args.loads}`")


if __name__ == "__main__":
    main()
