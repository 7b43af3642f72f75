"""## The flow step's level reading on kept stores: how far it differs, what it costs (issue 15, items 1 and 4; session 68).

``vfcli flow`` reads the sampled gap a third way, with the gap level free on the rays whose data reject their prior
level (:func:`vfcli.flow.gap.subpixel.readings.level_reading`), and warns when that reading's glottal area differs
from the product's by more than 5 %.  For each kept store (``bench/bench_unseen.py --keep DIR`` or
``bench/bench_diagnose.py --keep DIR``: its ``/hsc`` frames and stored config) this runs the flow step's calibration
on the same sampled frames as ``vfcli flow`` does, with the level reading and without it (the baseline,
:func:`vfcli.flow.gap.subpixel.readings.level_reading` replaced by a no-op for that call, in the same process), and
prints whether the gap was resolved, the edge readings' and the level reading's disagreements, the two calibration
times, and, afterwards and only for scoring, the stored glottal area's total error against the phantom's truth
(``raw/truth.h5`` or ``truth/truth.h5``; blank without one).

Reproduce::

    .venv/bin/python bench/bench_unseen.py 4279 4280 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_level_reading.py DIR/seed4279 DIR/seed4280
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vfcli.flow.pipeline as pipeline  # noqa: E402
from vfcli.config import load_config  # noqa: E402
from vfcli.store import Store  # noqa: E402


def _area_error(folder: Path, stored_area: np.ndarray) -> float:
    """Total glottal area error of the stored /flow against the phantom's truth (NaN without a truth file)."""
    import h5py

    for path in (folder / "raw" / "truth.h5", folder / "truth" / "truth.h5"):
        if path.exists():
            with h5py.File(path, "r") as t:
                true = np.asarray(t["screen/glottal_area"][:], float)
            return float(stored_area.sum() / true.sum() - 1.0)
    return float("nan")


def _pct(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{100 * x:.1f} %"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", nargs="+", type=Path, help="kept store folders (holding recording.h5)")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    print("| store | resolved | edge readings differ | level reading differs | calibration without / with (s) | "
          "stored area error |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    reading = pipeline.level_reading
    for folder in args.stores:
        with Store(folder / "recording.h5").read() as r:
            frames = np.asarray(r.frames("hsc", "frames")[:])
            hsc = r.attrs("hsc")
            cfg = load_config(stored_json=r.recording_config_json())[1]
            area = np.asarray(r.read("flow", "glottal_area"))
        sample = frames[pipeline.sample_indices(len(frames), cfg.flow.sample_frames)]
        times = []
        for check in (lambda *a: float("nan"), reading):
            pipeline.level_reading = check
            t = time.perf_counter()
            calib = pipeline.calibrate(sample, cfg.flow, float(hsc["fps_hz"]), float(hsc["px_per_mm"]),
                                       float(hsc.get("rotation_deg", 0.0)), cfg.camera.pose == "estimate")
            times.append(time.perf_counter() - t)
        pipeline.level_reading = reading
        print(f"| {folder.name} | {'yes' if calib.gap_resolved else 'no'} | {_pct(calib.edge_disagreement)} | "
              f"{_pct(calib.level_disagreement)} | {times[0]:.2f} / {times[1]:.2f} | {_pct(_area_error(folder, area))} |",
              flush=True)


if __name__ == "__main__":
    main()
