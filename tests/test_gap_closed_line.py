"""The closed line against a slit (issue 15, item 4: the gap on other optics; session 40).

Widened seed 4106 (sharp optics, 0.53 px; the folds closed for more than half the cycle) found a gap in 72 of its
130 closed frames: on a stretch of the glottis the contact line of the closed folds is darker than the recording's
threshold (410-480 counts against 551), so it passes the detection, and its narrow dip fits as a one-pixel slit at
the prior's gap level, which the rules of :func:`vfcli.flow.gap.subpixel.segment.raw_edges` kept. The per-ray crease
levels did not stop it: the detection is never below the threshold there, and the crease they measure (each ray's
lightest dips) is the crease at its lightest.

The calibration now measures how dark each ray's crease gets in the sampled frames where the whole glottis is
closed (:func:`vfcli.flow.gap.subpixel.crease.closed_floor`), and a ray shows the gap only where it is darker than
that (rule (d)), unless the closed frames' dips there are gap-like themselves (a gap that never closes, a chink).
Here: a glottis closed half the cycle, slits of 1.5-8 px, a 0.5 px PSF, dark medial walls, and along 16 of its 112
columns a contact line 2.5 px wide at 500 counts (530 in the median through the PSF, against a threshold of 805 and a
gap of 150): in a closed frame the edge fit reads it as a slit at the gap level, but it is there in every frame, the
closed ones too.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.ndimage import gaussian_filter

from vfcli.config import FlowConfig
from vfcli.flow.gap.subpixel import segment_gap
from vfcli.flow.gap.subpixel.crease import closed_floor, closed_sample
from vfcli.flow.pipeline import calibrate

H, W, MID = 96, 128, 47.0          # rows lateral, one ray per column; the glottal midline row
GLOTTIS = (8, 120)                 # columns of the glottis
LINE = (56, 72)                    # columns where the closed folds' contact line is dark
LINE_PX, LINE_LEVEL = 2.5, 500.0   # its width, px, and its level, counts
CHINK = (100, 120)                 # columns of the chink of test_a_chink_that_never_closes_keeps_its_closed_frames
G, T = 150.0, 1500.0               # gap and top surface, counts
WIDTHS = [0.0] * 8 + [1.5, 3.0, 5.0, 7.0, 8.0, 7.0, 5.0, 3.0]    # one cycle, px: closed half of it
SUB = 4                            # sub-pixels per pixel and axis


def _frame(width: float, rng, sigma: float = 0.5, chink_px: float = 0.0,
           line: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) counts and the true gap fraction of each pixel.

    The medial walls darken towards the midline (seen edge-on: 1500 -> 600 counts over a few px); along
    LINE the closed folds' contact line, LINE_PX wide at LINE_LEVEL (a crease that is there in every frame,
    under the slit when open); the slit of ``width`` px is at the gap level, at least ``chink_px`` wide on the
    CHINK columns. Integrated over each pixel, blurred by the PSF, with noise of 15 counts.
    """
    r = (np.arange(H * SUB) + 0.5) / SUB - 0.5
    c = (np.arange(W * SUB) + 0.5) / SUB - 0.5
    rr, cc = np.meshgrid(r, c, indexing="ij")
    in_glottis = (cc > GLOTTIS[0] - 0.5) & (cc < GLOTTIS[1] - 0.5)
    local = np.where((cc > CHINK[0] - 0.5) & (cc < CHINK[1] - 0.5), max(width, chink_px), width)
    slit = (np.abs(rr - MID) < 0.5 * local) & in_glottis
    dark = (np.abs(rr - MID) < 0.5 * LINE_PX) & (cc > LINE[0] - 0.5) & (cc < LINE[1] - 0.5) & line
    tissue = np.where(dark, LINE_LEVEL, T - 900.0 * np.exp(-np.abs(rr - MID) / 2.0))
    image = np.where(slit, G, tissue).reshape(H, SUB, W, SUB).mean(axis=(1, 3))
    frac = slit.reshape(H, SUB, W, SUB).mean(axis=(1, 3))
    image = gaussian_filter(image, sigma) + rng.normal(0.0, 15.0, (H, W))
    return np.clip(image, 0, 4095).astype(np.uint16), frac


def _video(**kw):
    rng = np.random.default_rng(40)
    made = [_frame(w, rng, **kw) for w in WIDTHS * 4]
    return np.stack([f for f, _ in made]), np.stack([t for _, t in made]), np.array(WIDTHS * 4)


def _areas(frames, gap):
    return np.array([segment_gap(f, gap).mask.sum() for f in frames]), [segment_gap(f, gap) for f in frames]


def test_closed_sample_takes_the_frames_the_whole_glottis_calls_closed():
    rng = np.random.default_rng(1)
    k, n = 32, 50
    open_ = np.arange(k) % 8 >= 4                                      # half the cycle open
    # each ray's crease lightens and darkens with the phase; open frames darken most rays at once
    crease = 700.0 + 200.0 * np.sin(np.arange(k) * 2 * np.pi / 8)[:, None] + rng.normal(0, 20, (k, n))
    minima = np.where(open_[:, None], rng.uniform(150, 500, (k, n)), crease)
    minima[:, :3] = np.nan                                             # rays not searched
    closed = closed_sample(minima)
    assert closed.sum() == 8 and not (closed & open_).any()
    floor = closed_floor(minima)
    assert np.isnan(floor[:3]).all()
    # the eight lightest frames' crease (phases sin = 1 and 0.71: 840-900 counts, noise 20): its floor below all
    # of them but the tail, above every open dip (measured 746-801)
    med = np.median(minima[closed][:, 3:])
    assert np.all((floor[3:] > 500.0) & (floor[3:] < med - 30.0))


