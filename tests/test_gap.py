"""Gap threshold, mask and glottal area on a synthetic video with an exact slit."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from _flow_phantom import SlitPhantom
from vfcli.errors import ConfigError
from vfcli.gap import gap_mask, gap_threshold, glottal_area, midline_from_masks

CYCLE = [0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30, 33, 36, 40, 46, 52, 58, 64]  # frames of one 150 Hz cycle


@pytest.fixture(scope="module")
def video():
    ph = SlitPhantom()
    frames = np.stack([ph.render(ph.frame_time(k)) for k in CYCLE])
    return ph, frames, gap_threshold(frames)


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_threshold_lies_between_gap_and_fold_surface(video):
    ph, frames, threshold = video
    # well above the gap's noise, well below the bright silicone
    assert ph.gap_counts + 10 * ph.noise_counts < threshold < 0.7 * ph.level_counts


def test_plain_otsu_would_split_the_texture_but_ours_finds_the_gap(video):
    from vfcli.gap import _otsu

    ph, frames, threshold = video
    x = frames.astype(float).ravel()
    hist, edges = np.histogram(x, 1024, (x.min(), x.max()))
    naive = edges[_otsu(hist)[0]]
    open_frames = [i for i, k in enumerate(CYCLE) if ph.gap_area_px2(ph.frame_time(k)) > 1000]
    iou = lambda th: np.mean([_iou(gap_mask(frames[i], th), ph.gap_mask(ph.frame_time(CYCLE[i]))) for i in open_frames])
    assert iou(threshold) > 0.9
    assert iou(naive) < iou(threshold) - 0.1


def test_gap_iou_above_0_9_when_open(video):
    ph, frames, threshold = video
    inter = union = 0
    for i, k in enumerate(CYCLE):
        t = ph.frame_time(k)
        est, true = gap_mask(frames[i], threshold), ph.gap_mask(t)
        inter += (est & true).sum()
        union += (est | true).sum()
        if ph.gap_area_px2(t) > 1500:  # > 6.7 mm^2, widest point > ~10 px: about half open
            assert _iou(est, true) > 0.9, k
    assert inter / union > 0.9  # pooled over the whole cycle, nearly closed frames included


def test_closed_frames_have_no_gap_despite_dark_contact_line(video):
    ph, frames, threshold = video
    closed = [i for i, k in enumerate(CYCLE) if ph.gap_area_px2(ph.frame_time(k)) == 0]
    assert len(closed) >= 4
    for i in closed:
        assert (frames[i] < threshold).any()  # dark texture / contact line pixels exist
        assert not gap_mask(frames[i], threshold).any()


def test_glottal_area_within_5_percent_when_open(video):
    ph, frames, threshold = video
    for i, k in enumerate(CYCLE):
        t = ph.frame_time(k)
        true_mm2 = ph.gap_area_px2(t) / ph.px_per_mm**2
        if true_mm2 > 1000 / ph.px_per_mm**2:
            est = glottal_area(gap_mask(frames[i], threshold), ph.px_per_mm)
            assert abs(est - true_mm2) < 0.05 * true_mm2, (k, est, true_mm2)


def test_glottal_area_counts_pixels_over_scale_squared():
    m = np.zeros((2, 10, 10), bool)
    m[0, 2:4, 1:6] = True  # 10 px
    assert glottal_area(m[0], 2.0) == pytest.approx(2.5)
    np.testing.assert_allclose(glottal_area(m, 2.0), [2.5, 0.0])
    with pytest.raises(ConfigError):
        glottal_area(m, 0.0)


def test_specks_off_the_midline_and_dark_texture_without_core_are_rejected():
    frame = np.full((100, 120), 2000, np.uint16)
    frame[48:53, 10:110] = 100  # the gap: black slit on the midline
    frame[5:15, 20:30] = 100  # black blob far from the midline
    frame[30:38, 60:70] = 800  # dark texture near the midline: below threshold, no core
    frame[25, 30] = 100  # single dark pixel: median filter
    m = gap_mask(frame, 1000.0)
    expected = np.zeros_like(m)
    expected[48:53, 10:110] = True
    assert _iou(m, expected) > 0.97
    assert not m[5:15, 20:30].any() and not m[30:38, 60:70].any() and not m[25, 30]


def test_two_openings_on_the_midline_are_both_kept():
    frame = np.full((100, 120), 2000, np.uint16)
    frame[47:53, 10:50] = 100
    frame[47:53, 70:110] = 100
    m = gap_mask(frame, 1000.0)
    assert m[50, 30] and m[50, 90] and not m[50, 60]


def test_columns_lateral_axis_is_the_transpose():
    frame = np.full((100, 120), 2000, np.uint16)
    frame[10:90, 57:63] = 100
    frame[20:30, 5:12] = 100  # far from the midline column 60
    m = gap_mask(frame, 1000.0, lateral_axis=1)
    assert m[50, 60] and not m[25, 8]
    np.testing.assert_array_equal(m, gap_mask(frame.T, 1000.0, lateral_axis=0).T)


def test_threshold_warns_when_the_gap_never_opens(video, caplog):
    ph, frames, _ = video
    closed = np.stack([f for f, k in zip(frames, CYCLE) if ph.gap_area_px2(ph.frame_time(k)) == 0])
    with caplog.at_level(logging.WARNING, logger="vfcli.gap"):
        gap_threshold(closed)
    assert "no distinct edge" in caplog.text or "no gap core" in caplog.text


def test_bad_settings_raise_config_errors():
    f = np.zeros((10, 10), np.uint16)
    with pytest.raises(ConfigError):
        gap_mask(f, 10.0, median_px=4)
    with pytest.raises(ConfigError):
        gap_mask(f, 10.0, lateral_axis=2)
    with pytest.raises(ConfigError):
        gap_threshold(f, open_fraction=0.0)


def test_midline_from_masks_is_the_mean_gap_row_per_column():
    m = np.zeros((2, 20, 4), bool)
    m[0, 8:11, 1] = True  # rows 8, 9, 10
    m[1, 9:14, 1] = True  # rows 9..13
    m[1, 3, 2] = True
    c = midline_from_masks(m)
    assert np.isnan(c[0]) and np.isnan(c[3])
    assert c[1] == pytest.approx((8 + 9 + 10 + 9 + 10 + 11 + 12 + 13) / 8)
    assert c[2] == 3.0
