"""Figures of an optimisation run (PNG, matplotlib with the Agg backend)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vfcli.model.mesh import FoldMesh


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def convergence_plot(history: dict[str, Any], path: str | Path, title: str) -> None:
    """E and its terms against the iteration (PNG)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    it = np.asarray(history["iteration"])
    for key, style in (("total", "-"), ("motion", "--"), ("gap", ":"), ("ridge", "-.")):
        if key in history and np.any(np.asarray(history[key]) > 0):
            ax.semilogy(it, np.maximum(np.asarray(history[key]), 1e-12), style, label=key)
    ax.set_xlabel("iteration")
    ax.set_ylabel("error E")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def uncertainty_map(mesh: FoldMesh, std: np.ndarray, displacements: np.ndarray, path: str | Path, title: str,
                    side: int = 1) -> None:
    """Map of the stated uncertainty on one side of both folds (default the inferior side), in (u, v).

    Parameters
    ----------
    mesh : the reconstruction mesh (``uv``, ``node_side``; fold 0 is the first half of the nodes' folds).
    std : (T, N, 3) standard deviation of every displacement component, mm.
    displacements : (T, N, 3) reconstructed displacements, mm (for the colour scale's reference).
    path : PNG to write.
    side : 1 inferior, 2 superior.

    Each node is coloured by the RMS over time of |std| (mm); the title gives the RMS
    displacement of the same nodes for comparison.
    """
    plt = _pyplot()
    sel = mesh.node_side == side
    node_fold = np.zeros(mesh.n_nodes, int)
    node_fold[mesh.fold_nodes(1)] = 1
    sd = np.sqrt(np.mean(np.sum(std ** 2, axis=2), axis=0))            # (N,) mm
    rms_disp = float(np.sqrt(np.mean(np.sum(displacements[:, sel] ** 2, axis=2))))
    vmax = float(np.nanmax(sd[sel])) if sel.any() else 1.0
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), dpi=110, sharey=True)
    for k, ax in enumerate(axes):
        m = sel & (node_fold == k)
        sc = ax.scatter(mesh.uv[m, 0], mesh.uv[m, 1], c=sd[m], s=14, cmap="magma", vmin=0.0, vmax=vmax)
        ax.set_title(f"fold {k}")
        ax.set_xlabel("u (along the fold)")
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
    axes[0].set_ylabel("v (lateral wall 0 -> medial 1)")
    cb = fig.colorbar(sc, ax=axes, shrink=0.9)
    cb.set_label("RMS standard deviation over time, mm")
    name = {1: "inferior", 2: "superior"}.get(side, str(side))
    fig.suptitle(f"{title}: {name} surface, RMS displacement {rms_disp:.3f} mm, "
                 f"RMS uncertainty {float(np.sqrt(np.mean(sd[sel] ** 2))):.3f} mm", fontsize=9)
    fig.savefig(path)
    plt.close(fig)
