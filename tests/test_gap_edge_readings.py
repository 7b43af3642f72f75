"""Two readings of the gap's edges: the flow step says when the video does not pin them (issue 15, items 1 and 4).

Under Lambert shading with the lamp off axis, the medial wall that faces away from the lamp is a dark band beside
one edge of the gap; the edge fit, held by pixels it takes as surely gap, read widened seeds 4112, 4165 and 4149's
glottal areas +55, +40 and +31 % with the gap "resolved" and no warning (docs/benchmarks.md, "Session 57").
Since session 59 the flow step's fit is no longer held by those pixels (a start only); the held reading is the
first of the two it compares.
"""
from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from vfcli.config import FlowConfig
from vfcli.flow.gap.subpixel.ambiguity import AMBIGUOUS_AREA, area_disagreement
from vfcli.flow.gap.subpixel.profile import EdgeModel, fit_slit_profiles, searched_edges
from vfcli.flow.gap.subpixel.ray_edges import fit_ray_edges
from vfcli.flow.pipeline import calibrate

#: Ray 100 of frame 100 of widened seed 4165 under Lambert shading (bench/bench_gap_optics.py's render, lateral
#: px 154-177, counts): the gap between 159.5 and 168.5 (the renderer's truth), the shaded wall brightening from
#: 275 to 670 counts over 168-172, the lit fold beyond; the flow step's start (158.5, 172.5) and surely-gap
#: bounds (159, 172), its blur 1.085 px and the ray's gap level 195 counts
RAY = np.array([1775, 1744, 1720, 1502, 875, 579, 339, 185, 190, 192, 192, 171, 178, 195, 275, 395, 499, 619, 671,
                874, 1099, 1391, 1717, 1876], float)
RAY_ROWS = 154.0 + np.arange(RAY.size)


def test_the_searched_edge_is_not_held_by_wall_pixels_taken_for_surely_gap():
    """Held at the surely-gap pixels the fit ends on its bound, 3.5 px beyond the true edge; searched, it finds the
    lower misfit 0.9 px from it (measured: 172.00 with misfit 208384 counts^2, searched 169.45 with 109272)."""
    y, r = RAY[None], RAY_ROWS[None]
    start0, start1 = np.array([158.5]), np.array([172.5])
    held = fit_slit_profiles(y, r, start0, start1, 1.085, 195.0, inner=(np.array([159.0]), np.array([172.0])))
    found = searched_edges(y, r, held.e0, held.e1, 1.085, 195.0, reach_px=4.0)
    assert held.e1[0] == pytest.approx(172.0, abs=0.01)
    assert abs(found.e1[0] - 168.5) < 1.0 and found.cost[0] < 0.6 * held.cost[0]
    assert abs(found.e0[0] - 159.5) < 1.6          # the lit side: measured 157.92 both ways


def test_the_flow_steps_edges_are_not_held_by_wall_pixels_and_the_held_reading_still_is():
    """The flow step's fit (fit_ray_edges as segment calls it) starts from the detection and from the surely-gap
    pixels but is not held by them: on the real ray the shaded edge is read 0.2 px from the truth at a fifth of the
    held fit's misfit (measured: 168.29, misfit 36 587 counts^2 summed over the window; held 172.00, 192 999), the
    lit edge 1.5 px out either way (158.04 free, 157.90 held; truth 159.5). Held (ambiguity's first reading), the
    fit ends on its bound. The ray is a column of a frame, lit tissue continuing beyond its window."""
    col = np.concatenate([np.full(154, RAY[0]), RAY, np.full(40, RAY[-1])])
    frame = np.repeat(col[:, None], 3, axis=1)
    run = (np.full(3, 158.0), np.full(3, 173.0))                   # the detection's pixel boundaries
    sure = (np.full(3, 159.0), np.full(3, 172.0))                  # the pixels surely in the gap
    model, level = EdgeModel(195.0, 1.085), np.full(3, 195.0)
    free = fit_ray_edges(frame, *run, model, 0, inner=sure, gap_counts=level)
    held = fit_ray_edges(frame, *run, model, 0, inner=sure, gap_counts=level, held=True)
    assert np.all(np.abs(free.e1 - 168.5) < 0.5) and np.all(held.e1 == pytest.approx(172.0, abs=0.01))
    assert np.all(np.abs(free.e0 - 159.5) < 1.7) and np.all(np.abs(held.e0 - 159.5) < 1.7)
    assert np.all(free.cost < 0.3 * held.cost)


