"""`vfcli optimize` on a phantom as a user runs it: history in the store, the camera pose
found from the gap, and --resume after SIGKILL ending where an uninterrupted run ends."""
from __future__ import annotations

import shlex
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from _export_store import meshed_store
from conftest import ROOT, run_vfcli
from vfcli.store.checkpoint import checkpoint_path
from vfcli.synth.scoring import interval_coverage
from vfcli.store import Store, read_truth
from vfcli.store.parts import copy_store

FIT = ["--setup", "3x3x10-one-sided", "--set", "optimize.n_frames=12", "--set", "optimize.first_frame=20",
       "--set", "mesh.target_edge_mm=2.5"]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """(store through /mesh, raw folder) of the phantom seed 5: a copy of the shared meshed store
    (tests/_export_store.py, the same PHANTOM), the tests add their runs to it."""
    shared, raw = meshed_store(tmp_path_factory)
    return copy_store(shared, tmp_path_factory.mktemp("opt") / "rec.h5"), raw


def _footprint_px(rotation_deg, offset_px, px_per_mm=9.0, length_mm=15.0, depth_mm=8.0):
    """(4, 2) image positions [col, row] of the model points x in {0, L}, y in {-D, D}."""
    r = np.radians(rotation_deg)
    rot = np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]])
    corners = np.array([[0.0, -depth_mm], [0.0, depth_mm], [length_mm, -depth_mm], [length_mm, depth_mm]])
    return px_per_mm * corners @ rot.T + np.asarray(offset_px, float)


def test_optimize_stores_a_decreasing_history_and_the_motion(store, tmp_path):
    path, raw = store
    plot = tmp_path / "conv.png"
    t0 = time.perf_counter()
    res = run_vfcli("optimize", path, *FIT, "--set", "optimize.max_iterations=4", "--run", "short", "--plot", plot)
    elapsed = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    with Store(path).read() as r:
        fit_time = r.read("optimize", "history_wall_time", "short")[-1]
        total = r.read("optimize", "history_total", "short")
        disp = r.read("optimize", "displacements", "short")
        names = r.read("optimize", "parameter_names", "short")
        attrs = r.attrs("optimize", "short")
        n_nodes = r.read("mesh", "nodes").shape[0]
    assert len(total) == 5 and np.all(np.diff(total) <= 0) and total[-1] < 0.8 * total[0]
    # the time printed and stored is the stage's (setup, fit, stated uncertainty), not only the fit loop's (hE: a
    # run printed 5.4 s and took 7 min 22 s); the history keeps the loop's
    assert fit_time < attrs["stage_time_s"] < elapsed
    # its parts: the setup before the fit and the stated uncertainty after it, each within the stage's time
    parts = attrs["setup_time_s"] + fit_time + attrs.get("uncertainty_time_s", 0.0)
    assert attrs["setup_time_s"] > 0 and parts <= attrs["stage_time_s"]
    assert f"wall_time_s={attrs['stage_time_s']:.1f}" in res.stdout and f"fit_time_s={fit_time:.1f}" in res.stdout
    assert disp.shape == (13, n_nodes, 3) and np.abs(disp).max() > 0.01
    assert (attrs["window_first_frame"], attrs["window_frames"]) == (20, 12)
    assert len(names) == 780 and names[0].startswith("fold0/inferior/x")
    assert plot.stat().st_size > 1000
    truth = read_truth(raw / "truth.h5", [])[1]
    # the pose found from the gap must beat the guess "folds centred, not rotated" (synth's nominal camera,
    # off by the phantom's unknown rotation <= 2 deg and offset <= 3 px): error = the largest image
    # distance (px) between where the two poses put the corners of the folds' footprint
    est = _footprint_px(attrs["camera_rotation_deg"], attrs["camera_offset_px"])
    true = _footprint_px(truth["camera_rotation_deg"], truth["camera_offset_px"])
    guess = _footprint_px(0.0, [79.5 - 9 * 15 / 2, 79.5])  # 160 x 160 px, 9 px/mm, L = 15 mm
    err, guess_err = np.linalg.norm(est - true, axis=1).max(), np.linalg.norm(guess - true, axis=1).max()
    rot_err = abs(attrs["camera_rotation_deg"] - truth["camera_rotation_deg"])
    print(f"pose error: {rot_err:.3f} deg, footprint {err:.2f} px; the centred guess: "
          f"{abs(truth['camera_rotation_deg']):.3f} deg, {guess_err:.2f} px")
    # measured 0.051 deg, 1.08 px since session 41 placed mid-length by the motion's symmetry with both ends of the
    # gap in view (along the glottis 1.01 px off on this 12-frame window, 0.76 px on a whole cycle; the gap's extent
    # 0.20 px here, but 1.30 mm off on widened seed 4114, whose opening is wider toward one end); 0.53 px with the
    # extent since session 30's edges beside dark walls (0.031 deg, 0.89 px before; 0.007 deg, 0.92 px with the
    # threshold detection before session 16); 0.05 deg is 0.12 px over the glottis
    assert rot_err < 0.08 and err < 1.4 and err < 0.5 * guess_err   # the centred guess: 1.78 deg, 3.96 px
    again = run_vfcli("optimize", path, *FIT, "--set", "optimize.max_iterations=4", "--run", "short")
    assert "up to date" in again.stdout


