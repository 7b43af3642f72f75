"""Phantom image formation: sub-pixel motion, gap truth, sensor noise and bit depth."""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.camera.camera import Camera
from vfcli.synth.render import (RenderSettings, expose, make_scene_textures, render_frame, render_radiance,
                          render_truth)


def flat_sheet(x0, x1, y0, y1, n=21):
    """A flat horizontal sheet z = 0 over a rectangle: (vertices, triangles)."""
    xs, ys = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n), indexing="ij")
    verts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    tris = np.concatenate([np.stack([i, i + n, i + n + 1], 1), np.stack([i, i + n + 1, i + 1], 1)])
    return verts, tris


def two_folds(slit_lo=-0.2, slit_hi=0.3, x0=1.0, x1=9.0):
    """Two flat folds, x in [x0, x1] mm, with a straight slit between y = slit_lo and y = slit_hi."""
    lv, lt = flat_sheet(x0, x1, -4.0, slit_lo, n=9)
    rv, rt = flat_sheet(x0, x1, slit_hi, 4.0, n=9)
    verts = np.concatenate([lv, rv])
    tris = np.concatenate([lt, rt + len(lv)])
    fold = np.repeat([0, 1], [len(lt), len(rt)])
    return verts, tris, fold


def phase_slope_shift(a, b):
    """Translation d (px, (col, row)) with b(p) = a(p - d), from the cross-spectrum phase slope."""
    h, w = a.shape
    win = np.outer(np.hanning(h), np.hanning(w))
    cross = np.fft.fft2((b - b.mean()) * win) * np.conj(np.fft.fft2((a - a.mean()) * win))
    ky = np.fft.fftfreq(h)[:, None] * np.ones((1, w))
    kx = np.ones((h, 1)) * np.fft.fftfreq(w)[None, :]
    k = np.hypot(kx, ky)
    sel = (k > 0) & (k < 0.15)
    sw = np.sqrt(np.abs(cross[sel]))
    design = -2 * np.pi * np.stack([kx[sel], ky[sel]], axis=1)
    d, *_ = np.linalg.lstsq(design * sw[:, None], np.angle(cross[sel]) * sw, rcond=None)
    return d


@pytest.mark.parametrize("shift_px", [(0.3, -0.2), (0.13, 0.41), (0.5, 0.5)])
def test_subpixel_translation_of_the_surface_shifts_the_image(shift_px):
    cam = Camera(15.0, 0.0, (64.0, 64.0), 128, 128)
    settings = RenderSettings(supersample=2)
    textures = make_scene_textures(cam, settings, np.random.default_rng(5))
    verts, tris = flat_sheet(-12.0, 12.0, -12.0, 12.0, n=31)
    fold = np.zeros(len(tris), dtype=int)
    material = verts[:, :2].copy()                       # the texture is attached to the material
    a = render_radiance(cam, verts, tris, material, fold, textures, settings)
    moved = verts.copy()
    moved[:, :2] += cam.unproject_xy(np.array(shift_px)) - cam.unproject_xy(np.zeros(2))
    b = render_radiance(cam, moved, tris, material, fold, textures, settings)
    assert np.abs(a - b).max() > 0.01                     # the texture moved
    assert np.allclose(phase_slope_shift(a, b), shift_px, atol=0.05)


def test_gap_truth_of_a_known_slit_and_the_gap_is_dark():
    cam = Camera(10.0, 0.0, (0.0, 50.0), 110, 100)
    settings = RenderSettings(supersample=3)
    verts, tris, fold = two_folds(-0.213, 0.311)
    truth = render_truth(cam, verts, tris, np.zeros_like(verts), fold, supersample=3)
    xy = cam.pixel_centres_xy()
    expect = (xy[..., 0] >= 1.0) & (xy[..., 0] <= 9.0) & (xy[..., 1] > -0.213) & (xy[..., 1] < 0.311)
    assert np.array_equal(truth.gap, expect)
    # area: 8 mm x 0.524 mm at 10 px/mm = 419.2 px^2, within the sub-sampling of the edges
    assert truth.gap_fraction.sum() == pytest.approx(419.2, rel=0.03)
    assert not (truth.visible & truth.gap).any()
    textures = make_scene_textures(cam, settings, np.random.default_rng(0))
    img = render_radiance(cam, verts, tris, verts[:, :2], fold, textures, settings)
    core = expect & (xy[..., 1] > -0.1) & (xy[..., 1] < 0.2) & (xy[..., 0] > 2) & (xy[..., 0] < 8)
    assert img[core].mean() < 0.1 * img[truth.visible].mean()


