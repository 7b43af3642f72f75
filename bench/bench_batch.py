"""## Many recordings: `vfcli batch` (Dask LocalCluster) against a shell loop of `vfcli run`.

Writes N tiny phantom recordings (`vfcli synth`, not timed), then for N = 1, 2, 4, 8 (``--n``):

* loop: ``for rec in ...; do vfcli run work/$rec.h5 --raw raw/$rec; done`` (one process per
  recording, one after the other), on fresh stores;
* batch: ``vfcli batch manifest.toml --workers W`` on fresh stores (the cluster's start and
  stop included).

Prints a markdown table: total wall time and time per recording of both, the CPU time their
processes used (user + system, workers included), and the speed-up (loop wall / batch wall).
Each recording runs up to ``--until`` (default: optimize, the whole `vfcli run` unit) with a
small optimize (recording.toml's [optimize]: 20 frames, 3 iterations, no uncertainty). A batch
of fewer recordings than workers spreads each recording's basis solves over the idle workers
(:func:`vfcli.batch.engine.use_inner_map`).

Reproduce::

    nice -n 5 .venv/bin/python bench/bench_batch.py [--n 1 2 4 8] [--workers 2] [--until optimize] [--dir DIR]
        [--inner-map auto|on|off]

``--dir DIR`` keeps the phantoms (and reuses those already there) between runs.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TINY = ["synth.duration_s=0.02", "synth.ldv_epoch_s=0.04", "synth.target_edge_mm=2.0", "synth.n_phase=64",
        "synth.width_px=128", "synth.height_px=128", "synth.px_per_mm=8", "synth.supersample=1"]
SMALL_OPTIMIZE = '\n[optimize]\nn_frames = 20\nmax_iterations = 3\nsetup = "3x3x10-one-sided"\nloads = "free"\nuncertainty = false\n'
VFCLI = [sys.executable, "-m", "vfcli.cli.main"]


def _check(res: subprocess.CompletedProcess, what: str) -> None:
    if res.returncode:
        raise SystemExit(f"{what} failed ({res.returncode}): {res.stderr[-2000:]}")


def make_phantoms(raw: Path, n: int) -> list[Path]:
    """``n`` phantom raw folders under ``raw`` (seeds 301...), written two at a time."""
    outs = [raw / f"rec{i:02d}" for i in range(n)]
    todo = [(o, 301 + i) for i, o in enumerate(outs) if not (o / "recording.toml").exists()]
    while todo:
        batch, todo = todo[:2], todo[2:]
        procs = []
        for out, seed in batch:
            args = [*VFCLI, "synth", str(out), "--seed", str(seed), "-q"] + sum((["--set", s] for s in TINY), [])
            procs.append(subprocess.Popen(args, stderr=subprocess.PIPE, text=True))
        for p in procs:
            _, err = p.communicate()
            if p.returncode:
                raise SystemExit(f"vfcli synth failed: {err}")
        for out, _ in batch:
            with (out / "recording.toml").open("a") as fh:
                fh.write(SMALL_OPTIMIZE)
    return outs


def _cpu_children() -> float:
    """User + system CPU time of every finished child process so far (their own children
    included once waited for), s."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def timed(fn, *args) -> tuple[float, float]:
    """(wall time, CPU time of the child processes) of ``fn(*args)``, s."""
    c0, t0 = _cpu_children(), time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0, _cpu_children() - c0


def loop(raws: list[Path], work: Path, until: str) -> float:
    """Wall time of a plain loop of `vfcli run` over ``raws`` (fresh stores), s."""
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    t = time.perf_counter()
    for r in raws:
        _check(subprocess.run([*VFCLI, "run", str(work / f"{r.name}.h5"), "--raw", str(r), "--until", until, "-q"],
                              capture_output=True, text=True), f"vfcli run {r.name}")
    return time.perf_counter() - t


def batch(raws: list[Path], work: Path, until: str, workers: int, inner_map: str = "auto") -> float:
    """Wall time of `vfcli batch` over ``raws`` on a LocalCluster (fresh stores and ledger), s."""
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    manifest = work / "batch.toml"
    manifest.write_text(f'[batch]\nuntil = "{until}"\n' + "".join(
        f'\n[[recording]]\nraw = "{r}"\nstore = "{work / (r.name + ".h5")}"\n' for r in raws))
    t = time.perf_counter()
    _check(subprocess.run([*VFCLI, "batch", str(manifest), "--workers", str(workers), "--inner-map", inner_map, "-q"],
                          capture_output=True, text=True), "vfcli batch")
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--until", default="optimize")
    ap.add_argument("--dir", type=Path)
    ap.add_argument("--inner-map", choices=("auto", "on", "off"), default="auto",
                    help="vfcli batch --inner-map (auto: a batch of fewer recordings than workers spreads its solves)")
    args = ap.parse_args()
    base = args.dir or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    raws = make_phantoms(base / "raw", max(args.n))
    print(f"until {args.until}, LocalCluster of {args.workers} worker processes (1 thread each), --inner-map "
          f"{args.inner_map}; load average at "
          f"the start: {' '.join(f'{x:.1f}' for x in os.getloadavg())}\n")
    print("| recordings | loop total (s) | loop per recording (s) | loop CPU (s) | batch total (s) "
          "| batch per recording (s) | batch CPU (s) | speed-up |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in args.n:
        t_loop, c_loop = timed(loop, raws[:n], base / "work_loop", args.until)
        t_batch, c_batch = timed(batch, raws[:n], base / "work_batch", args.until, args.workers, args.inner_map)
        print(f"| {n} | {t_loop:.1f} | {t_loop / n:.1f} | {c_loop:.1f} | {t_batch:.1f} | {t_batch / n:.1f} | {c_batch:.1f} "
              f"| {t_loop / t_batch:.2f} |", flush=True)
    print(f"\nload average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.dir is None:
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