def test_area_disagreement_is_the_relative_change_of_the_summed_open_widths():
    fit = lambda e0, e1: SimpleNamespace(e0=np.array(e0, float), e1=np.array(e1, float))
    started = [fit([10, 10, np.nan], [20, 18, np.nan]), fit([5], [9])]            # 10 + 8 + 4 = 22 px
    searched = [fit([10, 11, 12], [19, 18, 11]), fit([5], [9])]                   # 9 + 7 + 0 + 4 = 20 px
    assert area_disagreement(started, searched) == pytest.approx(2 / 22, rel=1e-12)
    assert np.isnan(area_disagreement([fit([np.nan], [np.nan])], searched))


def _walled_video(wall_px: float, sigma_px: float = 0.7) -> np.ndarray:
    """(16, 100, 120) counts: a glottal cycle of a slit around row 50 (gap 230 counts, half-widths 0-5 px) between
    lit tissue (1500 counts) and, beyond its lower edge, a medial wall in shade ``wall_px`` wide that brightens from
    400 counts at the edge by 100 counts/px (the wall's band stays when the glottis closes); integrated over each
    pixel, blurred by ``sigma_px``, noise 10 counts."""
    halves = [0, 0, 1.0, 2.5, 4.0, 5.0, 5.0, 4.0, 2.5, 1.0, 0, 0, 0, 1.5, 3.5, 5.0]
    sub = 8
    r = (np.arange(100 * sub) + 0.5) / sub - 0.5
    d = r - 50.0
    frames = []
    for k, half in enumerate(halves):
        column = np.full(r.shape, 1500.0)
        column[np.abs(d) < half] = 230.0
        wall = (d >= half) & (d < half + wall_px)
        column[wall] = 400.0 + 100.0 * (d[wall] - half)
        scene = np.repeat(column.reshape(100, sub).mean(axis=1)[:, None], 120, axis=1)
        frame = gaussian_filter(scene, (sigma_px, 0)) + np.random.default_rng(k).normal(0, 10, scene.shape)
        frames.append(np.clip(frame, 0, 4095))
    return np.stack(frames).astype(np.uint16)


def _doubt_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "does not pin the gap's edges" in r.getMessage()]


def test_a_slit_beside_a_shaded_wall_is_read_two_ways_and_flow_says_so(caplog):
    """A 4 px shaded wall: the started and the searched readings of the sampled gap differ by 8.8 % (measured; the
    searched one puts the shaded edge about 1 px into the gap); a clean slit's agree to 0.0004 %."""
    with caplog.at_level(logging.INFO, logger="vfcli"):
        walled = calibrate(_walled_video(4.0), FlowConfig(), 1e4, 15.0, 0.0)
    assert walled.gap_resolved and 0.06 < walled.edge_disagreement < 0.15
    assert len(_doubt_lines(caplog)) == 1
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="vfcli"):
        clean = calibrate(_walled_video(0.0), FlowConfig(), 1e4, 15.0, 0.0)
    assert clean.gap_resolved and clean.edge_disagreement < 0.01 and not _doubt_lines(caplog)


@pytest.mark.xfail(strict=True, reason="a 2.5 px shaded wall (400-650 counts) is the slit model's best reading on "
                   "either start: both put the shaded edge at the wall's far side, 2 px out (the sampled glottal area "
                   "+20-27 %), and agree to 0.16 %, so flow does not warn; the slit model knows one level beside each "
                   "edge (vfcli/flow/gap/subpixel/ambiguity.py; docs/benchmarks.md, 'Session 58')")
def test_a_narrow_shaded_wall_is_doubted_too(caplog):
    with caplog.at_level(logging.INFO, logger="vfcli"):
        walled = calibrate(_walled_video(2.5), FlowConfig(), 1e4, 15.0, 0.0)
    assert walled.edge_disagreement > AMBIGUOUS_AREA and _doubt_lines(caplog)
