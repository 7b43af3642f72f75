"""The tri-variate surface velocity field v(y, t) = (u, v, w) (paper, section 3.2).

* Horizontal (u, v): the optical flow on the pixel grid at the frame times
  (:mod:`vfcli.flow.optical_flow`).
* Vertical w: the LDV velocities synced onto the frame times, interpolated by a
  *thin-plate spline in space* (least squares with configurable smoothing) onto the pixels.

The pipeline uses the field where it is sampled, on the pixels at the frame times
(:func:`combine_fields`).

The TPS is linear in the measured values, so it is built once as a linear operator
``M`` of shape (n_query, n_good) (:class:`LdvTps`): a frame of w is ``M @ w_points``.
Flagged LDV points are left out of the operator (it is built from the good points).

Screen points are ``(col, row)`` pixels with the centre of the first pixel at (0, 0)
(``docs/conventions.md``); times in s; velocities in mm/s.
"""
from __future__ import annotations

import numpy as np

from vfcli.errors import InputDataError

#: Rows of query points evaluated at once when building a TPS operator.
_CHUNK = 16384


def pixel_grid(shape: tuple[int, int]) -> np.ndarray:
    """Pixel centres of an (H, W) image as screen points, (H*W, 2) float (col, row),
    in row-major order (index = row * W + col)."""
    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w]
    return np.stack([cols.ravel(), rows.ravel()], axis=1).astype(float)


