"""`vfcli optimize FILE`: fit the force field so the FEM model matches the recording.

Reads /mesh, /fields and /flow (and the subglottal pressure in /hsc when optimize.loads is
"pressure", vfcli/model/loads/pressure.py); writes /optimize/<run>. A long fit checkpoints after every
iteration to ``<store>.optimize-<run>.ckpt.npz`` (written atomically next to the store), so
``--resume`` after a killed job continues from the last iteration and ends where an
uninterrupted run ends; the checkpoint is removed once the run is in the store.

One descent: :func:`vfcli.store.fit.read_optimize_inputs` (everything from the store, once) ->
:func:`vfcli.inverse.setup.build_problem` -> fit -> :func:`reconstruction_uncertainty` -> write.
"""
from __future__ import annotations

import json
import logging
import os
import shlex
import time
from pathlib import Path
from typing import Any

import numpy as np

from vfcli.overrides import settings_changes
from vfcli.errors import ConfigError
from vfcli.inverse.linearization import gauss_newton_model
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR
from vfcli.inverse.problem import Problem
from vfcli.inverse.optimizers.base import FitOptions, FitState, fit, resume
from vfcli.inverse.setup import richer_load_problem, setup_summary
from vfcli.report.plots import convergence_plot, uncertainty_map
from vfcli.store import StageWriter, StoreReader
from vfcli.store.checkpoint import checkpoint_path, resume_flags
from vfcli.store.fit import problem_of_store
from vfcli.inverse.sandwich import sandwich
from vfcli.inverse.uncertainty import (corner_fits, data_kind_fits, displacement_std, effective_sample_size,
                                       instrument_fits, instrument_split, instrument_std, load_family_fit,
                                       relative_uncertainty, window_mean, window_oscillation)
from vfcli.model.loads.pressure import PressureLoad
from vfcli.progress import Phases
from vfcli.stages.base import RunContext, StageResult, optimize_settings_json, run_stage

log = logging.getLogger(__name__)


def _save_checkpoint(path: Path, state: FitState, settings_json: str) -> None:
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}.npz")
    np.savez(tmp, settings_json=np.array(settings_json), **state.to_arrays())
    os.replace(tmp, path)


def _load_checkpoint(path: Path, settings_json: str, store_path: Path, run: str) -> FitState | None:
    """The fit state ``--resume`` continues from, or None when there is no checkpoint.

    Raises
    ------
    ConfigError
        The checkpoint was written with other settings (a resumed fit must be the fit that was stopped): naming
        them and the ``--set`` options that resume it (it used to start afresh under the run's name)."""
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as z:
        saved = str(z["settings_json"])
        if saved != settings_json:
            changed = settings_changes(json.loads(saved), json.loads(settings_json))
            words = "; ".join(f"{k} {v!r} (now {now!r})" for k, v, now in changed)
            flags = " ".join(resume_flags(saved, settings_json))
            raise ConfigError(f"--resume: run {run!r} was stopped at iteration {int(z['iteration'])} with other settings "
                              f"({words}); resume it with `vfcli optimize {shlex.quote(str(store_path))} --run {run} "
                              f"--resume {flags}`, or leave out --resume to fit afresh")
        return FitState.from_arrays({k: z[k] for k in z.files if k != "settings_json"})


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


def check_convergence(result, method: str) -> bool:
    """Warn when the fit stopped before a minimum: its line search found no lower E where its direction
    promised one (the paper method's finite-difference gradient can point nowhere downhill).  Returns
    whether it did (then the recording is not to blame for what the stated uncertainty says)."""
    if result.converged or "before a minimum" not in result.message:
        return False
    total = result.history["total"]
    advice = "; fit with --method gauss-newton (exact gradients)" if method != "gauss-newton" else ""
    log.warning("optimize: the fit (%s) stopped before a minimum after %d iteration(s), E %.6g -> %.6g (%s): the "
                "displacements and their stated uncertainty are not those of a fitted minimum%s",
                method, len(total) - 1, total[0], total[-1], result.message, advice)
    return True


