"""One rotation convention, applied once, from ingest to optimize (issue 15).

A phantom is rendered through a camera turned by 30, -90 and 180 deg (the synth camera
of the default phantom, turned about the frame centre; frames of 128 x 128, 112 x 160 and
160 x 112 px, width x height), ingested, synced and run through
`flow` and `mesh` by the real command, with the rotation configured (camera.pose =
'config'). The optimisation problem the store gives must see the measured velocity in the
model's axes, (u, v) against the true (x, y) surface velocity of the phantom's truth, and
its gap term must have rays where the recording shows the gap.
"""
from __future__ import annotations

import re

import numpy as np
import pytest

from conftest import run_vfcli
import vfcli.synth.phantom as phantom
from vfcli.camera.camera import Camera
from vfcli.config import RecordingConfig, load_config
from vfcli.stages.optimize import problem_of_store
from vfcli.stages.synth import run_synth
from vfcli.store import Store, read_truth

#: 120 frames at f0 250 Hz (three cycles: sync needs two) hold the fit's window of frames 20-60; the 200 frames of 120 Hz
#: before took the file 48 s alone, now 38 s, the errors the same (0.31-0.32 of the RMS, corr(v, y) 0.954-0.957)
PHANTOM = {"f0_hz": 250.0, "duration_s": 0.012, "ldv_epoch_s": 0.03, "target_edge_mm": 2.0, "n_phase": 64,
           "width_px": 128, "height_px": 128, "px_per_mm": 7.0, "supersample": 1, "seed": 3}


def _turned_camera(angle_deg: float):
    """phantom_camera with the folds' centre at the frame centre, the model turned by angle_deg."""

    def camera(cfg, mesh_cfg, rng):
        rng.uniform(-1, 1, size=3)   # the draws of the original (same seed, same rest of the phantom)
        th = np.radians(angle_deg)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        centre_px = np.array([(cfg.width_px - 1) / 2, (cfg.height_px - 1) / 2])
        offset = centre_px - cfg.px_per_mm * rot @ np.array([mesh_cfg.length_mm / 2, 0.0])
        return Camera(cfg.px_per_mm, float(angle_deg), (float(offset[0]), float(offset[1])), cfg.width_px,
                      cfg.height_px)

    return camera


#: the frames (width, height) px at each angle: not square at -90 and 180 deg, each with the glottis along the longer
#: side, so that an image axis taken for the other (rows for columns) shows (every phantom of the suite was square)
FRAMES = {30.0: (128, 128), -90.0: (112, 160), 180.0: (160, 112)}