class LdvTps:
    """Thin-plate spline of the LDV vertical velocity as a fixed linear operator.

    Parameters
    ----------
    points_px : (n, 2) float
        Screen positions of all LDV points, (col, row) px.
    good : (n,) bool, optional
        Points to use (False: flagged, left out of the fit). Default: all.
    smoothing : float
        ``scipy.interpolate.RBFInterpolator`` smoothing (0: interpolation; larger:
        least-squares fit of the measured values).

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0., 0], [10, 0], [0, 10], [10, 10], [5, 5]])
    >>> tps = LdvTps(pts)
    >>> op = tps.operator(pts)
    >>> bool(np.allclose(op @ np.arange(5.0), np.arange(5.0), atol=1e-4))
    True
    """

    def __init__(self, points_px: np.ndarray, good: np.ndarray | None = None, smoothing: float = 0.0) -> None:
        pts = np.asarray(points_px, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ValueError(f"TPS: points_px must be (n, 2), got shape {pts.shape}")
        self.points_px = pts
        self.good = np.ones(len(pts), bool) if good is None else np.asarray(good, dtype=bool)
        if self.good.shape != (len(pts),):
            raise ValueError(f"TPS: good must be ({len(pts)},), got shape {self.good.shape}")
        if self.good.sum() < 3:
            raise InputDataError(f"TPS: needs at least 3 good LDV points, got {int(self.good.sum())}")
        if smoothing < 0:
            raise ValueError(f"TPS: smoothing must be >= 0, got {smoothing}")
        self.smoothing = float(smoothing)
        self.grid_operator_: np.ndarray | None = None
        self.shape_: tuple[int, int] | None = None

    @property
    def n_good(self) -> int:
        return int(self.good.sum())

    def operator(self, query_px: np.ndarray, dtype: type = np.float32) -> np.ndarray:
        """Operator from the good points' values to the TPS at ``query_px``.

        Parameters
        ----------
        query_px : (m, 2) float
            Screen points, (col, row) px.

        Returns
        -------
        (m, n_good) array of ``dtype``
        """
        from scipy.interpolate import RBFInterpolator

        q = np.asarray(query_px, dtype=float)
        n = self.n_good
        rbf = RBFInterpolator(self.points_px[self.good], np.eye(n), kernel="thin_plate_spline", smoothing=self.smoothing)
        out = np.empty((len(q), n), dtype=dtype)
        for i in range(0, len(q), _CHUNK):
            out[i : i + _CHUNK] = rbf(q[i : i + _CHUNK])
        return out

    def fit_grid(self, shape: tuple[int, int]) -> "LdvTps":
        """Build the operator onto every pixel of an (H, W) frame (float32); returns self."""
        self.shape_ = (int(shape[0]), int(shape[1]))
        self.grid_operator_ = self.operator(pixel_grid(self.shape_))
        return self

    def _good_values(self, w_points: np.ndarray) -> np.ndarray:
        w = np.asarray(w_points)
        if w.shape[0] != len(self.points_px):
            raise ValueError(f"TPS: expected values for {len(self.points_px)} points, got shape {w.shape}")
        return w[self.good]

    def frames(self, w_points: np.ndarray) -> np.ndarray:
        """Vertical velocity on the pixel grid.

        Parameters
        ----------
        w_points : (n,) or (n, T) float
            Velocity of *all* LDV points (flagged ones are ignored, may be NaN), mm/s.

        Returns
        -------
        (H, W) or (T, H, W) float32, mm/s
        """
        if self.grid_operator_ is None or self.shape_ is None:
            raise ValueError("TPS: call fit_grid(shape) before frames()")
        w = self._good_values(w_points).astype(np.float32)
        out = self.grid_operator_ @ w
        if w.ndim == 1:
            return out.reshape(self.shape_)
        return np.moveaxis(out, -1, 0).reshape((w.shape[1], *self.shape_))

    def at(self, query_px: np.ndarray, w_points: np.ndarray) -> np.ndarray:
        """Exact TPS at arbitrary screen points: (m,) or (m, T) float64, mm/s."""
        return self.operator(query_px, dtype=np.float64) @ self._good_values(w_points).astype(float)


def points_in_gap(points_px: np.ndarray, gap: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
    """Which LDV spots look through the gap in each frame.

    Parameters
    ----------
    points_px : (P, 2) float
        Screen points, (col, row) px.
    gap : (k, H, W) bool
        Gap masks of k frames.
    margin_px : float
        A spot within this distance of a gap pixel counts as in the gap (the laser spot
        has a size, the gap edge a blur), px; 0: the spot's own pixel only.

    Returns
    -------
    (k, P) bool
        True where the spot's pixel (rounded) lies within ``margin_px`` of the gap; spots off
        the frame are never in the gap.
    """
    g = np.asarray(gap, bool)
    k, h, w = g.shape
    pts = np.rint(np.asarray(points_px, dtype=float)).astype(int)
    on = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
    out = np.zeros((k, len(pts)), bool)
    if not on.any():
        return out
    r = int(np.floor(margin_px))
    if r > 0:
        from scipy.ndimage import binary_dilation

        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        disk = (xx**2 + yy**2) <= margin_px**2
        g = binary_dilation(g, structure=disk[None, :, :])
    out[:, on] = g[:, pts[on, 1], pts[on, 0]]
    return out


class GapAwareFill:
    """Replace, frame by frame, the values of LDV spots that look through the gap.

    Through the gap the beam has no surface to return from: the vibrometer reads noise
    around zero (or wanders), which a thin-plate spline over all points would pull into
    the fold's medial edge. In each frame the spots in the gap get the value of the
    thin-plate spline through the *other* good spots at that frame. With interpolation
    (smoothing 0) the spline through all spots with these values is exactly the spline
    through the other spots, so one fixed grid operator (:class:`LdvTps`) still serves
    every frame. The small fill operators are cached per pattern of spots in the gap.

    Parameters
    ----------
    points_px : (P, 2) float
        Screen positions of all LDV points, (col, row) px.
    good : (P,) bool
        Points the spline uses.
    smoothing : float
        The spline's smoothing (as :class:`LdvTps`).
    """

    def __init__(self, points_px: np.ndarray, good: np.ndarray, smoothing: float = 0.0) -> None:
        self.points_px = np.asarray(points_px, dtype=float)
        self.good = np.asarray(good, bool)
        self.smoothing = float(smoothing)
        self._ops: dict[bytes, np.ndarray | None] = {}

    def _operator(self, lost: np.ndarray) -> np.ndarray | None:
        key = np.packbits(lost).tobytes()
        if key not in self._ops:
            keep = self.good & ~lost
            if keep.sum() < 3:
                self._ops[key] = None
            else:
                from scipy.interpolate import RBFInterpolator

                rbf = RBFInterpolator(self.points_px[keep], np.eye(int(keep.sum())), kernel="thin_plate_spline",
                                      smoothing=self.smoothing)
                self._ops[key] = rbf(self.points_px[lost])
        return self._ops[key]

    def __call__(self, w_points: np.ndarray, in_gap: np.ndarray) -> np.ndarray:
        """Values of all points with the gap spots filled.

        Parameters
        ----------
        w_points : (P, k) float
            Velocity of every point at k frames, mm/s.
        in_gap : (k, P) bool
            :func:`points_in_gap` of the same frames.

        Returns
        -------
        (P, k) float
            ``w_points`` with the good spots in the gap replaced by the spline through the
            other good spots of that frame (unchanged when fewer than 3 would remain).
        """
        w = np.array(w_points, dtype=float, copy=True)
        lost_all = np.asarray(in_gap, bool) & self.good[None, :]
        for j in np.flatnonzero(lost_all.any(axis=1)):
            lost = lost_all[j]
            op = self._operator(lost)
            if op is not None:
                w[lost, j] = op @ w[self.good & ~lost, j]
        return w


def hull_mask(points_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixels inside the convex hull of screen points, (H, W) bool."""
    from scipy.spatial import Delaunay

    tri = Delaunay(np.asarray(points_px, dtype=float))
    return (tri.find_simplex(pixel_grid(shape)) >= 0).reshape(shape)


def combine_fields(
    flow_mm_s: np.ndarray, w_mm_s: np.ndarray, gap: np.ndarray, inside: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Combine horizontal flow and vertical TPS velocity into v = (u, v, w).

    Works on one frame or a stack: leading dimensions ``...`` are (T,) or ().

    Parameters
    ----------
    flow_mm_s : (..., H, W, 2) float
        (u, v) from the optical flow, mm/s (zero in the gap).
    w_mm_s : (..., H, W) float
        Vertical velocity from :class:`LdvTps`, mm/s.
    gap : (..., H, W) bool
        Gap masks.
    inside : (H, W) bool, optional
        Region where w is trusted (e.g. :func:`hull_mask` of the good LDV points);
        default: everywhere.

    Returns
    -------
    field : (..., H, W, 3) float32
        (u, v, w), mm/s.
    valid : (..., H, W) bool
        Fold surface visible (not gap), w finite, and inside ``inside``.
    """
    field = np.concatenate([np.asarray(flow_mm_s, np.float32), np.asarray(w_mm_s, np.float32)[..., None]], axis=-1)
    valid = ~np.asarray(gap, bool) & np.isfinite(field).all(axis=-1)
    if inside is not None:
        valid &= np.asarray(inside, bool)
    return field, valid
