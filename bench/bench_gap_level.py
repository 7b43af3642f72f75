"""## Where a heavy blur's gap error comes from: the edge model's level and blur against the phantom's (issue 15).

For each seed the widened phantom is rendered (or read from ``--cache``) as
:mod:`bench_gap_optics` does, the flow step calibrates on its sampled frames, and the gap is
segmented four ways, each scored as there (pooled IoU, total area error):

* ``as is``: the flow step's own edge model (gap level from the rough mask's interior, blur searched);
* ``level``: the gap level replaced by the phantom's channel level (the renderer's
  ``gap_level`` above its black level, counts), the blur searched again with it;
* ``level + blur``: the channel level and the drawn blur;
* ``+ no inner bound``: as the previous, with ``inner`` at +-inf (patched in this process): the fit no longer
  starts from the pixels surely in the gap either (it has not been held by them since session 59,
  :func:`vfcli.flow.gap.subpixel.fit_ray_edges`).

It also reports the blur the PSF search reads with the channel level over a range widened to
:data:`SIGMA_RANGE_PX` (the flow step's search stops at 3 px). The phantom's truth (channel level,
drawn blur) replaces the measured values here only, to find which of them the error follows;
the flow step never sees it.

Reproduce::

    .venv/bin/python bench/bench_gap_level.py SEED [SEED ...] [--duration 0.025] [--cache /tmp/gap_optics_cache]
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import vfcli.flow.gap.subpixel.segment as segment  # noqa: E402
from bench_gap_optics import render, score, seed_arguments  # noqa: E402
from vfcli.config import FlowConfig  # noqa: E402
from vfcli.flow.gap.subpixel import EdgeModel, estimate_edge_model, segment_stream  # noqa: E402
from vfcli.flow.pipeline import _sampled_masks, calibrate, sample_indices  # noqa: E402
from vfcli.synth.render import RenderSettings  # noqa: E402

#: Range of the PSF search with the channel level, px (twice the flow step's top).
SIGMA_RANGE_PX = (0.2, 6.0)


def channel_counts() -> float:
    """The phantom's channel level, counts: black level plus ``gap_level`` of the full scale."""
    s = RenderSettings()
    return s.black_level_dn + s.gap_level * s.full_scale_dn


def sampled_masks(sample: np.ndarray, calib, median_px: int) -> np.ndarray:
    """The rough gap masks (k, H, W) the calibration measured its edge model on: the flow step's own
    (:func:`vfcli.flow.pipeline._sampled_masks`) at the calibration's threshold, lateral axis, median and dark
    surroundings (this bench's copy of it, without the surroundings and the median along the glottis, stopped
    every seed once those came in)."""
    return _sampled_masks(sample, calib.threshold, median_px, calib.lateral_axis, False, calib.median_along_slit,
                          calib.surround)[0]


def segment_with(v: dict, gap, free_inner: bool) -> tuple[np.ndarray, np.ndarray]:
    """Masks (n, H, W) and areas (n,) mm^2 of the video with the sub-pixel gap settings ``gap``."""
    original = segment.fit_ray_edges_twice        # what segment's ray fits call (fit_ray_edges, before session 58)

    def unbounded(frames, e0s, e1s, model, search_px, lateral_axis=0, passes=2, inners=None, gap_counts=None,
                  held=False):
        free = [(np.full(len(e), np.inf), np.full(len(e), -np.inf)) for e in e0s]
        return original(frames, e0s, e1s, model, search_px, lateral_axis, passes, inners=free, gap_counts=gap_counts,
                        held=held)

    if free_inner:
        segment.fit_ray_edges_twice = unbounded
    try:
        masks, areas = [], []
        for _, seg in segment_stream(iter(v["frames"]), gap):
            masks.append(seg.mask)
            areas.append(seg.area_mm2(float(v["px_per_mm"])))
    finally:
        segment.fit_ray_edges_twice = original
    return np.stack(masks), np.asarray(areas)


def main() -> None:
    args = seed_arguments(__doc__.splitlines()[0]).parse_args()
    cfg = FlowConfig()
    level = channel_counts()
    print(f"channel level {level:.1f} counts; IoU / area error (total) per column")
    print("| seed | blur drawn / est. (px) | est. gap level | blur with the channel level (px) | as is | level | "
          "level + blur | + no inner bound |")
    print("| ---: | --- | ---: | ---: | --- | --- | --- | --- |")
    for seed in args.seeds:
        v = render(seed, args.duration, None, None, args.cache)
        frames, drawn = v["frames"], float(v["psf"])
        rotation = float(v["rotation"]) if bool(v["stated"]) else 0.0
        sample = frames[sample_indices(len(frames), cfg.sample_frames)]
        calib = calibrate(sample, cfg, float(v["fps"]), float(v["px_per_mm"]), rotation, axis_from_gap=True)
        if calib.gap is None:
            print(f"| {seed} | {drawn:.2f} / - | no edge model | | | | | |", flush=True)
            continue
        masks = sampled_masks(sample, calib, cfg.median_px)
        own = calib.edge_model
        if estimate_edge_model(sample, masks, calib.lateral_axis) != own:
            raise RuntimeError(f"seed {seed}: the rough masks here are not the calibration's")
        at_level = estimate_edge_model(sample, masks, calib.lateral_axis, gap_counts=level)
        wide = estimate_edge_model(sample, masks, calib.lateral_axis, gap_counts=level, sigma_range_px=SIGMA_RANGE_PX)
        cells = []
        for model, free in ((own, False), (at_level, False), (EdgeModel(level, drawn), False),
                            (EdgeModel(level, drawn), True)):
            s = score(v, *segment_with(v, replace(calib.gap, model=model), free))
            cells.append(f"{s['iou']:.3f} / {100 * s['area_total']:+.1f} %")
        print(f"| {seed} | {drawn:.2f} / {own.psf_sigma_px:.2f} | {own.gap_counts:.0f} | "
              f"{'-' if wide is None else f'{wide.psf_sigma_px:.2f}'} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
