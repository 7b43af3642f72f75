"""The dark surroundings of the folds: what the gap's level and mask must not be read from.

In many rigs the folds' block sits on a dark background (the channel's walls, the fixture, the
unlit room behind it) that fills the image around the folds. The gap threshold is read from the
darkest pixels of the open frames (:func:`vfcli.flow.gap.detect.gap_threshold`); where the
surroundings are as dark as a blurred slit, that level is the surroundings', and the mask then
takes the silicone's dark texture for gap (widened null 2042: blur 2.75 px, the surround at
680-800 counts, the slit's darkest pixels at 690-1010; threshold 745, gap IoU 0.00).

The surroundings differ from the gap in time: the glottis closes in the cycle, so every pixel of
the folds' block is lit in some sampled frame, while the surroundings stay dark in all of them.
:func:`dark_surround` takes the brightest value of each pixel over the sampled frames, splits that
image in two (Otsu), and keeps as surroundings the dark class's thick regions that touch the image
border, widened by a margin for the blurred edge of the block.

Limit: a glottis that stays open in every sampled frame by more than twice the opening's radius (20 px on
a 256 px image, 1.3 mm at 15 px/mm; the widened draw's pre-phonatory gap is at most 0.3 mm) and runs into
the surroundings would be taken for them; ``flow.exclude_surround = false`` turns the step off.
"""
from __future__ import annotations

import numpy as np

from vfcli.flow.gap.detect import MIN_SEPARATION, otsu_split

#: The surroundings' regions are opened with a disc of this fraction of the image's smaller side
#: (radius; 10 px on 256 px): a glottis that never closes stays dark in every frame too, but it is a
#: slit, far thinner than the disc, and the opening erases it.
OPENING_RADIUS_FRACTION = 0.04
#: A region of the surroundings covers at least this fraction of the image and touches its border.
MIN_AREA_FRACTION = 0.02
#: The surroundings are widened by this many px: the block's blurred edge is darker than the folds.
MARGIN_PX = 3


def dark_surround(frames_sample: np.ndarray, *, n_bins: int = 512) -> np.ndarray | None:
    """The image region that stays dark in every sampled frame and surrounds the folds, (H, W) bool.

    1. The brightest value of each pixel over the sample (the glottis is closed, or at its
       narrowest, in some sampled frame: the folds' block is lit everywhere).
    2. Otsu's split of that image. Where the two classes are not distinct (separation below
       :data:`vfcli.flow.gap.detect.MIN_SEPARATION`: the folds fill the view, or the surroundings
       are as light as the silicone) there are no dark surroundings: None.
    3. The dark class, opened with a disc of :data:`OPENING_RADIUS_FRACTION` of the smaller image
       side (a never-closing slit is erased); its 8-connected regions that touch the image border
       and cover at least :data:`MIN_AREA_FRACTION` of the image are the surroundings.
    4. Where the surroundings vary over the sample as much as the rest of the image (the median
       over their pixels of the temporal standard deviation at least the rest's), they are not
       static: the dark class was the folds themselves (a surround brighter than the folds); None.
    5. Widened by :data:`MARGIN_PX`.

    Parameters
    ----------
    frames_sample : (k, H, W) array of counts
        Frames spread over at least one cycle (``flow.sample_frames``).
    n_bins : int
        Histogram bins of step 2.

    Returns
    -------
    (H, W) bool or None
        True in the surroundings; None when there are none.
    """
    import cv2

    frames = np.asarray(frames_sample, dtype=np.float32)
    if frames.ndim != 3 or frames.shape[0] == 0:
        raise ValueError(f"dark surround: expected (k, H, W) frames, got shape {frames.shape}")
    brightest = frames.max(axis=0)
    lo, hi = float(brightest.min()), float(brightest.max())
    if hi <= lo:
        return None
    hist, edges = np.histogram(brightest, bins=n_bins, range=(lo, hi + 1e-3))
    k, separation = otsu_split(hist)
    if separation < MIN_SEPARATION:
        return None
    dark = (brightest < edges[k]).astype(np.uint8)
    h, w = dark.shape
    r = max(1, int(round(OPENING_RADIUS_FRACTION * min(h, w))))
    dark = cv2.morphologyEx(dark, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    _, labels, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
    x, y, cw, ch, area = (stats[1:, i] for i in range(5))
    border = (x == 0) | (y == 0) | (x + cw == w) | (y + ch == h)
    keep = border & (area >= MIN_AREA_FRACTION * h * w)
    if not keep.any():
        return None
    region = np.concatenate([[False], keep])[labels]
    spread = frames.std(axis=0)
    if len(frames) > 1 and np.median(spread[region]) >= np.median(spread[~region]):
        return None
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * MARGIN_PX + 1,) * 2)
    return cv2.dilate(region.astype(np.uint8), kernel) > 0
