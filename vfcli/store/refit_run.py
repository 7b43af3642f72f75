"""Write a confirmation refit (`vfcli diagnose`) into the store: as its own /optimize/<run>, and its
figures into /diagnose/<run>.

The extended model's run carries what every run does (sim_time, displacements, controls, history)
plus the candidate's parameters and their stated uncertainty; its attributes name the run it
extends, the candidate and theta +- sd.
"""
from __future__ import annotations

import numpy as np

from vfcli.store.stage_writer import StageWriter


def write_refit_params(s: StageWriter, names, theta: np.ndarray, sd: np.ndarray) -> None:
    """refit_parameter_name, refit_theta, refit_theta_sd (one per candidate parameter)."""
    s.put("refit_parameter_name", np.array(list(names), dtype=object))
    s.put("refit_theta", np.asarray(theta, dtype=np.float64))
    s.put("refit_theta_sd", np.asarray(sd, dtype=np.float64))


def write_refit_run(s: StageWriter, result, sim_time: np.ndarray, parameter_names, of_run: str,
                    source_attrs: dict) -> None:
    """The extended model as an /optimize run.

    result : :class:`vfcli.diagnose.refit.RefitResult`.  sim_time : (F + 1,) s.
    parameter_names : (n_params,) names of the load controls.  of_run : the run it extends.
    source_attrs : attributes of that run copied (setup, loads, ridge weight, pose, px_per_mm ...; pixel_stride: the
        diagnosis compared the motion on every s-th pixel of every s-th row, ``Measurement.pixel_stride``).
    """
    h = result.history
    s.put("sim_time", np.asarray(sim_time, dtype=np.float64))
    s.put("displacements", np.asarray(result.displacements, dtype=np.float32))
    s.put("controls", np.asarray(result.x, dtype=np.float64))
    s.put("parameter_names", np.array(list(parameter_names), dtype=object))
    s.put("kept_iterations", np.array([int(h["iteration"][-1])]))
    s.put("kept_controls", np.asarray(result.x, dtype=np.float64)[None])
    for key in ("iteration", "total", "motion", "gap", "ridge", "step", "wall_time"):
        s.put(f"history_{key}", np.asarray(h[key]))
    s.put("history_n_evals", np.arange(1, len(h["iteration"]) + 1))
    s.put("history_theta", np.asarray(h["theta"], dtype=np.float64))
    write_refit_params(s, result.parameter_names, result.theta, result.sd)
    keep = ("setup", "loads", "ridge_weight", "motion_outside", "px_per_mm", "camera_rotation_deg",
            "camera_offset_px", "pose_source", "gap_lateral_axis", "pixel_stride")
    theta = ", ".join(f"{n} = {t:.4g} +- {d:.2g}" for n, t, d in zip(result.parameter_names, result.theta, result.sd))
    s.set_attrs(**{k: source_attrs[k] for k in keep if k in source_attrs}, method="refit (joint Gauss-Newton)",
                converged=bool(result.converged), message=f"extends run {of_run} by {result.candidate}: {theta}",
                refit_of=of_run, refit_candidate=result.candidate, refit_uncertainty=result.uncertainty,
                refit_theta_text=theta)
