"""The vectorised rasteriser, silhouettes and ``Problem.freeze`` give exactly what the plain versions gave.

The reference implementations below are the straightforward formulations these
functions had before they were optimised (gathers by triangle, ``np.lexsort``,
row indexing of the full interpolation matrix, whole-frame float copies).  The
results must agree exactly: same visible pixels, same winning triangles
(including the tie-break among equal depths: the largest fragment index), the
same floating-point barycentrics and depths, the same silhouette edges and the
same ``_Frame`` contents.
"""
import numpy as np
import pytest
import scipy.sparse as sp

from vfcli.camera.camera import Camera
from vfcli.camera.raster import _INSIDE_TOL, rasterize
from vfcli.inverse.problem import Measurement, Problem
from vfcli.camera.silhouette import edge_crossings, extreme_per_ray

try:  # tests/ on sys.path (no tests/__init__.py)
    from _forward_case import CAMERA, forward_case
except ModuleNotFoundError:  # tests/ is a package
    from tests._forward_case import CAMERA, forward_case


# ------------------------------------------------------------------ reference implementations
def _ragged_arange(counts):
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.cumsum(counts) - counts
    return np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(starts, counts)


def _ref_resolve(n_pix, pix, tri, w1, w2, verts, tris):
    if pix.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    w1 = np.clip(w1, 0.0, 1.0)
    w2 = np.clip(w2, 0.0, 1.0)
    s12 = w1 + w2
    over = s12 > 1.0
    w1[over] /= s12[over]
    w2[over] /= s12[over]
    zt = verts[tris, 2]
    za, dz1, dz2 = zt[:, 0], zt[:, 1] - zt[:, 0], zt[:, 2] - zt[:, 0]
    z = za[tri] + w1 * dz1[tri] + w2 * dz2[tri]
    zbuf = np.full(n_pix, -np.inf)
    np.maximum.at(zbuf, pix, z)
    win = np.flatnonzero(z >= zbuf[pix])
    winner = np.full(n_pix, -1, dtype=np.int64)
    winner[pix[win]] = win
    vis = np.flatnonzero(winner >= 0)
    f = winner[vis]
    bary = np.empty((f.size, 3))
    bary[:, 1], bary[:, 2] = w1[f], w2[f]
    bary[:, 0] = 1.0 - bary[:, 1] - bary[:, 2]
    return vis, tri[f], bary, z[f]


def _ref_rasterize(camera, verts, tris):
    height, width = camera.shape
    scr = camera.project(verts)
    a, b, c = scr[tris[:, 0]], scr[tris[:, 1]], scr[tris[:, 2]]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / area2
        g1c, g1r = (c[:, 1] - a[:, 1]) * inv, -(c[:, 0] - a[:, 0]) * inv
        g2c, g2r = -(b[:, 1] - a[:, 1]) * inv, (b[:, 0] - a[:, 0]) * inv
        g10 = -(g1c * a[:, 0] + g1r * a[:, 1])
        g20 = -(g2c * a[:, 0] + g2r * a[:, 1])
        g0c, g0r, g00 = -(g1c + g2c), -(g1r + g2r), 1.0 - g10 - g20
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
    n_rows = (rmax[t_ok] - rmin[t_ok] + 1).astype(np.int64)
    tr = np.repeat(t_ok, n_rows)
    row = (rmin[tr] + _ragged_arange(n_rows)).astype(float)
    col_lo = cmin[tr].copy()
    col_hi = cmax[tr].copy()
    for gc, gr, g0 in ((g0c, g0r, g00), (g1c, g1r, g10), (g2c, g2r, g20)):
        gct = gc[tr]
        rhs = -_INSIDE_TOL - (gr[tr] * row + g0[tr])
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = rhs / gct
            col_lo = np.where(gct > 0, np.maximum(col_lo, np.ceil(bound)), col_lo)
            col_hi = np.where(gct < 0, np.minimum(col_hi, np.floor(bound)), col_hi)
        col_hi = np.where((gct == 0) & (rhs > 0), -1.0, col_hi)
    n_cols = np.maximum(col_hi - col_lo + 1, 0).astype(np.int64)
    keep = n_cols > 0
    tr, row, col_lo, n_cols = tr[keep], row[keep], col_lo[keep], n_cols[keep]
    tri = np.repeat(tr, n_cols)
    fr = np.repeat(row, n_cols)
    fc = np.repeat(col_lo, n_cols) + _ragged_arange(n_cols)
    w1 = g1c[tri] * fc + g1r[tri] * fr + g10[tri]
    w2 = g2c[tri] * fc + g2r[tri] * fr + g20[tri]
    pix = fr.astype(np.int64) * width + fc.astype(np.int64)
    return _ref_resolve(height * width, pix, tri, w1, w2, verts, tris)