def test_a_dark_contact_line_is_not_a_slit_in_the_closed_frames_and_the_slits_keep_their_width():
    frames, frac, widths = _video()
    cal = calibrate(frames, FlowConfig(), 1e4, 15.0, 0.0)
    gap = cal.gap
    assert gap is not None and gap.ray_closed_floor is not None
    line_cols = slice(LINE[0] + 2, LINE[1] - 2)
    assert cal.threshold > frames[widths == 0][:, 46:49, line_cols].min()   # the line passes the threshold
    closed = widths == 0
    found, segs = _areas(frames, gap)
    found_before, _ = _areas(frames, replace(gap, ray_closed_floor=None))
    # before: a "gap" along the dark line in every closed frame (measured 32 of 32, 15-49 px each)
    assert (found_before[closed] > 0).sum() >= 16
    # now none
    assert not found[closed].any()
    # the slits: every open frame found, along the dark line too, and the area within a few per cent of the
    # truth (measured: +3.7 % in all, the dark walls; the same with the floor left out)
    assert (found[~closed] > 0).all()
    true = frac[~closed].sum()
    area = sum(float(np.nansum(s.e1 - s.e0)) for s, o in zip(segs, ~closed) if o)
    assert abs(area / true - 1) < 0.05
    for s, w in zip(segs, widths):
        if w >= 3.0:
            assert np.isfinite((s.e1 - s.e0)[line_cols]).all()        # the slit across the dark line


def test_a_chink_that_never_closes_keeps_its_closed_frames():
    """A gap 3 px wide open in every frame on 20 columns (no contact line): the closed frames' dips there are the
    gap's own, nearer the gap level than the threshold, so the ray gets no floor and the chink is found in the closed
    frames as before (without that guard: in none of them)."""
    frames, _, widths = _video(chink_px=3.0, line=False)
    cal = calibrate(frames, FlowConfig(), 1e4, 15.0, 0.0)
    chink = slice(CHINK[0] + 2, CHINK[1] - 2)
    assert np.isnan(cal.gap.ray_closed_floor[chink]).all()
    closed = widths == 0
    _, segs = _areas(frames[closed], cal.gap)
    for s in segs:
        w = (s.e1 - s.e0)[chink]
        assert np.isfinite(w).all()
        assert abs(np.median(w) - 3.0) < 0.3                           # measured: 3.11 (the dark walls)


def test_a_crease_that_darkens_through_the_closed_phase_keeps_its_floor_above_the_gap():
    """Widened seed 4503 (blur 0.98 px, the folds closed a quarter of the cycle): in the sampled closed frames a
    ray's crease runs from 350-450 counts to 700-1100 as the closed phase goes (the folds' contact rolls), clusters,
    not a normal scatter, so the median less 3 MADs fell below 0 on 62 of its 173 rays, below the gap's 140-215: no
    dip could pass rule (d) there, and 65 of its 188 open frames, openings up to 3.75 px at the gap level, were read
    closed. The crease gets no darker than its darkest closed dip but for the pixels' noise and texture (the scatter
    between neighbouring rays): the floor is that, where the normal tail would fall below it (4503: 153 of the 188
    open frames found, no closed one read open; docs/benchmarks.md "Session 76")."""
    rng = np.random.default_rng(3)
    k, n, noise = 64, 60, 20.0
    phase = np.arange(k) % 16
    open_ = phase >= 4                                                    # closed a quarter of the cycle
    # the closed phase's crease: dark early, light late (420 -> 950), shading along the glottis, noise
    crease = (np.array([420.0, 560.0, 800.0, 950.0])[np.minimum(phase, 3)][:, None]
              + 40.0 * np.sin(np.arange(n) / 9.0)[None, :] + rng.normal(0, noise, (k, n)))
    minima = np.where(open_[:, None], rng.uniform(150, 250, (k, n)), crease)
    closed = closed_sample(minima)
    assert closed.sum() == 16 and not (closed & open_).any()
    m = minima[closed]
    med = np.median(m, axis=0)
    normal = med - 3.0 * 1.4826 * np.median(np.abs(m - med), axis=0)
    assert np.all(normal < 150.0)                 # the normal tail's floor: below every open dip (measured -298..-83)
    floor = closed_floor(minima)
    darkest = m.min(axis=0)
    ok = np.isfinite(floor)
    assert ok.sum() >= n - 4
    # the darkest crease less 3 sd of the noise (60 counts), smoothed over 5 rays: measured 14-94 counts below it
    assert np.all(floor[ok] < darkest[ok]) and np.all(floor[ok] > darkest[ok] - 150.0)
    assert np.all(floor[ok] > 250.0)              # every open dip passes rule (d)
