"""Frames per second of the whole flow step against OpenCV's raw optical-flow call.

The whole step is :func:`vfcli.flow.optical_flow.flow_stream`: 12-to-8-bit conversion, gap
mask (threshold, median, components), glottal area, opening function, optical flow
(one call per pair; two with ``split_folds``), central velocity at frame times, gap
zeroing and conversion to mm/s. The raw call is OpenCV's flow function alone on the
same, pre-converted 8-bit frames. Each figure is the best of ``--repeat`` runs (the
machine may be shared).

Reproduce::

    .venv/bin/python bench/bench_flow.py            # 256 x 256, 32 frames
    .venv/bin/python bench/bench_flow.py --frames 64 --size 256
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from _flow_phantom import SlitPhantom  # noqa: E402
from vfcli.flow.gap.detect import gap_threshold  # noqa: E402
from vfcli.flow.optical_flow import FlowEstimator, flow_stream, intensity_range, to_uint8  # noqa: E402

METHODS = [("sparse_to_dense", None, False), ("sparse_to_dense", None, True), ("dis", "medium", False),
           ("dis", "fast", False), ("dis", "ultrafast", False)]


def _fps(n: int, seconds: float) -> float:
    return n / seconds if seconds > 0 else float("inf")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=32, help="frames in the synthetic video")
    ap.add_argument("--size", type=int, default=256, help="frame height and width, px")
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure; the fastest counts")
    args = ap.parse_args()
    import cv2

    n, size = args.frames, args.size
    ph = SlitPhantom(height=size, width=size, midline_row=size / 2 - 0.7,
                     glottis_cols=(0.055 * size, 0.945 * size), lam_px=45.0 * size / 256)
    t0 = time.perf_counter()
    frames = np.stack([ph.render(ph.frame_time(k)) for k in range(n)])
    render_s = time.perf_counter() - t0
    threshold = gap_threshold(frames)
    rng = intensity_range(frames)
    eight = [to_uint8(f, rng) for f in frames]

    rows = []
    for method, preset, split in METHODS:
        est = FlowEstimator(method, dis_preset=preset or "medium")
        est(eight[0], eight[1])  # warm-up
        raw_s, whole_s = [], []
        for _ in range(args.repeat):
            t = time.perf_counter()
            for k in range(n - 1):
                est(eight[k], eight[k + 1])
            raw_s.append(time.perf_counter() - t)
            t = time.perf_counter()
            count = sum(1 for _ in flow_stream(iter(frames), fps=ph.fps, px_per_mm=ph.px_per_mm, threshold=threshold,
                                               counts_range=rng, estimator=est, split_folds=split))
            whole_s.append(time.perf_counter() - t)
        raw, whole = _fps(n - 1, min(raw_s)), _fps(count, min(whole_s))
        name = method + (f" ({preset})" if preset else "") + (", split_folds" if split else "")
        rows.append((name, raw, whole))

    print(f"## Flow step, {size} x {size} frames, {n} frames, cv2 {cv2.__version__}, "
          f"{cv2.getNumThreads()} OpenCV threads, {os.cpu_count()} CPUs (rendering took {render_s:.1f} s)\n")
    print("| method | OpenCV flow call alone (fps) | whole flow step (fps) | overhead (ms/frame) |")
    print("|---|---:|---:|---:|")
    for name, raw, whole in rows:
        print(f"| {name} | {raw:.1f} | {whole:.1f} | {1000 / whole - 1000 / raw:.2f} |")
    print(f"\nReproduce: `.venv/bin/python bench/bench_flow.py --frames {n} --size {size} --repeat {args.repeat}`")


if __name__ == "__main__":
    main()