@pytest.fixture(scope="module", params=[30.0, -90.0, 180.0])
def turned(request, tmp_path_factory):
    angle = request.param
    d = tmp_path_factory.mktemp(f"rot{int(angle)}")
    raw, store = d / "raw", d / "rec.h5"
    width, height = FRAMES[angle]
    cfg = RecordingConfig(synth={**PHANTOM, "width_px": width, "height_px": height})
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(phantom, "phantom_camera", _turned_camera(angle))
        run_synth(raw, cfg)
    truth, attrs = read_truth(raw / "truth.h5", ["screen/velocity", "screen/visible"])
    offset = np.asarray(attrs["camera_offset_px"], float)
    assert attrs["camera_rotation_deg"] == pytest.approx(angle)
    cam = ["--set", "camera.pose='config'", "--set", f"camera.rotation_deg={angle}",
           "--set", f"camera.offset_px=[{offset[0]}, {offset[1]}]"]
    # the scan grid turns with the camera: at +-90 deg its rows are the camera's columns, and the rig's
    # 17 x 22 grid is still read as one (vfcli.io.ldv.grid), with the default config
    for args in (["ingest-hsc", store, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms"],
                 ["ingest-ldv", store, raw / "scan.uff"], ["sync", store], ["flow", store],
                 ["mesh", store, "--set", "mesh.target_edge_mm=2.5"]):
        res = run_vfcli(*args, "--config", raw / "recording.toml", *cam)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(store).read() as r:
        assert tuple(r.attrs("ldv")["grid_shape"]) == (17, 22)
    _, config = load_config(raw / "recording.toml", overrides=list(cam[1::2]) + ["optimize.n_frames=40",
                                                                                 "optimize.first_frame=20"])
    return angle, store, config, truth


def test_the_measured_velocity_is_in_model_axes_and_the_gap_term_has_rays(turned):
    angle, store, config, truth = turned
    with Store(store).read() as r:
        problem, setup = problem_of_store(r, config)
    assert setup.rotation_deg == pytest.approx(angle)
    m = problem.meas
    f0 = config.optimize.first_frame
    true_v = truth["screen/velocity"][f0:f0 + len(m.times), ..., :2]
    sel = m.valid & truth["screen/visible"][f0:f0 + len(m.times)] & np.isfinite(true_v).all(axis=-1)
    est, ref = m.velocity[..., :2][sel], true_v[sel]
    # the error of the (x, y) velocity over the fold surface, and the lateral (y) motion, which dominates:
    # the measured y must follow the true y, not x or -y
    rel_err = np.sqrt(np.mean(np.sum((est - ref) ** 2, axis=-1)) / np.mean(np.sum(ref ** 2, axis=-1)))
    corr_y = np.corrcoef(est[:, 1], ref[:, 1])[0, 1]
    print(f"rotation {angle:+.0f} deg: (x, y) error {rel_err:.2f} of the RMS, corr(v, y) {corr_y:.3f}, "
          f"{len(problem.rays)} gap rays, {np.isfinite(m.gap_lo).sum()} measured silhouettes")
    assert corr_y > 0.9          # measured 0.95 at every angle (before the fix: 0.0 at -90 deg, -0.95 at 180 deg)
    assert rel_err < 0.45       # measured 0.31-0.32 (0.33 at 30 deg on the 120 Hz phantom; rotated twice: 0.58)
    assert len(problem.rays) > 20
    assert np.isfinite(m.gap_lo[:, problem.rays]).any()


@pytest.mark.parametrize("turned", [30.0], indirect=True)
def test_a_fit_whose_gap_term_is_empty_says_so(turned):
    """A configured pose that puts the model beside the glottis (offset 30 mm off): the gap term has
    no rays, and the stored summary of the run says the fit ignored the gap (with the settings to check)."""
    angle, store, _, _ = turned
    assert angle == 30.0
    res = run_vfcli("optimize", store, "--setup", "3x3x10-one-sided", "--set", "optimize.first_frame=20",
                    "--set", "optimize.n_frames=6", "--set", "optimize.max_iterations=1", "--set",
                    "optimize.uncertainty=false", "--set", "camera.pose='config'", "--set", "camera.offset_px=[-200, -200]",
                    "--run", "beside")
    assert res.returncode == 0, res.stderr
    with Store(store).read() as r:
        warnings = r.summary("optimize", "beside")["warnings"]
        axis, flow_axis = r.attrs("optimize", "beside")["gap_lateral_axis"], r.attrs("flow")["lateral_axis"]
    hit = [w for w in warnings if "the gap term has no rays" in w]
    assert len(hit) == 1 and "camera.rotation_deg" in hit[0]
    assert int(axis) == int(flow_axis)         # the run states the image axis of its gap rays (diagnose rebuilds it)


@pytest.mark.parametrize("turned", [30.0], indirect=True)
def test_a_configured_rotation_of_the_wrong_sign_is_a_stored_warning_of_flow(turned, tmp_path):
    """camera.rotation_deg with its sign flipped and camera.pose = 'config' ran to exit 0 with only the static-shape
    warning (inferior surface 6 % off on a widened phantom at 61 deg, 134 % at a half turn, which the gap cannot
    tell): the sampled gap's principal axis, 30 deg here, lies 60 deg from the configured -30. The right rotation
    (the fixture's own flow) draws no such warning."""
    from vfcli.store import copy_store

    angle, store, _, _ = turned
    with Store(store).read() as r:
        assert not [w for w in r.summary("flow")["warnings"] if "from camera.rotation_deg" in w]
        offset = np.asarray(r.attrs("hsc")["offset_px"], float)
    bad = copy_store(store, tmp_path / "rec.h5")
    raw = store.parent / "raw"
    cam = ["--set", "camera.pose='config'", "--set", f"camera.rotation_deg={-angle}",
           "--set", f"camera.offset_px=[{offset[0]}, {offset[1]}]"]
    for args in (["ingest-hsc", bad, raw / "video.cihx", "--pressure", raw / "video_pressure.tdms", "--force"],
                 ["sync", bad], ["flow", bad]):
        res = run_vfcli(*args, "--config", raw / "recording.toml", *cam)
        assert res.returncode == 0, (args[0], res.stderr)
    with Store(bad).read() as r:
        hit = [w for w in r.summary("flow")["warnings"] if "from camera.rotation_deg" in w]
    assert len(hit) == 1, hit
    found = float(re.search(r"the sampled gap runs at ([-0-9.]+) deg in the image, (\d+) deg from", hit[0]).group(1))
    assert abs((found - angle + 90) % 180 - 90) < 1.0 and "60 deg from camera.rotation_deg -30.0 deg" in hit[0]


@pytest.mark.parametrize("turned", [30.0], indirect=True)
@pytest.mark.parametrize("rotation, warned", [(50.0, False), (58.0, True)])
def test_near_a_diagonal_optimize_reads_the_gap_along_flows_axis_and_says_nothing(turned, caplog, rotation, warned):
    """A pose whose rotation lies across a diagonal from the axis /flow measured the gap along: within
    MEASURED_AXIS_TOLERANCE_DEG of the diagonal optimize reads the gap along /flow's axis and does not warn (widened
    seed 4229: the pose -46.6 deg, /flow's masks the other side of the diagonal; optimize advised setting the rotation,
    which changed nothing); further off it still warns, and its advice no longer sends the user to camera.pose =
    'config' without camera.offset_px."""
    import logging

    from vfcli.camera.pose import MEASURED_AXIS_TOLERANCE_DEG, lateral_axis_for

    angle, store, config, _ = turned
    with Store(store).read() as r:
        measured = int(r.attrs("flow")["lateral_axis"])
    assert lateral_axis_for(rotation) != measured and (abs(rotation - 45.0) <= MEASURED_AXIS_TOLERANCE_DEG) != warned
    turned_cfg = config.model_copy(update={"camera": config.camera.model_copy(update={"rotation_deg": rotation})})
    with Store(store).read() as r, caplog.at_level(logging.WARNING, logger="vfcli"):
        problem, setup = problem_of_store(r, turned_cfg)
    hits = [rec.getMessage() for rec in caplog.records if "makes image axis" in rec.getMessage()]
    assert setup.rotation_deg == pytest.approx(rotation)
    assert len(hits) == int(warned)
    assert problem.settings.lateral_axis == (lateral_axis_for(rotation) if warned else measured)
    if warned:
        assert f"about {rotation:.0f} deg" in hits[0] and "camera.offset_px" in hits[0]


def test_a_run_stored_before_the_diagonal_rule_is_rebuilt_with_the_axis_it_was_fitted_on():
    """diagnose rebuilds a run's problem with the gap rays' image axis the run states (``gap_lateral_axis``); a run
    stored before session 63 states none and ran them along its rotation's axis unless within 1 deg of a diagonal, so
    its rebuild does the same, not today's rule (a pose at 50 deg for a gap /flow read along axis 0: axis 1 then)."""
    from vfcli.camera.pose import lateral_axis_for
    from vfcli.stages.diagnose import run_gap_axis

    assert run_gap_axis({"gap_lateral_axis": 0, "camera_rotation_deg": 50.0}, {"lateral_axis": 0}) == 0
    assert run_gap_axis({"camera_rotation_deg": 50.0}, {"lateral_axis": 0}) == lateral_axis_for(50.0) == 1
    assert run_gap_axis({"camera_rotation_deg": 45.5}, {"lateral_axis": 0}) == 0     # within 1 deg: /flow's then too
    assert run_gap_axis({"camera_rotation_deg": 20.0}, {"lateral_axis": lateral_axis_for(20.0)}) == lateral_axis_for(20.0)
