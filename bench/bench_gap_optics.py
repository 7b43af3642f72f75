"""## The gap on other optics: IoU and glottal area of the flow step's gap on widened phantoms (issue 15).

For each seed: the widened phantom (:mod:`vfcli.synth.widened`: any camera angle, zoom, optics blur
0.3-3 px, fixture in view or not) is rendered in this process (``make_recording``, the frames
``vfcli synth`` writes, 12-bit counts), then the flow step's gap runs on it exactly as ``vfcli flow``
runs it (:func:`vfcli.flow.pipeline.calibrate` on ``flow.sample_frames`` frames spread over the
video, then :func:`vfcli.flow.gap.subpixel.segment_stream`), with what the lab's config gives
(the camera rotation where the seed states it, else 0; ``camera.pose = 'estimate'``). Afterwards,
and only then, the truth (the gap at pixel centres and the glottal area) is scored with
:mod:`vfcli.synth.scoring`:

* gap IoU pooled over all frames;
* glottal area error, total over frames (sum estimated / sum true - 1), and the median relative
  error over frames open more than 10 % of the widest;
* frames with a gap found / truly open; the estimated blur (px) against the drawn one;
* whether the flow step found the gap resolved (``FlowCalibration.gap_resolved``: wide enough to show its
  own level; where not, ``vfcli flow`` warns that the gap is not determined by the video);
* the gap's length share: its extent along its axis over the whole video, found and true, as a share of
  the glottis in view (:func:`vfcli.flow.plausibility.gap_length_share`, what ``vfcli flow`` warns on
  below :data:`vfcli.flow.plausibility.GAP_LENGTH_WARN`).

``--psf`` / ``--fov-rel`` pin the drawn blur (px) and the field of view (x the glottis length)
of every seed (the rest of the draw is the seed's). Rendered videos are cached in ``--cache``.

Reproduce::

    .venv/bin/python bench/bench_gap_optics.py SEED [SEED ...] [--duration 0.025] [--psf 0.3] [--fov-rel 1.0]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vfcli.synth.phantom as phantom  # noqa: E402
from vfcli.config import FlowConfig, MeshConfig, SynthConfig  # noqa: E402
from vfcli.flow.gap.subpixel import segment_stream  # noqa: E402
from vfcli.flow.gap.detect import gap_mask, glottal_area  # noqa: E402
from vfcli.flow.pipeline import calibrate, sample_indices  # noqa: E402
from vfcli.flow.plausibility import gap_length_share  # noqa: E402
from vfcli.synth.scoring import iou  # noqa: E402
from vfcli.synth.widened import draw_widened  # noqa: E402


def render(seed: int, duration: float, psf: float | None, fov_rel: float | None, cache: Path) -> dict:
    """Frames (n, H, W) uint16, true gap (n, H, W) bool, true area (n,) mm^2 and the draw, cached."""
    tag = f"seed{seed}_d{duration}" + (f"_psf{psf}" if psf else "") + (f"_fov{fov_rel}" if fov_rel else "")
    path = cache / f"{tag}.npz"
    if path.exists():
        z = np.load(path, allow_pickle=True)
        return {k: z[k] for k in z.files}
    cfg = SynthConfig(panel="widened", seed=seed, duration_s=duration)

    def draw(seed_, w, h, nominal):
        d = draw_widened(seed_, w, h, nominal)
        if psf:
            d = replace(d, psf_sigma_px=float(psf))
        if fov_rel:
            fov = fov_rel * d.length_mm
            d = replace(d, fov_mm=fov, px_per_mm=min(w, h) / fov)
        return d

    original = phantom.draw_widened
    phantom.draw_widened = draw       # pins the blur / zoom of the seed's draw (phantom parameters)
    try:
        rec = phantom.make_recording(cfg, MeshConfig())
    finally:
        phantom.draw_widened = original
    frames, gap, area, frac = [], [], [], []
    for image, truth, _, _ in rec.frames():
        frames.append(image)
        gap.append(truth.gap)
        frac.append(truth.gap_fraction.astype(np.float16))
        area.append(truth.gap_fraction.sum() / rec.camera.px_per_mm**2)
    d = rec.widened
    out = dict(frames=np.stack(frames), gap=np.stack(gap), area=np.asarray(area), frac=np.stack(frac),
               psf=d.psf_sigma_px, px_per_mm=d.px_per_mm, fov_rel=d.fov_mm / d.length_mm,
               fixture=d.fixture_in_view, rotation=d.rotation_deg, stated=d.rotation_stated, fps=rec.fps_hz)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **out)
    return out


def flow_gap(v: dict, cfg: FlowConfig) -> tuple[np.ndarray, np.ndarray, object]:
    """The flow step's gap masks (n, H, W) and areas (n,) mm^2, and its calibration."""
    frames = v["frames"]
    px = float(v["px_per_mm"])
    rotation = float(v["rotation"]) if bool(v["stated"]) else 0.0
    calib = calibrate(frames[sample_indices(len(frames), cfg.sample_frames)], cfg, float(v["fps"]), px, rotation,
                      axis_from_gap=True)
    if calib.gap is None:
        midline = calib.midline if calib.midline_line is None else calib.midline_line
        masks = np.stack([gap_mask(f, calib.threshold, cfg.median_px, midline=midline,
                                   lateral_axis=calib.lateral_axis, exclude=calib.surround) for f in frames])
        return masks, glottal_area(masks, px), calib
    masks, areas = [], []
    for _, seg in segment_stream(iter(frames), calib.gap):
        masks.append(seg.mask)
        areas.append(seg.area_mm2(px))
    return np.stack(masks), np.asarray(areas), calib


