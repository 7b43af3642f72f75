"""`vfcli ingest-hsc` and `vfcli ingest-ldv`: the instruments' files into the store."""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.calibration import WAV_FULL_SCALE, calibration_warnings, default_calibration
from vfcli.config import SyncConfig
from vfcli.errors import ConfigError, InputDataError
from vfcli.flow.plausibility import SCAN_FRAME_ADVICE, points_on_image, scan_beyond_frames
from vfcli.store.chunks import NBIT_BITS, ValueRangeError
from vfcli.io.ldv.read import LdvChannels, LdvScan, read_ldv
from vfcli.io.pressure import PA_PER_UNIT, Transducer, read_pressure
from vfcli.io.pressure.record import is_voltage_unit
from vfcli.io.pressure.plausibility import check_pressure_rate, pressure_unit_warnings
from vfcli.io.video.base import VideoMeta, open_video
from vfcli.store import StageWriter, StoreReader
from vfcli.stages.base import RunContext, StageResult, run_stage, stage_config_json

log = logging.getLogger(__name__)

_PHOTRON_SUFFIXES = (".mraw", ".cih", ".cihx")


def video_files(video: Path) -> list[Path]:
    """The files a video consists of (an MRAW and its CIH/CIHX travel together)."""
    if video.suffix.lower() in _PHOTRON_SUFFIXES:
        return sorted(p for s in _PHOTRON_SUFFIXES for p in [video.with_suffix(s)] if p.exists())
    return [video]


def _roi_rows_cols(roi_px: tuple[int, int, int, int] | None) -> tuple[int, int, int, int] | None:
    if roi_px is None:
        return None
    col0, row0, width, height = roi_px
    return row0, row0 + height, col0, col0 + width


def frame_filter(compression: str, meta: VideoMeta) -> str:
    """The frame filter (:data:`vfcli.store.frames.COMPRESSIONS`) for ``ingest_hsc.compression``.

    Parameters
    ----------
    compression : str
        The config value: "auto" or a filter name.
    meta : VideoMeta
        The source video's metadata.

    Returns
    -------
    str
        "auto": "nbit" when the file stores its pixels packed in 12 bits (12-bit MRAW), its
        own storage (frames copied as stored, not decoded, not compressed), else "gzip".
        Any other value as it is.

    Raises
    ------
    ConfigError
        "nbit" for a video of 8-bit frames (N-bit stores 12-bit values in uint16 only).
    """
    if compression == "auto":
        return "nbit" if meta.packed_bits == NBIT_BITS else "gzip"
    if compression == "nbit" and np.dtype(meta.dtype) != np.uint16:
        raise ConfigError(f"{meta.path}: ingest_hsc.compression = 'nbit' stores {NBIT_BITS}-bit pixels in uint16 "
                          f"only, this video has {np.dtype(meta.dtype)} frames; use 'auto' or 'gzip'")
    return compression


