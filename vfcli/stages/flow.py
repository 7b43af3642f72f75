"""`vfcli flow`: gap, opening, optical flow (/flow) and the tri-variate field (/fields).

Two stages, each written by its own atomic transaction:

1. /flow from /hsc: the video is streamed through :func:`vfcli.flow.optical_flow.flow_stream`
   (gap mask, glottal area, opening function, horizontal velocity at the frame times);
   every frame is written as soon as it is computed, so memory does not grow with the
   number of frames. The gap threshold (unless ``flow.threshold`` is set), the 8-bit
   intensity range, the glottal midline and, for the sub-pixel gap edges
   (``flow.subpixel_edges``, :func:`vfcli.flow.gap.subpixel.segment_stream`), the gap level and the
   blur of the optics (:func:`vfcli.flow.gap.subpixel.estimate_edge_model`) come from
   ``flow.sample_frames`` frames spread evenly over the video.
2. /fields from /flow, /sync and /ldv: the synced LDV velocities (good points: aligned
   and free of dropouts) are spread over the pixel grid by the fixed thin-plate-spline
   operator of :class:`vfcli.flow.velocity_field.LdvTps` and stacked with the flow into (u, v, w),
   a chunk of frames at a time.

The lateral image axis (the rays of the opening function, the gap's midline search) is
the one the model's y axis is closest to: rows when ``|cos(rotation)| >= |sin(rotation)|``
(``[col, row] = px_per_mm * R(rotation) @ [x, y] + offset``, so y maps to
``(-sin, cos)`` in (col, row)), else columns.
"""
from __future__ import annotations

import json
import logging
from typing import Any, Iterator

import numpy as np

from vfcli.store import layout
from vfcli.config import FlowConfig
from vfcli.errors import ConfigError, InputDataError, MissingStageError
from vfcli.flow.velocity_field import LdvTps, combine_fields, hull_mask
from vfcli.flow.gap.detect import gap_mask, gap_threshold, midline_from_masks
from vfcli.flow.gap.subpixel import SubpixelGap, estimate_edge_model
from vfcli.flow.optical_flow import FlowEstimator, flow_stream, intensity_range
from vfcli.store import FrameReader, StageWriter, StoreReader
from vfcli.stages.base import RunContext, StageResult, run_stage

log = logging.getLogger(__name__)

#: Frames read from the store at once (video batches, field chunks).
CHUNK_FRAMES = 16

#: A sampled gap covering more than this fraction of the image is implausible (a slit).
MAX_GAP_FRACTION = 0.05

#: FlowConfig fields that shape /flow (the others only shape /fields).
_FLOW_FIELDS = ("method", "threshold", "median_px", "sample_frames", "split_folds", "grid_step", "dis_preset",
                "subpixel_edges", "edge_window_mm", "edge_window_ms")
_FIELDS_FIELDS = ("rbf_smoothing", "w_inside_hull")


def lateral_axis_for(rotation_deg: float) -> int:
    """Image axis that is lateral for a camera rotation: 0 (rows) or 1 (columns).

    Parameters
    ----------
    rotation_deg : float
        Camera model rotation, degrees (``docs/conventions.md``).

    Returns
    -------
    int
        0 when the model's y axis is closer to the row axis (``|cos| >= |sin|``), else 1.
    """
    th = np.deg2rad(rotation_deg)
    return 0 if abs(np.cos(th)) >= abs(np.sin(th)) - 1e-12 else 1


def sample_indices(n_frames: int, n_sample: int) -> np.ndarray:
    """Up to ``n_sample`` frame indices spread evenly over ``n_frames``, increasing, unique."""
    k = max(1, min(int(n_sample), int(n_frames)))
    return np.unique(np.rint(np.linspace(0, n_frames - 1, k)).astype(int))


def _batches(frames_ds: FrameReader, n_frames: int) -> Iterator[np.ndarray]:
    """Frames 0..n_frames-1 of the video, (<= CHUNK_FRAMES, H, W) at a time."""
    for i in range(0, n_frames, CHUNK_FRAMES):
        yield frames_ds[i : i + CHUNK_FRAMES]


def _config_json(cfg: FlowConfig, keys: tuple[str, ...]) -> str:
    return json.dumps({"flow": cfg.model_dump(mode="json", include=set(keys))}, sort_keys=True)


def _check_sampled_gap(masks: np.ndarray, threshold: float, auto: bool) -> None:
    """Warn when the gap masks of the sampled frames (k, H, W) bool do not look like a glottis.

    The folds close in every cycle and the gap is a slit: a "gap" in every sampled frame
    or one covering more than :data:`MAX_GAP_FRACTION` of the image is more likely a dark
    fixture, shadow or texture below the threshold.
    """
    how = "automatic" if auto else "configured"
    open_share = float(masks.any(axis=(1, 2)).mean())
    area_share = float(masks.mean())
    if open_share == 0:
        log.warning("flow: no glottal gap in the %d sampled frames (%s threshold %.1f counts); "
                    "set flow.threshold if the glottis opens", len(masks), how, threshold)
    elif len(masks) >= 8 and (open_share == 1 or area_share > MAX_GAP_FRACTION):
        log.warning("flow: the %s threshold %.1f counts finds a gap in %.0f%% of the %d sampled frames, covering "
                    "%.1f%% of the image on average; the folds close every cycle and the gap is a slit, so it "
                    "probably segments a dark fixture, shadow or texture: set flow.threshold (counts) by hand",
                    how, threshold, 100 * open_share, len(masks), 100 * area_share)


