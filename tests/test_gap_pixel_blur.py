"""The blur of the pixel itself (issue 15 item 4: the blur measured robustly under sharp optics).

A camera pixel integrates the light over its area: whatever the optics, the image is blurred by at least a box one
pixel wide, standard deviation 1 / sqrt(12) px. Where the tissue brightens toward the gap's edge (a lit rim), the
blurred step is steeper than the PSF alone makes it, and the PSF search read the bottom of its range, 0.20 px
(widened phantoms 3001, 3009, 4103, 4107, 4109 under sharp optics: 0.22-0.25 px for optics and pixels that blur by
0.42-0.50 px). The estimate is now never below the pixel's own blur.

The render is analytic, no mocks: per ray (a column) a slit at the channel's level between tissue that darkens toward
the gap over 3 px and, at the edge, a rim brighter by ``rim`` counts decaying over 0.6 px; each pixel the mean of 16
point samples across it (its area), then a 0.15 px Gaussian (the optics; together 0.32 px) and noise of 12 counts.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from vfcli.flow.gap.rays import outermost_silhouette
from vfcli.flow.gap.subpixel import EdgeModel, estimate_edge_model, fit_ray_edges
from vfcli.flow.gap.subpixel.edge_model import PIXEL_APERTURE_SIGMA_PX

GAP = 150.0
OPTICS_SIGMA = 0.15


def _render(rim: float, n_rays: int = 120, height: int = 40, samples: int = 16, frames: int = 6, seed: int = 0):
    """(frames, height, n_rays) counts and each frame's true edges (e0, e1), lateral px (pixel centres at integers)."""
    rng = np.random.default_rng(seed)
    video, truth = [], []
    y = (np.arange(height * samples) + 0.5) / samples - 0.5          # point samples across the pixels, px
    for k in range(frames):
        centre = 19.3 + 0.4 * k
        width = np.linspace(3.0, 6.0, n_rays) * (0.7 + 0.06 * k)
        e0, e1 = centre - width / 2, centre + width / 2
        d = np.maximum(e0[None, :] - y[:, None], y[:, None] - e1[None, :])     # distance outside the gap, px
        tissue = 1800.0 - 600.0 * np.exp(-d / 3.0) + rim * np.exp(-d / 0.6)
        scene = np.where(d < 0, GAP, tissue)
        image = scene.reshape(height, samples, n_rays).mean(axis=1)            # each pixel integrates its area
        image = ndimage.gaussian_filter1d(image, OPTICS_SIGMA, axis=0)
        video.append(image + rng.normal(0.0, 12.0, image.shape))
        truth.append((e0, e1))
    return np.stack(video), truth


def _width_error(video, truth, model: EdgeModel) -> float:
    """Summed fitted slit width over every ray and frame against the true one, minus 1."""
    found = true = 0.0
    for frame, (t0, t1) in zip(video, truth):
        e0, e1 = outermost_silhouette(frame < 0.5 * (GAP + 1200.0), 0, border_is_edge=True)
        fit = fit_ray_edges(frame, e0, e1, model, 0)
        found += float(np.nansum(fit.e1 - fit.e0))
        true += float(np.sum(t1 - t0))
    return found / true - 1


def test_the_pixel_blur_is_one_over_root_12():
    assert PIXEL_APERTURE_SIGMA_PX == pytest.approx(np.sqrt(1 / 12))


@pytest.mark.parametrize("rim", [400.0, 800.0])
def test_a_rim_at_the_edge_does_not_read_sharper_than_a_pixel_blurs(rim):
    """Before: 0.20 px, the search range's bottom, on both; the widths 2.1 and 4.2 % narrow. Now the pixel's blur,
    and the widths nearer the truth (-1.7, -3.8 %)."""
    video, truth = _render(rim)
    model = estimate_edge_model(video, video < 0.5 * (GAP + 1200.0), 0)
    assert model is not None
    assert model.psf_sigma_px >= PIXEL_APERTURE_SIGMA_PX - 1e-12
    true_blur = np.hypot(OPTICS_SIGMA, PIXEL_APERTURE_SIGMA_PX)
    assert model.psf_sigma_px <= true_blur
    at_range_bottom = _width_error(video, truth, EdgeModel(model.gap_counts, 0.2))
    assert abs(_width_error(video, truth, model)) < abs(at_range_bottom)


def test_without_a_rim_the_estimate_is_the_search_s_own():
    """The pixel-integrated slit with plain tissue reads at or above the pixel's blur by itself (0.29 px); the
    bound changes nothing there, and the widths hold to 1.5 %."""
    video, truth = _render(0.0)
    model = estimate_edge_model(video, video < 0.5 * (GAP + 1200.0), 0)
    assert PIXEL_APERTURE_SIGMA_PX - 1e-12 <= model.psf_sigma_px < 0.45
    assert abs(_width_error(video, truth, model)) < 0.015
