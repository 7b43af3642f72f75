"""The closure figures of bench/bench_contact_closure.py on analytic areas and fields: a glottal area that
passes linearly through zero at uniformly spread sampling phases has clipping indices in [-1, 0) with mean
-0.5; one clipped by a jump of J slopes has its mean moved by J and is found; the closed stretches, the
cycles' closed quotients and the seam's speed ratio of a stopped band."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np

from conftest import ROOT

_spec = importlib.util.spec_from_file_location("bench_contact_closure", ROOT / "bench" / "bench_contact_closure.py")
bc = importlib.util.module_from_spec(_spec)
sys.modules["bench_contact_closure"] = bc
_spec.loader.exec_module(bc)


def _triangle_area(n_frames: int, period: float, floor_slopes: float = 0.0) -> np.ndarray:
    """A triangle wave of unit slope per frame between -0.3 period and +0.7 period, its positive part
    (the folds overlap below zero), and zero wherever it is below ``floor_slopes`` (a clip of that jump)."""
    t = np.arange(n_frames, dtype=float)
    ph = (t / period) % 1.0
    tri = np.where(ph < 0.5, ph, 1.0 - ph) * period - 0.15 * period          # slope 1 per frame
    return np.where(tri > floor_slopes, tri, 0.0)


def test_a_smooth_passage_through_zero_gives_indices_in_minus_one_to_zero_with_mean_minus_half():
    # an irrational period spreads the frames' phases at the closures uniformly
    q = np.array([v for _, v in bc.clipping_index(_triangle_area(40000, 37.0 * np.sqrt(2)))])
    assert len(q) > 1000
    assert q.min() >= -1.0 - 1e-9 and q.max() < 1e-9
    mean, se, p = bc.clipping_test(q)
    assert abs(mean + 0.5) < 0.02 and se < 0.01
    assert p > 0.01


def test_a_clipped_closure_moves_the_mean_by_its_jump_and_is_found():
    area = _triangle_area(4000, 37.0 * np.sqrt(2), floor_slopes=0.8)
    q = np.array([v for _, v in bc.clipping_index(area)])
    mean, se, p = bc.clipping_test(q)
    # the jump above the closed level (2 % of the largest area), in slopes (1 per frame)
    assert abs(mean - (-0.5 + 0.8 - bc.CLOSED_SHARE * area.max())) < 0.06
    assert p < 1e-6
    # a few edges (as a recording's four cycles give) still find a jump of 1.5 slopes
    q_few = np.array([v for _, v in bc.clipping_index(_triangle_area(330, 37.0 * np.sqrt(2), floor_slopes=1.5))])
    assert 8 <= len(q_few) <= 20
    assert bc.clipping_test(q_few)[2] < 0.01


def test_closed_runs_and_cycle_closed_quotients():
    area = np.array([3.0, 1.0, 0.0, 0.0, 2.0, 4.0, 0.01, 0.0, 5.0])
    assert bc.closed_runs(area) == [(2, 3), (6, 7)]          # 0.01 <= 2 % of 5 is closed
    cycle = np.array([-1, 0, 0, 0, 0, 1, 1, 1, -1])
    np.testing.assert_allclose(bc.cycle_closed_quotients(area, cycle), [0.5, 2 / 3])
    kinds = [k for k, _ in bc.clipping_index(area)]
    # the first closing has two falling open frames; the last opening has one open frame after it
    assert kinds == ["closing", "opening"]


def test_seam_speed_ratio_is_zero_for_a_stopped_band_and_one_for_a_uniform_motion():
    f, h, w = 4, 40, 30
    gap = np.zeros((f, h, w), bool)
    gap[0, 19:21, 5:25] = True                               # open in frame 0: a slit along x (rows lateral)
    visible = ~gap
    rows = np.arange(h)[None, :, None]
    vel = np.zeros((f, h, w, 3), np.float32)
    vel[..., 1] = np.where(np.abs(rows + 0.0 - 19.5) < 3, 0.0, 50.0)   # the band at the seam stopped
    closed = np.array([False, True, True, True])
    assert bc.seam_speed_ratio(gap, visible, vel, closed) == 0.0
    vel[..., 1] = 50.0
    np.testing.assert_allclose(bc.seam_speed_ratio(gap, visible, vel, closed), 1.0)


def test_the_clipping_test_keeps_its_level_with_as_few_edges_as_a_recording_has():
    # under the smooth null the indices are uniform in [-1, 0); a recording gives 9-14 edges
    rng = np.random.default_rng(7)
    for n in (9, 14):
        p = np.array([bc.clipping_test(rng.uniform(-1.0, 0.0, n))[2] for _ in range(4000)])
        rate = float(np.mean(p < 0.05))
        assert abs(rate - 0.05) < 3.5 * np.sqrt(0.05 * 0.95 / 4000), (n, rate)
