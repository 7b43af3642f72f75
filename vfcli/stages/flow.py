"""`vfcli flow`: gap, opening, optical flow (/flow) and the tri-variate field (/fields).

Two stages, written by ONE atomic transaction (both reach the store or neither does), each
reading its inputs from the store, calling one function of :mod:`vfcli.flow.pipeline` (the
science) and writing what it streams back, frame by frame (memory does not grow with the
number of frames):

1. /flow from /hsc: :func:`vfcli.flow.pipeline.flow_pipeline`.
2. /fields from /flow, /sync and /ldv: :func:`vfcli.flow.pipeline.velocity_fields`.

Which ``[flow]`` settings decide that each stage is up to date comes from the config model
(:func:`vfcli.config.fields_shaping`), not from a list kept here.
"""
from __future__ import annotations

import logging
from typing import Any, Iterator

import numpy as np

from vfcli.config import FlowConfig, SyncConfig
from vfcli.errors import ConfigError, InputDataError, MissingStageError
from vfcli.flow.plausibility import (FAR_BEYOND, FOLD_MARGIN_MM, OFF_FOLD_FAIL, OFF_FOLD_WARN, VELOCITY_ORDER,
                                    SCAN_FRAME_ADVICE, area_f0, contrast_block, points_on_folds_of_video,
                                    points_on_image, pressure_velocity_bound, scan_beyond_frames)
from vfcli.flow.pipeline import CHUNK_FRAMES, check_flow_product, flow_pipeline, good_ldv_points, velocity_fields
from vfcli.store import StageWriter, StoreReader, layout
from vfcli.store.frames import FrameSink
from vfcli.store.precision import round_mantissa
from vfcli.stages.base import RunContext, StageResult, StageSpec, run_stages, stage_config_json

log = logging.getLogger(__name__)

#: Stored mantissa bits of /fields/velocity (of 23): a relative error below 1.3e-4, far below the
#: field's own; the stage's largest dataset shrinks by about 40 % (docs/benchmarks.md).
FIELDS_MANTISSA_BITS = 12


def _check_one_cycle(reader: StoreReader, n_frames: int, fps_hz: float) -> None:
    """Refuse a video shorter than one glottal cycle at /sync's f0 (a 2-frame video ran through to a
    "converged" fit of 2 % of a cycle, with a stated uncertainty of 10 %). Nothing is checked without /sync's f0."""
    f0 = float(reader.attrs("sync").get("f0_video_hz", np.nan)) if reader.has_stage("sync") else np.nan
    if np.isfinite(f0) and f0 > 0 and n_frames / fps_hz * f0 < 1.0:
        raise InputDataError(
            f"the video holds {n_frames} frames ({1e3 * n_frames / fps_hz:.3g} ms), less than one glottal cycle "
            f"({1e3 / f0:.3g} ms at /sync's f0 {f0:.4g} Hz): the gap, the flow and the fit need at least one whole "
            "cycle; record a longer video (or widen ingest_hsc's frame range)", reader.path)


