"""The recording's edge model: gap level and PSF width, measured once on sampled frames."""
from __future__ import annotations

import logging

import numpy as np

from vfcli.flow.gap.rays import outermost_silhouette
from vfcli.flow.gap.subpixel.profile import EdgeModel, fit_slit_profiles
from vfcli.flow.gap.subpixel.ray_edges import ray_windows

log = logging.getLogger(__name__)

#: Half-width of the PSF search's window beyond each edge, in PSF standard deviations: the
#: blur itself is fitted, so the window holds the step's tails too (to 0.13 %; the edge fit's
#: :data:`vfcli.flow.gap.subpixel.profile.WINDOW_SIGMAS` is 2).
PSF_WINDOW_SIGMAS = 3.0

#: Range and resolution of the PSF search (:func:`estimate_edge_model`), px.
PSF_SIGMA_RANGE_PX = (0.2, 3.0)

#: The least blur an image can have, px: a camera pixel integrates the light over its area, a box one pixel wide,
#: whose standard deviation is 1 / sqrt(12) pixel; the optics' blur only adds to it (variances add), so the PSF of
#: optics and pixel together, which the edge model's Gaussian stands for, is never narrower. An edge that fits
#: sharper is the scene's, not the optics': tissue that brightens toward the gap's edge (a lit rim) steepens the
#: step, and the PSF search read 0.22-0.25 px on widened phantoms whose optics and pixels blur by 0.39-0.48 px
#: (seeds 3001, 3009, 4103, 4107, 4109; docs/benchmarks.md, "The blur of the pixel itself").
PIXEL_APERTURE_SIGMA_PX = 12 ** -0.5