def run_ingest_hsc(ctx: RunContext, video: str | Path, pressure: str | Path | None = None) -> StageResult:
    """Stream the video into /hsc (unchanged bit depth, one frame per chunk) with its pressure."""
    cfg, cam = ctx.config.ingest_hsc, ctx.config.camera
    video = Path(video)
    inputs = video_files(video) + ([Path(pressure)] if pressure else [])
    config_json = stage_config_json("hsc", ctx.config)

    def body(_reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        with open_video(video) as src:
            meta = src.meta
            fps = cam.fps_hz or meta.fps
            if fps is None:
                raise ConfigError(f"{video}: {meta.fps_note or 'the video does not record its frame rate'}; "
                                  "set camera.fps_hz in the config")
            if cam.fps_hz and meta.fps and abs(cam.fps_hz - meta.fps) > 1e-6 * meta.fps:
                log.warning("%s: camera.fps_hz = %g overrides the file's %g", video, cam.fps_hz, meta.fps)
            start = cfg.first_frame
            stop = meta.n_frames if cfg.n_frames is None else start + cfg.n_frames
            if stop > meta.n_frames or start >= meta.n_frames:
                raise ConfigError(
                    f"{video}: ingest_hsc frame range {start}..{stop} is outside the video's {meta.n_frames} frames"
                )
            roi = _roi_rows_cols(cfg.roi_px)
            h, w = (meta.height, meta.width) if roi is None else (roi[1] - roi[0], roi[3] - roi[2])
            n = stop - start
            compression = frame_filter(cfg.compression, meta)
            bar = ctx.progress(total=n, desc="ingest-hsc", unit="frame")
            try:
                s.write_frames("frames", (n, h, w), meta.dtype, src.iter_lazy_frames(start, stop, roi),
                               attrs={"bit_depth": meta.bit_depth, "compression": compression},
                               compression=compression, on_frames=bar.update)
            except ValueRangeError as exc:
                raise InputDataError(
                    f"frame {start + exc.frame} holds the value {exc.value}, more than the {exc.bits} bits "
                    f"ingest_hsc.compression = 'nbit' keeps (0..{2**exc.bits - 1}); use 'gzip'", meta.path) from None
            finally:
                bar.close()
            s.put("frame_time", np.arange(n) / fps)
            s.set_attrs(
                fps_hz=fps,
                n_frames=n,
                first_frame=start,
                trigger_time_s=(meta.start_frame + start) / fps,
                bit_depth=meta.bit_depth,
                px_per_mm=cam.px_per_mm,
                rotation_deg=cam.rotation_deg,
                offset_px=np.asarray(cam.offset_px) - (0 if roi is None else np.array([roi[2], roi[0]])),
                roi_px=np.asarray(cfg.roi_px if cfg.roi_px else (0, 0, meta.width, meta.height)),
                source=meta.description or meta.kind,
            )
        summary: dict[str, Any] = {"frames": n, "height": h, "width": w, "fps_hz": fps, "bit_depth": meta.bit_depth,
                                   "compression": compression}
        if pressure is not None:
            transducer = (Transducer(cfg.pressure_pa_per_volt, cfg.pressure_zero_volts)
                          if cfg.pressure_pa_per_volt is not None else None)
            rec = read_pressure(pressure, cfg.pressure_group, cfg.pressure_channel, unit=cfg.pressure_unit,
                                wav_pa_per_full_scale=cfg.wav_full_scale_pa, transducer=transducer)
            check_pressure_rate(rec.fs, ctx.config.sync.f0_max_hz, pressure)
            for line in pressure_unit_warnings(rec):
                log.warning("%s: %s", pressure, line)
            if Path(pressure).suffix.lower() == ".wav" and default_calibration(
                    ctx.stored_config, ctx.config, [WAV_FULL_SCALE]):
                log.warning("%s: a WAV states no unit; its samples were read as %g Pa at digital full scale, "
                            "ingest_hsc.wav_full_scale_pa's default: set your amplifier's calibration with `vfcli "
                            "config %s --set ingest_hsc.wav_full_scale_pa=VALUE` (or in recording.toml), then rerun",
                            pressure, cfg.wav_full_scale_pa, ctx.store.path)
            t = rec.t0 + np.arange(rec.samples.size) / rec.fs - start / fps
            duration = n / fps
            if t[0] > 0 or t[-1] < duration - 1 / fps:
                log.warning("%s: pressure covers %.4f..%.4f s, the video 0..%.4f s", pressure, t[0], t[-1], duration)
            volts = is_voltage_unit(rec.unit)
            s.put("pressure", rec.samples, attrs={"fs_hz": rec.fs, "unit_in_file": rec.unit, "unit_source": rec.unit_source,
                                                  "source": rec.source,
                                                  **({"pa_per_volt": transducer.pa_per_volt,
                                                      "zero_volts": transducer.zero_volts} if volts else {})})
            s.put("pressure_time", t)
            s.set_attrs(pressure_fs_hz=rec.fs)
            summary["pressure_samples"] = int(rec.samples.size)
        return summary

    result = run_stage(ctx, "hsc", config_json=config_json, body=body, input_paths=inputs)
    for line in calibration_warnings(ctx.stored_config, ctx.config, ctx.store.path):
        log.warning(line)  # after the write: a failed ingest prints its error alone
    return result


def _to_camera_frame(coords_mm: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """Scan coordinates (mm, the reader converts the file's unit) to the camera frame (2x3 affine on x, y)."""
    xy = coords_mm[:, :2] @ affine[:, :2].T + affine[:, 2]
    return np.column_stack([xy, coords_mm[:, 2]])


def _check_on_image(reader: StoreReader, coords_mm: np.ndarray, scan_path: str | Path) -> None:
    """Fail when no scan point lies on the ingested video's frames, warn when some do not (needs /hsc)."""
    if not reader.has_stage("hsc"):
        return
    hsc = reader.attrs("hsc")
    shape = tuple(int(v) for v in reader.dataset("hsc", "frames").shape[1:])
    roi = np.asarray(hsc.get("roi_px", (0, 0, 0, 0)), float)[:2]
    px = coords_mm[:, :2] * float(hsc["px_per_mm"]) - roi   # camera-frame mm -> stored pixel grid
    on = points_on_image(px, shape)
    if on.any() and on.all():
        return
    if not on.any():
        where = (f"(col, row) {np.nanmin(px[:, 0]):.0f}..{np.nanmax(px[:, 0]):.0f}, "
                 f"{np.nanmin(px[:, 1]):.0f}..{np.nanmax(px[:, 1]):.0f} px on {shape[1]} x {shape[0]} px frames")
        raise InputDataError(f"none of the {len(on)} scan points lies on the video's frames, {where}; "
                             f"{SCAN_FRAME_ADVICE}", scan_path)
    log.warning("ingest-ldv: %d of %d scan points lie outside the video's frames: %s", int((~on).sum()), len(on),
                scan_beyond_frames(px, shape, float(hsc["px_per_mm"])))


def _check_rate_against_video(reader: StoreReader, scan: LdvScan, sync_cfg: SyncConfig,
                              scan_path: str | Path) -> None:
    """Refuse a scan whose stated sampling rate the video's pressure contradicts (needs /hsc/pressure).

    The video's f0 comes from /hsc/pressure; a video pressure that gives none, or whose own f0 the
    scan's f0 explains clearly better (:func:`vfcli.sync.rate.scan_explains_video`: a record too short
    for an f0 of its own), is left for `vfcli sync` to report (this is the scan's stage).
    """
    if not reader.has_stage("hsc") or "pressure" not in reader.group("hsc"):
        return
    from vfcli.sync.f0 import estimate_f0        # scipy: imported only when there is a rate to check
    from vfcli.sync.rate import check_ldv_rate, scan_explains_video, scan_f0

    f_range = (sync_cfg.f0_min_hz, sync_cfg.f0_max_hz)
    video_pressure = reader.read("hsc", "pressure")
    fs_video = float(reader.attrs("hsc")["pressure_fs_hz"])
    try:
        f0_video = estimate_f0(video_pressure, fs_video, f_range, source="video pressure")
    except InputDataError:
        return
    f_scan = scan_f0(scan.reference, scan.fs, f_range, sync_cfg.max_drift)
    if f_scan is not None and scan_explains_video(video_pressure, fs_video, f0_video, f_scan, sync_cfg.n_harmonics):
        return   # the video's own f0 is a harmonic of a record too short for one: sync searches it near the scan's
    check_ldv_rate(f0_video, scan.reference, scan.fs, f_range=f_range, max_drift=sync_cfg.max_drift, source=scan_path)


def run_ingest_ldv(ctx: RunContext, scan_path: str | Path) -> StageResult:
    """Read a vibrometer scan into /ldv, points by node number, dropouts flagged."""
    cfg, frame = ctx.config.ingest_ldv, ctx.config.ldv_frame
    config_json = stage_config_json("ldv", ctx.config)

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        channels = LdvChannels(velocity_id1=cfg.velocity_id1, velocity_id2=cfg.velocity_id2,
                               reference_id1=cfg.reference_id1, reference_id2=cfg.reference_id2)
        scan = read_ldv(scan_path, channels, expected_grid=(cfg.grid_rows, cfg.grid_cols),
                        velocity_unit=cfg.velocity_unit, length_unit=cfg.length_unit)
        if scan.reference is None:
            raise InputDataError("the scan has no reference (pressure) channel; sync needs it", scan_path)
        expected = cfg.grid_rows * cfg.grid_cols
        cells = (np.unique(scan.grid_index[:, 0] * cfg.grid_cols + scan.grid_index[:, 1]).size
                 if scan.grid_index is not None else 0)
        if scan.grid_shape != (cfg.grid_rows, cfg.grid_cols):
            found = "x".join(map(str, scan.grid_shape)) if scan.grid_shape else "no regular grid"
            raise InputDataError(
                f"found {scan.n_points} scan points ({found}), expected a {cfg.grid_rows} x {cfg.grid_cols} scan "
                f"of {expected}; set ingest_ldv.grid_rows/grid_cols for another rig", scan_path)
        if cells != scan.n_points:             # (so at most one point per cell: no more than the grid holds)
            raise InputDataError(
                f"the {scan.n_points} scan points fill only {cells} cells of their {cfg.grid_rows} x {cfg.grid_cols} "
                "grid: some lie closer together than half the grid's spacing, which a regular scan grid does not; "
                "check the file's coordinates", scan_path)
        if scan.n_points < expected:
            # points deselected in the vibrometer's software (off the sample, or failed) are left out of its export:
            # sync, fields and optimize use the points there are (refused until session 69)
            log.warning("%s: %d of the %d x %d scan grid's points are not in the file (deselected or not exported); "
                        "the other %d are used", scan_path, expected - scan.n_points, cfg.grid_rows, cfg.grid_cols,
                        scan.n_points)
        for note in scan.notes:
            log.warning("%s: %s", scan_path, note)
        ref_unit = scan.reference_unit or "V"
        key = ref_unit.replace(" ", "").lower()
        ref, ref_units = scan.reference, ref_unit
        if key in PA_PER_UNIT:
            ref, ref_units = scan.reference * PA_PER_UNIT[key], "Pa"
        _check_rate_against_video(reader, scan, ctx.config.sync, scan_path)
        coords = _to_camera_frame(scan.coords_mm, np.asarray(frame.affine))
        _check_on_image(reader, coords, scan_path)
        s.put("node_id", scan.node_ids)
        s.put("grid_index", scan.grid_index if scan.grid_index is not None else np.full((scan.n_points, 2), -1))
        s.put("coords_mm", coords)
        s.put("velocity", scan.velocity_mm_s.astype(np.float32), attrs={"fs_hz": scan.fs})
        s.put("reference", ref.astype(np.float32), units=ref_units, attrs={"fs_hz": scan.fs})
        s.put("epoch_t0", scan.t0 if scan.t0 is not None else np.zeros(scan.n_points))
        s.put("dropout", scan.dropout)
        s.put("dropout_reason", np.array(scan.dropout_reasons, dtype=object))
        s.set_attrs(fs_hz=scan.fs, source=scan.source, notes=json.dumps(scan.notes),
                    grid_shape=np.asarray(scan.grid_shape or (0, 0)))
        return {
            "points": scan.n_points,
            "grid": "x".join(map(str, scan.grid_shape)) if scan.grid_shape else "irregular",
            "samples": scan.n_samples,
            "fs_hz": scan.fs,
            "dropouts": int(scan.dropout.sum()),
            "notes": scan.notes,
        }

    return run_stage(ctx, "ldv", config_json=config_json, body=body, input_paths=[scan_path])
