"""## How the cost of one optimisation iteration grows with control points, frames and mesh DOF.

On the demo store (`make demo`), builds the optimisation problem of `vfcli optimize` for
three sizes of each factor (the others at their middle value) and times, best of
``--repeat``: building the problem (mesh, factorisation, response basis), one evaluation of E
(rasterise every frame), one exact gradient (evaluation included), one Gauss-Newton model
(Hessian assembly, evaluation included) and one Levenberg-Marquardt solve. Times are wall
clock on 2 cores; each row's ratios against the first row of its group say how the cost grows.

Reproduce::

    .venv/bin/python bench/bench_optimize_scaling.py [--store demo/recording.h5] [--repeat 2]
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _runner import best  # noqa: E402
from vfcli.inverse.linearization import gauss_newton_model  # noqa: E402
from vfcli.inverse.optimizers.levenberg_marquardt import lm_solve  # noqa: E402
from vfcli.inverse.workspace import Workspace  # noqa: E402
from vfcli.stages.base import RunContext  # noqa: E402
from vfcli.stages.optimize import problem_of_store  # noqa: E402
from vfcli.store import Store  # noqa: E402

MIDDLE = {"setup": "3x3x10-two-sided", "n_frames": 42, "edge": 1.5}
GROUPS = {
    "control points": ("setup", ["3x3x10-one-sided", "3x3x10-two-sided", "5x5x15-two-sided"]),
    "frames": ("n_frames", [21, 42, 84]),
    "mesh DOF": ("edge", [2.5, 2.0, 1.5]),
}


def measure(store: Path, setup: str, n_frames: int, edge: float, repeat: int) -> dict[str, float]:
    sets = [f"optimize.setup='{setup}'", "optimize.loads='free'", f"optimize.n_frames={n_frames}",
            f"mesh.target_edge_mm={edge}"]
    ctx = RunContext.open(store, None, sets)
    t = time.perf_counter()
    with Store(store).read() as r:
        problem, _ = problem_of_store(r, ctx.config)
    build = time.perf_counter() - t
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 50.0, problem.n_params)
    ws = Workspace()   # reused across repeats, as a fit reuses it across iterations
    model = gauss_newton_model(problem, x, workspace=ws)
    return {
        "n_params": problem.n_params,
        "dof": 3 * problem.mesh.n_nodes,
        "build": build,
        "evaluate": best(lambda: problem.evaluate(x), repeat),
        "gradient": best(lambda: problem.value_and_grad(x), repeat),
        "gn_model": best(lambda: gauss_newton_model(problem, x, workspace=ws), repeat),
        "lm_solve": best(lambda: lm_solve(model.hessian, model.grad, 1e-3, ws), repeat),
    }


def store_with_mesh(store: Path, edge: float, work: Path) -> Path:
    """A copy of the store re-meshed at ``edge`` mm (through the real CLI)."""
    out = work / f"scaling_edge{edge}.h5"
    if not out.exists():
        shutil.copyfile(store, out)
        res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", "mesh", str(out), "--set",
                              f"mesh.target_edge_mm={edge}", "--force", "-q"], capture_output=True, text=True)
        if res.returncode:
            raise SystemExit(res.stderr)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="demo/recording.h5")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--workdir", default="/tmp")
    args = ap.parse_args()
    if not Path(args.store).is_file():
        ap.error(f"no store at {args.store}: run `make demo` first, or give --store")
    print("| factor | value | control values | mesh DOF | build (s) | evaluate E (s) | exact gradient (s) "
          "| Gauss-Newton model (s) | LM solve (s) | gradient vs first | GN model vs first |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for group, (key, values) in GROUPS.items():
        first = None
        for v in values:
            params = {**MIDDLE, key: v}
            store = store_with_mesh(Path(args.store), params["edge"], Path(args.workdir))
            m = measure(store, params["setup"], params["n_frames"], params["edge"], args.repeat)
            first = first or m
            print(f"| {group} | {v} | {m['n_params']} | {m['dof']} | {m['build']:.1f} | {m['evaluate']:.2f} "
                  f"| {m['gradient']:.2f} | {m['gn_model']:.2f} | {m['lm_solve']:.2f} "
                  f"| {m['gradient'] / first['gradient']:.1f}x | {m['gn_model'] / first['gn_model']:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
