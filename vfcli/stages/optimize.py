"""`vfcli optimize FILE`: fit the force field so the FEM model matches the recording.

Reads /mesh, /fields and /flow (and the subglottal pressure in /hsc when optimize.loads is
"pressure", vfcli/model/loads/pressure.py); writes /optimize/<run>. A long fit checkpoints after every
iteration to ``<store>.optimize-<run>.ckpt.npz`` (written atomically next to the store), so
``--resume`` after a killed job continues from the last iteration and ends where an
uninterrupted run ends; the checkpoint is removed once the run is in the store.

One descent: :func:`read_inputs` (everything from the store, once) ->
:func:`vfcli.inverse.setup.build_problem` -> fit -> :func:`reconstruction_uncertainty` -> write.
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.config import RecordingConfig
from vfcli.errors import ConfigError, InputDataError
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR
from vfcli.inverse.problem import Problem
from vfcli.inverse.optimizers.base import FitOptions, FitState, fit, resume
from vfcli.inverse.setup import OptimizeInputs, Setup, build_problem, setup_summary
from vfcli.report.plots import convergence_plot, uncertainty_map
from vfcli.store import StageWriter, StoreReader
from vfcli.store.mesh import read_stored_mesh
from vfcli.inverse.uncertainty import (displacement_std, effective_sample_size, instrument_fits, instrument_std, posterior,
                           relative_uncertainty)
from vfcli.stages.base import RunContext, StageResult, run_stage

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


def read_inputs(reader: StoreReader, config: RecordingConfig) -> OptimizeInputs:
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
    f0, n = cfg.first_frame, cfg.n_frames
    if f0 + n > len(times_all):
        raise ConfigError(f"optimize window: frames {f0}..{f0 + n} but the recording has {len(times_all)}; "
                          "set optimize.first_frame / optimize.n_frames")
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
    return OptimizeInputs(
        mesh=stored.mesh, youngs_modulus_pa=stored.youngs_modulus_pa, poisson_ratio=stored.poisson_ratio,
        density_kg_m3=stored.density_kg_m3, length_mm=stored.length_mm, times=times_all[sl],
        velocity=reader.dataset("fields", "velocity")[sl], valid=reader.dataset("fields", "valid")[sl],
        gap_masks=reader.dataset("flow", "gap_mask")[sl], px_per_mm=float(flow_attrs["px_per_mm"]),
        roi_origin_px=np.asarray(flow_attrs.get("roi_origin_px", (0.0, 0.0)), dtype=float),
        gap_counts=gap_counts, velocity_rotation_deg=float(flow_attrs.get("rotation_deg", 0.0)),
        lateral_axis=int(flow_attrs.get("lateral_axis", 0)), pressure_time=pressure_time, pressure=pressure)


def configured_pose(config: RecordingConfig) -> tuple[float, tuple[float, float]] | None:
    """The calibrated camera pose (rotation, full-frame offset) when camera.pose = 'config', else None."""
    cam = config.camera
    return (cam.rotation_deg, tuple(cam.offset_px)) if cam.pose == "config" else None


def problem_of_store(reader: StoreReader, config: RecordingConfig) -> tuple[Problem, Setup]:
    """The optimisation problem of a store under ``config`` (what a run fits; benchmarks use it)."""
    return build_problem(read_inputs(reader, config), config.optimize, configured_pose(config))


def check_gap_term(problem: Problem, gap_history: np.ndarray) -> None:
    """Warn when the fit's gap term is empty: no rays cross both folds' silhouettes in the camera
    pose, or E_gap was 0 at every kept iteration (no measured silhouette on the rays)."""
    if problem.settings.gap_weight == 0:
        return
    advice = ("check camera.rotation_deg with camera.pose (the glottis must run across the gap's rays) and that "
              "/flow found the gap (vfcli info)")
    if len(problem.rays) == 0:
        log.warning("optimize: the gap term has no rays (the model's folds do not both cross any image %s in the "
                    "camera pose), so the fit ignores the glottal gap; %s",
                    "column" if problem.ray_comp == 0 else "row", advice)
    elif gap_history.size and not np.any(gap_history != 0):
        log.warning("optimize: the gap term was 0 at every iteration (E_gap == 0: no measured silhouette on its "
                    "%d rays), so the fit ignores the glottal gap; %s", len(problem.rays), advice)


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


def optimize_settings_json(config: RecordingConfig) -> str:
    """The settings an optimisation run records (and compares to decide it is current), as JSON:
    [optimize] and [camera]; the mesh and its material are /mesh's (an upstream stage), not the
    live [mesh] section's."""
    return json.dumps({"optimize": config.optimize.model_dump(mode="json"),
                       "camera": config.camera.model_dump(mode="json")}, sort_keys=True)


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
    settings_json = optimize_settings_json(ctx.config)
    ckpt = checkpoint_path(ctx.store.path, run)

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        problem, setup = problem_of_store(reader, ctx.config)
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
        check_gap_term(problem, np.asarray(h["gap"], float))
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
        if setup.lcurve is not None:
            curve = setup.lcurve
            s.put("lcurve_weight", curve.weights)
            s.put("lcurve_misfit", curve.misfit)
            s.put("lcurve_penalty", curve.penalty)
        s.put("controls", result.x)
        s.put("parameter_names", np.array(setup.field.parameter_names(), dtype=object))
        s.put("kept_iterations", np.asarray(result.kept_iterations))
        s.put("kept_controls", np.asarray(result.kept_x))
        for key in ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time", "n_evals"):
            s.put(f"history_{key}", np.asarray(h[key]))
        s.set_attrs(setup=cfg.setup if cfg.loads != "pressure" else "pressure", loads=cfg.loads,
                    ridge_weight=problem.settings.ridge_weight, motion_outside=problem.settings.outside,
                    method=cfg.method, converged=bool(result.converged),
                    message=str(result.message), px_per_mm=problem.camera.px_per_mm, **setup_summary(setup), **unc)
        if plot is not None:
            convergence_plot(h, plot, label)
        return {
            "iterations": int(h["iteration"][-1]) if len(h["iteration"]) else 0,
            "E_final": float(h["total"][-1]),
            "E_start": float(h["total"][0]),
            "evaluations": int(h["n_evals"][-1]),
            "wall_time_s": round(float(h["wall_time"][-1]), 1),
            "converged": bool(result.converged),
            "pose": setup.pose_source,
            "ridge_weight": problem.settings.ridge_weight,
            **{k: round(v, 4) for k, v in unc.items() if k.endswith("_rel")},
        }

    result = run_stage(ctx, "optimize", config_json=settings_json, body=body, run=run,
                       upstream=[("mesh", None), ("fields", None), ("flow", None)]
                       + ([("hsc", None)] if cfg.loads == "pressure" else []))
    ckpt.unlink(missing_ok=True)
    return result
