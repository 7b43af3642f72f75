"""## Start-up of the command line: `vfcli --help` and a command's `--help`.

For each command line: the modules Python imports (``python -X importtime``) and the sum
of their own import times, and the best of ``--repeat`` runs' wall and CPU time (user +
sys of the child, from ``resource.getrusage``). On a shared machine the wall time includes
waiting for a core; the CPU time does not.

Reproduce::

    .venv/bin/python bench/bench_startup.py [--repeat 5] [--tree PATH]   # PATH: another checkout
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = {"numpy", "scipy", "h5py", "cv2", "matplotlib", "pydantic", "tqdm", "skfem", "tetgen"}


def run(tree: Path, args: list[str], repeat: int) -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, "-m", "vfcli.cli.main", *args]
    log = subprocess.run([sys.executable, "-X", "importtime", *cmd[1:]], capture_output=True, text=True, env=env, cwd=tree).stderr
    rows = [line.split("|") for line in log.splitlines() if line.startswith("import time:") and "self [us]" not in line]
    walls, cpus = [], []
    for _ in range(repeat):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(cmd, capture_output=True, env=env, cwd=tree, check=True)
        walls.append(time.perf_counter() - t)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
    return {"modules": len(rows), "import_s": sum(int(r[0].split(":")[1]) for r in rows) / 1e6,
            "heavy": sorted({r[2].strip().split(".")[0] for r in rows} & HEAVY),
            "wall_s": min(walls), "cpu_s": min(cpus)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout to measure (default: this one)")
    a = ap.parse_args()
    print(f"tree {a.tree}, load average {os.getloadavg()[0]:.1f}, best of {a.repeat}\n")
    print("| command | modules | sum of import times | heavy modules imported | wall | CPU |")
    print("| --- | --- | --- | --- | --- | --- |")
    for args in (["--help"], ["mesh", "--help"], ["config", "--help"]):
        r = run(a.tree, args, a.repeat)
        print(f"| `vfcli {' '.join(args)}` | {r['modules']} | {r['import_s']:.2f} s | {', '.join(r['heavy']) or 'none'} "
              f"| {r['wall_s']:.2f} s | {r['cpu_s']:.2f} s |")


if __name__ == "__main__":
    main()
