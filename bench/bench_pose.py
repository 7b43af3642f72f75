"""## The model's pose along the glottis: the gap alone against the gap and the motion (issue 15 item 2).

For each kept store of ``bench/bench_unseen.py --keep DIR`` (a widened phantom fitted by ``vfcli optimize``), the
pose is estimated twice the way optimize estimates it (:func:`vfcli.camera.pose.locate` on the run's own inputs,
:func:`vfcli.store.fit.read_optimize_inputs`): from the glottal gap alone, and with the RMS amplitude of the measured
velocity over the run's window (:func:`vfcli.camera.pose.motion_amplitude`, what ``vfcli optimize`` passes since
session 32). Printed: which
ends of the gap the image cuts, and for each estimate how mid-length was placed and the model origin's error along
the glottis (mm, estimate minus truth, from the phantom's truth.h5; the pose turned by 180 deg about the glottis
centre counts as the same, the folds being mirror images).

Reproduce::

    .venv/bin/python bench/bench_unseen.py 4003 4005 1151 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_pose.py DIR/seed4003 DIR/seed4005 DIR/seed1151
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.camera.pose import gap_axis, locate, motion_amplitude  # noqa: E402
from vfcli.config import RecordingConfig  # noqa: E402
from vfcli.stages.diagnose import run_recording_config  # noqa: E402
from vfcli.store.fit import read_optimize_inputs  # noqa: E402
from vfcli.store.runs import read_run  # noqa: E402
from vfcli.store.transaction import Store  # noqa: E402
from vfcli.store.truth import read_truth  # noqa: E402


def along_error(rotation_deg: float, offset_px, true_rotation_deg: float, true_offset_px, length_mm: float,
                px_per_mm: float) -> float:
    """Signed error (mm) of the model origin along the estimated axis, against the nearer of the true origin and
    the true x = L end (the pose turned by 180 deg)."""
    e = np.array([np.cos(np.radians(rotation_deg)), np.sin(np.radians(rotation_deg))])
    true_e = np.array([np.cos(np.radians(true_rotation_deg)), np.sin(np.radians(true_rotation_deg))])
    origin = np.asarray(true_offset_px, float)
    errs = [(np.asarray(offset_px) - o) @ e / px_per_mm for o in (origin, origin + length_mm * px_per_mm * true_e)]
    return float(min(errs, key=abs))


def pose_errors(work: Path) -> dict:
    """The two estimates of one kept store (module docstring), from the inputs its run ``default`` was fitted on."""
    with Store(work / "recording.h5").read() as r:
        stored = read_run(r, "default")
        roi = np.asarray(r.attrs("flow").get("roi_origin_px", (0.0, 0.0)), float)
        cfg = run_recording_config(RecordingConfig(), stored.config, stored.attrs, roi)   # the run's window
        estimate = cfg.camera.model_copy(update={"pose": "estimate"})
        inputs = read_optimize_inputs(r, cfg.model_copy(update={"camera": estimate}))
    _, a = read_truth(work / "raw" / "truth.h5", [])
    true_off = np.asarray(a["camera_offset_px"], float) - inputs.roi_origin_px
    args = (inputs.gap_counts, inputs.px_per_mm, inputs.length_mm, inputs.velocity_rotation_deg)
    out = {"cut": gap_axis(inputs.gap_counts, inputs.velocity_rotation_deg).cut}
    for name, amp in (("gap", None), ("gap and motion", lambda: motion_amplitude(inputs.velocity, inputs.valid))):
        pose = locate(*args, amp)
        out[name] = (pose.mid_length, along_error(pose.rotation_deg, pose.offset_px, float(a["camera_rotation_deg"]),
                                                  true_off, inputs.length_mm, inputs.px_per_mm))
    return out


def main() -> None:
    print("| store | ends cut | gap alone: mid-length, origin error (mm) "
          "| gap and motion: mid-length, origin error (mm) |")
    print("| --- | --- | --- | --- |")
    for w in sys.argv[1:]:
        e = pose_errors(Path(w))
        cut = {0: "none", 1: "one", 2: "both"}[sum(e["cut"])]
        print(f"| {Path(w).name} | {cut} | {e['gap'][0]}, {e['gap'][1]:+.2f} | "
              f"{e['gap and motion'][0]}, {e['gap and motion'][1]:+.2f} |", flush=True)


if __name__ == "__main__":
    main()