def _write_flow(ctx: RunContext, cfg: FlowConfig, reader: StoreReader, s: StageWriter) -> dict[str, Any]:
    """Body of /flow: stream /hsc frames through the flow step, one frame at a time."""
    hsc = reader.attrs("hsc")
    frames = reader.frames("hsc", "frames")   # N-bit frames unpacked by numpy, not libhdf5
    if frames.ndim != 3 or frames.shape[0] < 2:
        raise InputDataError(
            f"{layout.dataset_path('hsc', 'frames')} has shape {frames.shape}; the flow needs at least 2 frames",
            reader.path,
        )
    n, h, w = (int(v) for v in frames.shape)
    fps, px_per_mm = float(hsc["fps_hz"]), float(hsc["px_per_mm"])
    rotation = float(hsc.get("rotation_deg", 0.0))
    offset = np.asarray(hsc.get("offset_px", (0.0, 0.0)), dtype=float)
    frame_time = reader.read("hsc", "frame_time")
    lateral = lateral_axis_for(rotation)

    sample = frames[sample_indices(n, cfg.sample_frames)]
    auto = cfg.threshold is None
    threshold = float(gap_threshold(sample)) if auto else float(cfg.threshold)
    counts_range = intensity_range(sample)
    masks = np.stack([gap_mask(f, threshold, cfg.median_px, lateral_axis=lateral) for f in sample])
    _check_sampled_gap(masks, threshold, auto)
    centre = midline_from_masks(masks, lateral)
    seen = np.isfinite(centre)
    midline = float(np.median(centre[seen])) if seen.any() else None
    gap, model = None, None
    if cfg.subpixel_edges:
        model = estimate_edge_model(sample, masks, lateral)
        if model is None:
            log.warning("flow: the %d sampled frames show no gap wide enough to measure the gap level and blur "
                        "on; using the binary gap mask (pixel edges)", len(sample))
        else:
            gap = SubpixelGap(threshold, model, cfg.median_px, midline, lateral,
                              half_window_px=cfg.edge_window_mm * px_per_mm,
                              half_window_frames=int(round(cfg.edge_window_ms * 1e-3 * fps)))
    del sample, masks

    estimator = FlowEstimator(cfg.method, grid_step=cfg.grid_step, dis_preset=cfg.dis_preset)
    ds_mask = s.create("gap_mask", (n, h, w), bool)
    ds_open = s.create("opening", (n, h, w), np.float32)
    ds_flow = s.create("flow", (n, h, w, 2), np.float32)
    area = np.zeros(n)
    bar = ctx.progress(total=n, desc="flow", unit="frame")
    stream = flow_stream(
        _batches(frames, n), fps=fps, px_per_mm=px_per_mm, threshold=threshold, counts_range=counts_range,
        median_px=cfg.median_px, rotation_deg=rotation, lateral_axis=lateral,
        initial_center=centre if seen.any() else None, midline=midline, t0_s=float(frame_time[0]),
        estimator=estimator, split_folds=cfg.split_folds, gap=gap,
    )
    for fr in stream:
        k = fr.index
        ds_mask[k] = fr.mask
        ds_open[k] = fr.opening_px / np.float32(px_per_mm)
        ds_flow[k] = fr.velocity_mm_s
        area[k] = fr.area_mm2
        bar.update(1)
    bar.close()
    s.put("glottal_area", area)
    s.put("frame_time", frame_time)
    s.set_attrs(
        threshold_counts=threshold,
        threshold_auto=auto,
        method=cfg.method,
        split_folds=cfg.split_folds,
        counts_range=np.asarray(counts_range),
        lateral_axis=lateral,
        midline_px=np.nan if midline is None else midline,
        fps_hz=fps,
        px_per_mm=px_per_mm,
        rotation_deg=rotation,
        offset_px=offset,
        roi_origin_px=np.asarray(hsc.get("roi_px", (0, 0, 0, 0)), dtype=float)[:2],
        subpixel_edges=gap is not None,
        gap_level_counts=np.nan if model is None else model.gap_counts,
        psf_sigma_px=np.nan if model is None else model.psf_sigma_px,
        edge_window_px=np.nan if gap is None else float(gap.half_window_px),
        edge_window_frames=-1 if gap is None else int(gap.half_window_frames),
    )
    return {
        "frames": n,
        "threshold_counts": round(threshold, 1),
        "threshold": "auto" if auto else "config",
        "method": cfg.method,
        "psf_sigma_px": None if model is None else round(model.psf_sigma_px, 3),
        "open_frames": int((area > 0).sum()),
        "max_area_mm2": round(float(area.max()), 3),
    }


