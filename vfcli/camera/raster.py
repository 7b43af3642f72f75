"""A vectorised software rasteriser for the orthographic camera (:mod:`vfcli.camera.camera`).

``z`` is depth: where several surfaces cover one pixel, the one with the LARGEST z
(closest to the camera, which looks down -z) is visible.

:func:`rasterize` finds, for every pixel centre, the visible triangle and the
barycentric coordinates of the visible point in it.  With orthographic
projection the screen-space barycentric coordinates are the barycentric
coordinates of the 3D point, so any per-vertex attribute (material (u, v),
displacement, velocity) interpolates exactly with them.  For a fixed raster the
map from per-vertex values to per-pixel values is linear:
:meth:`Raster.interpolation_matrix` returns it as a sparse matrix, which is
what the optimizer differentiates through (the paper's ray-cast (u, v) are
held fixed within a step).  :func:`raycast_points` does the same for arbitrary
points, :func:`gap_mask` turns a raster of both folds into the simulated gap.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np
import scipy.sparse as sp

from vfcli.camera.camera import Camera

#: barycentric tolerance of the inside test: pixel centres on an edge are covered
_INSIDE_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class Raster:
    """What every pixel centre sees, stored compactly per visible pixel.

    Attributes
    ----------
    shape : (H, W) image shape.
    visible_index : (n,) int64 increasing row-major flat indices of the pixels
        where a surface is visible (the row order of :meth:`interpolation_matrix`).
    visible_triangle : (n,) int64 index of the visible triangle.
    visible_bary : (n, 3) float64 barycentric coordinates of the visible point
        (weights of ``triangles[visible_triangle]``'s vertices).
    visible_depth : (n,) float64 z (mm) of the visible point.
    triangles : (K, 3) int64, the triangles that were rasterised.
    n_vertices : N, number of vertices (columns of the interpolation matrix).

    Images (computed on first use): ``triangle`` (H, W) int64 (-1 where none;
    ``triangle >= 0`` is the paper's indicator m(y)), ``bary`` (H, W, 3) (0 where
    none), ``depth`` (H, W) (NaN where none), ``mask`` (H, W) bool.
    """

    shape: tuple[int, int]
    visible_index: np.ndarray
    visible_triangle: np.ndarray
    visible_bary: np.ndarray
    visible_depth: np.ndarray
    triangles: np.ndarray
    n_vertices: int

    @cached_property
    def triangle(self) -> np.ndarray:
        return self.scatter(self.visible_triangle, -1)

    @cached_property
    def bary(self) -> np.ndarray:
        return self.scatter(self.visible_bary, 0.0)

    @cached_property
    def depth(self) -> np.ndarray:
        return self.scatter(self.visible_depth, np.nan)

    @cached_property
    def mask(self) -> np.ndarray:
        """(H, W) bool: a surface is visible (the indicator m(y))."""
        return self.scatter(np.ones(self.visible_index.size, dtype=bool), False)

    @cached_property
    def _matrix(self) -> sp.csr_matrix:
        return self._csr(self.visible_triangle, self.visible_bary)

    def _csr(self, triangle: np.ndarray, bary: np.ndarray) -> sp.csr_matrix:
        """(n, N) csr with row i = the weights ``bary[i]`` (n, 3) of the vertices of ``triangles[triangle[i]]``.

        Index arrays are int32 whenever they fit, as scipy itself would choose (built in
        that dtype directly, which spares the constructor a conversion pass).
        """
        n = triangle.size
        idx = np.int32 if max(3 * n, self.n_vertices) <= np.iinfo(np.int32).max else np.int64
        cols = np.take(self.triangles.astype(idx), triangle, axis=0)   # (n, 3); np.take: fast row gather
        indptr = np.arange(0, 3 * n + 1, 3, dtype=idx)
        return sp.csr_matrix((bary.ravel(), cols.ravel(), indptr), shape=(n, self.n_vertices))

    def interpolation_matrix(self) -> sp.csr_matrix:
        """Sparse (n_visible, N) matrix M: per-vertex values -> values at visible pixels.

        ``(M @ f)[i]`` is the attribute ``f`` (N,) or (N, k) at the visible point of pixel
        ``visible_index[i]``.  M depends only on the raster, so for a fixed raster every
        per-pixel quantity built from vertex positions is linear in them (exact gradients:
        ``d(M @ f)/d f = M``).  Three nonzeros per row (the barycentric weights).
        """
        return self._matrix

    def interpolation_rows(self, rows: np.ndarray) -> sp.csr_matrix:
        """Sparse (m, N) matrix: the rows ``rows`` (m,) int of :meth:`interpolation_matrix`.

        Equal to ``interpolation_matrix()[rows]`` (same data, indices and dtypes), built
        directly from the selected pixels without the full matrix.
        """
        rows = np.asarray(rows, dtype=np.int64)
        return self._csr(self.visible_triangle[rows], np.take(self.visible_bary, rows, axis=0))

    def interpolate_visible(self, vertex_values: np.ndarray) -> np.ndarray:
        """(n_visible,) or (n_visible, k): per-vertex values at the visible points (``M @ values``)."""
        vals = np.asarray(vertex_values, dtype=float)
        if vals.shape[0] != self.n_vertices:
            raise ValueError(f"vertex_values has {vals.shape[0]} rows, the raster has {self.n_vertices} vertices")
        out = self._matrix @ vals.reshape(len(vals), -1)
        return out.reshape((-1,) + vals.shape[1:])

    def scatter(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Place (n_visible, ...) values on the (H, W, ...) image, ``fill`` elsewhere."""
        v = np.asarray(values)
        dtype = v.dtype if v.dtype.kind in "bi" and float(fill).is_integer() else np.result_type(v.dtype, np.float64)
        out = np.full((int(np.prod(self.shape)),) + v.shape[1:], fill, dtype=dtype)
        out[self.visible_index] = v
        return out.reshape(tuple(self.shape) + v.shape[1:])


def rasterize(camera: Camera, vertices: np.ndarray, triangles: np.ndarray) -> Raster:
    """Rasterise a triangle surface at the pixel centres with a depth test.

    Vectorised scanline over all triangles at once: for every pixel row of a
    triangle's bounding box the exact column span inside the triangle follows
    from its three affine barycentric (edge) functions, and the covered pixel
    centres are generated directly (no wasted tests).  Triangles with no
    screen area (seen edge-on) are skipped.  Among the triangles covering a pixel
    centre the one with the largest z there wins (the camera looks down -z).

    Parameters
    ----------
    camera : the camera.
    vertices : (N, 3) model-frame positions, mm.
    triangles : (K, 3) int vertex indices (any orientation).

    Returns
    -------
    Raster
    """
    verts = np.asarray(vertices, dtype=float)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise ValueError(f"vertices must be (N, 3), got {verts.shape}")
    if tris.size and (tris.min() < 0 or tris.max() >= len(verts)):
        raise ValueError("triangle vertex index out of range")
    height, width = camera.shape

    scr = camera.project(verts)
    a, b, c = scr[tris[:, 0]], scr[tris[:, 1]], scr[tris[:, 2]]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    # affine barycentric coordinates: w_i(col, row) = gc_i * col + gr_i * row + g0_i
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / area2
        g1c, g1r = (c[:, 1] - a[:, 1]) * inv, -(c[:, 0] - a[:, 0]) * inv      # weight of vertex b
        g2c, g2r = -(b[:, 1] - a[:, 1]) * inv, (b[:, 0] - a[:, 0]) * inv      # weight of vertex c
        g10 = -(g1c * a[:, 0] + g1r * a[:, 1])
        g20 = -(g2c * a[:, 0] + g2r * a[:, 1])
        g0c, g0r, g00 = -(g1c + g2c), -(g1r + g2r), 1.0 - g10 - g20      # weight of vertex a

    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    rmin = np.maximum(np.ceil(lo[:, 1] - 1e-9), 0)
    rmax = np.minimum(np.floor(hi[:, 1] + 1e-9), height - 1)
    cmin = np.maximum(np.ceil(lo[:, 0] - 1e-9), 0)
    cmax = np.minimum(np.floor(hi[:, 0] + 1e-9), width - 1)
    extent = np.maximum(hi - lo, 1.0).max(axis=1)
    ok = (np.isfinite(area2) & (np.abs(area2) > 1e-12 * extent * extent)
          & (cmin <= cmax) & (rmin <= rmax) & np.all(np.isfinite(scr[tris]), axis=(1, 2)))
    t_ok = np.flatnonzero(ok)

    # scanline: one span (triangle, row) per pixel row of each triangle's bounding box
    n_rows = (rmax[t_ok] - rmin[t_ok] + 1).astype(np.int64)
    tr = np.repeat(t_ok, n_rows)

    def per_span(per_triangle: np.ndarray) -> np.ndarray:
        return np.repeat(per_triangle[t_ok], n_rows)

    first_row = np.cumsum(n_rows) - n_rows                 # first span of each triangle
    row = np.repeat(rmin[t_ok] - first_row, n_rows) + np.arange(tr.size)    # exact integers
    # exact column span on this row: each barycentric w_i = gc_i col + gr_i row + g0_i >= -tol
    col_lo, col_hi = per_span(cmin), per_span(cmax)
    with np.errstate(divide="ignore", invalid="ignore"):
        for gc, gr, g0 in ((g0c, g0r, g00), (g1c, g1r, g10), (g2c, g2r, g20)):
            gct = per_span(gc)
            rhs = per_span(gr)
            rhs *= row
            rhs += per_span(g0)
            np.subtract(-_INSIDE_TOL, rhs, out=rhs)         # need gc * col >= rhs
            bound = rhs / gct
            np.maximum(col_lo, np.ceil(bound), out=col_lo, where=gct > 0)
            np.minimum(col_hi, np.floor(bound), out=col_hi, where=gct < 0)
            col_hi[(gct == 0) & (rhs > 0)] = -1.0            # edge parallel to the row, row outside
    n_cols = np.maximum(col_hi - col_lo + 1, 0).astype(np.int64)

    # fragments: the n_cols[i] pixel centres of span i, span after span (triangle, row, column order);
    # per-span values reach the fragments by np.repeat (cheaper than gathering by triangle)
    first = np.cumsum(n_cols) - n_cols                    # first fragment of each span
    k = np.arange(int(n_cols.sum()), dtype=np.int64)      # fragment index
    tri = np.repeat(tr, n_cols)
    fc = np.repeat(col_lo - first, n_cols) + k            # column (exact integers): col_lo + k - first
    pix = np.repeat((row * width + col_lo).astype(np.int64) - first, n_cols) + k

    def per_fragment(per_triangle: np.ndarray) -> np.ndarray:
        return np.repeat(per_triangle[tr], n_cols)

    def bary_weight(gc: np.ndarray, gr: np.ndarray, g0: np.ndarray) -> np.ndarray:
        # gc * col + gr * row + g0, evaluated in this order (gr * row is constant along a span)
        w = per_fragment(gc)
        w *= fc
        w += np.repeat(gr[tr] * row, n_cols)
        w += per_fragment(g0)
        return w

    w1, w2 = bary_weight(g1c, g1r, g10), bary_weight(g2c, g2r, g20)
    return _resolve_depth((height, width), pix, tri, w1, w2, verts, tris, per_fragment)


def _resolve_depth(shape: tuple[int, ...], pix: np.ndarray, tri: np.ndarray, w1: np.ndarray, w2: np.ndarray,
                   verts: np.ndarray, tris: np.ndarray,
                   per_fragment: Callable[[np.ndarray], np.ndarray] | None = None) -> Raster:
    """Depth test over fragments (sample index, triangle, barycentric w1, w2): largest z wins.

    Among fragments of equal z on one sample the one with the largest fragment index wins.
    ``per_fragment`` maps a (K,) per-triangle array to its (n,) values at the fragments
    (default ``a[tri]``; :func:`rasterize` passes a cheaper equivalent).  w1 and w2 are
    clipped to the triangle in place.
    """
    n_pix = math.prod(shape)
    if pix.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Raster(shape, empty, empty, np.zeros((0, 3)), np.zeros(0), tris, int(len(verts)))
    if per_fragment is None:
        def per_fragment(per_triangle: np.ndarray) -> np.ndarray:
            return per_triangle[tri]
    np.clip(w1, 0.0, 1.0, out=w1)
    np.clip(w2, 0.0, 1.0, out=w2)
    s12 = w1 + w2
    over = np.flatnonzero(s12 > 1.0)
    w1[over] /= s12[over]
    w2[over] /= s12[over]
    zt = verts[tris, 2]                                     # (K, 3)
    za, dz1, dz2 = zt[:, 0], zt[:, 1] - zt[:, 0], zt[:, 2] - zt[:, 0]
    z = per_fragment(dz1)                                   # z = za + w1 dz1 + w2 dz2, in this order
    z *= w1
    z += per_fragment(za)
    dz = per_fragment(dz2)
    dz *= w2
    z += dz
    zbuf = np.full(n_pix, -np.inf)
    np.maximum.at(zbuf, pix, z)
    win = np.flatnonzero(z >= zbuf[pix])
    winner = np.full(n_pix, -1, dtype=np.int64)
    winner[pix[win]] = win                                 # ties (shared edges): the last one wins
    vis = np.flatnonzero(winner >= 0)
    f = winner[vis]
    b1, b2 = w1[f], w2[f]
    b0 = 1.0 - b1
    b0 -= b2
    bary = np.empty((f.size, 3))
    bary[:, 0], bary[:, 1], bary[:, 2] = b0, b1, b2
    return Raster(shape, vis, tri[f], bary, z[f], tris, int(len(verts)))


def raycast_points(points_xy: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> Raster:
    """Cast vertical rays at scattered points (e.g. the LDV scan points): what each one hits.

    The result is a :class:`Raster` of shape ``(P,)``: ``visible_index`` lists the
    points that hit a surface, with the topmost (largest z) triangle and its
    barycentric coordinates, so :meth:`Raster.interpolate_visible` and
    :meth:`Raster.interpolation_matrix` work as for an image.  Meant for up to
    ~10^4 scattered points (candidate pairs come from the points' x order);
    use :func:`rasterize` for pixel grids.

    points_xy : (P, 2) model-frame (x, y), mm.  vertices : (N, 3) mm.  triangles : (K, 3) int.
    """
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    verts = np.asarray(vertices, dtype=float)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    a, b, c = verts[tris[:, 0], :2], verts[tris[:, 1], :2], verts[tris[:, 2], :2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    extent = np.maximum(hi - lo, 1e-12).max(axis=1)
    ok = np.flatnonzero((np.abs(area2) > 1e-12 * extent * extent) & np.isfinite(area2))
    order = np.argsort(pts[:, 0], kind="stable")
    xs = pts[order, 0]
    first = np.searchsorted(xs, lo[ok, 0] - 1e-12, side="left")
    count = np.searchsorted(xs, hi[ok, 0] + 1e-12, side="right") - first
    tri = np.repeat(ok, count)
    pid = order[np.repeat(first, count) + _ragged_arange(count)]
    p = pts[pid]
    ta, tb, tc = a[tri], b[tri], c[tri]
    inv = 1.0 / area2[tri]
    w1 = ((p[:, 0] - ta[:, 0]) * (tc[:, 1] - ta[:, 1]) - (p[:, 1] - ta[:, 1]) * (tc[:, 0] - ta[:, 0])) * inv
    w2 = ((tb[:, 0] - ta[:, 0]) * (p[:, 1] - ta[:, 1]) - (tb[:, 1] - ta[:, 1]) * (p[:, 0] - ta[:, 0])) * inv
    inside = (w1 >= -_INSIDE_TOL) & (w2 >= -_INSIDE_TOL) & (w1 + w2 <= 1 + _INSIDE_TOL)
    return _resolve_depth((len(pts),), pid[inside], tri[inside], w1[inside], w2[inside], verts, tris)


def _ragged_arange(counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(n)`` for every n in counts (int64)."""
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    starts = np.cumsum(counts) - counts
    return np.arange(total, dtype=np.int64) - np.repeat(starts, counts)


def interpolate(raster: Raster, vertex_values: np.ndarray, fill: float = np.nan) -> np.ndarray:
    """Per-vertex attribute at every pixel's visible point.

    vertex_values : (N,) or (N, k) values at the vertices (any unit).
    Returns (H, W) or (H, W, k) float64, ``fill`` where no surface is visible.
    """
    return raster.scatter(raster.interpolate_visible(vertex_values), fill)


def surface_velocity(raster: Raster, positions_t: np.ndarray, positions_next: np.ndarray,
                     dt: float, fill: float = np.nan) -> np.ndarray:
    """Velocity of the material point visible in each pixel (the paper's v_bar).

    The visible point is fixed by ``raster`` (rasterised at time t): its
    triangle and barycentric (i.e. material (u, v)) coordinates.  Its velocity is
    the finite difference of its position, ``(x(t + dt) - x(t)) / dt``, which for
    a fixed raster is linear in the vertex positions::

        v_visible = M @ (positions_next - positions_t) / dt,   M = raster.interpolation_matrix()

    Parameters
    ----------
    raster : raster of the surface at time t.
    positions_t, positions_next : (N, 3) vertex positions at t and t + dt, mm.
    dt : time step, s.

    Returns
    -------
    (H, W, 3) float64 velocity (u, v, w) in mm/s, ``fill`` where nothing is visible.
    Use ``camera.project_vector`` for the screen-space (col, row) motion in px/s.
    """
    if not dt > 0:
        raise ValueError(f"dt must be > 0, got {dt!r}")
    disp = (np.asarray(positions_next, dtype=float) - np.asarray(positions_t, dtype=float)) / dt
    return interpolate(raster, disp, fill)


def fold_x_range(vertices: np.ndarray, triangles: np.ndarray, triangle_fold: np.ndarray) -> tuple[float, float]:
    """Model x interval (mm) that both folds span: (largest of their smallest x, smallest of their largest x).

    vertices : (N, 3) mm.  triangles : (K, 3) int.  triangle_fold : (K,) int, 0 or 1.
    """
    x = np.asarray(vertices, dtype=float)[:, 0][np.asarray(triangles, dtype=np.int64)]
    fold = np.asarray(triangle_fold).ravel()
    lo = [float(x[fold == k].min()) for k in (0, 1) if (fold == k).any()]
    hi = [float(x[fold == k].max()) for k in (0, 1) if (fold == k).any()]
    return (max(lo), min(hi)) if lo else (-np.inf, np.inf)


def gap_mask(camera: Camera, raster: Raster, triangle_fold: np.ndarray,
             x_range: tuple[float, float] | None = None) -> np.ndarray:
    """Simulated glottal gap: pixels covered by no fold and lying between the two folds.

    A pixel belongs to the gap when no triangle is visible at its centre and,
    along the lateral (model y) line through it, fold 0 (left, y < 0) is seen at
    smaller y and fold 1 (right, y > 0) at larger y.  The lateral line is taken
    as the strip of pixels whose model x falls in the same bin of one pixel's
    width (exact for an unrotated camera, within a pixel otherwise).  Pixels
    beyond the anterior/posterior ends of the folds or outside their lateral
    walls are not gap: with ``x_range`` (:func:`fold_x_range`), a gap pixel's
    model x lies in it too (a turned camera's strip crosses a fold's end at a
    slant, so the strip alone would take the pixels just past the end).

    Parameters
    ----------
    camera : the camera the raster was made with.
    raster : raster of both folds' surfaces.
    triangle_fold : (K,) int, fold (0 or 1) of each rasterised triangle.
    x_range : (x_lo, x_hi) mm, optional; the model x interval both folds span.

    Returns
    -------
    (H, W) bool gap mask.
    """
    fold_of_tri = np.asarray(triangle_fold).ravel()
    if fold_of_tri.size != len(raster.triangles):
        raise ValueError(f"triangle_fold has {fold_of_tri.size} entries, raster has {len(raster.triangles)} triangles")
    xy = camera.pixel_centres_xy().reshape(-1, 2)
    label = raster.scatter(fold_of_tri[raster.visible_triangle], -1).ravel()
    xbin = np.floor(xy[:, 0] * camera.px_per_mm).astype(np.int64)
    xbin -= xbin.min()
    nb = int(xbin.max()) + 1
    ymin0 = np.full(nb, np.inf)
    ymax1 = np.full(nb, -np.inf)
    m0, m1 = label == 0, label == 1
    np.minimum.at(ymin0, xbin[m0], xy[m0, 1])
    np.maximum.at(ymax1, xbin[m1], xy[m1, 1])
    y = xy[:, 1]
    gap = (label < 0) & (y > ymin0[xbin]) & (y < ymax1[xbin])
    if x_range is not None:
        gap &= (xy[:, 0] >= x_range[0]) & (xy[:, 0] <= x_range[1])
    return gap.reshape(camera.shape)
