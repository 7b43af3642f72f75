"""Grid indices (row, col) of scan points laid out on a near-regular grid.

Pure numpy. The grid may be rotated in its plane and jittered by a fraction of
the spacing; points may be missing. Method: spacing ``d`` = median
nearest-neighbour distance in the (x, y) plane; orientation = circular median
of the nearest-neighbour directions modulo 90 degrees; after rotating the
points by minus that angle, each axis is split into levels wherever sorted
coordinates jump by more than ``d / 2``. Columns run along the rotated x,
rows along the rotated y (the camera convention: columns follow x).

The orientation is found modulo 90 degrees, so a grid turned by about 90 degrees in the
coordinates' plane (a scan registered to a camera turned by more than 45 degrees about its axis)
reads with rows and columns swapped.  When that is the expected shape transposed, the other of
the equivalent orientations is taken (90 degrees on: the found columns become rows, counted
backwards, a rotation, not a mirror), so the rig's 17 x 22 grid reads as 17 x 22 at any angle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GridFit:
    """Result of :func:`infer_grid`.

    Attributes
    ----------
    index : (P, 2) int
        (row, col) of each point.
    shape : (int, int)
        (rows, cols) found.
    spacing : float
        Median nearest-neighbour distance, input units.
    angle_deg : float
        Grid rotation in the (x, y) plane, degrees in (-45, 45], or in (45, 135] when the grid
        was turned to the expected shape (``turned``).
    complete : bool
        Every (row, col) cell holds exactly one point.
    message : str
        Empty when the grid has the expected shape and no two points share a cell (points may be missing:
        ``complete`` says whether any is), else what was found.
    turned : bool
        The rows and columns first found were the expected shape's columns and rows, and the grid
        was read 90 degrees on (module docstring).
    """

    index: np.ndarray
    shape: tuple[int, int]
    spacing: float
    angle_deg: float
    complete: bool
    message: str
    turned: bool = False


def _levels(v: np.ndarray, gap: float) -> np.ndarray:
    order = np.argsort(v, kind="stable")
    jumps = np.diff(v[order]) > gap
    lev = np.concatenate([[0], np.cumsum(jumps)])
    out = np.empty(v.size, np.int64)
    out[order] = lev
    return out


def infer_grid(coords: np.ndarray, expected: tuple[int, int] | None = (17, 22)) -> GridFit:
    """Infer (row, col) grid indices of scan points.

    Parameters
    ----------
    coords : (P, 2) or (P, 3) float
        Point coordinates; only x and y are used (z is the height of the surface).
    expected : (rows, cols) or None
        Expected grid shape (default 17 x 22 = 374 points); a grid found as its transpose
        is read 90 degrees on (module docstring); any other mismatch is reported in
        ``message``, not raised.

    Returns
    -------
    GridFit
    """
    xy = np.asarray(coords, dtype=np.float64)[:, :2]
    p = xy.shape[0]
    if p < 2:
        idx = np.zeros((p, 2), np.int64)
        msg = "" if expected in (None, (p, p)) else f"only {p} point(s); expected grid {expected}"
        return GridFit(idx, (p, p), 0.0, 0.0, p == 1, msg)
    d2 = np.sum((xy[:, None, :] - xy[None, :, :]) ** 2, axis=-1) if p <= 4000 else None
    if d2 is None:
        from scipy.spatial import cKDTree

        dist, nn = cKDTree(xy).query(xy, k=2)
        nn, dist = nn[:, 1], dist[:, 1]
    else:
        np.fill_diagonal(d2, np.inf)
        nn = np.argmin(d2, axis=1)
        dist = np.sqrt(d2[np.arange(p), nn])
    spacing = float(np.median(dist))
    if not spacing > 0:
        idx = np.zeros((p, 2), np.int64)
        return GridFit(idx, (1, 1), 0.0, 0.0, False, "scan points coincide: no grid")
    vec = xy[nn] - xy
    ang4 = 4.0 * np.arctan2(vec[:, 1], vec[:, 0])
    theta = 0.25 * np.arctan2(np.median(np.sin(ang4)), np.median(np.cos(ang4)))
    c, s = np.cos(theta), np.sin(theta)
    u = c * xy[:, 0] + s * xy[:, 1]
    v = -s * xy[:, 0] + c * xy[:, 1]
    col = _levels(u, 0.5 * spacing)
    row = _levels(v, 0.5 * spacing)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    turned = expected is not None and expected[0] != expected[1] and shape == (expected[1], expected[0])
    if turned:                        # theta + 90 deg: u' = v, v' = -u
        row, col = col.max() - col, row
        shape, theta = (shape[1], shape[0]), theta + 0.5 * np.pi
    cells = row * shape[1] + col
    complete = np.unique(cells).size == p == shape[0] * shape[1]
    msg = ""
    if expected is not None and tuple(expected) != shape:
        msg = (f"scan grid is {shape[0]} rows x {shape[1]} cols ({p} points), expected "
               f"{expected[0]} x {expected[1]} = {expected[0] * expected[1]}")
    elif np.unique(cells).size < p:
        msg = (f"scan grid {shape[0]} x {shape[1]} has shared cells "
               f"({p} points, {np.unique(cells).size} distinct cells)")
    return GridFit(np.column_stack([row, col]), shape, spacing, float(np.degrees(theta)),
                   bool(complete), msg, bool(turned))
