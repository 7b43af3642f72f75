"""## Where the pressure model's inferior-surface error comes from, on a kept phantom pipeline (issue 15).

A diagnostic (it reads the phantom's truth.h5; vfcli never does): for a pipeline kept by
``bench/bench_unseen.py SEED --keep DIR`` (or any store beside a ``raw/truth.h5``), the pressure
model is refitted (Gauss-Newton, from the stored run's control values, the run's ridge weight unless
the row says otherwise) with parts of the measurement replaced by the phantom's truth, and each
fit's inferior surface is scored like bench_unseen does (the oscillating part's relative RMS error,
the static part's RMS error in mm, the total relative error), with the superior surface's total
relative error beside it:

* ``best representation``: least squares of the model's displacements (the response is linear in
  the control values) on the true displacements of all inferior and superior nodes, every
  simulated time (what the load model can represent at all);
* ``best fit to the true superior surface``: the same on the superior nodes only (what perfect
  superior-surface data determine of the inferior surface);
* ``the run``: the stored fit (measured data);
* ``true velocities``: the measured ``/fields`` replaced by the true surface velocity (in the
  model axes of the pose the run used), valid where the true surface is visible and not gap;
* ``true camera velocities`` / ``true vibrometer velocities``: only the in-plane (x, y) or only the
  vertical (z) component replaced by the truth (where both are valid), the other as measured;
* ``+ true gap, true pose``: also the true gap masks and the true camera pose;
* ``true E``: the measured data, the mesh's material set to the phantom's true Young's modulus
  (the ridge weight scaled by (E_nominal / E_true)^2, so the same loads cost the same);
* ``time degree D`` rows: the measured data with ``optimize.pressure_time_degree = D``
  (a longer free correction in time), and the best representation with it;
* any ``--variant NAME=KEY=VALUE[,KEY=VALUE]`` rows: the measured data refitted with those
  ``optimize`` settings (the ridge weight from the L-curve unless set).

Reproduce::

    .venv/bin/python bench/bench_load_error.py DIR/seed300 [DIR/seed301 ...] [--run default]
        [--degrees 8] [--variant NAME=optimize.X=Y,...] [--rows run,best,...]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vfcli.camera.pose import model_axes_velocity  # noqa: E402
from vfcli.config import CameraConfig, OptimizeConfig, load_config  # noqa: E402
from vfcli.inverse.optimizers.base import FitOptions, fit  # noqa: E402
from vfcli.inverse.setup import build_problem  # noqa: E402
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR, FoldMesh  # noqa: E402
from vfcli.store.fit import configured_pose, read_optimize_inputs  # noqa: E402
from vfcli.store.transaction import Store  # noqa: E402
from vfcli.store.truth import read_truth  # noqa: E402
from vfcli.synth.scoring import rms, side_truth  # noqa: E402

ROWS = ("best", "best_superior", "run", "true_velocity", "true_xy", "true_z", "true_all", "true_E", "degrees", "variants", "edge_band")


def _jacobian(problem) -> np.ndarray:
    """(n_params, T, N, 3) displacements per unit control value (the response is linear)."""
    n = problem.n_params
    return np.stack([problem.displacements(np.eye(n)[i]) for i in range(n)])


def _least_squares(jac: np.ndarray, target: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Control values minimising |U(x) - target| over ``nodes`` (every time and component)."""
    a = jac[:, :, nodes].reshape(len(jac), -1).T
    b = target[:, nodes].ravel()
    ok = np.isfinite(b)
    x, *_ = np.linalg.lstsq(a[ok], b[ok], rcond=1e-10)
    return x


class Scorer:
    """The truth at the reconstruction mesh's surface nodes, and the scores of a displacement history."""

    def __init__(self, mesh: FoldMesh, truth: dict, sim_time: np.ndarray) -> None:
        tm = FoldMesh(**{k.split("/")[1]: truth[k] for k in truth if k.startswith("mesh/")})
        idx = np.searchsorted(truth["frames/time"], sim_time - 1e-9)
        disp = truth["frames/displacement"][idx].astype(float)
        self.inf, ref_inf = side_truth(mesh.uv, mesh.node_side, tm.uv, tm.node_side, disp, SIDE_INFERIOR)
        self.sup, ref_sup = side_truth(mesh.uv, mesh.node_side, tm.uv, tm.node_side, disp, SIDE_SUPERIOR)
        self.target = np.full((len(sim_time), mesh.n_nodes, 3), np.nan)
        self.target[:, self.inf] = ref_inf
        self.target[:, self.sup] = ref_sup

    def score(self, u: np.ndarray) -> dict:
        """Inferior oscillating / static / total error and superior total error over the window (times but the last)."""
        est, ref = u[:-1, self.inf], self.target[:-1, self.inf]
        em, rm = est.mean(axis=0), ref.mean(axis=0)
        sup_e, sup_r = u[:-1, self.sup], self.target[:-1, self.sup]
        return {"inf_osc": rms((est - em) - (ref - rm)) / rms(ref - rm), "inf_static_mm": rms(em - rm),
                "mean_z_true": float(rm[:, 2].mean()), "mean_z_est": float(em[:, 2].mean()),
                "inf_total": rms(est - ref) / rms(ref), "sup_total": rms(sup_e - sup_r) / rms(sup_r)}