@pytest.mark.parametrize("rotation_deg", [-4.0, 7.0, 30.0, 71.0])
def test_gap_truth_of_a_turned_camera_stops_at_the_fold_ends(rotation_deg):
    # the gap is the slit between the folds, x in [1.03, 9.05] mm (ends inside a pixel strip); a turned
    # camera's pixel strips cross the folds' ends at a slant, and the pixels just past an end are not
    # gap (before: a band along each end, 72 px a frame on a widened phantom turned by -4 deg)
    cam = Camera(10.0, rotation_deg, (55.0, 50.0), 110, 100)
    cam = Camera(10.0, rotation_deg, tuple(np.array([55.0, 50.0]) - cam.project(np.array([[5.0, 0.0]]))[0]
                                      + np.array(cam.offset_px)), 110, 100)
    verts, tris, fold = two_folds(-0.213, 0.311, 1.03, 9.05)
    truth = render_truth(cam, verts, tris, np.zeros_like(verts), fold, supersample=3)
    xy = cam.pixel_centres_xy()
    expect = (xy[..., 0] >= 1.03) & (xy[..., 0] <= 9.05) & (xy[..., 1] > -0.213) & (xy[..., 1] < 0.311)
    beyond = (truth.gap & ((xy[..., 0] < 1.03) | (xy[..., 0] > 9.05))).sum()
    assert beyond == 0
    # within the strip's pixel tolerance along the slit's sides: the slit is 80 x 5.24 px
    assert (truth.gap ^ expect).sum() <= 0.1 * expect.sum()
    assert truth.gap_fraction.sum() == pytest.approx(80.2 * 5.24, rel=0.03)


def test_gap_truth_with_an_even_supersampling_factor_matches_the_odd_one():
    cam = Camera(10.0, 7.0, (10.0, 40.0), 110, 100)
    verts, tris, fold = two_folds()
    t2 = render_truth(cam, verts, tris, np.zeros_like(verts), fold, supersample=2)
    t3 = render_truth(cam, verts, tris, np.zeros_like(verts), fold, supersample=3)
    assert np.array_equal(t2.gap, t3.gap) and np.array_equal(t2.visible, t3.visible)


def test_truth_velocity_of_a_rigid_motion_is_exact():
    cam = Camera(10.0, 20.0, (30.0, 50.0), 100, 100)
    verts, tris, fold = two_folds()
    velocity = np.array([50.0, -120.0, 300.0])
    truth = render_truth(cam, verts, tris, np.broadcast_to(velocity, verts.shape), fold)
    assert truth.visible.sum() > 3000
    assert np.allclose(truth.velocity[truth.visible], velocity)
    assert np.isnan(truth.velocity[~truth.visible]).all()


def test_flat_field_noise_level_and_bit_depth_are_as_stated():
    settings = RenderSettings(snr=40.0, read_noise_dn=2.0, bit_depth=12, black_level_dn=32.0)
    level = settings.surface_level
    radiance = np.full((200, 200), level)
    a = expose(radiance, settings, np.random.default_rng(1))
    b = expose(radiance, settings, np.random.default_rng(2))
    assert a.dtype == np.uint16
    expected_std = level * settings.full_scale_dn / 40.0
    measured_std = np.std(a.astype(float) - b.astype(float)) / np.sqrt(2)
    assert measured_std == pytest.approx(expected_std, rel=0.03)
    assert a.mean() == pytest.approx(32.0 + level * settings.full_scale_dn, rel=0.002)
    # saturation and black: the range is exactly 12 bits
    sat = expose(np.full((10, 10), 3.0), settings, np.random.default_rng(3))
    assert sat.max() == 4095 and sat.min() == 4095
    dark = expose(np.zeros((100, 100)), settings, np.random.default_rng(3))
    assert dark.mean() == pytest.approx(32.0, abs=0.5) and dark.std() == pytest.approx(2.0, rel=0.1)


