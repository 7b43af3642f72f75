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
