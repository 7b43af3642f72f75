"""## The instruments' part of the stated uncertainty: what the single-instrument fits disagree by (issue 15).

For each kept store of ``bench/bench_unseen.py --keep DIR`` (a run ``default`` fitted with
``optimize.uncertainty``), the run's problem is rebuilt from the store (its own settings and ridge
weight) and the camera-only and vibrometer-only Gauss-Newton steps from the joint fit are taken two
ways: with the ridge centred on 0 (optimize methods 1-3) and centred on the joint fit (method 4,
:func:`vfcli.inverse.uncertainty.instrument_fits`). Printed, in mm RMS over the inferior surface and
the window's frames: the joint fit's error (from the phantom's truth), both disagreements, the
per-frame scatter of the first (the long-run covariance of each frame's contribution, as
:mod:`vfcli.inverse.sandwich` measures the fit's own), and the coverage of the 90 % intervals with
the fit's MSE alone and with each instrument part added (``RMS_t |d_a - d_b| / sqrt(2)`` in quadrature);
and the fit's MSE split into its scatter (``H^-1 S H^-1``) and the ridge's expected bias, with the
coverage of the scatter alone (:mod:`vfcli.inverse.sandwich`); and, in place of the expected bias under the
ridge's own prior, the plug-in bias of this fit, ``H^-1 Lambda x_hat`` (its square added to the scatter; session 29),
with the coverage of scatter + plug-in bias + instruments and of scatter + instruments.

A kept store's truth is read from ``DIR/raw/truth.h5`` (``bench_unseen.py``) or ``DIR/truth/truth.h5``
(``bench_diagnose.py``, which keeps it out of the raw folder).

Reproduce::

    .venv/bin/python bench/bench_unseen.py 300 301 302 303 304 --duration 0.025 --keep DIR
    .venv/bin/python bench/bench_instrument_split.py DIR/seed300 DIR/seed301 ...
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from _runner import side_truth_at  # noqa: E402

from vfcli.config import RecordingConfig  # noqa: E402
from vfcli.inverse.block_matrix import BlockMatrix  # noqa: E402
from vfcli.inverse.linearization import gauss_newton_model  # noqa: E402
from vfcli.inverse.sandwich import frame_scores, long_run_covariance, mse_covariance, sandwich  # noqa: E402
from vfcli.inverse.uncertainty import INSTRUMENTS, displacement_std, instrument_fits  # noqa: E402
from vfcli.stages.diagnose import run_recording_config  # noqa: E402
from vfcli.store import Store  # noqa: E402
from vfcli.store.fit import problem_of_store  # noqa: E402
from vfcli.store.mesh import read_mesh  # noqa: E402
from vfcli.store.runs import read_run  # noqa: E402
from vfcli.synth.scoring import interval_coverage  # noqa: E402


def split(work: Path) -> dict[str, float]:
    """The figures of one kept store (module docstring)."""
    with Store(work / "recording.h5").read() as r:
        stored = read_run(r, "default")
        roi = np.asarray(r.attrs("flow").get("roi_origin_px", (0.0, 0.0)), float)
        cfg = run_recording_config(RecordingConfig(), stored.config, stored.attrs, roi)
        prob, _ = problem_of_store(r, cfg)
        mesh = read_mesh(r)
        std = np.asarray(r.read("optimize", "displacement_std", "default"), float)[:-1]
        si = np.asarray(r.read("optimize", "displacement_std_instruments", "default"), float)
    x = stored.controls.ravel()
    u = prob.displacements(x)
    frames = prob.freeze(x, u)
    joint = gauss_newton_model(prob, x, frames, u)
    lin = joint.linearization
    mse = sandwich(prob, x, joint, frames, u)
    mse_std = displacement_std(mse.covariance, lin)[:-1]
    scatter_std = displacement_std(mse.scatter, lin)[:-1]
    old, q = {}, 0.0
    for sign, (name, weights) in zip((-1.0, 1.0), INSTRUMENTS.items()):
        pk = prob.with_weights(component_weights=weights)
        mk = gauss_newton_model(pk, x, frames, u)
        old[name] = x - mk.hessian.solve(mk.grad)                      # ridge centred on 0
        q = q + sign * mk.hessian.solve(frame_scores(pk, x, frames, u, lin).T).T
    new = instrument_fits(prob, x, frames, u)
    diff = lambda xs: np.mean((prob.displacements(xs["camera"]) - prob.displacements(xs["vibrometer"]))[:-1] ** 2, 0)  # noqa: E731
    d_old, d_new = diff(old), diff(new)
    cov = BlockMatrix(len(x), (np.arange(len(x)),), (long_run_covariance(q).covariance,))
    scatter = np.mean(displacement_std(cov, lin)[:-1] ** 2, axis=0)
    # the plug-in bias H^-1 Lambda x_hat of this fit, squared, in place of the ridge's expected bias
    lam_x = (2.0 * float(prob.settings.ridge_weight) / prob.n_params) * (sp.csr_matrix(prob.penalty) @ x)
    score_cov = long_run_covariance(frame_scores(prob, x, frames, u, lin)).covariance
    plug_std = displacement_std(mse_covariance(joint.hessian, score_cov, np.outer(lam_x, lam_x))[0], lin)[:-1]
    truth = work / "raw" / "truth.h5"
    nodes, ref = side_truth_at(truth if truth.is_file() else work / "truth" / "truth.h5", mesh, stored.sim_time[:-1],
                               rotation_deg=float(stored.attrs["camera_rotation_deg"]))
    est = np.asarray(stored.displacements, float)[:-1][:, nodes]
    post2 = np.maximum(std[:, nodes] ** 2 - si[nodes][None] ** 2, 0.0)
    rms = lambda a: float(np.sqrt(np.mean(a)))  # noqa: E731
    return {"error": rms((est - ref) ** 2), "centred on 0": rms(d_old[nodes]), "its scatter": rms(scatter[nodes]),
            "centred on the fit": rms(d_new[nodes]),
            "coverage, posterior": interval_coverage(est, np.sqrt(post2), ref),
            "coverage, centred on 0": interval_coverage(est, np.sqrt(post2 + d_old[nodes][None] / 2), ref),
            "coverage, centred on the fit": interval_coverage(est, np.sqrt(post2 + d_new[nodes][None] / 2), ref),
            "MSE: scatter": rms(scatter_std[:, nodes] ** 2),
            "MSE: ridge bias": rms(np.maximum(mse_std[:, nodes] ** 2 - scatter_std[:, nodes] ** 2, 0.0)),
            "coverage, scatter only": interval_coverage(est, scatter_std[:, nodes], ref),
            "MSE: plug-in ridge bias": rms(np.maximum(plug_std[:, nodes] ** 2 - scatter_std[:, nodes] ** 2, 0.0)),
            "coverage, scatter + plug-in bias + instruments": interval_coverage(
                est, np.sqrt(plug_std[:, nodes] ** 2 + si[nodes][None] ** 2), ref),
            "coverage, scatter + instruments": interval_coverage(
                est, np.sqrt(scatter_std[:, nodes] ** 2 + si[nodes][None] ** 2), ref),
            "coverage, as stated": interval_coverage(est, std[:, nodes], ref)}


def main() -> None:
    if len(sys.argv) < 2:
        print("usage: bench_instrument_split.py DIR [DIR ...] (stores kept by bench_unseen.py --keep)", file=sys.stderr)
        sys.exit(2)
    rows = {Path(w).name: split(Path(w)) for w in sys.argv[1:]}
    keys = list(next(iter(rows.values())))
    print("| store | " + " | ".join(keys) + " |")
    print("| --- |" + " ---: |" * len(keys))
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{100 * v:.1f} %" if k.startswith("coverage") else f"{v:.3f}"
                                         for k, v in row.items()) + " |")


if __name__ == "__main__":
    main()