def _check_area_rhythm(reader: StoreReader, area: np.ndarray, fps_hz: float, sync: SyncConfig) -> None:
    """Warn when the glottal area repeats at another frequency than the pressure beside the video (/sync's
    f0), beyond sync.max_drift: the video's frame rate is wrong (a CIHX recordRate of 20000 for 10000 ran to
    an inferior surface 26 % off with no word about it). Nothing is checked without /sync's f0."""
    f0 = float(reader.attrs("sync").get("f0_video_hz", np.nan)) if reader.has_stage("sync") else np.nan
    fa = area_f0(area, fps_hz, (sync.f0_min_hz, sync.f0_max_hz), f0)
    if fa is not None and abs(fa / f0 - 1.0) > sync.max_drift:
        log.warning("flow: the glottal area repeats at %.4g Hz on the video's time base (%.6g frames/s), the pressure "
                    "beside the video at %.4g Hz (/sync's f0); the folds open once per cycle of the pressure, so the "
                    "video's frame rate is likely wrong by a factor of %.3g: check the frame rate the video file "
                    "states (or camera.fps_hz), then rerun ingest-hsc", fa, fps_hz, f0, fa / f0)


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
    _check_one_cycle(reader, n, fps)
    rotation = float(hsc.get("rotation_deg", 0.0))
    frame_time = reader.read("hsc", "frame_time")
    calib, stream = flow_pipeline(frames, cfg, fps=fps, px_per_mm=px_per_mm, rotation_deg=rotation,
                                  t0_s=float(frame_time[0]), axis_from_gap=ctx.config.camera.pose == "estimate")
    ds_mask = FrameSink(s.create("gap_mask", (n, h, w), bool))
    ds_open = FrameSink(s.create("opening", (n, h, w), np.float32))
    ds_flow = FrameSink(s.create("flow", (n, h, w, 2), np.float32))
    area = np.zeros(n)
    gap_counts = np.zeros((h, w), np.int32)
    bar = ctx.progress(total=n, desc="flow", unit="frame")
    for fr in stream:
        k = fr.index
        ds_mask[k] = fr.mask
        gap_counts += fr.mask
        ds_open[k] = fr.opening_px / np.float32(px_per_mm)
        ds_flow[k] = fr.velocity_mm_s
        area[k] = fr.area_mm2
        bar.update(1)
    bar.close()
    try:
        check_flow_product(area, calib, gap_counts, ctx.config.mesh.length_mm * px_per_mm)
    except InputDataError as exc:
        raise InputDataError(str(exc), reader.path) from None
    _check_area_rhythm(reader, area, fps, ctx.config.sync)
    s.put("glottal_area", area)
    s.put("frame_time", frame_time)
    model, gap = calib.edge_model, calib.gap
    surround = 0.0 if calib.surround is None else float(calib.surround.mean())
    s.set_attrs(
        threshold_counts=calib.threshold,
        threshold_auto=calib.auto,
        method=cfg.method,
        split_folds=cfg.split_folds,
        counts_range=np.asarray(calib.counts_range),
        lateral_axis=calib.lateral_axis,
        midline_px=np.nan if calib.midline is None else calib.midline,
        fps_hz=fps,
        px_per_mm=px_per_mm,
        rotation_deg=rotation,
        offset_px=np.asarray(hsc.get("offset_px", (0.0, 0.0)), dtype=float),
        roi_origin_px=np.asarray(hsc.get("roi_px", (0, 0, 0, 0)), dtype=float)[:2],
        subpixel_edges=gap is not None,
        gap_level_counts=np.nan if model is None else model.gap_counts,
        psf_sigma_px=np.nan if model is None else model.psf_sigma_px,
        gap_level_resolved=calib.gap_resolved,
        edge_disagreement=calib.edge_disagreement,
        level_disagreement=calib.level_disagreement,
        median_along_slit=calib.median_along_slit,
        surround_fraction=surround,
        edge_window_px=np.nan if gap is None else float(gap.half_window_px),
        edge_window_frames=-1 if gap is None else int(gap.half_window_frames),
    )
    return {
        "frames": n,
        "threshold_counts": round(calib.threshold, 1),
        "threshold": "auto" if calib.auto else "config",
        "method": cfg.method,
        "psf_sigma_px": None if model is None else round(model.psf_sigma_px, 3),
        "gap_resolved": calib.gap_resolved,
        "edge_disagreement": (None if not np.isfinite(calib.edge_disagreement)
                              else round(calib.edge_disagreement, 4)),
        "level_disagreement": (None if not np.isfinite(calib.level_disagreement)
                               else round(calib.level_disagreement, 4)),
        "surround_fraction": round(surround, 3),
        "open_frames": int((area > 0).sum()),
        "max_area_mm2": round(float(area.max()), 3),
    }


