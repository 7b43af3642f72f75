"""The residual map image (PNG): where on the superior surface, and phase of the cycle x region.

Top row: the RMS residual over the window per pixel (mm/s, the three components together) as
the camera sees the folds, and, per fold, the largest size in units of the noise floor
(sqrt F over components, phases and harmonics) on the 3 x 3 grid of bands across and along
the fold.  Bottom row, one panel per component: the phase-mean residual in units of the
noise floor, phase of the cycle x region, signed (measured above simulated is positive).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vfcli.diagnose.cycles import PHASE_NAMES
from vfcli.diagnose.locate import Located
from vfcli.diagnose.regions import DEPTH_NAMES, FOLD_NAMES, LENGTH_NAMES
from vfcli.diagnose.noise import _quiet
from vfcli.diagnose.residual import WindowResidual, grid_filled


def rms_map(residual: WindowResidual) -> np.ndarray:
    """(H, W) RMS over frames and components of the window's motion residual, mm/s; NaN never seen (compared on
    a coarser pixel grid: each grid pixel's value fills its block, :func:`grid_filled`)."""
    with _quiet():
        rms = np.sqrt(np.nanmean(np.asarray(residual.motion, float) ** 2, axis=(0, 3)))
    return grid_filled(rms, residual.pixel_stride)


def region_ratio(located: Located) -> np.ndarray:
    """(18,) largest ratio (sqrt F) of each motion region over components, phases and harmonics."""
    d = located.families["motion"]
    with _quiet():
        both = np.concatenate([d.bin_ratio.reshape(len(d.region_names), -1),
                               d.harm_ratio.reshape(len(d.region_names), -1)], axis=1)
        return np.nanmax(np.where(np.isfinite(both), both, -np.inf), axis=1)


def residual_map(located: Located, residual: WindowResidual, path: str | Path, title: str) -> None:
    """Write the residual map (module docstring) of Locate's ``located`` and the window's ``residual`` to ``path``
    (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = located.families["motion"]
    fig, axes = plt.subplots(2, 3, figsize=(14, 9), dpi=100, layout="constrained")   # titles clear of colour bars
    ax = axes[0, 0]
    im = ax.imshow(rms_map(residual), cmap="magma")
    ax.set_title("RMS residual over the window")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    fig.colorbar(im, ax=ax, shrink=0.8, label="mm/s")
    ratio = region_ratio(located).reshape(2, 3, 3)
    vmax = max(3.0, float(np.nanmax(np.where(np.isfinite(ratio), ratio, 0.0))))
    for fold in range(2):
        ax = axes[0, 1 + fold]
        im = ax.imshow(ratio[fold], cmap="viridis", vmin=0, vmax=vmax)
        ax.set_xticks(range(3), [n.split()[0] for n in LENGTH_NAMES])
        ax.set_yticks(range(3), [n.split()[0] for n in DEPTH_NAMES])
        ax.set_title(f"{FOLD_NAMES[fold]}: largest x noise floor")
        for (i, j), v in np.ndenumerate(ratio[fold]):
            if np.isfinite(v):
                ax.text(j, i, f"{v:.1f}", ha="center", va="center", color="w" if v < 0.6 * vmax else "k")
        fig.colorbar(im, ax=ax, shrink=0.8)
    with _quiet():
        signed = d.bin_mean / d.bin_sd                                          # (R, C, 4)
    lim = max(3.0, float(np.nanmax(np.abs(np.where(np.isfinite(signed), signed, 0.0)))))
    for c in range(3):
        ax = axes[1, c]
        im = ax.imshow(signed[:, c, :], cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
        ax.set_xticks(range(len(PHASE_NAMES)), PHASE_NAMES)
        ax.set_yticks(range(len(d.region_names)), [n.replace(" third", "").replace(" fold", "")
                                                   for n in d.region_names], fontsize=6)
        ax.set_title(f"{d.component_names[c]}: phase mean / noise floor")
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(title)
    fig.savefig(path)
    plt.close(fig)
