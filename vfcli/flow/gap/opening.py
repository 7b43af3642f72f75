"""The gap opening function o(y, t) (paper, section 3.3), streamed frame by frame.

For a screen point y at time t, o is the unsigned *lateral* distance from y to the
closest point of the gap silhouette met by the lateral ray through y (the pixel's
column when rows are lateral). If that ray meets no gap in this frame, o is the
distance to the last known opening location on that ray.

Definitions used here (units: px):

* Rays run along the lateral axis (``lateral_axis=0``: rows are lateral, one ray per
  column; ``lateral_axis=1``: one ray per row).
* The silhouette on a ray is the set of boundaries between a gap and a non-gap pixel,
  at half-integer positions (between pixel centres ``r`` and ``r + 1`` lies the edge
  ``r + 0.5``). The image border is not a silhouette (:mod:`vfcli.flow.gap.rays`).
* The opening location of an open ray is the centre between its outermost silhouette
  points (for a single gap run: the centre of the gap). :class:`OpeningTracker`
  remembers it per ray as the *last known opening location*.
* A ray that has never been open uses a fallback centre: the linear interpolation
  (constant extrapolation at the ends) of the known centres of the other rays; while no
  ray is known yet, ``initial_center`` (see :func:`vfcli.flow.gap.detect.midline_from_masks`) and
  finally the image centre ``(n - 1) / 2``.

:func:`opening_distance` is the pure per-frame function; it serves the measured masks
and, equally, simulated gap masks (pass the measured tracker's fallback centres so
both use the same last known locations). :func:`measured_silhouettes` gives the gap
term of the objective the outermost silhouette points of every frame and ray, with the
same last known locations on closed rays.
"""
from __future__ import annotations

import numpy as np

from vfcli.flow.gap.rays import as_rays, outermost_silhouette, silhouette_points


def gap_centers(mask: np.ndarray, lateral_axis: int = 0) -> np.ndarray:
    """Opening location of each ray of one frame, lateral px; NaN on closed rays.

    Parameters
    ----------
    mask : (H, W) bool
        Gap mask.
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows).

    Returns
    -------
    (n_rays,) float
        Centre between the outermost silhouette points of each ray.
    """
    lo, hi = outermost_silhouette(mask, lateral_axis)
    return 0.5 * (lo + hi)


def opening_distance(mask: np.ndarray, fallback_center: np.ndarray | float, lateral_axis: int = 0) -> np.ndarray:
    """Gap opening function of one frame, o(y), px.

    Parameters
    ----------
    mask : (H, W) bool
        Gap mask of the frame (measured or simulated).
    fallback_center : (n_rays,) float or float
        Lateral position used on rays that meet no gap in this frame (the last known
        opening location), px; NaN entries are not allowed.
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows, one ray per column).

    Returns
    -------
    (H, W) float32
        Unsigned lateral distance from each pixel centre to the nearest silhouette point
        on its ray (inside the gap too), else to the fallback centre.
    """
    m = as_rays(mask, lateral_axis)
    n, n_rays = m.shape
    fallback = np.broadcast_to(np.asarray(fallback_center, dtype=float), (n_rays,))
    if not np.all(np.isfinite(fallback)):
        raise ValueError("opening: fallback_center must be finite on every ray")
    trans, _ = silhouette_points(m)  # edge at i + 0.5 between pixels i and i + 1
    pos = np.arange(n - 1, dtype=np.float32)[:, None] + np.float32(0.5)
    inf = np.float32(np.inf)
    up = np.empty((n, n_rays), np.float32)  # for pixel r: the last edge before r
    up[0] = -inf
    np.maximum.accumulate(np.where(trans, pos, -inf), axis=0, out=up[1:])
    down = np.empty((n, n_rays), np.float32)  # for pixel r: the first edge after r
    down[-1] = inf
    np.minimum.accumulate(np.where(trans, pos, inf)[::-1], axis=0, out=down[-2::-1])
    rows = np.arange(n, dtype=np.float32)[:, None]
    up -= rows
    down -= rows
    dist = np.minimum(np.negative(up, out=up), down, out=up)
    closed = ~trans.any(axis=0)
    if closed.any():
        dist[:, closed] = np.abs(rows - fallback[None, closed].astype(np.float32))
    return dist if lateral_axis == 0 else np.ascontiguousarray(dist.T)