def test_uniform_silicone_renders_the_stated_surface_level():
    # no texture, horizontal surface, light at any angle: radiance = surface_level exactly
    cam = Camera(8.0, 0.0, (40.0, 40.0), 80, 80)
    settings = RenderSettings(texture_contrast=0.0, mark_density=0.0, psf_sigma_px=0.0, light_dir=(0.4, -0.3, 1.0))
    textures = make_scene_textures(cam, settings, np.random.default_rng(0))
    verts, tris = flat_sheet(-10.0, 10.0, -10.0, 10.0, n=5)
    img = render_radiance(cam, verts, tris, verts[:, :2], np.zeros(len(tris), int), textures, settings)
    assert np.allclose(img, settings.surface_level, rtol=1e-4)


@pytest.mark.parametrize("two_sided", [False, True])
@pytest.mark.parametrize("slope", [-4.0, 4.0])
def test_a_steep_surface_turned_away_from_the_lamp_gets_the_diffuse_light_only(slope, two_sided):
    """Lambert's cosine law at the outward normal: the sheet z = slope * y has the normal (0, -slope, 1) / sqrt(1 +
    slope^2); under a lamp towards (0, 0.4, 1) it is lit at (n . l) / l_z of a horizontal surface's direct light
    when it faces the lamp (slope -4: 2.6 / sqrt(17)) and gets the diffuse share only when it faces away (slope 4:
    n . l < 0). The default panel's historical two-sided shading (``two_sided_lambert``) lights it at
    |n . l| = 0.6 / sqrt(17) instead."""
    cam = Camera(8.0, 0.0, (40.0, 40.0), 80, 80)
    settings = RenderSettings(texture_contrast=0.0, mark_density=0.0, psf_sigma_px=0.0, light_dir=(0.0, 0.4, 1.0),
                              two_sided_lambert=two_sided)
    textures = make_scene_textures(cam, settings, np.random.default_rng(0))
    verts, tris = flat_sheet(-10.0, 10.0, -10.0, 10.0, n=5)
    verts[:, 2] = slope * verts[:, 1]
    img = render_radiance(cam, verts, tris, verts[:, :2], np.zeros(len(tris), int), textures, settings)
    cosine = (-slope * 0.4 + 1.0) / np.sqrt(1.0 + slope**2)
    direct = abs(cosine) if two_sided else max(cosine, 0.0)
    expected = settings.surface_level * (settings.ambient + (1.0 - settings.ambient) * direct)
    assert np.allclose(img, expected, rtol=1e-4)


def test_same_seed_gives_the_same_frame_bytes():
    cam = Camera(10.0, 3.0, (0.0, 50.0), 100, 100)
    settings = RenderSettings()
    verts, tris, fold = two_folds()

    def frame(seed):
        rng = np.random.default_rng(seed)
        textures = make_scene_textures(cam, settings, rng)
        return render_frame(cam, verts, tris, verts[:, :2], fold, np.zeros_like(verts), textures, settings, rng)

    f1, f2, f3 = frame(7), frame(7), frame(8)
    assert f1.image.tobytes() == f2.image.tobytes()
    assert f1.image.tobytes() != f3.image.tobytes()
    assert f1.image.max() <= 4095


def test_motion_blur_averages_the_sub_instants():
    cam = Camera(10.0, 0.0, (0.0, 50.0), 100, 100)
    settings = RenderSettings(supersample=2)
    verts, tris, fold = two_folds()
    textures = make_scene_textures(cam, settings, np.random.default_rng(1))
    stack = np.stack([verts + [0.04 * k, 0.0, 0.0] for k in range(3)])     # 0.4 px per sub-instant
    velocity = np.broadcast_to([400.0, 0.0, 0.0], verts.shape)
    frame = render_frame(cam, stack, tris, verts[:, :2], fold, velocity, textures, settings,
                         np.random.default_rng(2))
    singles = [render_radiance(cam, v, tris, verts[:, :2], fold, textures, settings) for v in stack]
    assert np.allclose(frame.radiance, np.mean(singles, axis=0))
    middle = render_truth(cam, stack[1], tris, velocity, fold, supersample=2)
    assert np.array_equal(frame.truth.visible, middle.visible)
