"""What a fit is made of, read from the store: the inputs of an optimisation run and its problem.

Shared by the stages that build a run's :class:`vfcli.inverse.problem.Problem` from a store
(`optimize` fits it, `diagnose` rebuilds a fitted run's) and by the benchmarks.
"""
from __future__ import annotations

import math

import numpy as np

from vfcli.config import RecordingConfig
from vfcli.errors import ConfigError, InputDataError
from vfcli.inverse.problem import Problem
from vfcli.inverse.setup import OptimizeInputs, Setup, build_problem
from vfcli.model.fem import ElasticModel
from vfcli.parallel import Mapper
from vfcli.store.mesh import read_stored_mesh
from vfcli.store.reader import StoreReader


def video_f0_hz(reader: StoreReader) -> float:
    """The video's f0, Hz: /sync's ``f0_video_hz``; NaN without /sync."""
    return float(reader.attrs("sync").get("f0_video_hz", np.nan)) if reader.has_stage("sync") else float("nan")


def pressure_f0_hz(reader: StoreReader) -> float:
    """f0 of the subglottal pressure, Hz: the median of ``/sync``'s f0 over the vibrometer points it aligned
    (no dropout); NaN without /sync and /ldv.  The glottal cycles are counted with it
    (:func:`vfcli.diagnose.cycles.glottal_cycles`). Here, not in :mod:`vfcli.stages.diagnose`, so that `vfcli run`
    judges whether diagnose can run without importing it (0.7-1 s of a fresh process's start)."""
    if not (reader.has_stage("sync") and reader.has_stage("ldv")):
        return float("nan")
    used = np.asarray(reader.read("sync", "ok"), bool) & ~np.asarray(reader.read("ldv", "dropout"), bool)
    f0 = np.asarray(reader.read("sync", "f0_hz"), float)[used]
    f0 = f0[np.isfinite(f0) & (f0 > 0)]
    return float(np.median(f0)) if f0.size else float("nan")


def window_frames(reader: StoreReader, config: RecordingConfig, frame_interval_s: float) -> int:
    """Frames in the optimize window: ``optimize.n_frames`` when it is set, else one glottal cycle of the
    video, ``ceil(1 / (f0 dt))`` frames (84 at 120 Hz and 10 kHz), f0 the video's: /sync's
    ``f0_video_hz``, or without /sync the f0 of /hsc's pressure (:func:`vfcli.sync.f0.estimate_f0` in
    ``sync.f0_min_hz`` .. ``sync.f0_max_hz``).

    frame_interval_s : dt, the video's frame interval, s.

    Raises
    ------
    ConfigError
        n_frames is not set and the store holds no f0 to count a cycle with.
    """
    n = config.optimize.n_frames
    if n is not None:
        return int(n)
    f0 = video_f0_hz(reader)
    if not (np.isfinite(f0) and f0 > 0) and reader.has_stage("hsc") and "pressure" in reader.group("hsc"):
        from vfcli.sync.f0 import estimate_f0        # scipy: only when /sync has no f0

        sync = config.sync
        try:
            f0 = estimate_f0(reader.read("hsc", "pressure"), float(reader.attrs("hsc")["pressure_fs_hz"]),
                             (sync.f0_min_hz, sync.f0_max_hz), source="/hsc/pressure")
        except InputDataError:
            f0 = float("nan")
    if not (np.isfinite(f0) and f0 > 0 and frame_interval_s > 0):
        raise ConfigError("optimize.n_frames is not set and the recording's f0 (one glottal cycle, the default "
                          "window) cannot be measured: no /sync and no f0 in the video's pressure; set "
                          "optimize.n_frames")
    return max(2, math.ceil(1.0 / (f0 * frame_interval_s) - 1e-6))