def _ref_extreme_per_ray(e, c, s, take_max):
    if e.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.lexsort((s if take_max else -s, c))
    cs = c[order]
    last = np.flatnonzero(np.r_[cs[1:] != cs[:-1], True])
    return cs[last], e[order[last]]


def _ref_edge_crossings(screen, edges, ray_comp, limits=None):
    lat_comp = 1 - ray_comp
    a, b = screen[edges[:, 0], ray_comp], screen[edges[:, 1], ray_comp]
    c0, c1 = np.ceil(np.minimum(a, b)), np.ceil(np.maximum(a, b))
    if limits is not None:
        c0, c1 = np.maximum(c0, limits[0]), np.minimum(c1, limits[1])
    counts = np.maximum(c1 - c0, 0).astype(np.int64)
    e = np.repeat(np.arange(len(edges)), counts)
    c = np.repeat(c0, counts) + _ragged_arange(counts)
    lam = (c - a[e]) / (b[e] - a[e])
    la, lb = screen[edges[e, 0], lat_comp], screen[edges[e, 1], lat_comp]
    return e, c.astype(np.int64), la + lam * (lb - la)


def _ref_freeze(p: Problem, u):
    cw = np.asarray(p.settings.component_weights, dtype=float)
    frames = []
    for f in range(p.n_frames):
        pos = p.mesh.nodes + u[f]
        raster = rasterize(p.camera, pos, p.tri)
        valid = p.meas.valid[f].ravel()
        vel = p.meas.velocity[f].reshape(-1, 3).astype(float)
        vis = raster.visible_index
        both = valid[vis]
        only = valid.copy()
        only[vis] = False
        if p.settings.outside == "symmetric":
            both |= p.meas.gap[f].ravel()[vis]
            vel = np.where(valid[:, None], vel, 0.0)
        m_both = raster.interpolation_matrix()[np.flatnonzero(both)]
        frames.append((m_both, vel[vis[both]], float(np.sum(vel[only] ** 2 @ cw)), float(max(1, valid.sum())),
                       vis[both], np.flatnonzero(only)))
    return frames


# ------------------------------------------------------------------ helpers
def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (a.shape, b.shape, a.dtype, b.dtype)
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def _same_csr(a, b):
    assert sp.issparse(a) and a.format == "csr" and type(a) is type(b) and a.shape == b.shape
    for name in ("indptr", "indices", "data"):     # unsorted indices compared as stored
        _same(getattr(a, name), getattr(b, name))


def _tie_mesh(rng, n=14):
    """Random overlapping triangles, some duplicated (equal depths), plus a grid whose
    vertices lie on pixel centres (pixel centres exactly on shared edges)."""
    centres = rng.uniform([-1, 0], [5, 4], size=(n, 2))
    verts = np.concatenate([np.column_stack([centres + rng.normal(scale=1.2, size=(n, 2)),
                                             rng.normal(size=n)]) for _ in range(3)])
    tris = np.arange(3 * n).reshape(3, n).T.copy()
    tris = np.concatenate([tris, tris[::3], tris[1::4][:, [1, 2, 0]]])      # exact duplicates: ties
    gx, gy = np.meshgrid(np.arange(6) * 0.5, np.arange(5) * 0.5)
    grid = np.column_stack([gx.ravel() - 0.5, gy.ravel(), np.zeros(gx.size)])   # flat: equal depths on edges
    q = np.arange(gx.size).reshape(gy.shape)
    quads = np.column_stack([q[:-1, :-1].ravel(), q[:-1, 1:].ravel(), q[1:, 1:].ravel(), q[1:, :-1].ravel()])
    gtris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]) + len(verts)
    return np.concatenate([verts, grid]), np.concatenate([tris, gtris])


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("camera", [Camera(4.0, 17.0, (12.0, 3.0), 26, 21), Camera(2.0, 0.0, (2.0, 1.0), 14, 11)])
def test_rasterize_is_identical_to_the_reference(seed, camera):
    verts, tris = _tie_mesh(np.random.default_rng(seed))
    ras = rasterize(camera, verts, tris)
    vis, tri, bary, depth = _ref_rasterize(camera, verts, tris)
    assert vis.size > 50
    _same(ras.visible_index, vis)
    _same(ras.visible_triangle, tri)
    _same(ras.visible_bary, bary)
    _same(ras.visible_depth, depth)


