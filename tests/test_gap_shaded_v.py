"""A ray with pixels surely in the gap is open, even where the slit model fits its dip better as a V.

The blurred-slit model says "no gap" with crossed edges (``e1 <= e0``): its gap basis turns negative between
them and the two tissue ramps meet in a V. Widened phantom 4199 (blur 1.05 px, a glottis at -16.5 deg, medial
walls in shade that darken gradually toward the gap) showed the gap at its own level (227-260 counts for a
recorded gap level of 243) on rays whose fit crossed: 12 of the 167 rays across the gap in its widest frame
were closed that way (its sampled glottal area read 17 % low, a third of the rays across the true gap
empty). The profiles below are three such rays of that frame as rendered (image columns 60, 45 and 61; rows
from ``row0``), with the detection's run and the pixel centres darker than half-way from the tissue beside
the gap to the gap level (``inner``).
"""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.flow.gap.subpixel.profile import EdgeModel
from vfcli.flow.gap.subpixel.ray_edges import fit_ray_edges

GAP_COUNTS = 243.0        # the recording's gap level, counts
PSF_SIGMA_PX = 0.984      # its estimated blur

# (profile counts, row0, detection run (e0, e1) px, inner (pixel centres surely in the gap) px, true gap rows)
RAYS = {
    "column 60": ([1676, 1527, 1394, 1326, 1100, 740, 407, 235, 265, 467, 511, 549, 675, 833, 1015], 115,
                  (121.5, 124.5), (122.0, 123.0), (121, 123)),
    "column 45": ([1458, 1261, 1062, 1062, 1006, 818, 549, 336, 260, 333, 501, 636, 823, 1144, 1320], 119,
                  (125.5, 128.5), (127.0, 127.0), (125, 128)),
    "column 61": ([1507, 1516, 1469, 1216, 936, 669, 408, 241, 292, 393, 512, 596, 668, 914, 1142], 115,
                  (121.5, 123.5), (122.0, 123.0), (121, 123)),
}


@pytest.mark.parametrize("name", sorted(RAYS))
def test_a_dip_at_the_gap_level_between_shaded_walls_stays_open(name):
    counts, row0, (a, b), (lo, hi), (t0, t1) = RAYS[name]
    prof = np.full(160, 1500.0)
    prof[row0:row0 + len(counts)] = counts
    frame = np.repeat(prof[:, None], 3, axis=1)                  # three identical rays (columns), rows lateral
    fit = fit_ray_edges(frame, np.full(3, a), np.full(3, b), EdgeModel(GAP_COUNTS, PSF_SIGMA_PX), 0,
                        inner=(np.full(3, lo), np.full(3, hi)), gap_counts=np.full(3, GAP_COUNTS))
    width = fit.e1[0] - fit.e0[0]
    print(f"{name}: edges {fit.e0[0]:.2f} .. {fit.e1[0]:.2f}, level {fit.levels[0, 0]:.0f}")
    # open, and the edges at or beyond the pixels surely in the gap (measured widths 1.55-1.91 px for true
    # pixel runs of 3-4 px: still narrow, the shaded walls' ramps trade against the edges)
    assert fit.e0[0] <= lo and fit.e1[0] >= hi and width > 1.0
    # inside the true gap's pixel run widened by a pixel (the truth masks pixels, not edges; measured: the far edge
    # up to 0.2 px beyond the run's outer pixel boundary, the near one up to 1.5 px inside it)
    assert t0 - 1.0 <= fit.e0[0] and fit.e1[0] <= t1 + 1.0
    assert abs(fit.levels[0, 0] - GAP_COUNTS) < 15


def test_a_ray_with_no_pixel_surely_in_the_gap_may_still_close():
    """Without a pixel centre surely in the gap (``inner`` empty) a crossed fit stays closed: a narrow dark line
    (a closed glottis's crease) is not opened by this rule."""
    counts, row0, (a, b), _, _ = RAYS["column 60"]
    prof = np.full(160, 1500.0)
    prof[row0:row0 + len(counts)] = counts
    frame = np.repeat(prof[:, None], 3, axis=1)
    fit = fit_ray_edges(frame, np.full(3, a), np.full(3, b), EdgeModel(GAP_COUNTS, PSF_SIGMA_PX), 0,
                        inner=(np.full(3, np.inf), np.full(3, -np.inf)), gap_counts=np.full(3, GAP_COUNTS))
    assert not fit.e1[0] > fit.e0[0], (fit.e0[0], fit.e1[0])     # the V: crossed, closed
