"""`vfcli synth OUTDIR`: write a phantom recording's raw files and its truth.h5.

OUTDIR receives what a lab would copy off its instruments, plus the truth:

- ``video.mraw`` + ``video.cihx``: Photron SA-X2 style, 12-bit packed; ``video.tif`` the same
  frames as a multi-page TIFF;
- ``video_pressure.tdms`` and ``video_pressure.csv``: the subglottal pressure beside the video
  (50 kHz, from the first frame);
- ``scan.uff`` (Polytec PSV layout) and ``scan.csv``: the vibrometer scan, one epoch per point
  with its pressure reference channel; coordinates in camera-frame mm (pixel / px_per_mm);
- ``recording.toml``: what the lab knows (frame scale, fold geometry and mounting; with
  ``synth.panel = "widened"`` also the camera rotation in the seeds that state it, docs/synth.md);
- ``truth.h5``: the true motion, the hidden effect and every generator parameter (read by
  tests and benchmarks only; no other command opens it);
- ``phantom.json``: the settings that made the folder (so an unchanged rerun does nothing).

The folder is written under a temporary name and renamed when complete.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from vfcli import __version__
from vfcli.config import RecordingConfig
from vfcli.errors import ConfigError
from vfcli.io.ldv.read import LdvScan
from vfcli.io.ldv.write import write_ldv_csv, write_ldv_uff
from vfcli.io.video.photron import write_mraw
from vfcli.io.pressure import write_pressure_csv, write_pressure_tdms
from vfcli.io.video.base import open_video
from vfcli.io.video.tiff_avi import write_tiff
from vfcli.progress import Phases, Progress, no_progress
from vfcli.store import write_truth
from vfcli.store.frames import FrameSink
from vfcli.store.parts import is_no_room, no_room_error
from vfcli.synth.phantom import Recording, make_recording
from vfcli.stages.base import StageResult

log = logging.getLogger(__name__)

MANIFEST = "phantom.json"


def _lab_config(rec: Recording, cfg: RecordingConfig) -> dict[str, Any]:
    """What the lab knows: frame scale, fold geometry and mounting; not the camera pose or the effect."""
    wide = rec.widened
    mesh = (cfg.mesh if wide is None else wide.lab_mesh(cfg.mesh)).model_dump(mode="json")
    add = rec.truth.adduction_mm
    mesh["offset_y_mm"] = [mesh["offset_y_mm"][0] + add, mesh["offset_y_mm"][1] - add]
    camera: dict[str, Any] = {"px_per_mm": cfg.synth.px_per_mm if wide is None else wide.px_per_mm}
    if wide is not None and wide.rotation_stated:   # measured by the lab in half of the widened seeds
        camera["rotation_deg"] = wide.rotation_deg
        camera["pose"] = "estimate"   # the rotation is known, the origin is not: estimated from the gap
    return {
        "name": f"phantom seed {cfg.synth.seed}",
        "camera": camera,
        "mesh": mesh,
    }


def _write_video(rec: Recording, out: Path, progress: Progress) -> None:
    n = len(rec.frame_times)
    h, w = rec.camera.height, rec.camera.width
    n_nodes = rec.truth.mesh.n_nodes
    with write_truth(out / "truth.h5") as tw:
        disp, vel, screen_v, gap, visible = (FrameSink(tw.create(key, shape, dtype)) for key, shape, dtype in (
            ("frames/displacement", (n, n_nodes, 3), np.float32), ("frames/velocity", (n, n_nodes, 3), np.float32),
            ("screen/velocity", (n, h, w, 3), np.float32), ("screen/gap", (n, h, w), bool),
            ("screen/visible", (n, h, w), bool)))
        area = np.zeros(n)
        bar = progress(total=n, desc="synth: render", unit="frame")

        def frames():
            for i, (image, truth, d, v) in enumerate(rec.frames()):
                disp[i], vel[i] = d, v
                screen_v[i] = truth.velocity
                gap[i], visible[i] = truth.gap, truth.visible
                area[i] = truth.gap_fraction.sum() / rec.camera.px_per_mm**2
                bar.update(1)
                yield image

        write_mraw(out / "video.mraw", frames(), rec.fps_hz, bit_depth=12, comment="vfcli phantom")
        bar.close()
        tw.put("screen/glottal_area", area)
        _write_truth_rest(rec, tw)
    with open_video(out / "video.cihx") as src:
        write_tiff(out / "video.tif", src.iter_frames(), fps=src.meta.fps)


def _write_truth_rest(rec: Recording, tw: Any) -> None:
    t = rec.truth
    for key, arr in t.mesh.to_arrays().items():
        tw.put(f"mesh/{key}", arr)
    tw.put("motion/coeffs_real", t.motion.coeffs.real)
    tw.put("motion/coeffs_imag", t.motion.coeffs.imag)
    tw.put("motion/load_coefficients", t.load_coefficients)
    tw.put("frames/time", rec.frame_times)
    tw.put("frames/phase", rec.frame_phase)
    lt = rec.ldv.truth
    tw.put("ldv/points_model_mm", rec.ldv_points_model_mm)
    tw.put("ldv/points_camera_mm", rec.ldv_points_camera_mm())
    tw.put("ldv/start_phase", lt.start_phase)
    tw.put("ldv/f0_hz", lt.f0_hz)
    tw.put("ldv/sync_offset_s", rec.sync_offset_s())
    tw.put("ldv/dropout_kind", lt.dropout_kind)
    tw.put("ldv/clean_velocity", lt.velocity.astype(np.float32))
    tw.put("pressure/true_pa", rec.pressure.true_pa)
    tw.put("pressure/phase", rec.pressure.phase_cycles)
    tw.set_attrs(
        effect=t.effect, strength=t.strength, adduction_mm=t.adduction_mm,
        camera_px_per_mm=rec.camera.px_per_mm, camera_rotation_deg=rec.camera.rotation_deg,
        camera_offset_px=np.asarray(rec.camera.offset_px), f0_hz=float(np.mean(rec.frame_f0)),
        ldv_noise_std_mm_s=rec.ldv.truth.noise_std,
    )
    if rec.widened is not None:
        tw.set_attrs(panel="widened", **rec.widened.truth_attrs())


def _write_instruments(rec: Recording, out: Path) -> None:
    p = rec.pressure
    fs = 1.0 / (p.t[1] - p.t[0])
    write_pressure_tdms(out / "video_pressure.tdms", p.measured_pa, fs, t0=float(p.t[0]))
    write_pressure_csv(out / "video_pressure.csv", p.measured_pa, fs, t0=float(p.t[0]))
    cam_mm = rec.ldv_points_camera_mm()
    n = len(cam_mm)
    scan = LdvScan(
        node_ids=np.arange(1, n + 1), coords_mm=np.column_stack([cam_mm, np.zeros(n)]),
        velocity_mm_s=rec.ldv.velocity, fs=rec.ldv.fs_hz, reference=rec.ldv.pressure, reference_unit="Pa",
        t0=np.zeros(n), source="vfcli phantom",
    )
    if rec.widened is None or rec.widened.uff_units_record:
        write_ldv_uff(out / "scan.uff", scan)
    else:   # as some exports do: coordinates in mm and no units record (dataset 164)
        write_ldv_uff(out / "scan.uff", scan, length_unit="mm", units_record=False)
    write_ldv_csv(out / "scan.csv", scan)


def run_synth(out_dir: str | Path, cfg: RecordingConfig, *, force: bool = False, progress: Progress = no_progress) -> StageResult:
    """Simulate a phantom and write its files into ``out_dir`` (whole or not at all)."""
    out = Path(out_dir)
    settings = {"vfcli_version": __version__, "synth": cfg.synth.model_dump(mode="json"), "mesh": cfg.mesh.model_dump(mode="json")}
    manifest = out / MANIFEST
    if out.exists() and not force:
        if manifest.exists() and json.loads(manifest.read_text()) == settings:
            return StageResult(str(out), "up-to-date")
        if any(out.iterdir()):
            raise ConfigError(f"{out} exists and holds other files; use --force to replace it")
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    seconds: dict[str, float] = {}
    try:
        # the true motion (mesh, loads, FEM, the hidden effect) takes most of a widened phantom's time and has no
        # steps of its own to count: a bar that names it and its time (-v logs it); the frames have their own bar
        phases = Phases(progress, "synth", 1, log)
        phases("true motion")
        rec = make_recording(cfg.synth, cfg.mesh)
        seconds.update(phases.close())
        phases = Phases(progress, "synth", 1, log)
        phases("render and video files")
        _write_video(rec, tmp, progress)
        phases("instrument files")
        phases.expect(1)
        _write_instruments(rec, tmp)
        seconds.update(phases.close())
        (tmp / "recording.toml").write_text(
            "# What the lab knows about this recording (written by vfcli synth).\n" + tomli_w.dumps(_lab_config(rec, cfg)))
        (tmp / MANIFEST).write_text(json.dumps(settings, indent=2, sort_keys=True) + "\n")
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException as exc:
        written = sum(f.stat().st_size for f in tmp.rglob("*") if f.is_file()) if tmp.is_dir() else 0
        shutil.rmtree(tmp, ignore_errors=True)
        if is_no_room(exc):   # a full disk or a file-size limit: one line, exit 4 (not libhdf5's traceback)
            raise no_room_error(out, written, what=str(out)) from None
        raise
    return StageResult(str(out), "written", {
        "frames": int(rec.frame_times.size),
        "ldv_points": int(rec.ldv.velocity.shape[0]),
        "files": sorted(p.name for p in out.iterdir()),
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
    })