def read_optimize_inputs(reader: StoreReader, config: RecordingConfig) -> OptimizeInputs:
    """Everything the run uses, read from the store: /mesh (mesh, material, length), the window
    of /fields and /flow, the camera scale and ROI origin (/flow), the gap counts over the whole
    recording when the pose is estimated, and /hsc's pressure for the pressure load model.

    Raises
    ------
    ConfigError
        The window (optimize.first_frame, optimize.n_frames) runs past the recording.
    InputDataError
        optimize.loads = 'pressure' and /hsc holds no pressure.
    """
    cfg = config.optimize
    stored = read_stored_mesh(reader)
    times_all = reader.read("fields", "frame_time")
    f0 = cfg.first_frame
    n = window_frames(reader, config, float(np.median(np.diff(times_all))) if len(times_all) > 1 else 0.0)
    if f0 + n > len(times_all):
        raise ConfigError(f"optimize window: frames {f0}-{f0 + n - 1} but the recording has {len(times_all)} frames "
                          f"(0-{len(times_all) - 1}); set optimize.first_frame / optimize.n_frames")
    sl = slice(f0, f0 + n)
    flow_attrs = reader.attrs("flow")
    gap_counts = None
    if config.camera.pose == "estimate":
        masks = reader.dataset("flow", "gap_mask")
        gap_counts = np.zeros(masks.shape[1:])
        for i in range(0, masks.shape[0], 64):  # streamed: memory does not grow with the frames
            gap_counts += masks[i:i + 64].sum(axis=0)
    pressure_time = pressure = None
    if cfg.loads == "pressure":
        if not reader.has_stage("hsc") or "pressure" not in reader.group("hsc"):
            raise InputDataError("optimize.loads='pressure' needs the subglottal pressure recorded with the video; "
                                 "ingest it with `vfcli ingest-hsc ... --pressure FILE`", reader.path)
        pressure_time, pressure = reader.read("hsc", "pressure_time"), reader.read("hsc", "pressure")
        _check_pressure_covers(pressure_time, times_all, f0, n)
    return OptimizeInputs(
        mesh=stored.mesh, youngs_modulus_pa=stored.youngs_modulus_pa, poisson_ratio=stored.poisson_ratio,
        density_kg_m3=stored.density_kg_m3, length_mm=stored.length_mm, times=times_all[sl],
        velocity=reader.dataset("fields", "velocity")[sl], valid=reader.dataset("fields", "valid")[sl],
        gap_masks=reader.dataset("flow", "gap_mask")[sl], px_per_mm=float(flow_attrs["px_per_mm"]),
        roi_origin_px=np.asarray(flow_attrs.get("roi_origin_px", (0.0, 0.0)), dtype=float),
        gap_counts=gap_counts, velocity_rotation_deg=float(flow_attrs.get("rotation_deg", 0.0)),
        lateral_axis=int(flow_attrs.get("lateral_axis", 0)), pressure_time=pressure_time, pressure=pressure,
        f0_hz=video_f0_hz(reader))


def _check_pressure_covers(pressure_time: np.ndarray, times_all: np.ndarray, first: int, n: int) -> None:
    """The pressure load acts from the window's first frame to one frame interval past its last (the
    simulation's last step, which gives the last frame its velocity): refuse a window the pressure record
    does not cover, naming the frame it can start or end at (times in s)."""
    dt = float(np.median(np.diff(times_all))) if len(times_all) > 1 else 0.0
    tol = 0.5 * float(np.median(np.diff(pressure_time))) if len(pressure_time) > 1 else 0.0
    window = f"optimize window: frames {first}-{first + n - 1}"
    if times_all[first] < pressure_time[0] - tol:
        start = int(np.searchsorted(times_all, pressure_time[0] - tol))
        raise ConfigError(f"{window} start at {times_all[first]:.6f} s, before /hsc's pressure ({pressure_time[0]:.6f} s "
                          f"on); start it at frame {start} or later (optimize.first_frame)")
    need = times_all[first + n - 1] + dt
    if need <= pressure_time[-1] + tol:
        return
    last = int(np.searchsorted(times_all + dt, pressure_time[-1] + tol, side="right")) - 1
    fix = (f"end it at frame {last} or earlier (optimize.n_frames = {last - first + 1})" if last >= first + 1
           else "move optimize.first_frame earlier")
    raise ConfigError(f"{window} need the pressure up to {need:.6f} s (the simulation runs one frame past the last), "
                      f"but /hsc's pressure ends at {pressure_time[-1]:.6f} s; {fix}")


def configured_pose(config: RecordingConfig) -> tuple[float, tuple[float, float]] | None:
    """The calibrated camera pose (rotation, full-frame offset) when camera.pose = 'config', else None."""
    cam = config.camera
    return (cam.rotation_deg, tuple(cam.offset_px)) if cam.pose == "config" else None


def problem_of_store(reader: StoreReader, config: RecordingConfig, map: Mapper | None = None,
                     lateral_axis: int | None = None) -> tuple[Problem, Setup]:
    """The optimisation problem of a store under ``config`` (what a run fits; benchmarks use it);
    ``map`` runs the response's basis solves (:mod:`vfcli.parallel`; default one after the other);
    ``lateral_axis``: the gap rays' image axis a stored run had (:func:`vfcli.inverse.setup.build_problem`)."""
    return build_problem(read_optimize_inputs(reader, config), config.optimize, configured_pose(config), map=map,
                         lateral_axis=lateral_axis)


def run_model(reader: StoreReader) -> ElasticModel:
    """The elastic model a run of this store is fitted with: /mesh's mesh and the material the mesh
    stage recorded (E, nu, density; the values :func:`read_optimize_inputs` gives the run's problem),
    not yet factorised (the first solve does it)."""
    stored = read_stored_mesh(reader)
    return ElasticModel(stored.mesh, stored.youngs_modulus_pa, stored.poisson_ratio, stored.density_kg_m3)
