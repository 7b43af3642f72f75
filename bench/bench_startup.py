"""## Start-up of the command line: `vfcli --help`, a command's `--help`, a call with nothing to do.

For each command line: the modules Python imports (``python -X importtime``) and the sum
of their own import times, and the best of ``--repeat`` runs' wall and CPU time (user +
sys of the child, from ``resource.getrusage``). On a shared machine the wall time includes
waiting for a core; the CPU time does not. ``--before PATH`` measures another checkout too,
in the same run, command by command (the "before" of a change).

The calls with nothing to do run on a small phantom's store that this script first makes with
`vfcli run` (every stage up to date; the phantom's settings in its recording.toml, so that
every stage command finds its stored config): `vfcli info`, each stage command, and `vfcli run`.

Reproduce::

    .venv/bin/python bench/bench_startup.py [--repeat 5] [--tree PATH] [--before PATH] [--no-store]
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


PHANTOM = ["synth.duration_s=0.02", "synth.ldv_epoch_s=0.03", "synth.target_edge_mm=2.0", "synth.n_phase=64",
           "synth.width_px=160", "synth.height_px=160", "synth.px_per_mm=9", "synth.supersample=1"]
#: appended to the phantom's recording.toml: a coarse mesh and a short fit
SMALL_FIT = "\n[optimize]\nn_frames = 12\nfirst_frame = 20\nmax_iterations = 3\n"


def make_store(tree: Path, work: Path) -> tuple[Path, Path]:
    """A small phantom's raw folder and its store with every stage written (by `vfcli run`)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    vf = [sys.executable, "-m", "vfcli.cli.main"]
    raw, store = work / "raw", work / "rec.h5"
    subprocess.run([*vf, "synth", str(work / "synth"), "--seed", "7", *sum((["--set", s] for s in PHANTOM), []), "-q"],
                   env=env, check=True)
    raw.mkdir()
    for name in ("video.cihx", "video.mraw", "video_pressure.tdms", "scan.uff", "recording.toml"):
        shutil.copy(work / "synth" / name, raw / name)
    toml = (raw / "recording.toml").read_text().replace("target_edge_mm = 1.5", "target_edge_mm = 2.5")
    (raw / "recording.toml").write_text(toml + SMALL_FIT)
    subprocess.run([*vf, "run", str(store), "--raw", str(raw), "-q"], env=env, check=True)
    return raw, store


def has(tree: Path, command: str) -> bool:
    """Whether the checkout has the command (`vfcli run` is new)."""
    return command != "run" or (tree / "vfcli/cli/run.py").exists()


def row(label: str, results: list[dict[str, object] | None]) -> str:
    cells = []
    for key, fmt in (("modules", "{}"), ("import_s", "{:.2f} s"), ("heavy", "{}"), ("wall_s", "{:.2f} s"),
                     ("cpu_s", "{:.2f} s")):
        vals = []
        for r in results:
            if r is None:
                vals.append("-")
            elif key == "heavy":
                vals.append(", ".join(r["heavy"]) or "none")  # type: ignore[arg-type]
            else:
                vals.append(fmt.format(r[key]))
        cells.append(" / ".join(vals))
    return f"| `{label}` | " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout to measure (default: this one)")
    ap.add_argument("--before", type=Path, help="another checkout, measured in the same run (shown first)")
    ap.add_argument("--no-store", action="store_true", help="only the --help lines (no phantom store)")
    a = ap.parse_args()
    trees = [a.before, a.tree] if a.before else [a.tree]
    print(f"trees {' and '.join(map(str, trees))}, load average {os.getloadavg()[0]:.1f}, best of {a.repeat}")
    print("(each cell: " + ("before / after" if a.before else "this tree") + ")\n")
    print("| command | modules | sum of import times | heavy modules imported | wall | CPU |")
    print("| --- | --- | --- | --- | --- | --- |")
    for args in (["--help"], ["config", "--help"], ["mesh", "--help"], ["sync", "--help"], ["optimize", "--help"],
                 ["run", "--help"]):
        print(row("vfcli " + " ".join(args), [run(t, args, a.repeat) if has(t, args[0]) else None for t in trees]),
              flush=True)
    if a.no_store:
        return
    with tempfile.TemporaryDirectory(prefix="vfcli-bench-startup-") as tmp:
        raw, store = make_store(a.tree, Path(tmp))
        calls = [["info", store], ["ingest-ldv", store, raw / "scan.uff"], ["sync", store], ["flow", store],
                 ["mesh", store], ["optimize", store], ["run", store, "--raw", raw]]
        for args in calls:
            label = "vfcli " + " ".join(Path(x).name if isinstance(x, Path) else x for x in args) + " (up to date)"
            results = [run(t, [str(x) for x in args], a.repeat) if has(t, args[0]) else None for t in trees]
            print(row(label, results), flush=True)


if __name__ == "__main__":
    main()