def _ldv_points(reader: StoreReader, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
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
    try:
        return coords, good_ldv_points(ok, dropout, finite)
    except InputDataError as exc:
        raise InputDataError(str(exc), reader.path) from None


def _check_fields(reader: StoreReader, points_px: np.ndarray, good: np.ndarray, shape: tuple[int, int],
                  px_per_mm: float, speed_p99: float, rms_vertical: float = np.nan, rms_horizontal: float = np.nan) -> None:
    """The LDV points the spline uses lie on the frames (none: exit 3), the field's speeds (largest chunk's 99th
    percentile, mm/s) are within what the recorded pressure can drive, and its vertical velocity (the
    vibrometer's, RMS mm/s) is of the order of its horizontal one (the video's): VELOCITY_ORDER."""
    on = points_on_image(points_px[good], shape)
    if not on.any():
        raise InputDataError(f"fields: none of the {int(good.sum())} LDV points the spline uses lies on the "
                             f"{shape[1]} x {shape[0]} px frames; {SCAN_FRAME_ADVICE}, then rerun ingest-ldv",
                             reader.path)
    if not on.all():
        log.warning("fields: %d of %d LDV points the spline uses lie outside the frames, where the video cannot show "
                    "that they are on the folds (the spline uses them for the field inside): %s",
                    int((~on).sum()), len(on), scan_beyond_frames(points_px[good], shape, px_per_mm))
    _check_on_folds(reader, points_px[good][on], shape)
    if reader.has_stage("hsc") and "pressure" in reader.group("hsc"):
        bound = pressure_velocity_bound(reader.read("hsc", "pressure"))
        if np.isfinite(bound) and speed_p99 > FAR_BEYOND * bound:
            log.warning("fields: surface speeds reach %.0f mm/s (99th percentile), far beyond the %.0f mm/s the "
                        "recorded pressure can drive; check ingest_ldv.length_unit and the vibrometer's velocity unit, "
                        "camera.px_per_mm and camera.fps_hz, and the pressure's unit (a WAV's: "
                        "ingest_hsc.wav_full_scale_pa)", speed_p99, bound)
    if rms_vertical > 0 and rms_horizontal > 0 and not (
            1 / VELOCITY_ORDER <= rms_vertical / rms_horizontal <= VELOCITY_ORDER):
        log.warning("fields: the vibrometer's vertical velocity (RMS %.3g mm/s where the fields are valid) is %.2g "
                    "times the video's horizontal velocity (RMS %.3g mm/s), where the superior surface moves by the "
                    "same order both ways: check the velocity unit of the vibrometer's file (m/s against mm/s), "
                    "camera.px_per_mm and camera.fps_hz", rms_vertical, rms_vertical / rms_horizontal, rms_horizontal)


def _check_on_folds(reader: StoreReader, points_px: np.ndarray, shape: tuple[int, int]) -> None:
    """The LDV points (P, 2) px on the frames lie on the folds, i.e. near pixels that move in the video
    (:func:`vfcli.flow.plausibility.points_on_folds_of_video`); warn when more than OFF_FOLD_WARN of them do
    not, fail (exit 3) when more than OFF_FOLD_FAIL do not. Needs /hsc/frames of ``shape`` holding at
    least one phonation cycle (at /sync's f0_video_hz: a shorter video does not show where the folds
    move) and 2 blocks of frames; otherwise nothing is checked."""
    if not reader.has_stage("hsc") or "frames" not in reader.group("hsc") or len(points_px) == 0:
        return
    frames = reader.frames("hsc", "frames")
    hsc = reader.attrs("hsc")
    f0 = float(reader.attrs("sync").get("f0_video_hz", np.nan))
    if tuple(frames.shape[1:]) != tuple(shape) or not len(frames) / float(hsc["fps_hz"]) * f0 >= 1.0:
        return
    chunks = (frames[i : i + CHUNK_FRAMES] for i in range(0, len(frames), CHUNK_FRAMES))
    block = contrast_block(float(hsc["fps_hz"]) / f0)
    on = points_on_folds_of_video(chunks, points_px, float(hsc["px_per_mm"]), block)
    if on is None:
        return
    off = int((~on).sum())
    if off <= OFF_FOLD_WARN * len(on):
        return
    what = (f"{off} of the {len(on)} LDV points the spline uses on the frames lie off the folds (no pixel "
            f"within {FOLD_MARGIN_MM} mm of them moves in the video: the fixture, the silicone around the folds "
            "or the background)")
    advice = ("check ldv_frame.affine (scan to camera mm), ingest_ldv.length_unit and camera.px_per_mm, "
              "then rerun ingest-ldv")
    if off > OFF_FOLD_FAIL * len(on):
        raise InputDataError(f"fields: {what}; {advice}", reader.path)
    log.warning("fields: %s; their vertical velocity is not the folds'; %s", what, advice)


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
    coords, good = _ldv_points(reader, n)
    # LDV coordinates are camera-frame mm: full-frame pixel / px_per_mm (docs/conventions.md)
    points_px = coords[:, :2] * float(fl["px_per_mm"]) - np.asarray(fl.get("roi_origin_px", (0.0, 0.0)), float)
    aligned = reader.dataset("sync", "aligned_w")

    def chunks() -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        for i in range(0, n, CHUNK_FRAMES):
            j = min(i + CHUNK_FRAMES, n)
            yield ds_flow[i:j], ds_gap[i:j], aligned[:, i:j]

    ds_vel = FrameSink(s.create("velocity", (n, h, w, 3), np.float32, attrs={"mantissa_bits": FIELDS_MANTISSA_BITS}))
    ds_valid = FrameSink(s.create("valid", (n, h, w), bool))
    n_valid = i = 0
    speed_p99 = 0.0
    sum_sq = np.zeros(2)                 # vertical, horizontal squared speeds over the valid pixels
    bar = ctx.progress(total=n, desc="fields", unit="frame")
    for field, valid in velocity_fields(chunks(), points_px, good, (h, w), cfg):
        j = i + len(field)
        ds_vel[i:j] = round_mantissa(field.astype(np.float32, copy=False), FIELDS_MANTISSA_BITS)
        ds_valid[i:j] = valid
        n_valid += int(valid.sum())
        if valid.any():
            v = field[valid].astype(float)
            speed_p99 = max(speed_p99, float(np.percentile(np.linalg.norm(v, axis=-1), 99)))
            sum_sq += np.nansum(v[:, 2] ** 2), np.nansum(v[:, 0] ** 2 + v[:, 1] ** 2)
        bar.update(j - i)
        i = j
    bar.close()
    rms = np.sqrt(sum_sq / max(n_valid, 1))
    _check_fields(reader, points_px, good, (h, w), float(fl["px_per_mm"]), speed_p99, float(rms[0]), float(rms[1]))
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
    """Write /flow (from /hsc) then /fields (from /flow, /sync, /ldv), each unless up to date,
    in one transaction.

    Returns
    -------
    [StageResult of /flow, StageResult of /fields]
    """
    cfg = ctx.config.flow
    if cfg.median_px % 2 == 0:
        raise ConfigError(f"flow.median_px = {cfg.median_px}: must be odd")
    if not ctx.store.exists():
        raise MissingStageError("stage /hsc is missing; run `vfcli ingest-hsc` first", ctx.store.path)
    with ctx.store.read() as r:  # fail before the long flow step when /fields could not be written
        r.upstream_digests([("hsc", None), ("sync", None), ("ldv", None)])
    return run_stages(ctx, [
        StageSpec("flow", stage_config_json("flow", ctx.config), lambda r, s: _write_flow(ctx, cfg, r, s),
                  upstream=[("hsc", None)]),
        StageSpec("fields", stage_config_json("fields", ctx.config), lambda r, s: _write_fields(ctx, cfg, r, s),
                  upstream=[("flow", None), ("sync", None), ("ldv", None)]),
    ])
