"""`vfcli optimize FILE`: fit the force field so the FEM model matches the recording.

Reads /mesh, /fields and /flow (and the subglottal pressure in /hsc when optimize.loads is
"pressure", vfcli/model/loads/pressure.py); writes /optimize/<run>. A long fit checkpoints after every
iteration to ``<store>.optimize-<run>.ckpt.npz`` (written atomically next to the store), so
``--resume`` after a killed job continues from the last iteration and ends where an
uninterrupted run ends; the checkpoint is removed once the run is in the store.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.errors import ConfigError, InputDataError
from vfcli.model.fem import ElasticModel
from vfcli.model.loads.force_field import ForceField, ForceFieldSpec, LoadModel
from vfcli.model.loads.pressure import PressureLoad
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR
from vfcli.inverse.problem import Measurement, ObjectiveSettings, Problem
from vfcli.inverse.optimizers.base import FitOptions, FitState, fit, resume
from vfcli.report.plots import convergence_plot, uncertainty_map
from vfcli.inverse.regularization import lcurve
from vfcli.camera.pose import camera_to_model, estimate_pose
from vfcli.model.response.quasi_static import QuasiStaticResponse
from vfcli.store.transaction import StageWriter, StoreReader
from vfcli.inverse.uncertainty import (displacement_std, effective_sample_size, instrument_fits, instrument_std, posterior,
                           relative_uncertainty)
from vfcli.stages.base import RunContext, StageResult, run_stage
from vfcli.stages.mesh import read_mesh

log = logging.getLogger(__name__)


def checkpoint_path(store_path: Path, run: str) -> Path:
    return store_path.with_name(f"{store_path.name}.optimize-{run}.ckpt.npz")


def _save_checkpoint(path: Path, state: FitState, settings_json: str) -> None:
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}.npz")
    np.savez(tmp, settings_json=np.array(settings_json), **state.to_arrays())
    os.replace(tmp, path)


def _load_checkpoint(path: Path, settings_json: str) -> FitState | None:
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as z:
        if str(z["settings_json"]) != settings_json:
            log.warning("%s was written with other settings; starting afresh", path)
            return None
        return FitState.from_arrays({k: z[k] for k in z.files if k != "settings_json"})


#: ridge weight (1/Pa^2) of each load model when optimize.ridge_weight is null (None: chosen by the L-curve)
DEFAULT_RIDGE = {"free": 0.0, "free-regularised": None, "pressure": None}


def load_model(reader: StoreReader, ctx: RunContext, t_range: tuple[float, float]) -> LoadModel:
    """The load model optimize.loads selects, over the time window ``t_range`` (s).

    'free' and 'free-regularised': the paper's force field (optimize.setup, optimize.tie_folds);
    'pressure': :class:`vfcli.model.loads.pressure.PressureLoad` on the subglottal pressure recorded with the
    video (/hsc).
    """
    cfg = ctx.config.optimize
    if cfg.loads in ("free", "free-regularised"):
        return ForceField(ForceFieldSpec.from_name(cfg.setup, tie_folds=cfg.tie_folds), t_range)
    if not reader.has_stage("hsc") or "pressure" not in reader.group("hsc"):
        raise InputDataError("optimize.loads='pressure' needs the subglottal pressure recorded with the video; "
                             "ingest it with `vfcli ingest-hsc ... --pressure FILE`", ctx.store.path)
    n_z, n_x = cfg.pressure_medial_shapes
    return PressureLoad(reader.read("hsc", "pressure_time"), reader.read("hsc", "pressure"), t_range,
                        time_degree=cfg.pressure_time_degree, medial_z=n_z, medial_x=n_x,
                        inferior_linear_x=cfg.pressure_inferior_linear)


def build_problem(reader: StoreReader, ctx: RunContext) -> tuple[Problem, dict[str, Any]]:
    """The optimisation problem of a store: mesh, model, force field, camera pose, measurement."""
    cfg, cam_cfg, mesh_cfg = ctx.config.optimize, ctx.config.camera, ctx.config.mesh
    mesh = read_mesh(reader)
    times_all = reader.read("fields", "frame_time")
    f0, n = cfg.first_frame, cfg.n_frames
    if f0 + n > len(times_all):
        raise ConfigError(f"optimize window: frames {f0}..{f0 + n} but the recording has {len(times_all)}; "
                          "set optimize.first_frame / optimize.n_frames")
    sl = slice(f0, f0 + n)
    gaps = reader.dataset("flow", "gap_mask")[sl]
    velocity = reader.dataset("fields", "velocity")[sl].astype(np.float64)
    valid = reader.dataset("fields", "valid")[sl]
    flow_attrs = reader.attrs("flow")
    px_per_mm = float(flow_attrs["px_per_mm"])
    if cam_cfg.rotation_deg or any(cam_cfg.offset_px):
        rotation, offset = cam_cfg.rotation_deg, tuple(cam_cfg.offset_px)
        pose_source = "config"
    else:
        masks = reader.dataset("flow", "gap_mask")
        counts = np.zeros(masks.shape[1:])
        for i in range(0, masks.shape[0], 64):  # streamed: memory does not grow with the frames
            counts += masks[i:i + 64].sum(axis=0)
        rotation, offset = estimate_pose(counts, px_per_mm, mesh_cfg.length_mm)
        pose_source = "estimated from the glottal gap"
    velocity[..., :2] = camera_to_model(velocity[..., :2], rotation)
    h, w = gaps.shape[1:]
    camera = Camera(px_per_mm, rotation, offset, w, h)
    times = times_all[sl]
    dt = float(times[1] - times[0])
    field = load_model(reader, ctx, (float(times[0]), float(times[-1] + dt)))
    model = ElasticModel(mesh, mesh_cfg.youngs_modulus_pa, mesh_cfg.poisson_ratio, mesh_cfg.density_kg_m3)
    response = QuasiStaticResponse(model, field)
    ridge = cfg.ridge_weight if cfg.ridge_weight is not None else DEFAULT_RIDGE[cfg.loads]
    settings = ObjectiveSettings(motion_weight=cfg.motion_weight, gap_weight=cfg.gap_weight,
                                 gap_length_mm=cfg.gap_length_mm, ridge_weight=ridge or 0.0, outside=cfg.motion_outside)
    measurement = Measurement.from_gap_masks(times, velocity, valid, gaps)
    info: dict[str, Any] = {"rotation_deg": rotation, "offset_px": list(offset), "pose_source": pose_source,
                            "field": field, "lcurve": None}
    problem = Problem(mesh, camera, response, measurement, settings)
    if ridge is None:
        # the weight of the bounded free fields, from the data: the L-curve's corner on the
        # Gauss-Newton model at the start (vfcli/inverse/regularization.py)
        curve = lcurve(gauss_newton_model(problem, np.zeros(problem.n_params)), np.zeros(problem.n_params),
                       problem.penalty)
        log.info("L-curve: ridge weight %.3g 1/Pa^2", curve.chosen)
        info["lcurve"] = curve
        problem = Problem(mesh, camera, response, measurement, replace(settings, ridge_weight=curve.chosen))
    return problem, info


def reconstruction_uncertainty(problem: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Standard deviation of the displacements of a fit at ``x``, and its summary.

    Laplace posterior of the Gauss-Newton model at x, scaled by the motion residuals'
    own size and correlation, plus in quadrature the systematic part the camera-only and
    vibrometer-only reconstructions disagree by (vfcli/inverse/uncertainty.py).

    Returns
    -------
    std : (F + 1, N, 3) total standard deviation, mm.
    systematic : (N, 3) its instrument-disagreement part, mm.
    summary : figures relative to the RMS reconstructed displacement of each surface.
    """
    u = problem.displacements(x)
    frames = problem.freeze(x, u)
    model = gauss_newton_model(problem, x, frames, u)
    corr = effective_sample_size(problem.motion_residuals(x, frames))
    post = posterior(model, corr)
    noise = displacement_std(post.covariance, model.linearization)
    systematic = instrument_std({k: problem.displacements(v) for k, v in instrument_fits(problem, x, frames, u).items()})
    std = np.sqrt(noise ** 2 + systematic[None] ** 2)
    inferior = problem.mesh.node_side == SIDE_INFERIOR
    superior = problem.mesh.node_side == SIDE_SUPERIOR
    summary = {"inferior_uncertainty_rel": relative_uncertainty(std, u, inferior),
               "superior_uncertainty_rel": relative_uncertainty(std, u, superior),
               "inferior_posterior_rel": relative_uncertainty(noise, u, inferior),
               "inferior_instruments_rel": relative_uncertainty(np.broadcast_to(systematic, u.shape), u, inferior),
               "residual_n_eff": corr.n_eff, "residual_area_px": corr.area_px, "residual_tau_frames": corr.tau_frames,
               "fitted_dof": post.dof}
    return std, systematic, summary


