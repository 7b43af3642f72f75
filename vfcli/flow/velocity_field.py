"""The tri-variate surface velocity field v(y, t) = (u, v, w) (paper, section 3.2).

* Horizontal (u, v): the optical flow on the pixel grid (:mod:`vfcli.flow.optical_flow`),
  interpolated *bilinearly in space* (C0) and by a *quadratic spline in time* (C1).
* Vertical w: the LDV velocities synced onto the frame times, interpolated by a
  *thin-plate spline in space* (least squares with configurable smoothing) and
  *linearly in time*.

The TPS is linear in the measured values, so it is built once as a linear operator
``M`` of shape (n_query, n_good) (:class:`LdvTps`): a frame of w is ``M @ w_points``.
Flagged LDV points are left out of the operator (it is built from the good points).

Screen points are ``(col, row)`` pixels with the centre of the first pixel at (0, 0)
(``docs/conventions.md``); times in s; velocities in mm/s.

The quadratic spline in time has its knots half-way between the frames, so each frame
sample is the centre of one parabola: ``s(tau) = c[j-1] (1/2 - u)^2 / 2 + c[j] (3/4 - u^2)
+ c[j+1] (1/2 + u)^2 / 2`` with ``j = round(tau)``, ``u = tau - j`` and tau the time in
frames. It interpolates every sample, is C1 everywhere, and has zero second derivative
on the first and last half-frame (natural end conditions); the coefficients solve one
tridiagonal, diagonally dominant system (influence of a sample decays by a factor of
about 0.17 per frame, so there is no long-range ringing).
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


# ---- time: quadratic C1 spline ---------------------------------------------------------
def quadratic_spline_coefficients(samples: np.ndarray) -> np.ndarray:
    """Coefficients of the C1 quadratic spline through uniformly spaced samples.

    Parameters
    ----------
    samples : (T, ...) float
        Values at frames 0..T-1.

    Returns
    -------
    (T + 2, ...) float64
        B-spline coefficients c[-1..T] (stored at index + 1); see the module docstring.
    """
    from scipy.linalg import solve_banded

    f = np.asarray(samples, dtype=float)
    n = f.shape[0]
    if n == 0:
        raise ValueError("time spline: needs at least one sample")
    flat = f.reshape(n, -1)
    if n <= 2:
        c = flat.copy()
    else:
        ab = np.zeros((3, n))
        ab[0, 2:] = 1.0 / 8  # super-diagonal (row i, col i+1) for interior rows i = 1..n-2
        ab[1, :] = 6.0 / 8
        ab[1, 0] = ab[1, -1] = 1.0  # natural ends: c[0] = f[0], c[n-1] = f[n-1]
        ab[2, :-2] = 1.0 / 8  # sub-diagonal (row i, col i-1) for interior rows
        c = solve_banded((1, 1), ab, flat)
    if n == 1:
        padded = np.concatenate([c, c, c])
    else:
        padded = np.concatenate([2 * c[:1] - c[1:2], c, 2 * c[-1:] - c[-2:-1]])
    return padded.reshape((n + 2, *f.shape[1:]))


def quadratic_spline_eval(coeffs: np.ndarray, tau: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
    """Evaluate the quadratic time spline.

    Parameters
    ----------
    coeffs : (T + 2, m, ...) float
        From :func:`quadratic_spline_coefficients`.
    tau : (n,) float
        Times in frames, clipped to [0, T - 1].
    index : (n,) int, optional
        Column of ``coeffs`` (axis 1) used by each query; default: evaluate all columns
        at every tau, giving (n, m, ...).

    Returns
    -------
    (n, ...) with ``index``, else (n, m, ...).
    """
    n_frames = coeffs.shape[0] - 2
    tau = np.clip(np.asarray(tau, dtype=float), 0.0, n_frames - 1)
    j = np.clip(np.floor(tau + 0.5).astype(int), 0, n_frames - 1)
    u = tau - j
    b = [0.5 * (0.5 - u) ** 2, 0.75 - u**2, 0.5 * (0.5 + u) ** 2]
    out = 0.0
    for d, bd in enumerate(b):  # coefficient c[j - 1 + d] is stored at j + d
        c = coeffs[j + d] if index is None else coeffs[j + d, index]
        out = out + bd.reshape(bd.shape + (1,) * (c.ndim - 1)) * c
    return out


# ---- the combined field ------------------------------------------------------------------
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


def _frame_coordinate(times: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or len(times) == 0:
        raise ValueError("field: times must be a non-empty (T,) array")
    if len(times) == 1:
        tau = np.zeros(np.shape(t))
        return tau, np.isclose(np.asarray(t, float), times[0])
    dt = np.diff(times)
    if not (np.all(dt > 0) and np.allclose(dt, dt[0], rtol=1e-6, atol=0)):
        raise ValueError("field: frame times must be uniformly spaced and increasing")
    tau = (np.asarray(t, dtype=float) - times[0]) / dt[0]
    inside = (tau >= -1e-9) & (tau <= len(times) - 1 + 1e-9)
    return np.clip(tau, 0, len(times) - 1), inside


def evaluate_field(
    field: np.ndarray,
    times: np.ndarray,
    mask: np.ndarray | None,
    y_px: np.ndarray,
    t: np.ndarray,
    *,
    tps: LdvTps | None = None,
    w_points: np.ndarray | None = None,
) -> np.ndarray:
    """Evaluate v(y, t) at arbitrary screen points and times.

    (u, v): bilinear in space between the four surrounding pixel centres, then the
    quadratic C1 spline in time through the frame samples. w: linear in time between
    the two surrounding frames; in space the exact TPS when ``tps`` and ``w_points`` are
    given, else bilinear in the TPS already sampled on the pixels (``field[..., 2]``;
    the two differ by O(pixel^2 * curvature), negligible at pixel scale).

    Parameters
    ----------
    field : (T, H, W, 3) float
        (u, v, w) on the pixel grid at ``times``, mm/s (:func:`combine_fields`).
    times : (T,) float
        Uniformly spaced frame times, s.
    mask : (T, H, W) bool or None
        Validity (:func:`combine_fields`); a query is valid when the pixel nearest to
        it in the frame nearest in time is valid. None: all valid.
    y_px : (n, 2) float
        Screen points, (col, row) px.
    t : (n,) float
        Times, s.
    tps : LdvTps, optional
    w_points : (n_points, T) float, optional
        LDV velocities on the frame times (all points; flagged ones ignored), mm/s.

    Returns
    -------
    (n, 3) float64
        (u, v, w), mm/s; NaN rows for invalid queries and for queries outside the
        pixel-centre rectangle [0, W-1] x [0, H-1] or the time range.
    """
    fld = np.asarray(field)
    n_t, h, w_ = fld.shape[:3]
    y = np.asarray(y_px, dtype=float).reshape(-1, 2)
    tq = np.broadcast_to(np.asarray(t, dtype=float), (len(y),))
    if len(times) != n_t:
        raise ValueError(f"field: {len(times)} times for {n_t} frames")
    tau, in_time = _frame_coordinate(times, tq)
    col, row = y[:, 0], y[:, 1]
    in_space = (col >= 0) & (col <= w_ - 1) & (row >= 0) & (row <= h - 1)
    col, row = np.clip(col, 0, w_ - 1), np.clip(row, 0, h - 1)
    c0 = np.minimum(np.floor(col).astype(int), max(w_ - 2, 0))
    r0 = np.minimum(np.floor(row).astype(int), max(h - 2, 0))
    fc, fr = col - c0, row - r0
    c1, r1 = np.minimum(c0 + 1, w_ - 1), np.minimum(r0 + 1, h - 1)
    corners = [(r0, c0, (1 - fr) * (1 - fc)), (r0, c1, (1 - fr) * fc), (r1, c0, fr * (1 - fc)), (r1, c1, fr * fc)]

    # (u, v): spline coefficients only for the pixels the queries touch
    flat = np.concatenate([r * w_ + c for r, c, _ in corners])
    uniq, inv = np.unique(flat, return_inverse=True)
    series = fld.reshape(n_t, h * w_, -1)[:, uniq, :2]
    coeffs = quadratic_spline_coefficients(series)
    n = len(y)
    uv = np.zeros((n, 2))
    for i, (_, _, wt) in enumerate(corners):
        uv += wt[:, None] * quadratic_spline_eval(coeffs, tau, inv[i * n : (i + 1) * n])

    # w: linear in time
    k0 = np.minimum(np.floor(tau).astype(int), max(n_t - 2, 0))
    k1 = np.minimum(k0 + 1, n_t - 1)
    a = tau - k0
    if tps is not None and w_points is not None:
        wp = np.asarray(w_points, dtype=float)
        op = tps.operator(y, dtype=np.float64)
        wg = wp[tps.good]
        w0 = np.einsum("ij,ji->i", op, wg[:, k0])
        w1 = np.einsum("ij,ji->i", op, wg[:, k1])
    else:
        wf = fld[..., 2]
        w0 = sum(wt * wf[k0, r, c] for r, c, wt in corners)
        w1 = sum(wt * wf[k1, r, c] for r, c, wt in corners)
    wv = (1 - a) * w0 + a * w1

    out = np.column_stack([uv, wv])
    ok = in_time & in_space
    if mask is not None:
        kn = np.clip(np.rint(tau).astype(int), 0, n_t - 1)
        ok &= np.asarray(mask)[kn, np.rint(row).astype(int), np.rint(col).astype(int)]
    out[~ok] = np.nan
    return out
