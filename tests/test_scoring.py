"""The phantom scores' own arithmetic (vfcli/synth/scoring.py)."""
import numpy as np

from vfcli.synth.scoring import interval_coverage, opening_width_px, rms


def test_coverage_leaves_out_what_the_model_fixes_and_counts_a_wrong_zero_interval_as_a_miss():
    """A clamped node (stated sd 0, estimate right up to round-off) has no interval: it neither adds
    a hit nor, through a 1e-17 mm round-off error, a miss.  Of 1000 normal errors with their true sd,
    90 % intervals cover 90 % within the binomial spread, whatever share of clamped entries is added,
    and an sd-0 entry that is wrong is a miss."""
    rng = np.random.default_rng(3)
    sd = rng.uniform(0.01, 0.1, 1000)
    truth = rng.normal(size=1000)
    est = truth + sd * rng.normal(size=1000)
    free = interval_coverage(est, sd, truth)
    assert abs(free - 0.90) < 3 * np.sqrt(0.9 * 0.1 / 1000)
    for roundoff in (0.0, 1e-17):
        clamped_est = np.concatenate([est, np.full(300, roundoff)])
        clamped_sd = np.concatenate([sd, np.zeros(300)])
        clamped_truth = np.concatenate([truth, np.zeros(300)])
        assert interval_coverage(clamped_est, clamped_sd, clamped_truth) == free
    wrong = interval_coverage(np.append(est, 0.5), np.append(sd, 0.0), np.append(truth, 0.0))
    assert wrong == (free * 1000) / 1001


def test_the_truth_half_turned_is_the_truth_seen_from_a_camera_turned_by_180_degrees():
    """A pose fitted half a turn off is the same reconstruction in a frame turned by 180 deg about the
    glottis' centre.  A displacement field given in physical coordinates (linear, with no symmetry, so
    every fold, end and component is told apart) is re-expressed through :func:`half_turned` and read
    at the inferior nodes by :func:`side_truth`; it must equal the field evaluated directly in the
    turned frame (position and displacement both turned), and differ from it without the turn."""
    from vfcli.model.m5 import M5Params
    from vfcli.model.mesh import build_mesh
    from vfcli.synth.scoring import half_turned, pose_half_turned, side_truth

    params = M5Params()
    mesh = build_mesh(params, target_edge_mm=1.5)
    turn = np.diag([-1.0, -1.0, 1.0])
    centre = np.array([params.length_mm / 2, 0.0, 0.0])
    a = np.array([[0.02, -0.05, 0.01], [0.04, 0.03, -0.02], [-0.01, 0.06, 0.05]])

    def field(x):                                       # (N, 3) mm -> (2, N, 3) mm at two times
        d = (x - centre) @ a.T + np.array([0.1, -0.2, 0.3])
        return np.stack([d, -0.5 * d])

    disp = field(mesh.nodes)
    # seen from the turned frame: the node at X' sits where the phantom's X = centre + turn (X' - centre) is,
    # and its displacement is turned too
    expected = field(centre + (mesh.nodes - centre) @ turn) @ turn
    nodes, got = side_truth(mesh.uv, mesh.node_side, *half_turned(mesh.uv, mesh.node_side, disp), 1)
    assert len(nodes) == np.sum(mesh.node_side == 1)
    scale = rms(expected[:, nodes])
    # the M5 mesh is symmetric under the turn, so every turned node lands on a node: exact up to round-off
    # (measured 5e-17 of the field's RMS); without the turn the error is 125 %
    assert rms(got - expected[:, nodes]) < 1e-12 * scale
    _, unturned = side_truth(mesh.uv, mesh.node_side, mesh.uv, mesh.node_side, disp, 1)
    assert rms(unturned - expected[:, nodes]) > 0.5 * scale
    assert pose_half_turned(-84.2, 95.8) and pose_half_turned(170.0, -170.0 + 180.0 + 1.0)
    assert not pose_half_turned(179.0, -179.0) and not pose_half_turned(10.0, 99.0)