def refit(inputs, cfg: OptimizeConfig, pose, x0: np.ndarray | None, max_iter: int = 30):
    """(problem, x) of a Gauss-Newton fit from ``x0`` (zeros when None or of another size)."""
    problem, _ = build_problem(inputs, cfg, pose)
    if x0 is not None and len(x0) != problem.n_params:
        x0 = None
    res = fit(problem, x0, "gauss-newton", max_iter, options=FitOptions(ftol=cfg.stop_rel_decrease,
                                                                           xtol=cfg.stop_rel_change))
    return problem, res.x


def true_measurement(inputs, truth: dict, attrs: dict, rotation_used: float, sim_time: np.ndarray, gap: bool):
    """``inputs`` with the true velocity (model axes of ``rotation_used``) and, with ``gap``, the true gap masks."""
    idx = np.searchsorted(truth["frames/time"], inputs.times - 1e-9)
    c0, r0 = (int(round(v)) for v in inputs.roi_origin_px)
    h, w = inputs.gap_masks.shape[1:]
    crop = (slice(None), slice(r0, r0 + h), slice(c0, c0 + w))
    vel = truth["screen/velocity"][idx][crop].astype(np.float64)
    vis = truth["screen/visible"][idx][crop].astype(bool)
    tgap = truth["screen/gap"][idx][crop].astype(bool)
    vel[..., :2] = model_axes_velocity(vel[..., :2], float(attrs["camera_rotation_deg"]), rotation_used)
    # inputs' velocity is in the model axes of /flow's rotation: express it there (build_problem turns it)
    vel[..., :2] = model_axes_velocity(vel[..., :2], rotation_used, inputs.velocity_rotation_deg)
    valid = vis & ~tgap & np.isfinite(vel).all(axis=-1)
    vel[~valid] = 0.0
    out = replace(inputs, velocity=vel, valid=valid)
    return replace(out, gap_masks=tgap) if gap else out


