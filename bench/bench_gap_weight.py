"""## The gap term's weight against the inferior surface: kept stores refitted at other weights (issue 15, item 5).

For each kept store (``bench/bench_unseen.py --keep DIR`` or ``bench/bench_diagnose.py --keep DIR``, with the
phantom's truth in ``DIR/raw/truth.h5`` or ``DIR/truth/truth.h5``), ``vfcli optimize`` is run again at each
``--weights`` value of ``optimize.gap_weight`` as the run ``gw<k>`` (the store's ``default`` run is the weight 1 it
was made with), then every run is scored against the truth (read after the fits, to score only): the inferior
surface's oscillating error (relative to the RMS true oscillation), its static error (mm RMS of each node's time
mean), its total error (relative to the RMS true displacement), the mean vertical displacement of the inferior
surface true / estimated (mm) and the coverage of the stated 90 % intervals (clamped nodes left out, as
:func:`vfcli.synth.scoring.interval_coverage` and ``bench_unseen.py`` score them).

Reproduce (prints a markdown table)::

    .venv/bin/python bench/bench_unseen.py 4125 4126 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_gap_weight.py DIR/seed4125 DIR/seed4126 --weights 0 0.3
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_unseen import read_truth, score_inferior  # noqa: E402

from vfcli.store import Store  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.synth.scoring import pose_half_turned  # noqa: E402

MESH_KEYS = ("nodes", "tets", "tet_fold", "faces", "face_tag", "face_fold", "uv", "node_side")


def run_name(weight: float) -> str:
    """The run a weight is stored as: ``gw`` and its digits (0.3 -> gw03, 10 -> gw10)."""
    return "gw" + f"{weight:g}".replace(".", "").replace("-", "m")


def score(work: Path, run: str) -> dict:
    """The inferior surface of the run ``run`` of ``work``'s store against its phantom's truth
    (:func:`bench_unseen.score_inferior`, as ``bench_unseen.py`` scores its runs)."""
    truth = work / "raw" / "truth.h5"
    t, a = read_truth(truth if truth.is_file() else work / "truth" / "truth.h5",
                      ["frames/time", "frames/displacement"] + [f"mesh/{k}" for k in MESH_KEYS])
    with Store(work / "recording.h5").read() as r:
        mesh = read_mesh(r)
        disp = np.asarray(r.read("optimize", "displacements", run), float)[:-1]
        std = np.asarray(r.read("optimize", "displacement_std", run), float)[:-1]
        sim_time = np.asarray(r.read("optimize", "sim_time", run), float)[:-1]
        rotation = float(r.attrs("optimize", run)["camera_rotation_deg"])
    turned = pose_half_turned(rotation, float(a["camera_rotation_deg"]))
    return score_inferior(t, mesh, disp, std, None, sim_time, turned)


def refit(work: Path, setting: str | list[str], run: str, force: bool = False) -> bool:
    """``vfcli optimize`` on ``work``'s store with one ``--set`` (``optimize.X=Y``) or several as the run ``run``;
    False (and the command's last words on stderr) when it did not exit 0."""
    vfcli = str(Path(sys.executable).with_name("vfcli"))
    sets = [a for one in ([setting] if isinstance(setting, str) else setting) for a in ("--set", one)]
    res = subprocess.run([vfcli, "optimize", str(work / "recording.h5"), *sets, "--run", run, "-q"]
                         + (["--force"] if force else []), capture_output=True, text=True)
    if res.returncode != 0:
        print(f"{work.name}: optimize --set {setting} exited {res.returncode}: {res.stderr.strip()[-300:]}",
              file=sys.stderr)
    return res.returncode == 0


def row(label: str, s: dict) -> str:
    """The table's columns of a :func:`score` (label: the store and the setting)."""
    return (f"| {label} | {100 * s['inf_osc_err']:.1f} % | {s['inf_static_err_mm']:.4f} | "
            f"{100 * s['inf_total_err']:.2f} % | {s['inf_mean_z_true_mm']:.3f} / {s['inf_mean_z_est_mm']:.3f} | "
            f"{100 * s['coverage90']:.1f} % |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", type=Path, nargs="+", help="kept store folders (holding recording.h5)")
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.3])
    args = ap.parse_args()
    print("| store | optimize.gap_weight | inferior oscillating | static (mm) | total | mean z true / est (mm) | "
          "90 % coverage |")
    print("| --- | ---: | ---: | ---: | ---: | --- | ---: |")
    for work in args.stores:
        runs = [(1.0, "default")]
        for w in args.weights:
            if refit(work, f"optimize.gap_weight={w}", run_name(w)):
                runs.append((w, run_name(w)))
        for w, name in runs:
            print(row(f"{work.name} | {w:g}", score(work, name)), flush=True)


if __name__ == "__main__":
    main()