def run_optimize(ctx: RunContext, run: str = "default", resume_run: bool = False, plot: str | Path | None = None,
                 uncertainty_plot: str | Path | None = None) -> StageResult:
    """Fit (or resume) an optimisation run and store it as /optimize/<run>.

    plot : convergence plot (PNG).  uncertainty_plot : map of the inferior surface's stated
    uncertainty (PNG; needs optimize.uncertainty).
    """
    cfg = ctx.config.optimize
    if uncertainty_plot is not None and not cfg.uncertainty:
        raise ConfigError("--uncertainty-map needs optimize.uncertainty = true (it maps the stated uncertainty)")
    if not run.replace("-", "").replace("_", "").isalnum():
        raise ConfigError(f"run name {run!r}: use letters, digits, '-' and '_'")
    settings_json = json.dumps({"optimize": cfg.model_dump(mode="json"), "camera": ctx.config.camera.model_dump(mode="json"),
                                "mesh": ctx.config.mesh.model_dump(mode="json")}, sort_keys=True)
    ckpt = checkpoint_path(ctx.store.path, run)

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        problem, info = build_problem(reader, ctx)
        label = f"{'pressure loads' if cfg.loads == 'pressure' else f'{cfg.setup}, {cfg.loads}'} ({cfg.method})"
        opts = FitOptions(keep_every=cfg.keep_every, ftol=cfg.stop_rel_decrease, xtol=cfg.stop_rel_change)
        bar = ctx.progress(total=cfg.max_iterations, desc=f"optimize {run}", unit="it")

        def checkpoint(state: FitState) -> None:
            _save_checkpoint(ckpt, state, settings_json)
            bar.n = state.iteration
            bar.set_postfix(E=f"{state.value[0]:.4g}")
            bar.refresh()

        state = _load_checkpoint(ckpt, settings_json) if resume_run else None
        if state is not None:
            log.info("resuming run %s from iteration %d", run, state.iteration)
            result = resume(problem, state, cfg.max_iterations, checkpoint, opts)
        else:
            result = fit(problem, None, cfg.method, cfg.max_iterations, checkpoint, options=opts)
        bar.close()
        h = result.history
        s.put("sim_time", problem.sim_times)
        disp = problem.displacements(result.x)
        s.put("displacements", disp.astype(np.float32))
        unc: dict[str, float] = {}
        if cfg.uncertainty:
            std, systematic, unc = reconstruction_uncertainty(problem, result.x)
            s.put("displacement_std", std.astype(np.float32))
            s.put("displacement_std_instruments", systematic.astype(np.float32))
            if uncertainty_plot is not None:
                uncertainty_map(problem.mesh, std, disp, uncertainty_plot, f"run {run} ({label})")
        if info["lcurve"] is not None:
            curve = info["lcurve"]
            s.put("lcurve_weight", curve.weights)
            s.put("lcurve_misfit", curve.misfit)
            s.put("lcurve_penalty", curve.penalty)
        s.put("controls", result.x)
        s.put("parameter_names", np.array(info["field"].parameter_names(), dtype=object))
        s.put("kept_iterations", np.asarray(result.kept_iterations))
        s.put("kept_controls", np.asarray(result.kept_x))
        for key in ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "n_evals"):
            s.put(f"history_{key}", np.asarray(h[key]))
        s.set_attrs(setup=cfg.setup if cfg.loads != "pressure" else "pressure", loads=cfg.loads,
                    ridge_weight=problem.settings.ridge_weight, motion_outside=problem.settings.outside,
                    method=cfg.method, converged=bool(result.converged),
                    message=str(result.message), camera_rotation_deg=info["rotation_deg"],
                    camera_offset_px=np.asarray(info["offset_px"]), pose_source=info["pose_source"],
                    px_per_mm=problem.camera.px_per_mm, **unc)
        if plot is not None:
            convergence_plot(h, plot, label)
        return {
            "iterations": int(h["iteration"][-1]) if len(h["iteration"]) else 0,
            "E_final": float(h["total"][-1]),
            "E_start": float(h["total"][0]),
            "evaluations": int(h["n_evals"][-1]),
            "wall_time_s": round(float(h["wall_time"][-1]), 1),
            "converged": bool(result.converged),
            "pose": info["pose_source"],
            "ridge_weight": problem.settings.ridge_weight,
            **{k: round(v, 4) for k, v in unc.items() if k.endswith("_rel")},
        }

    result = run_stage(ctx, "optimize", config_json=settings_json, body=body, run=run,
                       upstream=[("mesh", None), ("fields", None), ("flow", None)]
                       + ([("hsc", None)] if cfg.loads == "pressure" else []))
    ckpt.unlink(missing_ok=True)
    return result