def _good_points(reader: StoreReader, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """LDV coordinates (P, 3) mm and the points the TPS uses (P,) bool."""
    coords = reader.read("ldv", "coords_mm")
    dropout = reader.read("ldv", "dropout").astype(bool)
    ok = reader.read("sync", "ok").astype(bool)
    aligned = reader.dataset("sync", "aligned_w")
    p = len(coords)
    sync_path = layout.stage("sync").group_path()
    if ok.shape != (p,) or dropout.shape != (p,) or tuple(aligned.shape) != (p, n_frames):
        raise MissingStageError(
            f"{sync_path} does not match {layout.stage('ldv').group_path()} and {layout.stage('flow').group_path()} "
            f"({ok.shape[0]} points and aligned_w {tuple(aligned.shape)} for {p} LDV points and {n_frames} frames); "
            "rerun `vfcli sync`",
            reader.path,
        )
    finite = np.ones(p, bool)
    for i in range(0, n_frames, 4096):
        finite &= np.isfinite(aligned[:, i : i + 4096]).all(axis=1)
    good = ok & ~dropout
    if (good & ~finite).any():
        log.warning("fields: %d aligned LDV points have non-finite velocities; left out", int((good & ~finite).sum()))
    good &= finite
    if good.sum() < 3:
        raise InputDataError(
            f"only {int(good.sum())} of {p} LDV points are aligned, finite and free of dropouts; "
            "the thin-plate spline needs at least 3",
            reader.path,
        )
    return coords, good


def _write_fields(ctx: RunContext, cfg: FlowConfig, reader: StoreReader, s: StageWriter) -> dict[str, Any]:
    """Body of /fields: TPS of the synced LDV velocities + the flow, chunk by chunk."""
    fl = reader.attrs("flow")
    ds_gap, ds_flow = reader.dataset("flow", "gap_mask"), reader.dataset("flow", "flow")
    n, h, w = (int(v) for v in ds_gap.shape)
    frame_time = reader.read("flow", "frame_time")
    sync_time = reader.read("sync", "frame_time")
    if sync_time.shape != frame_time.shape or not np.allclose(sync_time, frame_time, rtol=0, atol=1e-9):
        raise MissingStageError(
            f"{layout.stage('sync').group_path()} frame times differ from the video's ({len(sync_time)} vs "
            f"{len(frame_time)} frames); rerun `vfcli sync`",
            reader.path,
        )
    coords, good = _good_points(reader, n)
    # LDV coordinates are camera-frame mm: full-frame pixel / px_per_mm (docs/conventions.md)
    points_px = coords[:, :2] * float(fl["px_per_mm"]) - np.asarray(fl.get("roi_origin_px", (0.0, 0.0)), float)
    tps = LdvTps(points_px, good, smoothing=cfg.rbf_smoothing).fit_grid((h, w))
    inside = hull_mask(points_px[good], (h, w)) if cfg.w_inside_hull else None
    aligned = reader.dataset("sync", "aligned_w")

    ds_vel = s.create("velocity", (n, h, w, 3), np.float32)
    ds_valid = s.create("valid", (n, h, w), bool)
    n_valid = 0
    bar = ctx.progress(total=n, desc="fields", unit="frame")
    for i in range(0, n, CHUNK_FRAMES):
        j = min(i + CHUNK_FRAMES, n)
        w_grid = tps.frames(aligned[:, i:j])
        field, valid = combine_fields(ds_flow[i:j], w_grid, ds_gap[i:j], inside)
        ds_vel[i:j] = field
        ds_valid[i:j] = valid
        n_valid += int(valid.sum())
        bar.update(j - i)
    bar.close()
    s.put("frame_time", frame_time)
    s.put("ldv_px", points_px)
    s.put("ldv_used", good)
    s.set_attrs(rbf_smoothing=cfg.rbf_smoothing, w_inside_hull=cfg.w_inside_hull, n_ldv_used=int(good.sum()))
    return {
        "frames": n,
        "ldv_points_used": int(good.sum()),
        "ldv_points": int(len(good)),
        "valid_fraction": round(n_valid / float(n * h * w), 3),
    }


def run_flow(ctx: RunContext) -> list[StageResult]:
    """Write /flow (from /hsc) then /fields (from /flow, /sync, /ldv), each unless up to date.

    Returns
    -------
    [StageResult of /flow, StageResult of /fields]
    """
    cfg = ctx.config.flow
    if cfg.median_px % 2 == 0:
        raise ConfigError(f"flow.median_px = {cfg.median_px}: must be odd")
    if ctx.store.exists():  # fail before the long flow step when /fields could not be written
        with ctx.store.read() as r:
            r.upstream_digests([("hsc", None), ("sync", None), ("ldv", None)])
    flow = run_stage(ctx, "flow", config_json=_config_json(cfg, _FLOW_FIELDS),
                     body=lambda r, s: _write_flow(ctx, cfg, r, s), upstream=[("hsc", None)])
    fields = run_stage(ctx, "fields", config_json=_config_json(cfg, _FIELDS_FIELDS),
                       body=lambda r, s: _write_fields(ctx, cfg, r, s),
                       upstream=[("flow", None), ("sync", None), ("ldv", None)])
    return [flow, fields]
