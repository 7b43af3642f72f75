"""Camera model and rasteriser: brute-force reference, analytic shapes, linear interpolation."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vfcli.camera.camera import Camera
from vfcli.camera.raster import gap_mask, interpolate, rasterize, raycast_points, surface_velocity


def grid_surface(nx, ny, x0, x1, y0, y1, height=lambda x, y: 0.0 * x):
    """Triangulated height field z = height(x, y) over a rectangle: (vertices, triangles)."""
    xs, ys = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny), indexing="ij")
    verts = np.stack([xs.ravel(), ys.ravel(), height(xs.ravel(), ys.ravel())], axis=1)
    i = (np.arange(nx - 1)[:, None] * ny + np.arange(ny - 1)[None, :]).ravel()
    tris = np.concatenate([np.stack([i, i + ny, i + ny + 1], 1), np.stack([i, i + ny + 1, i + 1], 1)])
    return verts, tris


def brute_force(camera, verts, tris):
    """Per-pixel loop over all triangles: (triangle id, barycentrics, depth)."""
    scr = camera.project(verts)
    H, W = camera.shape
    tri_img = np.full((H, W), -1)
    bary = np.zeros((H, W, 3))
    depth = np.full((H, W), -np.inf)
    for r in range(H):
        for c in range(W):
            for k, (i, j, l) in enumerate(tris):
                m = np.array([[scr[i, 0], scr[j, 0], scr[l, 0]], [scr[i, 1], scr[j, 1], scr[l, 1]], [1, 1, 1]])
                if abs(np.linalg.det(m)) < 1e-12:
                    continue
                w = np.linalg.solve(m, [c, r, 1.0])
                if np.all(w >= 0):
                    z = w @ verts[[i, j, l], 2]
                    if z > depth[r, c]:
                        depth[r, c], tri_img[r, c], bary[r, c] = z, k, w
    return tri_img, bary, np.where(np.isfinite(depth), depth, np.nan)


def test_project_unproject_round_trip_and_convention():
    cam = Camera(20.0, 30.0, (5.0, -3.0), 64, 48)
    pts = np.random.default_rng(0).normal(size=(10, 3))
    px = cam.project(pts)
    assert np.allclose(cam.unproject_xy(px), pts[:, :2])
    # conventions.md: columns follow x and rows follow y at zero rotation
    cam0 = Camera(10.0, 0.0, (1.0, 2.0), 8, 8)
    assert np.allclose(cam0.project([[1.0, 0.0, 5.0], [0.0, 1.0, -5.0]]), [[11.0, 2.0], [1.0, 12.0]])
    # 90 degrees: x maps onto rows
    cam90 = Camera(10.0, 90.0, (0.0, 0.0), 8, 8)
    assert np.allclose(cam90.project([[1.0, 0.0, 0.0]]), [[0.0, 10.0]])


def test_camera_rejects_bad_scale():
    with pytest.raises(ValueError):
        Camera(0.0, 0.0, (0.0, 0.0), 8, 8)
    with pytest.raises(ValueError):
        Camera(10.0, 0.0, (np.nan, 0.0), 8, 8)


@pytest.mark.parametrize("override", ["camera.px_per_mm=nan", "camera.offset_px=[0, inf]", "camera.rotation_deg=nan"])
def test_the_config_refuses_non_finite_camera_values_before_the_camera_sees_them(override):
    from vfcli.config import load_config
    from vfcli.errors import ConfigError

    with pytest.raises(ConfigError, match=override.split("=")[0]):
        load_config(overrides=[override])


def test_rasterize_matches_brute_force_on_random_overlapping_triangles():
    rng = np.random.default_rng(1)
    cam = Camera(4.0, 17.0, (12.0, 3.0), 26, 21)
    centres = rng.uniform([-1, 0], [5, 4], size=(12, 2))
    verts = np.concatenate([np.column_stack([centres + rng.normal(scale=1.2, size=(12, 2)),
                                             rng.normal(size=12)]) for _ in range(3)])
    tris = np.arange(36).reshape(3, 12).T.copy()
    ras = rasterize(cam, verts, tris)
    ref_tri, ref_bary, ref_depth = brute_force(cam, verts, tris)
    assert (ref_tri >= 0).sum() > 100            # the case is not trivial
    assert np.array_equal(ras.triangle, ref_tri)
    assert np.allclose(ras.bary, ref_bary, atol=1e-9)
    assert np.allclose(ras.depth, ref_depth, atol=1e-9, equal_nan=True)


def test_depth_test_keeps_the_higher_of_two_overlapping_triangles():
    cam = Camera(1.0, 0.0, (0.0, 0.0), 20, 20)
    low = [[0, 0, -1.0], [19, 0, -1.0], [0, 19, -1.0]]
    high = [[2, 2, 0.5], [19, 2, 0.5], [2, 19, 0.5]]
    for order in ((0, 1), (1, 0)):            # independent of the drawing order
        verts = np.array([low, high][order[0]] + [low, high][order[1]], dtype=float)
        ras = rasterize(cam, verts, np.array([[0, 1, 2], [3, 4, 5]]))
        high_id = order.index(1)
        assert ras.triangle[5, 5] == high_id and ras.depth[5, 5] == pytest.approx(0.5)
        assert ras.triangle[0, 5] == 1 - high_id and ras.depth[0, 5] == pytest.approx(-1.0)
        assert ras.triangle[19, 19] == -1


def test_tilted_plane_depth_and_coverage_are_analytic():
    # plane z = 0.3 x - 0.2 y + 1 over [0, 4] x [0, 3] mm, camera rotated
    verts, tris = grid_surface(9, 7, 0.0, 4.0, 0.0, 3.0, lambda x, y: 0.3 * x - 0.2 * y + 1.0)
    cam = Camera(10.0, 12.0, (8.0, 2.0), 50, 50)
    ras = rasterize(cam, verts, tris)
    xy = cam.pixel_centres_xy()
    inside = (xy[..., 0] > 1e-6) & (xy[..., 0] < 4 - 1e-6) & (xy[..., 1] > 1e-6) & (xy[..., 1] < 3 - 1e-6)
    outside = (xy[..., 0] < -1e-6) | (xy[..., 0] > 4 + 1e-6) | (xy[..., 1] < -1e-6) | (xy[..., 1] > 3 + 1e-6)
    assert ras.mask[inside].all() and not ras.mask[outside].any()
    expect = 0.3 * xy[..., 0] - 0.2 * xy[..., 1] + 1.0
    assert np.allclose(ras.depth[ras.mask], expect[ras.mask], atol=1e-10)
    # interpolating the vertex positions gives back the pixel centre (orthographic camera)
    pos = interpolate(ras, verts)
    assert np.allclose(pos[ras.mask][:, :2], xy[ras.mask], atol=1e-10)


def test_closed_mesh_surface_without_holes_between_triangles():
    # pixel centres exactly on shared edges must be covered (no cracks)
    verts, tris = grid_surface(5, 5, 0.0, 4.0, 0.0, 4.0)
    cam = Camera(4.0, 0.0, (0.0, 0.0), 17, 17)          # vertices fall exactly on pixel centres
    assert rasterize(cam, verts, tris).mask.all()


def test_interpolation_matrix_equals_direct_interpolation():
    rng = np.random.default_rng(2)
    verts, tris = grid_surface(12, 9, -2.0, 3.0, -1.0, 2.0, lambda x, y: 0.2 * np.sin(x) * y)
    cam = Camera(9.0, -8.0, (25.0, 12.0), 60, 40)
    ras = rasterize(cam, verts, tris)
    vals = rng.normal(size=(len(verts), 4))
    direct = interpolate(ras, vals)
    # independent per-pixel blend from the triangle and barycentric images
    corner_vals = vals[tris[np.maximum(ras.triangle, 0)]]                    # (H, W, 3, 4)
    by_hand = np.where(ras.mask[..., None], np.einsum("hwk,hwkd->hwd", ras.bary, corner_vals), np.nan)
    assert np.allclose(direct, by_hand, equal_nan=True)
    m = ras.interpolation_matrix()
    assert m.shape == (ras.mask.sum(), len(verts))
    assert np.allclose(ras.scatter(m @ vals), direct, equal_nan=True)
    assert np.allclose(np.asarray(m.sum(axis=1)).ravel(), 1.0)      # partition of unity
    assert np.isnan(direct[~ras.mask]).all()


def test_velocity_of_a_rigid_translation_is_exact_and_linear():
    verts, tris = grid_surface(10, 10, 0.0, 3.0, 0.0, 3.0, lambda x, y: 0.1 * x * y)
    cam = Camera(12.0, 5.0, (4.0, 4.0), 48, 48)
    ras = rasterize(cam, verts, tris)
    velocity = np.array([120.0, -40.0, 310.0])           # mm/s
    dt = 1e-4
    vel = surface_velocity(ras, verts, verts + velocity * dt, dt)
    assert np.allclose(vel[ras.mask], velocity, rtol=1e-9)
    # linear: M @ displacement / dt reproduces it for an arbitrary (non-rigid) motion
    disp = np.random.default_rng(3).normal(size=verts.shape) * 1e-3
    direct = surface_velocity(ras, verts, verts + disp, dt)
    assert np.allclose(ras.interpolation_matrix() @ disp / dt, direct[ras.mask])


def test_gap_mask_of_a_known_slit():
    # two flat folds with a slit 0.5 mm wide between y = -0.2 and y = 0.3, x in [1, 9]
    left_v, left_t = grid_surface(9, 5, 1.0, 9.0, -4.0, -0.2)
    right_v, right_t = grid_surface(9, 5, 1.0, 9.0, 0.3, 4.0)
    verts = np.concatenate([left_v, right_v])
    tris = np.concatenate([left_t, right_t + len(left_v)])
    fold = np.repeat([0, 1], [len(left_t), len(right_t)])
    cam = Camera(10.0, 0.0, (0.0, 50.0), 110, 100)
    gap = gap_mask(cam, rasterize(cam, verts, tris), fold)
    xy = cam.pixel_centres_xy()
    expect = (xy[..., 0] >= 1.0) & (xy[..., 0] <= 9.0) & (xy[..., 1] > -0.2 + 1e-9) & (xy[..., 1] < 0.3 - 1e-9)
    assert expect.sum() == 81 * 4
    assert np.array_equal(gap, expect)
    # rotated camera: the gap area is preserved within the pixels along its boundary
    camr = Camera(10.0, 25.0, (10.0, 30.0), 110, 100)
    gap_r = gap_mask(camr, rasterize(camr, verts, tris), fold)
    assert abs(gap_r.sum() - 8.0 * 0.5 * 100) < 0.15 * 8.0 * 0.5 * 100


@pytest.mark.parametrize("factor", [2, 3])
def test_supersampled_camera_splits_pixels(factor):
    cam = Camera(7.0, 11.0, (3.0, 4.0), 10, 8)
    fine = cam.supersampled(factor)
    pts = np.random.default_rng(4).normal(size=(5, 3))
    # fine pixel coordinates map back to coarse ones as (fine + 0.5) / factor - 0.5
    assert np.allclose((fine.project(pts) + 0.5) / factor - 0.5, cam.project(pts))
    assert fine.shape == (8 * factor, 10 * factor)


def box_surface():
    """Closed surface of the box [0, 4] x [0, 3] x [-2, 0.5] mm (12 triangles, 4 vertical faces)."""
    x, y, z = (0.0, 4.0), (0.0, 3.0), (-2.0, 0.5)
    verts = np.array([[x[i], y[j], z[k]] for k in range(2) for j in range(2) for i in range(2)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    return verts, tris


def test_closed_box_shows_its_top_face_and_skips_edge_on_faces():
    verts, tris = box_surface()
    cam = Camera(5.0, 0.0, (2.3, 1.7), 30, 25)
    ras = rasterize(cam, verts, tris)
    top = np.flatnonzero(np.all(verts[tris, 2] == 0.5, axis=1))
    assert set(np.unique(ras.visible_triangle)) <= set(top)
    assert np.allclose(ras.visible_depth, 0.5)
    xy = cam.pixel_centres_xy()
    inside = (xy[..., 0] >= 0) & (xy[..., 0] <= 4) & (xy[..., 1] >= 0) & (xy[..., 1] <= 3)
    assert np.array_equal(ras.mask, inside)


def test_nothing_in_view_gives_an_empty_raster():
    verts, tris = box_surface()
    ras = rasterize(Camera(5.0, 0.0, (500.0, 500.0), 20, 20), verts, tris)
    assert not ras.mask.any() and ras.interpolation_matrix().shape == (0, len(verts))
    assert np.isnan(interpolate(ras, verts)).all()


def test_raycast_at_scattered_points_matches_the_rasteriser_at_pixel_centres():
    verts, tris = grid_surface(14, 11, -2.0, 3.0, -1.0, 2.0, lambda x, y: 0.3 * np.sin(2 * x) * y)
    # a second, higher sheet over part of it: the depth test decides
    verts2, tris2 = grid_surface(5, 5, -0.5, 1.5, -0.5, 1.0, lambda x, y: 1.0 + 0.1 * x)
    verts_all = np.concatenate([verts, verts2])
    tris_all = np.concatenate([tris, tris2 + len(verts)])
    cam = Camera(9.0, -13.0, (25.0, 14.0), 60, 45)
    ras = rasterize(cam, verts_all, tris_all)
    hits = raycast_points(cam.pixel_centres_xy().reshape(-1, 2), verts_all, tris_all)
    assert hits.shape == (60 * 45,)
    assert np.array_equal(hits.triangle, ras.triangle.ravel())
    assert np.allclose(hits.bary, ras.bary.reshape(-1, 3), atol=1e-9)
    vals = verts_all[:, 2] * 3.0 + 1.0
    assert np.allclose(hits.interpolation_matrix() @ vals, ras.interpolation_matrix() @ vals)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rotation=st.floats(-180, 180), scale=st.floats(0.5, 4.0))
def test_rasterize_matches_brute_force_for_any_camera(seed, rotation, scale):
    rng = np.random.default_rng(seed)
    cam = Camera(scale, rotation, tuple(rng.uniform(-3, 15, size=2)), 14, 11)
    verts = rng.uniform([-4, -4, -1], [8, 8, 1], size=(15, 3))
    tris = rng.permutation(15).reshape(5, 3)
    ras = rasterize(cam, verts, tris)
    ref_tri, ref_bary, _ = brute_force(cam, verts, tris)
    assert np.array_equal(ras.triangle, ref_tri)
    assert np.allclose(ras.bary, ref_bary, atol=1e-8)