def estimate_edge_model(
    frames_sample: np.ndarray, masks: np.ndarray, lateral_axis: int = 0, *, min_width_px: float = 3.0, max_rays: int = 1000,
    gap_counts: float | None = None, sigma_range_px: tuple[float, float] = PSF_SIGMA_RANGE_PX,
) -> EdgeModel | None:
    """Gap level and PSF width of a recording, measured on sampled frames and their rough masks.

    * Gap level: ``gap_counts`` when the caller knows it (the flow step does not; the bench
      ``bench/bench_gap_level.py`` passes a phantom's), else the median intensity of the
      mask pixels whose two lateral neighbours are in the mask too (the gap's interior, away
      from the blurred edges). On a slit narrower than about 4 PSF widths in every sampled frame
      that median is the blurred dip's floor, brighter than the gap (docs/benchmarks.md, "A slit
      narrower than about 2.5 blur widths reads too wide").
    * PSF width: the sigma that minimises the pooled residual of :func:`fit_slit_profiles`
      over the rays where the rough gap is at least ``min_width_px`` wide (on narrower
      slits blur and width cannot be told apart), each fit starting at the rough run's edges
      but free to move inside them (the run may hold dark wall pixels); a log-spaced search over
      ``sigma_range_px`` (default :data:`PSF_SIGMA_RANGE_PX`) refined by a parabola, with a
      window of 3 px beyond each edge, widened to :data:`PSF_WINDOW_SIGMAS` sigmas if the PSF
      turns out wider; never below the pixel's own blur, :data:`PIXEL_APERTURE_SIGMA_PX` (the search's
      cost is then least at that bound, the nearest the optics allow).

    Parameters
    ----------
    frames_sample : (k, H, W) array of counts
    masks : (k, H, W) bool
        Rough gap masks of those frames (e.g. :func:`gap_mask`).
    lateral_axis : {0, 1}
    min_width_px : float
        Narrowest rough gap used for the PSF, px.
    max_rays : int
        At most this many rays (spread evenly) enter the PSF search.
    gap_counts : float, optional
        The gap's level, counts, when known; None: measured (above). With the level known the
        blur of a slit too narrow to show it is measured right (``tests/test_gap_known_level.py``).
    sigma_range_px : (float, float)
        Range of the PSF search, px.

    Returns
    -------
    EdgeModel, or None when the sample shows no gap at least ``min_width_px`` wide
    (nothing to measure the blur on).
    """
    frames = np.asarray(frames_sample)
    m = np.asarray(masks, dtype=bool)
    if frames.ndim == 2:
        frames, m = frames[None], m[None]
    if frames.shape != m.shape:
        raise ValueError(f"edge model: frames {frames.shape} and masks {m.shape} differ")
    if not m.any():
        return None
    lat = 1 + lateral_axis  # lateral axis of the (k, H, W) stack
    interior = m & np.roll(m, 1, axis=lat) & np.roll(m, -1, axis=lat)
    if gap_counts is None:
        pixels = frames[interior] if interior.sum() >= 16 else frames[m]
        gap_counts = float(np.median(pixels))
    gap_counts = float(gap_counts)
    rays = []
    for f, mk in zip(frames, m):
        e0, e1 = outermost_silhouette(mk, lateral_axis, border_is_edge=True)
        wide = np.isfinite(e0) & (e1 - e0 >= min_width_px)
        if wide.any():
            rays.append((f, np.where(wide, e0, np.nan), np.where(wide, e1, np.nan)))
    if not rays:
        log.warning("edge model: the sampled gap is never %.0f px wide, too narrow to measure the blur on; "
                    "no sub-pixel edges", min_width_px)
        return None

    def collect(margin: int):
        windows = [ray_windows(f, e0, e1, margin, lateral_axis) + (e0, e1) for f, e0, e1 in rays]
        width = max(p.shape[1] for p, *_ in windows)
        prof, rows, a, b = [], [], [], []
        for p, r, e0, e1 in windows:
            sel = np.isfinite(e0)
            pad = ((0, 0), (0, width - p.shape[1]))
            prof.append(np.pad(p[sel], pad, constant_values=np.nan))
            rows.append(np.pad(r[sel], pad, constant_values=0.0))
            a.append(e0[sel])
            b.append(e1[sel])
        prof, rows, a, b = (np.concatenate(v) for v in (prof, rows, a, b))
        take = np.unique(np.linspace(0, len(prof) - 1, min(len(prof), max_rays)).astype(int))
        return prof[take], rows[take], a[take], b[take]

    def search(margin: int) -> float:
        prof, rows, a, b = collect(margin)

        def cost(s: float) -> float:
            # no inner bound at the rough run's pixels: beside dark medial walls (darker than the threshold under
            # sharp optics) the run holds wall pixels, and edges held at them were fitted with a blur 1.4-1.6 times
            # too wide (tests/test_gap_tilted.py; widened seed 1104: 0.95 px for 0.66, its gap +8.6 %)
            fit = fit_slit_profiles(prof, rows, a, b, s, gap_counts)
            return float(np.sum(fit.rms**2))

        grid = np.geomspace(*sigma_range_px, 13)  # steps of 25 % on the default range
        k = int(np.argmin([cost(s) for s in grid]))
        fine = np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 9)  # steps of about 5 %
        values = np.array([cost(s) for s in fine])
        k = int(np.argmin(values))
        if 0 < k < len(fine) - 1:  # parabola through the three lowest points, in log sigma
            x = np.log(fine[k - 1 : k + 2])
            c = np.polyfit(x, values[k - 1 : k + 2], 2)
            if c[0] > 0:
                return float(np.exp(np.clip(-c[1] / (2 * c[0]), x[0], x[2])))
        return float(fine[k])

    sigma = search(3)
    if np.ceil(PSF_WINDOW_SIGMAS * sigma) > 3:
        sigma = search(int(np.ceil(PSF_WINDOW_SIGMAS * sigma)))
    if sigma < PIXEL_APERTURE_SIGMA_PX:
        log.debug("edge model: the PSF search reads %.2f px, sharper than a pixel blurs (%.2f px); taking the pixel's",
                  sigma, PIXEL_APERTURE_SIGMA_PX)
        sigma = PIXEL_APERTURE_SIGMA_PX
    return EdgeModel(gap_counts, sigma)
