"""## The inertia candidate on short inertia phantoms: screening, refit of the density, held-out errors.

Each case is a `vfcli synth --effect inertia --strength S` phantom (or a null, `--effect none`) with the
short settings of tests/_diagnose_phantom.py (0.03 s, 160 x 160 px, 9 px/mm; seeds outside the reserved
panels), taken through ingest, sync, flow, mesh (2.5 mm) and `vfcli optimize` with the pressure load
model (60 frames from frame 120, 6 iterations), then `vfcli diagnose --run fit --refit inertia --json`.
The diagnosis reads nothing from truth.h5; this script scores afterwards (the phantom's density factor).

Printed per case: the truth, the screening's inertia line (one-step estimate, naive p, its reach),
the refitted density with its 95 % interval, the held-out errors before -> after, and wall times.

Reproduce (about 10 min per case on 2 shared cores)::

    .venv/bin/python bench/bench_inertia_refit.py [--cases inertia:35:1.0 none:36:0] [--dir DIR]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _diagnose_phantom import PHANTOM  # noqa: E402

FIT = ["--set", "optimize.loads=pressure", "--set", "optimize.n_frames=60", "--set", "optimize.first_frame=120",
       "--set", "mesh.target_edge_mm=2.5", "--set", "optimize.max_iterations=6", "--run", "fit"]


def run(*args) -> tuple[str, float]:
    """Run `vfcli ARGS` in a subprocess; (stdout, wall time s).  Exits on failure."""
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vfcli.cli.main", *map(str, args)], capture_output=True, text=True,
                         cwd=ROOT)
    if res.returncode:
        raise SystemExit(f"vfcli {args[0]} failed: {res.stderr}")
    return res.stdout, time.perf_counter() - t


def case(d: Path, effect: str, seed: int, strength: float) -> dict:
    raw, store = d / "raw", d / "rec.h5"
    steps = [
        ["synth", raw, "--seed", seed, "--effect", effect, "--strength", strength,
         *sum((["--set", s] for s in PHANTOM), [])],
        ["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--config",
         raw / "recording.toml"],
        ["ingest-ldv", store, raw / "scan.uff"],
        ["sync", store], ["flow", store], ["mesh", store, "--set", "mesh.target_edge_mm=2.5"],
        ["optimize", store, *FIT],
    ]
    t_pipe = sum(run(*s)[1] for s in steps)
    out, t_diag = run("diagnose", store, "--run", "fit", "--refit", "inertia", "--json")
    diag = json.loads(out)
    with h5py.File(raw / "truth.h5", "r") as f:        # scoring only, after the diagnosis
        truth = float(f.attrs["strength"]) if effect == "inertia" else 0.0
    return {"effect": effect, "seed": seed, "truth": truth, "diagnosis": diag, "pipeline_s": t_pipe,
            "diagnose_s": t_diag}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["inertia:35:1.0", "none:36:0"],
                    help="effect:seed:strength (seeds outside 1001-1020 and 2001-2100)")
    ap.add_argument("--dir", type=Path, default=None, help="keep the phantoms here (default: a temporary folder)")
    args = ap.parse_args()
    base = args.dir or Path(tempfile.mkdtemp(prefix="bench_inertia_"))
    for spec in args.cases:
        effect, seed, strength = spec.split(":")
        if 1001 <= int(seed) <= 1020 or 2001 <= int(seed) <= 2100:
            raise SystemExit(f"seed {seed} is reserved")
        d = base / f"{effect}{seed}"
        d.mkdir(parents=True, exist_ok=True)
        r = case(d, effect, int(seed), float(strength))
        lines = r["diagnosis"]["lines"]
        ref = r["diagnosis"].get("refit") or {}
        par = ref.get("parameters", {}).get("density_factor", {})
        print(f"\n{effect} seed {seed} (density factor {r['truth']:g}); pipeline {r['pipeline_s']:.0f} s, "
              f"diagnose {r['diagnose_s']:.0f} s")
        print("  " + next((ln for ln in lines if ln.startswith("inertia:")), "inertia: (no screening line)"))
        if par:
            est, (lo, hi) = par["estimate"], par["interval"]
            rel = f", {100 * (est - r['truth']) / r['truth']:+.1f} % of the truth" if r["truth"] else ""
            print(f"  refit: density_factor {est:.4g} (95 % {lo:.4g} .. {hi:.4g}){rel}")
        for h in ref.get("heldout", []):
            b, e = (sum(v ** 2 for v in h[k]) / len(h[k]) for k in ("baseline", "extended"))
            print(f"  held-out ({h['kind']}): {b ** 0.5:.1f} -> {e ** 0.5:.1f} mm/s, reduction {h['reduction']:+.3f}, "
                  f"{'beyond' if h['beyond_spread'] else 'not beyond'} the spread")
        print("  " + next((ln for ln in lines if ln.startswith(("decision", "no missing", "missing"))), "decision: -"))


if __name__ == "__main__":
    main()