def test_the_timing_error_over_the_frames_is_that_of_the_instants_matched_by_inverting_each_phase():
    """Epochs whose phase is linear in their own time (each its f0 and start phase, estimated with an
    error), a video phase estimated with a smooth error that grows along the record: the instant of each
    epoch matched to each frame, found by inverting the estimated and the true phases numerically on a fine
    grid, errs by what :func:`sync_frame_error` says (to the grid's interpolation), and not by the offset's
    error alone, which holds at the first frame only."""
    from vfcli.synth.scoring import sync_frame_error, sync_offset_error

    rng = np.random.default_rng(5)
    n_points, fps = 7, 10_000.0
    f0 = 120.0 * (1 + 0.01 * rng.uniform(-1, 1, n_points))
    start_true = rng.uniform(0, 1, n_points)                   # cycles, epoch phase at its first sample
    start_est = start_true + rng.normal(0, 3e-4, n_points)     # the epochs' own phase errors
    t_frame = np.arange(250) / fps
    true_frame_phase = 0.37 + 119.8 * t_frame + 0.02 * np.sin(2 * np.pi * 40 * t_frame)
    video_phase = true_frame_phase + 4e-4 - 0.03 * t_frame + 2e-4 * np.cos(2 * np.pi * 60 * t_frame)
    tau = np.linspace(0, 0.2, 400_001)                         # epoch time, s

    def matched(phase_of_tau, target):                         # first instant at or after 0 with that phase mod 1
        k = np.ceil(phase_of_tau[0] - target)                  # the cycle whose phase lies ahead
        return np.interp(target + k, phase_of_tau, tau)

    err = np.empty((n_points, t_frame.size))
    off_est, off_true = np.empty(n_points), np.empty(n_points)
    for p in range(n_points):
        est_phase, true_phase = start_est[p] + f0[p] * tau, start_true[p] + f0[p] * tau
        off_est[p], off_true[p] = matched(est_phase, video_phase[0]), matched(true_phase, true_frame_phase[0])
        # every frame's instant in the cycle after the offset's, where the two phases meet it
        est_i = np.interp(video_phase - video_phase[0] + est_phase[0] + f0[p] * off_est[p] + 1, est_phase, tau)
        true_i = np.interp(true_frame_phase - true_frame_phase[0] + true_phase[0] + f0[p] * off_true[p] + 1,
                           true_phase, tau)
        err[p] = est_i - true_i
    offset_error = sync_offset_error(off_est, off_true, f0)
    got = sync_frame_error(offset_error, video_phase, true_frame_phase, f0)
    assert np.max(np.abs(got - err)) < 2e-9                     # s: the grid's 0.5 us steps, interpolated
    assert np.sqrt(np.mean(err**2)) > 1e-6                        # the frames' error is not the offset's alone
    assert np.max(np.abs(err - offset_error[:, None])) > 1.5e-6


def test_the_opening_width_is_the_gaps_area_per_length_of_glottis_at_any_angle():
    """A drawn slit 41 px long, its pixel centres within 0.5, 1.5 or 2.5 px of its midline, at 0, 10, 30, 45 and 90
    deg: the width read is its pixel count per pixel of length (the drawn 1, 3 and 5 px along the image axes, 3.49
    px for the 3 px slit at 45 deg, where five rows of the lattice lie within 1.5 px), exactly along the image
    axes and within half a pixel at the oblique angles (pieces one pixel long read up to twice that: 7 for the 5 px
    slit at 45 deg), and 0 in a frame with no gap."""
    rows, cols = np.mgrid[0:120, 0:120].astype(float)
    for angle in (0.0, 10.0, 30.0, 45.0, 90.0):
        a = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
        along = (cols - 60) * a[0] + (rows - 60) * a[1]
        across = -(cols - 60) * a[1] + (rows - 60) * a[0]
        frames = np.stack([np.zeros_like(rows, bool)] + [(np.abs(along) <= 20.5) & (np.abs(across) < w / 2)
                                                          for w in (1.0, 3.0, 5.0)])
        got = opening_width_px(frames, a)
        drawn = frames[1:].sum(axis=(1, 2)) / 41.0
        assert got[0] == 0.0
        np.testing.assert_allclose(got[1:], drawn, atol=0.5 if angle % 90 else 1e-12)
        if angle % 90 == 0:
            np.testing.assert_allclose(got[1:], [1.0, 3.0, 5.0], atol=1e-12)
