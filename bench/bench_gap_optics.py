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
* the two readings of the edges (``FlowCalibration.edge_disagreement``, :mod:`vfcli.flow.gap.subpixel.ambiguity`):
  how far the sampled glottal area moves between the edge fit from the detected edges and the one searched over
  each edge's neighbourhood, where ``vfcli flow`` warns above 5 % (blank where the gap is not resolved);
* the gap's length share: its extent along its axis over the whole video, found and true, as a share of
  the glottis in view (:func:`vfcli.flow.plausibility.gap_length_share`, what ``vfcli flow`` warns on
  below :data:`vfcli.flow.plausibility.GAP_LENGTH_WARN`).

``--edges`` also prints, per seed, each final (smoothed) edge's error against the truth's sub-pixel edge on the
same ray (the truth's gap fraction per pixel along the ray: the run's first and last covered pixels place its
ends), by the ray's true width: the mean (bias) and standard deviation of e0's and e1's errors, px along the ray.
A width error that both edges share is the gap level or the blur; one edge's alone is what lies beside that edge
(the rim's shading, the light's direction).

``--psf`` / ``--fov-rel`` pin the drawn blur (px) and the field of view (x the glottis length)
of every seed (the rest of the draw is the seed's). Rendered videos are cached in ``--cache``.

Reproduce::

    .venv/bin/python bench/bench_gap_optics.py SEED [SEED ...] [--duration 0.025] [--psf 0.3] [--fov-rel 1.0] [--edges]
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


def flow_gap(v: dict, cfg: FlowConfig) -> tuple[np.ndarray, np.ndarray, object, list]:
    """The flow step's gap masks (n, H, W), areas (n,) mm^2, its calibration and each frame's final edges
    ((e0, e1) per frame, (n_rays,) lateral px; empty without sub-pixel edges)."""
    frames = v["frames"]
    px = float(v["px_per_mm"])
    rotation = float(v["rotation"]) if bool(v["stated"]) else 0.0
    calib = calibrate(frames[sample_indices(len(frames), cfg.sample_frames)], cfg, float(v["fps"]), px, rotation,
                      axis_from_gap=True)
    if calib.gap is None:
        midline = calib.midline if calib.midline_line is None else calib.midline_line
        masks = np.stack([gap_mask(f, calib.threshold, cfg.median_px, midline=midline,
                                   lateral_axis=calib.lateral_axis, exclude=calib.surround) for f in frames])
        return masks, glottal_area(masks, px), calib, []
    masks, areas, edges = [], [], []
    for _, seg in segment_stream(iter(frames), calib.gap):
        masks.append(seg.mask)
        areas.append(seg.area_mm2(px))
        edges.append((seg.e0, seg.e1))
    return np.stack(masks), np.asarray(areas), calib, edges


#: True-width bins of :func:`edge_errors`, px along the ray
WIDTH_BINS_PX = (1, 2, 3, 4, 5, 6, 8, 12, 40)


def true_edges(frac: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The truth's sub-pixel edges on each ray of one frame: ``frac`` (n_lat, n_rays) the gap's area fraction per
    pixel with the lateral axis first. The first and last covered pixels of a ray hold its edges (a covered share
    c of the first pixel puts e0 at its centre + 1/2 - c). Returns (e0, e1, width), NaN where fewer than two
    pixels are covered; width: the covered area along the ray, px."""
    f = np.asarray(frac, float)
    covered = f > 0
    n = covered.sum(axis=0)
    first = np.argmax(covered, axis=0)
    last = f.shape[0] - 1 - np.argmax(covered[::-1], axis=0)
    cols = np.arange(f.shape[1])
    e0 = first + 0.5 - f[first, cols]
    e1 = last - 0.5 + f[last, cols]
    ok = n >= 2
    return np.where(ok, e0, np.nan), np.where(ok, e1, np.nan), np.where(ok, f.sum(axis=0), np.nan)


def edge_errors(v: dict, edges: list, lateral_axis: int) -> list[tuple]:
    """Per true-width bin (:data:`WIDTH_BINS_PX`): (lo, hi, n, e0 bias, e0 sd, e1 bias, e1 sd), px along the ray,
    over the rays open in both the flow step's edges and the truth."""
    d0, d1, tw = [], [], []
    for (e0, e1), frac in zip(edges, v["frac"]):
        f = np.asarray(frac, float)
        t0, t1, w = true_edges(f if lateral_axis == 0 else f.T)
        ok = np.isfinite(e0) & np.isfinite(t0)
        d0.append(e0[ok] - t0[ok])
        d1.append(e1[ok] - t1[ok])
        tw.append(w[ok])
    d0, d1, tw = (np.concatenate(x) if x else np.zeros(0) for x in (d0, d1, tw))
    out = []
    for lo, hi in zip(WIDTH_BINS_PX[:-1], WIDTH_BINS_PX[1:]):
        s = (tw >= lo) & (tw < hi)
        if s.sum() >= 20:
            out.append((lo, hi, int(s.sum()), d0[s].mean(), d0[s].std(), d1[s].mean(), d1[s].std()))
    return out


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


def _share(x: float) -> str:
    """A share as a percentage to one place, blank when NaN; marked "(warned)" above the flow step's doubt level."""
    from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA

    return "" if not np.isfinite(x) else f"{100 * x:.1f}%" + (" (warned)" if x > AMBIGUOUS_AREA else "")


def seed_arguments(description: str) -> argparse.ArgumentParser:
    """The command line the gap benchmarks share: seeds, ``--duration`` (s) and ``--cache`` (the renders' folder)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--duration", type=float, default=0.025)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/gap_optics_cache"))
    return ap


def main() -> None:
    ap = seed_arguments(__doc__.splitlines()[0])
    ap.add_argument("--psf", type=float, default=None)
    ap.add_argument("--fov-rel", type=float, default=None)
    ap.add_argument("--edges", action="store_true", help="also each edge's error by true width (px along the ray)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="flow.X=Y")
    args = ap.parse_args()
    over = {}
    for s in args.sets:
        k, val = s.split("=", 1)
        over[k.removeprefix("flow.")] = eval(val)  # noqa: S307 - a bench's own command line
    cfg = FlowConfig(**over)
    print("| seed | blur (px) | est. blur (px) | px/mm | FOV / L | fixture | gap IoU | area error (total) | "
          "area error (median, open) | frames with gap / open | false | length share found / true | resolved | "
          "edge readings differ | s |")
    print("| ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |")
    for seed in args.seeds:
        v = render(seed, args.duration, args.psf, args.fov_rel, args.cache)
        t = time.perf_counter()
        masks, areas, calib, edges = flow_gap(v, cfg)
        wall = time.perf_counter() - t
        s = score(v, masks, areas)
        est = calib.edge_model.psf_sigma_px if calib.edge_model is not None else float("nan")
        found, true = length_shares(v, masks, seed)
        print(f"| {seed} | {float(v['psf']):.2f} | {est:.2f} | {float(v['px_per_mm']):.1f} | {float(v['fov_rel']):.2f} | "
              f"{'yes' if v['fixture'] else 'no'} | {s['iou']:.3f} | {100 * s['area_total']:+.1f}% | "
              f"{100 * s['area_median']:.1f}% | {s['found']} | {s['false']} | {found:.2f} / {true:.2f} | "
              f"{'yes' if calib.gap_resolved else 'no'} | {_share(calib.edge_disagreement)} | {wall:.0f} |",
              flush=True)
        if args.edges and edges:
            for lo, hi, n, b0, s0, b1, s1 in edge_errors(v, edges, calib.gap.lateral_axis):
                print(f"|   {seed} true width {lo}-{hi} px | {n} rays | e0 {b0:+.3f} (sd {s0:.3f}) | e1 {b1:+.3f} "
                      f"(sd {s1:.3f}) | width {b1 - b0:+.3f} px |", flush=True)


if __name__ == "__main__":
    main()