def analyse(work: Path, run: str, degrees: list[int], variants: dict[str, list[str]], rows: set[str]) -> list:
    store, raw = work / "recording.h5", work / "raw"
    with Store(store).read() as r:
        stored_json = r.recording_config_json()
        ga = r.attrs("optimize", run)
        x_run = r.read("optimize", "controls", run)
        sim_time = r.read("optimize", "sim_time", run)
        _, config = load_config(None, stored_json, [])
        prov = json.loads(ga["config_json"]) if "config_json" in ga else None
        if prov is not None:
            config = config.model_copy(update={"optimize": OptimizeConfig(**prov["optimize"]),
                                               "camera": CameraConfig(**prov["camera"])})
        inputs = read_optimize_inputs(r, config)
    ridge = float(ga["ridge_weight"])
    rot_used, off_used = float(ga["camera_rotation_deg"]), np.asarray(ga["camera_offset_px"], float)
    truth, attrs = read_truth(raw / "truth.h5")
    cfg_run = config.optimize.model_copy(update={"ridge_weight": ridge})
    pose_used = (rot_used, tuple(off_used + np.asarray(inputs.roi_origin_px, float)))
    problem, _ = build_problem(inputs, cfg_run, pose_used)
    scorer = Scorer(inputs.mesh, truth, sim_time)
    out = []

    def add(name: str, u: np.ndarray, t0: float, extra: str = "") -> None:
        s = scorer.score(u)
        s.update(name=name, seconds=time.perf_counter() - t0, note=extra)
        out.append(s)
        print(f"  {work.name}: {name}: inferior osc {100 * s['inf_osc']:.1f} %, static {s['inf_static_mm']:.3f} mm, "
              f"superior {100 * s['sup_total']:.1f} % ({s['seconds']:.0f} s)", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    if "best" in rows or "best_superior" in rows:
        jac = _jacobian(problem)
        both = np.concatenate([scorer.inf, scorer.sup])
        if "best" in rows:
            add(f"best representation (time degree {cfg_run.pressure_time_degree})",
                problem.displacements(_least_squares(jac, scorer.target, both)), t0)
        if "best_superior" in rows:
            t0 = time.perf_counter()
            add("best fit to the true superior surface",
                problem.displacements(_least_squares(jac, scorer.target, scorer.sup)), t0)
    if "run" in rows:
        add("the run (measured data)", problem.displacements(x_run), time.perf_counter())
    if "true_velocity" in rows:
        t0 = time.perf_counter()
        p, x = refit(true_measurement(inputs, truth, attrs, rot_used, sim_time, gap=False), cfg_run, pose_used, x_run)
        add("true velocities, measured gap", p.displacements(x), t0)
    for key, comps, label in (("true_xy", [0, 1], "true camera (x, y) velocities"),
                              ("true_z", [2], "true vibrometer (z) velocities")):
        if key in rows:
            t0 = time.perf_counter()
            tm = true_measurement(inputs, truth, attrs, rot_used, sim_time, gap=False)
            vel = np.array(inputs.velocity, dtype=np.float64)
            ok = inputs.valid & tm.valid
            vel[..., comps] = np.where(ok[..., None], tm.velocity[..., comps], vel[..., comps])
            p, x = refit(replace(inputs, velocity=vel), cfg_run, pose_used, x_run)
            add(f"{label}, the other measured, measured gap", p.displacements(x), t0)
    if "edge_band" in rows:
        from scipy.ndimage import binary_dilation
        for k in (4, 8):
            t0 = time.perf_counter()
            band = binary_dilation(inputs.gap_masks.any(axis=0), iterations=k)
            for comps, label in (([0, 1, 2], "all components"), ([2], "the vibrometer's z")):
                vel = np.array(inputs.velocity, dtype=np.float64)
                if comps == [0, 1, 2]:
                    inp = replace(inputs, valid=inputs.valid & ~band[None])
                else:   # z only: the simulated z cannot be masked per component here; skip
                    continue
                p, x = refit(inp, cfg_run, pose_used, x_run)
                add(f"measured data without the motion term within {k} px of the measured gap ({label})",
                    p.displacements(x), t0)
    if "true_all" in rows:
        t0 = time.perf_counter()
        true_pose = (float(attrs["camera_rotation_deg"]), tuple(np.asarray(attrs["camera_offset_px"], float)))
        p, x = refit(true_measurement(inputs, truth, attrs, true_pose[0], sim_time, gap=True), cfg_run, true_pose, None)
        add("true velocities, true gap, true camera pose", p.displacements(x), t0)
    if "true_E" in rows and "widened_youngs_modulus_pa" in attrs:
        t0 = time.perf_counter()
        e_true = float(attrs["widened_youngs_modulus_pa"])
        scale = inputs.youngs_modulus_pa / e_true
        cfg_e = cfg_run.model_copy(update={"ridge_weight": ridge * scale ** 2})
        p, x = refit(replace(inputs, youngs_modulus_pa=e_true), cfg_e, pose_used, x_run / scale)
        add(f"measured data, true E ({e_true / inputs.youngs_modulus_pa:.3f} x nominal)", p.displacements(x), t0)
    if "degrees" in rows:
        for d in degrees:
            t0 = time.perf_counter()
            cfg_d = config.optimize.model_copy(update={"pressure_time_degree": d})
            pd, _ = build_problem(inputs, cfg_d.model_copy(update={"ridge_weight": ridge}), pose_used)
            add(f"best representation (time degree {d})",
                pd.displacements(_least_squares(_jacobian(pd), scorer.target,
                                                np.concatenate([scorer.inf, scorer.sup]))), t0)
            t0 = time.perf_counter()
            p, x = refit(inputs, cfg_d, pose_used, None)
            add(f"measured data, time degree {d} (L-curve ridge {p.settings.ridge_weight:.2g})", p.displacements(x), t0)
    if "variants" in rows:
        for name, sets in variants.items():
            t0 = time.perf_counter()
            upd = {}
            for item in sets:
                key, val = item.split("=", 1)
                upd[key.removeprefix("optimize.")] = json.loads(val)
            cfg_v = OptimizeConfig(**{**config.optimize.model_dump(), **upd})
            p, x = refit(inputs, cfg_v, pose_used, None)
            add(f"measured data, {name} (ridge {p.settings.ridge_weight:.2g})", p.displacements(x), t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", type=Path, nargs="+")
    ap.add_argument("--run", default="default")
    ap.add_argument("--degrees", type=int, nargs="*", default=[8])
    ap.add_argument("--variant", action="append", default=[], help="NAME=optimize.X=Y[,optimize.Z=W]")
    ap.add_argument("--rows", default=",".join(ROWS), help="comma-separated subset of " + ", ".join(ROWS))
    args = ap.parse_args()
    rows = set(args.rows.split(","))
    variants = {}
    for v in args.variant:
        name, rest = v.split("=", 1)
        variants[name] = rest.split(",")
    for d in args.dirs:
        res = analyse(d, args.run, args.degrees, variants, rows)
        print(f"\n{d.name}\n\n| fit | inferior oscillating error | inferior static error (mm) | mean z true / est (mm) "
              "| inferior total error | superior total error |\n| --- | ---: | ---: | ---: | ---: | ---: |")
        for s in res:
            print(f"| {s['name']} | {100 * s['inf_osc']:.1f}% | {s['inf_static_mm']:.3f} | {s['mean_z_true']:.3f} / "
                  f"{s['mean_z_est']:.3f} | {100 * s['inf_total']:.1f}% | {100 * s['sup_total']:.1f}% |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
