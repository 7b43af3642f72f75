"""The stated uncertainty of stored optimize runs against the phantom's truth: how much of the inferior surface
the 90 % intervals cover (in all and by component), the static part's, the stated sd against the error, and the parts
of the stated sd.

For kept stores (``bench_unseen.py --keep DIR`` or ``bench_diagnose.py --keep DIR``: a folder holding
``recording.h5`` and the phantom's ``truth.h5`` in ``raw/`` or ``truth/``), one markdown row per store and run.
To compare two methods on the same fit, refit a copy of a store with the other tree under another run name
(``vfcli optimize DIR/recording.h5 --run new``) and name both runs. Reads truth.h5: a benchmark, never the
pipeline.

    .venv/bin/python bench/bench_coverage.py DIR [DIR ...] --runs default new
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_unseen import read_truth, score_inferior  # noqa: E402
from vfcli.store import Store  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.synth.scoring import pose_half_turned  # noqa: E402

MESH_KEYS = ("nodes", "tets", "tet_fold", "faces", "face_tag", "face_fold", "uv", "node_side")
#: the parts of the stated sd a run's attributes give (relative to the RMS reconstructed motion; absent: "-")
PARTS = ("inferior_posterior_rel", "inferior_instruments_rel", "inferior_data_kinds_rel", "inferior_load_family_rel",
         "inferior_regularisation_rel")


def truth_path(folder: Path) -> Path:
    """The phantom's truth.h5 beside a kept store: ``raw/`` (bench_unseen) or ``truth/`` (bench_diagnose)."""
    for p in (folder / "raw" / "truth.h5", folder / "truth" / "truth.h5"):
        if p.exists():
            return p
    raise SystemExit(f"{folder}: no raw/truth.h5 or truth/truth.h5")


def score_run(folder: Path, run: str) -> dict:
    """The inferior surface of ``run`` in ``folder``'s store against its truth (:func:`bench_unseen.score_inferior`),
    with the run's stated parts and the time its stated uncertainty took."""
    t, a = read_truth(truth_path(folder), ["frames/time", "frames/displacement"] + [f"mesh/{k}" for k in MESH_KEYS])
    with Store(folder / "recording.h5").read() as r:
        mesh = read_mesh(r)
        disp = r.read("optimize", "displacements", run).astype(float)[:-1]
        std = r.read("optimize", "displacement_std", run).astype(float)[:-1]
        std_static = r.read("optimize", "displacement_std_static", run).astype(float)
        sim_time = r.read("optimize", "sim_time", run)[:-1]
        attrs = dict(r.attrs("optimize", run))
    turned = pose_half_turned(float(attrs["camera_rotation_deg"]), a["camera_rotation_deg"])
    s = score_inferior(t, mesh, disp, std, std_static, sim_time, turned)
    s["parts"] = [float(attrs[k]) if k in attrs else float("nan") for k in PARTS]
    s["uncertainty_time_s"] = float(attrs.get("uncertainty_time_s", np.nan))
    return s


def _pct(v: float) -> str:
    return "-" if not np.isfinite(v) else f"{100 * v:.1f} %"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--runs", nargs="+", default=["default"])
    args = ap.parse_args()
    print("| store | run | inferior total error | 90 % coverage | static part's | by component: longitudinal / lateral / "
          "vertical | stated sd / RMS true | parts: posterior / instruments / kinds of data / load family / "
          "regularisation | stated uncertainty, s |")
    print("| --- | --- | ---: | ---: | ---: | --- | ---: | --- | ---: |")
    for folder in args.folders:
        for run in args.runs:
            s = score_run(folder, run)
            print(f"| {folder.name} | {run} | {_pct(s['inf_total_err'])} | {_pct(s['coverage90'])} | "
                  f"{_pct(s['coverage90_static'])} | {' / '.join(_pct(v) for v in s['coverage90_xyz'])} | "
                  f"{_pct(s['stated_std_rel'])} | "
                  f"{' / '.join(_pct(v) for v in s['parts'])} | {s['uncertainty_time_s']:.1f} |")


if __name__ == "__main__":
    main()
