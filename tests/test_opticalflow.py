"""Optical flow against the exact flow of a synthetic video (no image warping involved)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _flow_phantom import SlitPhantom
from vfcli.errors import ConfigError
from vfcli.flow.gap.detect import gap_mask, gap_threshold, glottal_area
from vfcli.flow.gap.opening import OpeningTracker
from vfcli.flow.gap.opening import gap_centers
from vfcli.flow.optical_flow import (
    FlowEstimator,
    flow_stream,
    intensity_range,
    pixel_to_model_velocity,
    sparse_to_dense,
    split_fold_flow,
    to_uint8,
)

PAIRS = [2, 8, 28, 33, 50]  # opening fast, opening, closing, closing fast, closed
STREAM = list(range(26, 35))  # nine consecutive frames while the gap closes (fastest lateral motion)


@pytest.fixture(scope="module")
def phantom():
    return SlitPhantom()


@pytest.fixture(scope="module")
def pairs(phantom):
    frames = {k: phantom.render(phantom.frame_time(k)) for k in sorted({*PAIRS, *(k + 1 for k in PAIRS)})}
    rng = intensity_range(np.stack(list(frames.values())))
    return frames, rng


@pytest.fixture(scope="module")
def stream(phantom):
    frames = np.stack([phantom.render(phantom.frame_time(k)) for k in STREAM])
    threshold = gap_threshold(frames, open_fraction=1.0)
    rng = intensity_range(frames)
    out = list(flow_stream(iter(frames), fps=phantom.fps, px_per_mm=phantom.px_per_mm, threshold=threshold,
                           counts_range=rng, t0_s=phantom.frame_time(STREAM[0])))
    return frames, threshold, out


def _epe(phantom, frames, rng, estimator, k):
    """Mean end-point error (px/frame) on all fold pixels, and on the fast-moving fold
    pixels (> 0.5 px/frame) farther than 3 px from the gap; and the top speed."""
    import cv2

    flow = estimator(to_uint8(frames[k], rng), to_uint8(frames[k + 1], rng))
    true = phantom.true_flow(phantom.frame_time(k), phantom.frame_time(k + 1))
    fold = np.isfinite(true[..., 0])
    far = cv2.dilate((~fold).astype(np.uint8), np.ones((7, 7), np.uint8)) == 0
    speed = np.linalg.norm(true, axis=-1)
    err = np.linalg.norm(flow - true, axis=-1)
    fast = fold & far & (speed > 0.5)
    return float(err[fold].mean()), (float(err[fast].mean()) if fast.any() else 0.0), float(np.nanmax(speed))


@pytest.mark.parametrize(
    "method, preset, limit, fast_limit",
    [("sparse_to_dense", None, 0.08, 0.25), ("dis", "medium", 0.1, 0.2), ("dis", "fast", 0.12, 0.35)],
)
def test_flow_end_point_error_below_0_3_px_per_frame_on_the_folds(phantom, pairs, method, preset, limit, fast_limit):
    """Measured (px/frame): mean over the fold up to 0.042 (S2D), 0.056 (DIS medium),
    0.069 (DIS fast); fast pixels >3 px from the gap up to 0.19 / 0.12 / 0.29."""
    frames, rng = pairs
    est = FlowEstimator(method, dis_preset=preset or "medium")
    fastest = 0.0
    for k in PAIRS:
        epe, epe_fast, top = _epe(phantom, frames, rng, est, k)
        fastest = max(fastest, top)
        assert epe < limit, (k, epe)  # the target is 0.3
        assert epe_fast < fast_limit, (k, epe_fast)
    assert fastest > 0.9  # realistic motion: a zero flow would be > 0.5 px/frame off on the fast pixels


def test_split_folds_sharpens_the_flow_next_to_the_gap(phantom, pairs):
    """Measured near-edge (<= 3 px) EPE, S2D: 0.20-0.48 px/frame plain, 0.058-0.078 split (0.16-0.31 of plain)."""
    import cv2

    frames, rng = pairs
    est = FlowEstimator()
    threshold = gap_threshold(np.stack(list(frames.values())))
    for k in (8, 28, 33):
        a, b = to_uint8(frames[k], rng), to_uint8(frames[k + 1], rng)
        centre = gap_centers(gap_mask(frames[k], threshold))
        assert np.isfinite(centre).sum() > 100
        centre = np.interp(np.arange(256), np.flatnonzero(np.isfinite(centre)), centre[np.isfinite(centre)])
        true = phantom.true_flow(phantom.frame_time(k), phantom.frame_time(k + 1))
        fold = np.isfinite(true[..., 0])
        near = fold & (cv2.dilate((~fold).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0)
        plain = np.linalg.norm(est(a, b) - true, axis=-1)[near].mean()
        split = np.linalg.norm(split_fold_flow(est, a, b, centre) - true, axis=-1)[near].mean()
        assert split < 0.15 and split < 0.5 * plain, (k, plain, split)


def test_eight_bit_mapping_is_fixed_per_recording():
    a = np.array([[0, 2040, 4095]], np.uint16)
    rng = (0.0, 4080.0)
    assert to_uint8(a, rng).tolist() == [[0, 128, 255]]
    b = np.array([[2040]], np.uint16)  # same counts in another frame: same 8-bit value
    assert to_uint8(b, rng)[0, 0] == to_uint8(a, rng)[0, 1]
    lo, hi = intensity_range(np.arange(1001.0), 0.0, 100.0)
    assert (lo, hi) == (0.0, 1000.0)


def test_pixel_flow_converts_to_model_velocity_with_scale_rate_and_rotation():
    flow = np.array([[1.0, 0.5]])
    np.testing.assert_allclose(pixel_to_model_velocity(flow, 20.0, 10_000.0), [[500.0, 250.0]])
    # rotation 90 deg: [col, row] = s R [x, y], R = [[0, -1], [1, 0]]: a +x motion moves +row
    np.testing.assert_allclose(pixel_to_model_velocity(np.array([[0.0, 1.0]]), 1.0, 1.0, 90.0), [[1.0, 0.0]], atol=1e-12)
    with pytest.raises(ValueError):
        pixel_to_model_velocity(flow, 0.0, 1.0)


def test_stream_yields_every_frame_on_the_frame_time_base(phantom, stream):
    frames, _, out = stream
    assert [f.index for f in out] == list(range(len(STREAM)))
    np.testing.assert_allclose([f.time_s for f in out], [phantom.frame_time(k) for k in STREAM])


def test_stream_velocity_matches_the_instantaneous_velocity_at_frame_times(phantom, stream):
    frames, _, out = stream
    eps = 1e-8
    assert len(out) == len(STREAM)
    for f, k in zip(out, STREAM):
        t = phantom.frame_time(k)
        v_true = (phantom.true_flow(t, t + eps) - phantom.true_flow(t, t - eps)) / (2 * eps) / phantom.fps
        fold = np.isfinite(v_true[..., 0]) & ~f.mask
        err = np.linalg.norm(f.flow_px - v_true, axis=-1)[fold].mean()
        assert err < 0.12, (k, err)  # measured 0.024-0.062 px/frame, the extrapolated ends included
        np.testing.assert_allclose(f.velocity_mm_s, pixel_to_model_velocity(f.flow_px, phantom.px_per_mm, phantom.fps), rtol=1e-6)


def test_stream_with_split_folds_matches_the_instantaneous_velocity(phantom, stream):
    frames, threshold, _ = stream
    out = list(flow_stream(iter(frames), fps=phantom.fps, px_per_mm=phantom.px_per_mm, threshold=threshold,
                           counts_range=intensity_range(frames), t0_s=phantom.frame_time(STREAM[0]), split_folds=True))
    eps = 1e-8
    assert len(out) == len(STREAM)
    for f, k in zip(out[1:-1], STREAM[1:-1]):
        t = phantom.frame_time(k)
        v_true = (phantom.true_flow(t, t + eps) - phantom.true_flow(t, t - eps)) / (2 * eps) / phantom.fps
        fold = np.isfinite(v_true[..., 0]) & ~f.mask
        assert np.linalg.norm(f.flow_px - v_true, axis=-1)[fold].mean() < 0.1, k
        assert np.all(f.flow_px[f.mask] == 0)


def test_stream_sets_the_gap_to_zero_and_reports_mask_area_and_opening(phantom, stream):
    frames, threshold, out = stream
    tracker = OpeningTracker(frames.shape[1:])
    assert any(f.mask.any() for f in out)
    for f, frame in zip(out, frames):
        expected = gap_mask(frame, threshold)
        np.testing.assert_array_equal(f.mask, expected)
        assert np.all(f.flow_px[f.mask] == 0) and np.all(f.velocity_mm_s[f.mask] == 0)
        assert f.area_mm2 == pytest.approx(glottal_area(expected, phantom.px_per_mm))
        np.testing.assert_allclose(f.opening_px, tracker.update(expected))


def test_stream_holds_only_a_few_frames(phantom):
    taken = []

    def frames():
        rng = np.random.default_rng(0)
        for i in range(50):
            taken.append(i)
            yield rng.integers(1000, 3000, (32, 40)).astype(np.uint16)

    gen = flow_stream(frames(), fps=1e4, px_per_mm=15.0, threshold=500.0, counts_range=(0, 4095), method="dis")
    next(gen)
    assert len(taken) <= 3
    next(gen)
    assert len(taken) <= 4
    rest = list(gen)
    assert len(rest) == 48 and len(taken) == 50


def test_stream_accepts_batches_and_short_videos():
    rng = np.random.default_rng(1)
    batch = rng.integers(1000, 3000, (2, 16, 16)).astype(np.uint16)
    out = list(flow_stream([batch], fps=1e4, px_per_mm=15.0, threshold=10.0, counts_range=(0, 4095), method="dis"))
    assert len(out) == 2
    np.testing.assert_array_equal(out[0].flow_px, out[1].flow_px)
    with pytest.raises(ConfigError):
        list(flow_stream([batch[:1]], fps=1e4, px_per_mm=15.0, threshold=10.0, counts_range=(0, 4095), method="dis"))


def test_unknown_method_or_preset_is_a_value_error():
    with pytest.raises(ValueError):
        FlowEstimator("farneback")
    with pytest.raises(ValueError):
        FlowEstimator("dis", dis_preset="slow")


def _textured(shape, shift, seed=0):
    """A smooth random texture (uint8) and the same texture moved by ``shift`` (d col, d row) px."""
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.uint8), (5, 5), 1.5)
    m = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    return img, cv2.warpAffine(img, m, (shape[1], shape[0]))


def test_sparse_to_dense_is_opencvs_flow_bit_for_bit_where_opencv_is_safe():
    """256 x 256 frames, grid step 8: 1024 matches, more than k = 128, where the library is sound."""
    import cv2

    a, b = _textured((256, 256), (1.3, -0.7))
    ref = cv2.optflow.calcOpticalFlowSparseToDense(a, b, None, 8, 128, 0.05, True, 500.0, 1.5)
    mine = sparse_to_dense(a, b)
    assert np.array_equal(mine, ref)
    assert abs(float(np.median(mine[..., 0])) - 1.3) < 0.05 and abs(float(np.median(mine[..., 1])) + 0.7) < 0.05


def test_sparse_to_dense_on_frames_with_fewer_matches_than_k_gives_the_motion_and_never_crashes():
    """48 x 64 frames, grid step 8: 48 matches < k = 128, where OpenCV reads past its arrays (opencv_contrib
    issue 4195); 6 x 8: one match. In a subprocess, so a crash is a failure of this test, not of the suite."""
    code = (
        "import numpy as np, sys; sys.path.insert(0, 'tests'); from test_opticalflow import _textured\n"
        "from vfcli.flow.optical_flow import sparse_to_dense\n"
        "for i in range(20):\n"
        "    a, b = _textured((48, 64), (0.8, 0.4), seed=i)\n"
        "    f = sparse_to_dense(a, b)\n"
        "    c = f[12:36, 16:48]\n"
        "    assert abs(float(np.median(c[..., 0])) - 0.8) < 0.1 and abs(float(np.median(c[..., 1])) - 0.4) < 0.1\n"
        "a, b = _textured((6, 8), (0.5, 0.0))\n"
        "assert not sparse_to_dense(a, b).any()\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=Path(__file__).resolve().parents[1])
    assert res.returncode == 0 and res.stdout.strip() == "ok", (res.returncode, res.stderr[-2000:])