def score(v: dict, masks: np.ndarray, areas: np.ndarray) -> dict:
    ta = v["area"]
    open_ = ta > 0.1 * ta.max()
    return dict(
        iou=iou(masks, v["gap"]),
        area_total=float(areas.sum() / ta.sum() - 1),
        area_median=float(np.median(np.abs(areas[open_] - ta[open_]) / ta[open_])),
        found=f"{int((areas > 0).sum())}/{int((ta > 0).sum())}",
        false=int(((areas > 0) & (ta == 0)).sum()),
    )


def length_shares(v: dict, masks: np.ndarray, seed: int) -> tuple[float, float]:
    """The gap's length share of the glottis in view over the video: found by ``masks``, and true."""
    h, w = masks.shape[1:]
    length_px = draw_widened(seed, w, h, MeshConfig()).length_mm * float(v["px_per_mm"])
    shares = []
    for counts in (masks.sum(axis=0), v["gap"].sum(axis=0)):
        found, in_view = gap_length_share(counts, length_px) if (counts > 0).sum() >= 3 else (0.0, 1.0)
        shares.append(found / in_view)
    return shares[0], shares[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--duration", type=float, default=0.025)
    ap.add_argument("--psf", type=float, default=None)
    ap.add_argument("--fov-rel", type=float, default=None)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/gap_optics_cache"))
    ap.add_argument("--set", dest="sets", action="append", default=[], help="flow.X=Y")
    args = ap.parse_args()
    over = {}
    for s in args.sets:
        k, val = s.split("=", 1)
        over[k.removeprefix("flow.")] = eval(val)  # noqa: S307 - a bench's own command line
    cfg = FlowConfig(**over)
    print("| seed | blur (px) | est. blur (px) | px/mm | FOV / L | fixture | gap IoU | area error (total) | "
          "area error (median, open) | frames with gap / open | false | length share found / true | resolved | s |")
    print("| ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |")
    for seed in args.seeds:
        v = render(seed, args.duration, args.psf, args.fov_rel, args.cache)
        t = time.perf_counter()
        masks, areas, calib = flow_gap(v, cfg)
        wall = time.perf_counter() - t
        s = score(v, masks, areas)
        est = calib.edge_model.psf_sigma_px if calib.edge_model is not None else float("nan")
        found, true = length_shares(v, masks, seed)
        print(f"| {seed} | {float(v['psf']):.2f} | {est:.2f} | {float(v['px_per_mm']):.1f} | {float(v['fov_rel']):.2f} | "
              f"{'yes' if v['fixture'] else 'no'} | {s['iou']:.3f} | {100 * s['area_total']:+.1f}% | "
              f"{100 * s['area_median']:.1f}% | {s['found']} | {s['false']} | {found:.2f} / {true:.2f} | "
              f"{'yes' if calib.gap_resolved else 'no'} | {wall:.0f} |",
              flush=True)


if __name__ == "__main__":
    main()