def reconstruction_uncertainty(problem: Problem, x: np.ndarray, field=None, minimum: bool = True,
                               richer: tuple[Problem, np.ndarray] | None = None,
                               corner: tuple[float, float] | None = None
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float]]:
    """Standard deviation of the displacements of a fit at ``x``, and its summary.

    The mean squared error of the fit (vfcli/inverse/sandwich.py: the sandwich covariance
    from the per-frame scores, plus the ridge's expected bias where the ridge is a prior), plus in
    quadrature the systematic parts four splits of the fit measure (vfcli/inverse/uncertainty.py): what
    the camera-only and the vibrometer-only reconstructions disagree by, what the velocities-only and the
    gap-only ones disagree by, how far the next richer load family moves the reconstruction (given
    ``richer``) and how far the ridge weights across the L-curve corner's width move it (given ``corner``: the RMS
    of the two sides' moves); each split into the static part (the mean over the window) and the oscillating part.

    field : the load model (a :class:`vfcli.model.loads.pressure.PressureLoad` adds how much
        of the static inferior shape the measured pressure carries).
    richer : (problem, embedding) of :func:`vfcli.inverse.setup.richer_load_problem`, or None.
    corner : (weaker, stronger) ridge weights of :meth:`vfcli.inverse.regularization.LCurve.corner_width`, or None
        (the weight was given, not read off an L-curve).
    minimum : x is a fitted minimum (False: no warning that the recording leaves the static shape open,
        :func:`check_convergence` has said why the figures are what they are).

    Returns
    -------
    std : (F + 1, N, 3) total standard deviation, mm.
    systematic : (N, 3) its instrument-disagreement part, mm.
    static_std : (N, 3) standard deviation of the static part (the mean over the window), mm.
    summary : figures relative to the RMS reconstructed displacement of each surface, and the
        inferior surface's static part (mean over the window) and oscillating part separately.
    """
    u = problem.displacements(x)
    frames = problem.freeze(x, u)
    model = gauss_newton_model(problem, x, frames, u)
    corr = effective_sample_size(problem.motion_residuals(x, frames))
    mse = sandwich(problem, x, model, frames, u)
    lin = model.linearization
    noise = displacement_std(mse.covariance, lin)
    noise_static = displacement_std(mse.covariance, window_mean(lin))[0]
    noise_osc = displacement_std(mse.covariance, window_oscillation(lin))
    inst = {k: problem.displacements(v) for k, v in instrument_fits(problem, x, frames, u).items()}
    systematic = instrument_std(inst)
    sys_static, sys_osc = instrument_split(inst)
    kinds = {k: problem.displacements(v) for k, v in data_kind_fits(problem, x, frames, u).items()}
    splits = [("data_kinds", [kinds], True)]
    if richer is not None:
        rich_problem, embed = richer
        rich_u = rich_problem.displacements(load_family_fit(rich_problem, embed, x))
        splits.append(("load_family", [{"fit": u, "richer": rich_u}], False))
    if corner is not None:
        sides = corner_fits(problem, x, dict(zip(("weaker", "stronger"), corner)), frames, u)
        splits.append(("regularisation", [{"fit": u, k: problem.displacements(v)} for k, v in sides.items()], False))
    parts = {"instruments": systematic}
    other = np.zeros_like(systematic)
    for name, pairs, independent in splits:
        # several pairs of one split (the corner's two sides): the RMS of their parts
        part = np.sqrt(np.mean([instrument_std(p, independent) ** 2 for p in pairs], axis=0))
        halves = [instrument_split(p, independent) for p in pairs]
        part_static, part_osc = (np.sqrt(np.mean([h[i] ** 2 for h in halves], axis=0)) for i in (0, 1))
        parts[name] = part
        other = np.sqrt(other ** 2 + part ** 2)
        sys_static = np.sqrt(sys_static ** 2 + part_static ** 2)
        sys_osc = np.sqrt(sys_osc ** 2 + part_osc ** 2)
    std = np.sqrt(noise ** 2 + systematic[None] ** 2 + other[None] ** 2)
    inferior = problem.mesh.node_side == SIDE_INFERIOR
    superior = problem.mesh.node_side == SIDE_SUPERIOR
    win = u[:-1]
    static = win.mean(axis=0)
    osc = win - static
    static_std = np.sqrt(noise_static ** 2 + sys_static ** 2)
    osc_std = np.sqrt(noise_osc[:-1] ** 2 + sys_osc[None] ** 2)
    rms = lambda a: float(np.sqrt(np.mean(np.asarray(a) ** 2)))  # noqa: E731
    summary = {"inferior_uncertainty_rel": relative_uncertainty(std, u, inferior),
               "superior_uncertainty_rel": relative_uncertainty(std, u, superior),
               "inferior_posterior_rel": relative_uncertainty(noise, u, inferior),
               **{f"inferior_{k}_rel": relative_uncertainty(np.broadcast_to(v, u.shape), u, inferior)
                  for k, v in parts.items()},
               "inferior_oscillating_uncertainty_rel": relative_uncertainty(osc_std, osc, inferior),
               "inferior_static_rms_mm": rms(static[inferior]),
               "inferior_static_std_mm": rms(static_std[inferior]),
               "inferior_static_mean_z_mm": float(static[inferior, 2].mean()),
               "inferior_static_mean_z_std_mm": rms(static_std[inferior, 2]),
               "residual_n_eff": corr.n_eff, "residual_area_px": corr.area_px, "residual_tau_frames": corr.tau_frames,
               "score_lag_frames": float(mse.lag), "ridge_prior_scale": float(np.sqrt(mse.tau2))}
    if isinstance(field, PressureLoad):
        # the static shape the measured pressure carries (gains x mean pressure) against the free correction's mean
        carried = problem.displacements(np.where(field.free_mask(), 0.0, x))[:-1].mean(axis=0)
        summary["inferior_static_mean_z_from_pressure_mm"] = float(carried[inferior, 2].mean())
    if minimum and summary["inferior_static_mean_z_std_mm"] > abs(summary["inferior_static_mean_z_mm"]):
        log.warning("optimize: the recording does not determine the static shape: the inferior surface's mean "
                    "vertical displacement is %+.3f mm +- %.3f mm (1 sd); its oscillation is stated to %.0f %%",
                    summary["inferior_static_mean_z_mm"], summary["inferior_static_mean_z_std_mm"],
                    100 * summary["inferior_oscillating_uncertainty_rel"])
    return std, systematic, static_std, summary


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
    # read (and refused) before the write opens: a refusal leaves the store untouched
    resumed = _load_checkpoint(ckpt, settings_json, ctx.store.path, run) if resume_run else None

    def body(reader: StoreReader, s: StageWriter) -> dict[str, Any]:
        t_body = time.perf_counter()
        before = Phases(ctx.progress, f"optimize {run}", 1, log)
        before("setup (model, measurement, ridge weight)")
        problem, setup = problem_of_store(reader, ctx.config, ctx.map)
        (setup_s,) = before.close().values()
        label = f"{'pressure loads' if cfg.loads == 'pressure' else f'{cfg.setup}, {cfg.loads}'} ({cfg.method})"
        opts = FitOptions(keep_every=cfg.keep_every, ftol=cfg.stop_rel_decrease, xtol=cfg.stop_rel_change)
        bar = ctx.progress(total=cfg.max_iterations, desc=f"optimize {run}", unit="it")

        def checkpoint(state: FitState) -> None:
            _save_checkpoint(ckpt, state, settings_json)
            bar.n = state.iteration
            bar.set_postfix(E=f"{state.value[0]:.4g}")
            bar.refresh()

        state = resumed
        if resume_run and state is None:      # --resume without a checkpoint started afresh without a word
            log.warning("--resume: no checkpoint of this run (%s); fitting from the start", ckpt.name)
        if state is not None:
            log.info("resuming run %s from iteration %d", run, state.iteration)
            result = resume(problem, state, cfg.max_iterations, checkpoint, opts)
        else:
            result = fit(problem, None, cfg.method, cfg.max_iterations, checkpoint, options=opts)
        bar.close()
        h = result.history
        stalled = check_convergence(result, cfg.method)
        check_gap_term(problem, np.asarray(h["gap"], float))
        s.put("sim_time", problem.sim_times)
        disp = problem.displacements(result.x)
        s.put("displacements", disp.astype(np.float32))
        unc: dict[str, float] = {}
        if cfg.uncertainty:
            after = Phases(ctx.progress, f"optimize {run}", 1, log)
            after("stated uncertainty")
            richer = richer_load_problem(problem, setup.field, setup.model, ctx.map)
            corner = setup.lcurve.corner_width() if setup.lcurve is not None else None
            std, systematic, static_std, unc = reconstruction_uncertainty(problem, result.x, setup.field,
                                                                          minimum=not stalled, richer=richer,
                                                                          corner=corner)
            s.put("displacement_std", std.astype(np.float32))
            s.put("displacement_std_instruments", systematic.astype(np.float32))
            s.put("displacement_std_static", static_std.astype(np.float32))
            (uncertainty_s,) = after.close().values()
            s.set_attrs(uncertainty_time_s=float(uncertainty_s))
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
        s.set_attrs(window_first_frame=int(cfg.first_frame), window_frames=int(problem.n_frames),
                    setup=cfg.setup if cfg.loads != "pressure" else "pressure", loads=cfg.loads,
                    ridge_weight=problem.settings.ridge_weight, motion_outside=problem.settings.outside,
                    method=cfg.method, converged=bool(result.converged),
                    message=str(result.message), px_per_mm=problem.camera.px_per_mm,
                    **setup_summary(setup, problem), **unc)
        if plot is not None:
            convergence_plot(h, plot, label)
        # the whole stage: setup (the L-curve's fits), the fit, the stated uncertainty; the history's wall time is the fit's
        stage_time = time.perf_counter() - t_body
        s.set_attrs(stage_time_s=float(stage_time), setup_time_s=float(setup_s))
        return {
            "iterations": int(h["iteration"][-1]) if len(h["iteration"]) else 0,
            "E_final": float(h["total"][-1]),
            "E_start": float(h["total"][0]),
            "evaluations": int(h["n_evals"][-1]),
            "wall_time_s": round(stage_time, 1),
            "fit_time_s": round(float(h["wall_time"][-1]), 1),
            "window": f"frames {cfg.first_frame}-{cfg.first_frame + problem.n_frames - 1}",
            "converged": bool(result.converged),
            "pose": setup.pose_source,
            "ridge_weight": problem.settings.ridge_weight,
            **{k: round(v, 4) for k, v in unc.items() if k.endswith(("_rel", "_mm"))},
        }

    result = run_stage(ctx, "optimize", config_json=settings_json, body=body, run=run,
                       upstream=[("mesh", None), ("fields", None), ("flow", None)]
                       + ([("hsc", None), ("sync", None)] if cfg.loads == "pressure" else []))
    ckpt.unlink(missing_ok=True)
    return result
