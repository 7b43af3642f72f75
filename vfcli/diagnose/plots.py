"""Velocity at points (PNG): measured vs the baseline vs the extended model, at a few pixels.

The pixels are those the baseline's frozen raster compares in the most frames, the ones with the
largest measured vertical velocity first (the vibrometer's component), half of them on each fold
(the region the model shows there), at most :data:`N_POINTS` of them, a few pixels apart.  Per pixel two panels: lateral (model y) and vertical (model z)
velocity, mm/s, over the window's frame times (ms).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: pixels plotted at most
N_POINTS = 4
#: smallest distance between two plotted pixels, px
MIN_SEPARATION_PX = 4.0


def point_series(baseline, disps: list[np.ndarray], pixels: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Measured and simulated velocity (mm/s) at ``pixels`` (flat indices) over the window's frames.

    disps : displacement histories (F + 1, N, 3) of the models, mm.
    Returns measured (F, P, 3) and one (F, P, 3) per model, NaN where the raster does not compare a pixel.
    """
    p = baseline.problem
    n_f, n_p = p.n_frames, len(pixels)
    meas = np.full((n_f, n_p, 3), np.nan)
    sims = [np.full((n_f, n_p, 3), np.nan) for _ in disps]
    for f, fr in enumerate(baseline.frames):
        pos = {int(q): i for i, q in enumerate(fr.pix_both)}
        for j, q in enumerate(pixels):
            i = pos.get(int(q))
            if i is None:
                continue
            meas[f, j] = fr.v_both[i]
            row = fr.m_both[i]
            for s, u in zip(sims, disps):
                s[f, j] = row @ p.frame_velocity(u, f)
    return meas, sims


def choose_pixels(baseline, n: int = N_POINTS) -> np.ndarray:
    """(<= n,) flat pixel indices (module docstring)."""
    p = baseline.problem
    n_pix = int(np.prod(p.camera.shape))
    count = np.zeros(n_pix)
    vz2 = np.zeros(n_pix)
    for fr in baseline.frames:
        count[fr.pix_both] += 1
        vz2[fr.pix_both] += fr.v_both[:, 2] ** 2
    if not count.any():
        return np.zeros(0, int)
    from vfcli.diagnose.regions import N_REGIONS
    from vfcli.diagnose.residual import pixel_regions

    fold = pixel_regions(baseline).ravel() // (N_REGIONS // 2)            # -1 // 9 = -1: no fold
    cand = np.flatnonzero(count >= 0.9 * count.max())
    order = cand[np.argsort(-vz2[cand])]
    w = p.camera.shape[1]
    out: list[int] = []
    for k in (0, 1):                                                      # half of the pixels on each fold
        mine: list[int] = []
        for q in order[fold[order] == k]:
            if all(np.hypot(q // w - o // w, q % w - o % w) >= MIN_SEPARATION_PX for o in mine):
                mine.append(int(q))
            if len(mine) == n // 2:
                break
        out += mine
    return np.asarray(out, int)


def velocity_at_points(baseline, baseline_disp: np.ndarray, extended_disp: np.ndarray, path: str | Path,
                       title: str, extended_label: str = "extended") -> np.ndarray:
    """Write the plot (module docstring) to ``path`` (PNG); returns the pixels plotted (flat indices)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pixels = choose_pixels(baseline)
    meas, (base, ext) = point_series(baseline, [baseline_disp, extended_disp], pixels)
    t_ms = 1e3 * np.asarray(baseline.problem.meas.times, float)
    w = baseline.problem.camera.shape[1]
    rows = max(len(pixels), 1)
    fig, axes = plt.subplots(rows, 2, figsize=(11, 2.4 * rows + 0.8), dpi=100, squeeze=False)
    for j, q in enumerate(pixels):
        for k, (c, name) in enumerate(((1, "lateral (y)"), (2, "vertical (z)"))):
            ax = axes[j, k]
            ax.plot(t_ms, meas[:, j, c], "k.", ms=4, label="measured")
            ax.plot(t_ms, base[:, j, c], "-", color="tab:blue", label="baseline")
            ax.plot(t_ms, ext[:, j, c], "-", color="tab:red", label=extended_label)
            ax.set_title(f"pixel (row {q // w}, col {q % w}): {name}", fontsize=9)
            ax.set_ylabel("mm/s")
            if j == rows - 1:
                ax.set_xlabel("time (ms)")
    if len(pixels):
        axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return pixels