def test_interpolation_rows_equal_row_indexing_of_the_full_matrix():
    verts, tris = _tie_mesh(np.random.default_rng(3))
    ras = rasterize(Camera(4.0, 17.0, (12.0, 3.0), 26, 21), verts, tris)
    rows = np.flatnonzero(np.random.default_rng(4).random(ras.visible_index.size) < 0.7)
    _same_csr(ras.interpolation_rows(rows), ras.interpolation_matrix()[rows])
    _same_csr(ras.interpolation_rows(rows[:0]), ras.interpolation_matrix()[rows[:0]])


def test_extreme_per_ray_is_identical_to_the_sorted_reference():
    rng = np.random.default_rng(0)
    for trial in range(400):
        n = int(rng.integers(0, 120))
        c = rng.integers(-5, int(rng.integers(1, 30)), n)
        if trial % 7 == 0:
            c = c * 10 ** 6                               # sparse ray coordinates
        s = rng.integers(-3, 4, n) * rng.choice([1.0, 0.5])   # many equal positions
        if trial % 5 == 0 and n:
            s[rng.integers(0, n, 3)] = rng.choice([np.inf, -np.inf, -0.0, 0.0], 3)
        if trial % 11 == 0 and n:
            s[rng.integers(0, n)] = np.nan
        e = rng.integers(0, 1000, n)
        for take_max in (True, False):
            for got, want in zip(extreme_per_ray(e, c, s, take_max), _ref_extreme_per_ray(e, c, s, take_max)):
                _same(got, want)


@pytest.mark.parametrize("limits", [None, (3, 40)])
def test_edge_crossings_are_identical_to_the_reference(limits):
    rng = np.random.default_rng(5)
    screen = rng.uniform(0, 60, (80, 2))
    edges = rng.integers(0, 80, (200, 2))
    for got, want in zip(edge_crossings(screen, edges, 0, limits), _ref_edge_crossings(screen, edges, 0, limits)):
        _same(got, want)


@pytest.fixture(scope="module")
def case():
    return forward_case(resolution=(2, 2, 4), sides=("inferior", "superior"), n_frames=6)


@pytest.mark.parametrize("outside", ["paper", "symmetric"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_freeze_is_identical_to_the_reference(case, outside, dtype):
    m = case.measurement
    valid = m.valid.copy()
    valid[:, ::7] = False                                 # pixels seen only by the simulation
    meas = Measurement(m.times, m.velocity.astype(dtype), valid, m.gap_lo, m.gap_hi, m.gap)
    p = Problem(case.model.mesh, CAMERA, case.response, meas,
                case.problem.settings.__class__(**{**case.problem.settings.__dict__, "outside": outside,
                                                   "component_weights": (1.0, 0.5, 2.0)}))
    x = 0.7 * case.x_true
    u = p.displacements(x)
    frames = p.freeze(x, u)
    ref = _ref_freeze(p, u)
    assert len(frames) == len(ref) == p.n_frames
    for fr, (m_both, v_both, const, n_norm, pix_both, pix_only) in zip(frames, ref):
        _same_csr(fr.m_both, m_both)
        _same(fr.v_both, v_both)
        assert fr.const == const and fr.n_norm == n_norm
        _same(fr.pix_both, pix_both)
        _same(fr.pix_only, pix_only)
    # silhouettes: the chosen edges are the lexsort reference's
    scr_rays = p.rays
    for f in range(p.n_frames):
        pos = p.mesh.nodes + u[f]
        scr = p.camera.project(pos)
        for side, k in enumerate(p.fold_order):
            e, c, s = _ref_edge_crossings(scr, p.fold_edges[k], p.ray_comp)
            keep = np.isin(c, scr_rays)
            rays, edge = _ref_extreme_per_ray(e[keep], c[keep], s[keep], take_max=(side == 0))
            got_rays, got_edge, _ = p.silhouettes(pos)[side]
            _same(got_rays, rays)
            _same(got_edge, edge)
