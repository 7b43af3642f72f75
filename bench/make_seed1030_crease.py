"""Writes tests/data/seed1030_crease.npz (tests/test_gap_tilted.py): two frames of widened seed 1030 and the flow
step's calibration of that recording.

The widened phantom (panel 'widened', seed 1030, 0.025 s) is rendered as ``bench/bench_gap_optics.py`` renders it
(cached in /tmp/gap_optics_cache), calibrated by :func:`vfcli.flow.pipeline.calibrate` with the default flow
config, and frames 1 (opening) and 62 (closed) are cropped to the 63 columns around the glottis (the lateral
axis), with the renderer's gap fraction as truth. Calibrated on the flow step of 3bd96c0 (session 16); the
calibration's fields are stored, so the test does not depend on later changes to ``calibrate``. On b1dd8c4,
which searches the crease along the whole glottis, the rays' levels and creases differ (38 rays unset instead of
45); the other arrays are the same.

Reproduce::

    .venv/bin/python bench/make_seed1030_crease.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_gap_optics import render  # noqa: E402
from vfcli.config import FlowConfig  # noqa: E402
from vfcli.flow.pipeline import calibrate, sample_indices  # noqa: E402

FRAMES = [1, 62]
HALF_PX = 20          # columns kept beyond the midline's extremes


def main() -> None:
    v = render(1030, 0.025, None, None, Path("/tmp/gap_optics_cache"))
    cfg = FlowConfig()
    cal = calibrate(v["frames"][sample_indices(len(v["frames"]), cfg.sample_frames)], cfg, float(v["fps"]),
                    float(v["px_per_mm"]), float(v["rotation"]) if bool(v["stated"]) else 0.0, axis_from_gap=True)
    g = cal.gap
    if g.lateral_axis != 1:
        raise SystemExit("seed 1030's glottis is expected along the image rows (lateral axis 1)")
    mid = np.asarray(g.midline)
    lo, hi = int(np.floor(np.nanmin(mid))) - HALF_PX, int(np.ceil(np.nanmax(mid))) + HALF_PX
    np.savez_compressed(
        ROOT / "tests" / "data" / "seed1030_crease.npz",
        frames=v["frames"][FRAMES][:, :, lo:hi], gap_fraction=v["frac"][FRAMES][:, :, lo:hi].astype(np.float16),
        gap_counts=g.model.gap_counts, psf_sigma_px=g.model.psf_sigma_px, threshold=g.threshold,
        median_px=g.median_px, midline=mid - lo, lateral_axis=g.lateral_axis, ray_levels=g.ray_levels,
        ray_crease=g.ray_crease, px_per_mm=float(v["px_per_mm"]))


if __name__ == "__main__":
    main()