class OpeningTracker:
    """Streams o(y, t) frame by frame, carrying the last known opening location per ray.

    Parameters
    ----------
    shape : (H, W)
        Frame shape, px.
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows, one ray per column).
    initial_center : float or (n_rays,) float, optional
        Opening location assumed before a ray (or any ray) has been seen open, lateral
        px; NaN entries mean unknown. Default: unknown (image centre as a last resort).

    Attributes
    ----------
    center_ : (n_rays,) float
        Last known opening location per ray, NaN where never seen open.

    Examples
    --------
    >>> import numpy as np
    >>> tracker = OpeningTracker((5, 3))
    >>> mask = np.zeros((5, 3), bool); mask[2, :] = True
    >>> tracker.update(mask)[:, 0].tolist()
    [1.5, 0.5, 0.5, 0.5, 1.5]
    >>> tracker.update(np.zeros((5, 3), bool))[:, 0].tolist()  # closed: last centre, row 2
    [2.0, 1.0, 0.0, 1.0, 2.0]
    """

    def __init__(self, shape: tuple[int, int], lateral_axis: int = 0, initial_center: np.ndarray | float | None = None) -> None:
        if lateral_axis not in (0, 1):
            raise ValueError(f"opening: lateral_axis must be 0 (rows) or 1 (columns), got {lateral_axis}")
        self.shape = tuple(int(s) for s in shape)
        self.lateral_axis = lateral_axis
        self.n_lateral = self.shape[lateral_axis]
        self.n_rays = self.shape[1 - lateral_axis]
        init = np.full(self.n_rays, np.nan) if initial_center is None else np.asarray(initial_center, float)
        self.initial_center = np.broadcast_to(init, (self.n_rays,)).copy()
        self.center_ = np.full(self.n_rays, np.nan)

    def fallback_center(self) -> np.ndarray:
        """Per-ray fallback opening location, lateral px, (n_rays,) finite."""
        known = np.where(np.isfinite(self.center_), self.center_, self.initial_center)
        ok = np.isfinite(known)
        if not ok.any():
            return np.full(self.n_rays, 0.5 * (self.n_lateral - 1))
        idx = np.arange(self.n_rays)
        return np.interp(idx, idx[ok], known[ok])

    def observe(self, mask: np.ndarray) -> None:
        """Record the frame's opening locations (rays open in it), without distances."""
        if tuple(np.shape(mask)) != self.shape:
            raise ValueError(f"opening: mask shape {np.shape(mask)} differs from the tracker's {self.shape}")
        centres = gap_centers(mask, self.lateral_axis)
        seen = np.isfinite(centres)
        self.center_[seen] = centres[seen]

    def update(self, mask: np.ndarray) -> np.ndarray:
        """Record the frame's opening locations and return its o(y), (H, W) float32 px."""
        self.observe(mask)
        return opening_distance(mask, self.fallback_center(), self.lateral_axis)


def measured_silhouettes(gap_masks: np.ndarray, lateral_axis: int = 0,
                         initial_center: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Measured gap silhouettes per frame and ray from gap masks.

    Parameters
    ----------
    gap_masks : (F, H, W) bool.
    lateral_axis : 0 (rows lateral, one ray per column) or 1.
    initial_center : fallback opening location before a ray is seen open (see
        :class:`OpeningTracker`).

    Returns
    -------
    lo, hi : (F, n_rays) float64 lateral px of the outermost silhouette points (edges at
        half-integers, :func:`vfcli.flow.gap.rays.outermost_silhouette`); on closed rays both
        are the last known opening location.
    """
    masks = np.asarray(gap_masks, dtype=bool)
    tracker = OpeningTracker(masks.shape[1:], lateral_axis, initial_center)
    lo = np.empty((len(masks), tracker.n_rays))
    hi = np.empty_like(lo)
    for f, mask in enumerate(masks):
        first, last = outermost_silhouette(mask, lateral_axis)
        tracker.observe(mask)
        fb = tracker.fallback_center()
        has = np.isfinite(first)
        lo[f] = np.where(has, first, fb)
        hi[f] = np.where(has, last, fb)
    return lo, hi
