"""## The diagnosis on one core and on several (`vfcli diagnose --jobs`), timed in the same run on the same store.

`vfcli diagnose STORE --force --json --jobs N` on copies of one store, for each N given (the first, normally 1, is
the baseline): wall time, the step times the command reports (`seconds` of its `--json`), CPU time and peak
resident memory of the command (``os.wait4``: its forked pieces included, the largest process's peak), and whether every figure of the diagnosis is the baseline's (its JSON with the times and the images'
folder left out).  Nothing reads a truth file: the store is any fitted recording's, e.g. the demo's
(`make demo`, then `DEMO/recording.h5`).

Reproduce::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose_jobs.py DEMO/recording.h5 \
        --jobs 1 2 --work /tmp/jobs
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.store.parts import copy_store  # noqa: E402

#: keys of the command's JSON that differ between runs of the same diagnosis by design
VOLATILE = ("seconds", "images")


def figures(summary: object) -> object:
    """The diagnosis's JSON without :data:`VOLATILE` keys (the times, and the images' paths, which name the folder)."""
    if isinstance(summary, dict):
        return {k: figures(v) for k, v in summary.items() if k not in VOLATILE}
    if isinstance(summary, list):
        return [figures(v) for v in summary]
    return summary


def run(store: Path, jobs: int) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "vfcli.cli.main", "diagnose", str(store), "--force", "--json", "-q",
                             "--jobs", str(jobs)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    stdout, stderr = proc.stdout.read(), proc.stderr.read()     # -q: a few lines on stderr at most
    _, status, usage = os.wait4(proc.pid, 0)                   # this command's own usage, its forked pieces included
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"--jobs {jobs}: exit {proc.returncode}\n{stderr}")
    out = json.loads(stdout)
    summary = out.get("summary", out)
    return {"jobs": jobs, "wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_gb": usage.ru_maxrss / 1e6,
            "steps": summary.get("seconds", {}), "figures": figures(summary), "verdict": summary.get("decision")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", type=Path, help="a store with a fitted /optimize/default (e.g. the demo's)")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2], help="the --jobs values; the first is the baseline")
    ap.add_argument("--work", type=Path, required=True, help="folder for the copies (one per --jobs value)")
    args = ap.parse_args()
    rows = []
    for n in args.jobs:
        copy = args.work / f"jobs{n}" / "recording.h5"
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy_store(args.store, copy)
        rows.append(run(copy, n))
        print(f"--jobs {n}: {rows[-1]['wall_s']:.0f} s", flush=True)
    base = rows[0]
    print(f"\nStore {args.store}; verdict: {base['verdict']}\n")
    print("| --jobs | wall (s) | ratio to --jobs %d | CPU (s) | peak (GB) | steps (s) | every figure the baseline's |"
          % base["jobs"])
    print("| ---: | ---: | ---: | ---: | ---: | --- | --- |")
    for r in rows:
        steps = ", ".join(f"{k} {v:.0f}" for k, v in r["steps"].items() if v >= 0.5)
        print(f"| {r['jobs']} | {r['wall_s']:.0f} | {r['wall_s'] / base['wall_s']:.2f} | {r['cpu_s']:.0f} | "
              f"{r['peak_gb']:.1f} | {steps} | {'yes' if r['figures'] == base['figures'] else 'NO'} |")


if __name__ == "__main__":
    main()
