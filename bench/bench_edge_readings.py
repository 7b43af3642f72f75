"""## The cost of the flow step's second reading of the gap's edges (issue 15; session 58).

``vfcli flow`` reads the sampled gap's edges twice (:func:`vfcli.flow.gap.subpixel.readings.edge_readings`): as the edge fit
places them from the detected edges held beyond the pixels surely in the gap (the product until session 59), and
with each edge also searched over 4 px around it (:func:`vfcli.flow.gap.subpixel.profile.searched_edges`), and warns
when the two glottal areas differ by more than 5 %.  For each widened seed (rendered as ``bench/bench_gap_optics.py``
renders it, cached in ``--cache``) this times the flow step's calibration of the same sampled frames with the second
reading and without it (the baseline, :func:`vfcli.flow.gap.subpixel.readings.edge_readings` replaced by a no-op for that call),
in one process, and prints their ratio and the disagreement.  The calibration runs once per recording; the rest of ``vfcli flow`` (every frame's
edges and optical flow) does not change.

Reproduce::

    .venv/bin/python bench/bench_edge_readings.py SEED [SEED ...] [--duration 0.025] [--cache DIR]
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_gap_optics import render, seed_arguments  # noqa: E402

import vfcli.flow.pipeline as pipeline  # noqa: E402
from vfcli.config import FlowConfig  # noqa: E402


def main() -> None:
    args = seed_arguments(__doc__.splitlines()[0]).parse_args()
    cfg = FlowConfig()
    print("| seed | calibration without (s) | with the second reading (s) | ratio | readings differ |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    checked = pipeline.edge_readings
    for seed in args.seeds:
        v = render(seed, args.duration, None, None, args.cache)
        frames = v["frames"]
        sample = frames[pipeline.sample_indices(len(frames), cfg.sample_frames)]
        rotation = float(v["rotation"]) if bool(v["stated"]) else 0.0
        times = []
        for check in (lambda *a: float("nan"), checked):
            pipeline.edge_readings = check
            t = time.perf_counter()
            calib = pipeline.calibrate(sample, cfg, float(v["fps"]), float(v["px_per_mm"]), rotation,
                                       axis_from_gap=True)
            times.append(time.perf_counter() - t)
        pipeline.edge_readings = checked
        share = calib.edge_disagreement
        print(f"| {seed} | {times[0]:.2f} | {times[1]:.2f} | {times[1] / times[0]:.2f} | "
              f"{'not resolved' if share != share else f'{100 * share:.1f}%'} |", flush=True)


if __name__ == "__main__":
    main()