def test_setup_with_pressure_loads_is_refused_and_resume_without_a_checkpoint_says_so(store):
    """`--setup 3x3x10-two-sided --loads pressure` fitted the pressure model with the setup silently dropped (a
    result equal to the default run's); `--resume` of a run with no checkpoint started afresh without a word."""
    path, _ = store
    before = {p.name: p.stat().st_mtime_ns for p in path.parent.rglob("*")}
    res = run_vfcli("optimize", path, "--setup", "3x3x10-two-sided", "--loads", "pressure", "--run", "both")
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert "--setup 3x3x10-two-sided fits the paper's free force field, --loads pressure" in res.stderr
    assert {p.name: p.stat().st_mtime_ns for p in path.parent.rglob("*")} == before
    res = run_vfcli("optimize", path, *FIT, "--set", "optimize.max_iterations=1", "--run", "fresh", "--resume")
    assert res.returncode == 0, res.stderr
    assert "--resume: no checkpoint of this run" in res.stderr and "fitting from the start" in res.stderr


def test_resume_after_sigkill_ends_where_an_uninterrupted_run_ends(store):
    path, _ = store
    opts = [*FIT, "--set", "optimize.max_iterations=7"]
    assert run_vfcli("optimize", path, *opts, "--run", "whole").returncode == 0
    ckpt = checkpoint_path(path, "killed")
    proc = subprocess.Popen([sys.executable, "-m", "vfcli.cli.main", "optimize", str(path), *map(str, opts), "--run", "killed"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if ckpt.exists():
            with np.load(ckpt) as z:
                if int(z["iteration"]) >= 3:
                    break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with Store(path).read() as r:
        assert not r.has_stage("optimize", "killed")  # nothing half-written in the store
    # info names the stopped fit and the command that continues it (it said nothing of the checkpoint; then it
    # printed `--resume` alone, which the run's own --setup/--set settings made start afresh: hF, session 37)
    with np.load(ckpt) as z:
        stopped_at = int(z["iteration"])
    info = run_vfcli("info", path)
    line = next(ln for ln in info.stdout.splitlines() if "optimize run 'killed' was stopped" in ln)
    assert f"was stopped at iteration {stopped_at}: `vfcli optimize {path} --run killed --resume --set" in line, line
    command = shlex.split(line.split("`")[1])
    # --resume with other settings is refused, naming them and the command; the checkpoint and the store stay
    before = {p.name: p.stat().st_mtime_ns for p in [path, *sorted(path.parent.glob("rec.h5.parts/*"))]}
    res = run_vfcli("optimize", path, "--run", "killed", "--resume")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert f"--resume: run 'killed' was stopped at iteration {stopped_at} with other settings (" in res.stderr
    assert "optimize.setup '3x3x10-one-sided' (now " in res.stderr and res.stderr.split("`")[1] == line.split("`")[1]
    assert ckpt.exists() and {p.name: p.stat().st_mtime_ns for p in [path, *sorted(path.parent.glob("rec.h5.parts/*"))]} == before
    res = run_vfcli(*command[1:])                       # the command info printed, as a user pastes it
    assert res.returncode == 0, res.stderr
    assert not ckpt.exists() and "was stopped" not in run_vfcli("info", path).stdout
    with Store(path).read() as r:
        a = r.read("optimize", "controls", "whole")
        b = r.read("optimize", "controls", "killed")
        ha = r.read("optimize", "history_total", "whole")
        hb = r.read("optimize", "history_total", "killed")
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hb, ha, rtol=1e-12)


def _inferior_truth(path, raw, run):
    """(estimate, stated std, truth) of the inferior-surface displacements over the run's window."""
    from vfcli.model.mesh import FoldMesh
    from vfcli.synth.scoring import side_truth
    from vfcli.store.mesh import read_mesh

    t, _ = read_truth(raw / "truth.h5")
    tm = FoldMesh(**{k.split("/")[1]: t[k] for k in t if k.startswith("mesh/")})
    with Store(path).read() as r:
        mesh = read_mesh(r)
        disp = r.read("optimize", "displacements", run).astype(float)[:-1]
        std = r.read("optimize", "displacement_std", run).astype(float)[:-1]
        sim_time = r.read("optimize", "sim_time", run)
    true = t["frames/displacement"][np.searchsorted(t["frames/time"], sim_time[:-1] - 1e-9)].astype(float)
    nodes, ref = side_truth(mesh.uv, mesh.node_side, tm.uv, tm.node_side, true, 1)
    return disp[:, nodes], std[:, nodes], ref


@pytest.fixture(scope="module")
def pressure_run(store, tmp_path_factory):
    """optimize --loads pressure, run "p": (coverage of the inferior surface's 90 % intervals,
    relative RMS error, relative RMS stated std, uncertainty map path)."""
    path, raw = store
    png = tmp_path_factory.mktemp("unc") / "unc.png"
    res = run_vfcli("optimize", path, "--loads", "pressure", "--set", "optimize.n_frames=48",
                    "--set", "optimize.first_frame=10", "--set", "mesh.target_edge_mm=2.5", "--run", "p",
                    "--uncertainty-map", png)
    assert res.returncode == 0, res.stderr
    est, std, ref = _inferior_truth(path, raw, "p")
    err = est - ref
    coverage = interval_coverage(est, std, ref)
    rel_err = np.sqrt(np.mean(err ** 2)) / np.sqrt(np.mean(ref ** 2))
    rel_std = np.sqrt(np.mean(std ** 2)) / np.sqrt(np.mean(est ** 2))
    print(f"inferior: error {100 * rel_err:.1f} %, stated {100 * rel_std:.1f} %, 90 % interval coverage "
          f"{100 * coverage:.1f} %")
    return coverage, rel_err, rel_std, png


def test_pressure_loads_state_an_uncertainty_that_covers_the_unseen_inferior_surface(store, pressure_run):
    """The error of the reconstructed inferior surface (never observed) is within the stated uncertainty,
    and the map is drawn (measured: error 2.2 %, stated 4.7 % since the instruments' part centres the ridge on
    the joint fit (session 13); 2.2 %, 14.4 % with the L-curve's real corner (session 12); 5.2 %, 10.0 %
    before, 6.5 %, 11.7 % before flow.ldv_skip_gap).  The intervals' floor of 85 % is the two-sided test's
    below: 84.1 % scored without the clamped nodes (90.3 % with them counted as hits; 95.9 %, 90.7 %, 89.5 %
    in the sessions named)."""
    path, _ = store
    coverage, rel_err, rel_std, png = pressure_run
    assert rel_err <= rel_std
    assert png.stat().st_size > 5000
    with Store(path).read() as r:
        attrs = r.attrs("optimize", "p")
    assert attrs["ridge_weight"] > 0 and attrs["residual_n_eff"] > 0


@pytest.mark.xfail(strict=True, reason="scored without the clamped nodes (vfcli/synth/scoring.py, session 13) the "
                   "test phantom's 90 % intervals cover 77.8 % on optimize method 9 (75.4 % on method 8, the load "
                   "model's error measured by the splits, not the gains' ridge share; 84.1 % before): too narrow; "
                   "issue 15 item 6")
def test_the_90_percent_intervals_cover_85_to_95_percent_of_the_truth(pressure_run):
    """The issue's claim, two-sided: a 90 % interval is neither too narrow nor too wide (measured 77.8 % on optimize
    method 9, error 3.4 % against a stated 4.4 %; 75.4 % and 4.1 % on method 8; 84.1 % before,
    scored without the clamped nodes, 90.3 % with them counted as hits, since the instruments' part
    centres the ridge on the joint fit; 95.9 % with session 12's
    L-curve and the ridge centred on 0, 90.7 % before it, 89.5 % before flow.ldv_skip_gap; the Laplace
    posterior scaled by the residual's size gave 98.6 %)."""
    coverage = pressure_run[0]
    assert 0.85 <= coverage <= 0.95, f"coverage {100 * coverage:.1f} %"


def test_the_stated_uncertainty_does_not_hang_on_the_gains_ridge_share(store, pressure_run):
    """The gains' share of the ridge (``PressureLoad.penalty_operator``, 1e-6) is a numerical device, so the
    stated uncertainty of the inferior surface must not follow it: the run's problem rebuilt from the store, its
    sandwich MSE (vfcli/inverse/sandwich.py) with the share at 1e-8 must state the inferior surface within 10 % of
    what it states at 1e-6. Measured 0.0082 against 0.0083 mm since the expected bias leaves out the ridge's device
    entries (``vfcli.inverse.sandwich.prior_part``, optimize method 8); before, 0.0087 against 0.0379 mm, 0.23
    times (on widened seed 4001, 0.22 times)."""
    import scipy.sparse as sp

    from vfcli.config import RecordingConfig
    from vfcli.inverse.linearization import gauss_newton_model
    from vfcli.inverse.sandwich import sandwich
    from vfcli.inverse.uncertainty import displacement_std
    from vfcli.stages.diagnose import run_recording_config
    from vfcli.store.fit import problem_of_store
    from vfcli.store.mesh import read_mesh
    from vfcli.store.runs import read_run

    path, _ = store
    with Store(path).read() as r:
        stored = read_run(r, "p")
        roi = np.asarray(r.attrs("flow").get("roi_origin_px", (0.0, 0.0)), float)
        problem, _ = problem_of_store(r, run_recording_config(RecordingConfig(), stored.config, stored.attrs, roi))
        inferior = read_mesh(r).node_side == 1
    x = stored.controls.ravel()
    u = problem.displacements(x)
    frames = problem.freeze(x, u)
    model = gauss_newton_model(problem, x, frames, u)
    stated = {}
    for share in (1e-6, 1e-8):
        diag = problem.penalty.diagonal().copy()
        diag[diag < 0.5] = share                                   # the gains' entries (the free corrections carry 1)
        problem.penalty = sp.diags(diag).tocsr()
        sd = displacement_std(sandwich(problem, x, model, frames, u).covariance, model.linearization)[:-1][:, inferior]
        stated[share] = float(np.sqrt(np.mean(sd ** 2)))
    print(f"inferior stated sd: {stated[1e-6]:.4f} mm at a share of 1e-6, {stated[1e-8]:.4f} mm at 1e-8")
    assert stated[1e-8] == pytest.approx(stated[1e-6], rel=0.1)


def test_the_static_shape_under_the_mean_pressure_is_recovered_and_stated(store, pressure_run):
    """The mean over the window of the inferior surface's vertical displacement (the static shape
    under the recorded mean pressure, which the velocities alone do not fix) is stored with its
    stated standard deviation, apart from the oscillating part: measured +0.951 mm +- 0.046 mm
    against the phantom's +0.944 mm, all of it carried by the measured pressure's gains (session 12's
    L-curve shrinks the free correction to the noise's share; before: +0.891 +- 0.094 mm, the gains
    +0.879 mm)."""
    path, raw = store
    with Store(path).read() as r:
        attrs = r.attrs("optimize", "p")
    est, _, ref = _inferior_truth(path, raw, "p")
    true_z = float(ref.mean(axis=0)[:, 2].mean())
    z, z_std = attrs["inferior_static_mean_z_mm"], attrs["inferior_static_mean_z_std_mm"]
    print(f"static mean z: {z:+.3f} +- {z_std:.3f} mm, true {true_z:+.3f} mm; "
          f"from the pressure's gains {attrs['inferior_static_mean_z_from_pressure_mm']:+.3f} mm; oscillating part "
          f"stated to {attrs['inferior_oscillating_uncertainty_rel']:.3f}")
    assert z == pytest.approx(float(est.mean(axis=0)[:, 2].mean()), abs=1e-5)   # the stored figure is the run's
    assert abs(z - true_z) < 0.05                                                 # measured 0.007 mm
    assert abs(z - true_z) <= 1.645 * z_std and 0.02 < z_std < 0.25              # measured 0.046 mm
    assert 0.5 * z < attrs["inferior_static_mean_z_from_pressure_mm"] < 1.5 * z
    assert 0 < attrs["inferior_oscillating_uncertainty_rel"] < 0.3               # measured 0.047 (0.105 in session 12)


def test_uncertainty_map_without_the_uncertainty_is_a_config_error(store, tmp_path):
    path, _ = store
    res = run_vfcli("optimize", path, "--loads", "pressure", "--set", "optimize.uncertainty=false",
                    "--uncertainty-map", tmp_path / "u.png", "--run", "nomap")
    assert res.returncode == 2 and "optimize.uncertainty" in res.stderr
    assert not (tmp_path / "u.png").exists()
    with Store(path).read() as r:
        assert not r.has_stage("optimize", "nomap")


def _forward_store(path, case, masks, pad_rows: int, pad_cols: int, roi: bool) -> None:
    """A store of the forward case's window: the frames as recorded (``roi``: the case's
    128 x 96 grid, an ingest ROI whose corner is (pad_cols, pad_rows) in the full frame) or the
    full frame (the case's grid padded by nothing-seen pixels)."""
    from vfcli.config import MeshConfig

    m = case.measurement
    f, h, w = m.valid.shape
    vel, valid, gap = m.velocity.astype(np.float32), m.valid, masks
    if not roi:
        big = (f, h + 2 * pad_rows, w + 2 * pad_cols)
        sl = (slice(None), slice(pad_rows, pad_rows + h), slice(pad_cols, pad_cols + w))
        vel_b, valid_b, gap_b = np.zeros((*big, 3), np.float32), np.zeros(big, bool), np.zeros(big, bool)
        vel_b[sl], valid_b[sl], gap_b[sl] = vel, valid, gap
        vel, valid, gap = vel_b, valid_b, gap_b
    mesh = case.model.mesh
    store = Store(path)
    with store.write("test") as wr:
        with wr.stage("mesh", config_json=MeshConfig().model_dump_json()) as s:
            for key, arr in mesh.to_arrays().items():
                s.put(key, arr)
            s.set_attrs(youngs_modulus_pa=4400.0, poisson_ratio=0.499, density_kg_m3=1070.0)
        with wr.stage("flow", config_json="{}") as s:
            s.put("gap_mask", gap)
            s.put("frame_time", m.times)
            s.set_attrs(px_per_mm=8.0, roi_origin_px=np.array([pad_cols, pad_rows] if roi else [0, 0], float))
        with wr.stage("fields", config_json="{}") as s:
            s.put("velocity", vel)
            s.put("valid", valid)
            s.put("frame_time", m.times)


def test_a_configured_pose_with_an_roi_gives_the_fit_of_the_full_frame(tmp_path):
    """camera.offset_px is in full-frame pixels; the stored frames of an ROI start at its corner.
    The fit of the ROI must be the fit of the full frame (before the fix it was off by the ROI
    origin: another camera, another fit). The ROI run also has another live [mesh] material:
    the fit uses the material /mesh was built for (before, the live config's: another fit)."""
    from _forward_case import CAMERA, forward_case

    from vfcli.camera.raster import gap_mask, rasterize
    from vfcli.model.mesh import TAG_FIXTURE
    from vfcli.stages.base import RunContext
    from vfcli.stages.optimize import run_optimize

    case = forward_case()
    mesh = case.model.mesh
    free = mesh.face_tag != TAG_FIXTURE
    u = case.problem.displacements(case.x_true)
    masks = np.array([gap_mask(CAMERA, rasterize(CAMERA, mesh.nodes + u[k], mesh.faces[free]), mesh.face_fold[free])
                      for k in range(len(case.measurement.times))])
    assert masks.any(axis=(1, 2)).sum() >= 4               # the gap opens: the gap term is active
    pad_rows, pad_cols = 20, 30
    offset_full = (CAMERA.offset_px[0] + pad_cols, CAMERA.offset_px[1] + pad_rows)
    sets = ["camera.pose='config'", f"camera.offset_px=[{offset_full[0]}, {offset_full[1]}]", "camera.rotation_deg=0.0",
            "optimize.loads='free'", "optimize.setup='3x3x10-one-sided'", "optimize.first_frame=0",
            f"optimize.n_frames={len(case.measurement.times)}", "optimize.max_iterations=2", "optimize.uncertainty=false"]
    fits = {}
    for name, roi in (("full", False), ("roi", True)):
        path = tmp_path / f"{name}.h5"
        _forward_store(path, case, masks, pad_rows, pad_cols, roi)
        live = ["mesh.youngs_modulus_pa=8800.0", "mesh.density_kg_m3=2000.0"] if roi else []
        run_optimize(RunContext.open(path, overrides=sets + live), "r")
        with Store(path).read() as r:
            fits[name] = (r.read("optimize", "controls", "r"), r.read("optimize", "history_total", "r"),
                          r.attrs("optimize", "r"))
    (x_full, e_full, a_full), (x_roi, e_roi, a_roi) = fits["full"], fits["roi"]
    assert e_full[-1] < 0.9 * e_full[0]                     # the fit moved
    np.testing.assert_allclose(e_roi, e_full, rtol=1e-6)
    np.testing.assert_allclose(x_roi, x_full, rtol=1e-5, atol=1e-6 * np.abs(x_full).max())
    np.testing.assert_allclose(a_roi["camera_offset_px"], CAMERA.offset_px, atol=1e-12)
    np.testing.assert_allclose(a_full["camera_offset_px"], offset_full, atol=1e-12)
    assert a_roi["pose_source"] == "config"


def test_the_default_window_is_one_glottal_cycle_of_the_recording(store):
    """No optimize.n_frames: the run fits ceil(fps / f0) frames with sync's f0 of the video (the phantom's
    120 Hz at 10 kHz: 84), reported in its summary and attributes."""
    path, _ = store
    res = run_vfcli("optimize", path, "--setup", "3x3x10-one-sided", "--set", "mesh.target_edge_mm=2.5",
                    "--set", "optimize.max_iterations=1", "--set", "optimize.uncertainty=false", "--run", "cycle",
                    "--json")
    assert res.returncode == 0, res.stderr
    with Store(path).read() as r:
        attrs = r.attrs("optimize", "cycle")
        f0 = float(r.attrs("sync")["f0_video_hz"])
        dt = float(np.median(np.diff(r.read("fields", "frame_time"))))
        n_sim = len(r.read("optimize", "sim_time", "cycle"))
    assert abs(f0 - 120.0) < 0.5
    assert attrs["window_frames"] == int(np.ceil(1.0 / (f0 * dt) - 1e-6)) == 84 == n_sim - 1
    assert '"window": "frames 0-83"' in res.stdout


def test_a_pressure_window_ending_at_the_last_frame_names_the_frame_it_can_end_at(store):
    """A window ending at the video's last frame passed the window check, then the pressure load refused it in
    other words ("the pressure record covers ... the fitted window ..."): the simulation runs one frame past the
    window.  The refusal now names the last frame a window can end at, and a window ending there fits."""
    path, _ = store
    with Store(path).read() as r:
        n_video = len(r.read("fields", "frame_time"))
    files = lambda: {p.name: p.stat().st_mtime_ns for p in [path, *sorted(path.parent.glob("rec.h5.parts/*"))]}  # noqa: E731
    before = files()
    window = ["--loads", "pressure", "--set", f"optimize.first_frame={n_video - 8}", "--set", "mesh.target_edge_mm=2.5",
              "--set", "optimize.max_iterations=1", "--set", "optimize.uncertainty=false", "--run", "end"]
    res = run_vfcli("optimize", path, *window, "--set", "optimize.n_frames=8")
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    line = res.stderr.strip()
    assert f"optimize window: frames {n_video - 8}-{n_video - 1} need the pressure up to" in line, line
    assert f"end it at frame {n_video - 2} or earlier (optimize.n_frames = 7)" in line, line
    assert files() == before
    res = run_vfcli("optimize", path, *window, "--set", "optimize.n_frames=7")
    assert res.returncode == 0, res.stderr
    with Store(path).read() as r:
        assert r.attrs("optimize", "end")["window_frames"] == 7
    res = run_vfcli("optimize", path, *window, "--set", "optimize.n_frames=9")
    assert res.returncode == 2 and f"frames {n_video - 8}-{n_video} but the recording has {n_video} frames" in res.stderr
