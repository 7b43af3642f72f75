"""The paper's figures and the voice lab's everyday ones, as PNG and SVG (matplotlib, Agg).

Every function takes numpy arrays (units in the parameter docs), writes ``<base>.<format>`` for each of
``formats`` (default :data:`FORMATS`, PNG and SVG; the HTML report asks for the PNG alone, which it embeds) and
returns the paths written.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from vfcli.export.sampling import FOLD_NAMES  # 0 left, 1 right (/mesh tet_fold)
from vfcli.model.mesh import SIDE_INFERIOR, SIDE_SUPERIOR, FoldMesh


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: What a figure function writes unless told otherwise: a PNG to look at and an SVG to edit or print.
FORMATS = ("png", "svg")


def _save(fig, base: str | Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """``<base>.<format>`` for each of ``formats`` ("png" at 110 dpi, "svg"), in that order; the figure closed."""
    plt = _pyplot()
    try:
        unknown = [f for f in formats if f not in FORMATS]
        if unknown:
            raise ValueError(f"figure format {unknown[0]!r}: choose from {', '.join(FORMATS)}")
        out = [Path(base).with_suffix(f".{fmt}") for fmt in formats]
        for path, fmt in zip(out, formats):
            fig.savefig(path, **({"dpi": 110} if fmt == "png" else {}))
    finally:
        plt.close(fig)
    return out


def convergence(histories: dict[str, dict[str, np.ndarray]], base: str | Path,
                formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Figure 7: the error E against the iteration, one line per run.

    histories : run -> {"iteration": (I,), "total": (I,) E, optional "wall_time": (I,) s}.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4), dpi=110)
    for run, h in histories.items():
        it, e = np.asarray(h["iteration"]), np.asarray(h["total"])
        label = run + (f" ({float(h['wall_time'][-1]):.0f} s)" if "wall_time" in h and len(h["wall_time"]) else "")
        ax.semilogy(it, np.maximum(e, 1e-12), "o-", ms=3, label=label)
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))   # iterations are whole: no 0.25 ticks on a short run
    ax.set_xlabel("iteration")
    ax.set_ylabel("error E (dimensionless)")
    ax.set_title("Convergence of each optimisation run (paper, fig. 7)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(title="run (wall time)")
    fig.tight_layout()
    return _save(fig, base, formats)


def velocities(t_meas: np.ndarray, measured: np.ndarray, simulated: dict[str, tuple[np.ndarray, np.ndarray]],
               point_labels: list[str], base: str | Path,
               formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Figure 8: vertical, longitudinal and lateral surface velocity at screen points, measurement against each run.

    t_meas : (F,) s.  measured : (F, P, 3) mm/s, model frame (x longitudinal, y lateral, z vertical),
    NaN where the surface is not seen.  simulated : run -> ((T,) s, (T, P, 3) mm/s).
    """
    plt = _pyplot()
    n_p = measured.shape[1]
    comps = [(2, "vertical  v_z"), (0, "longitudinal  v_x"), (1, "lateral  v_y")]
    fig, axes = plt.subplots(3, n_p, figsize=(4.2 * n_p, 7.2), dpi=110, sharex=True, squeeze=False)
    for j in range(n_p):
        for i, (c, name) in enumerate(comps):
            ax = axes[i, j]
            ax.plot(1e3 * t_meas, measured[:, j, c], "k.-", lw=1, ms=3, label="measured")
            for run, (t, v) in simulated.items():
                ax.plot(1e3 * t, v[:, j, c], "-", lw=1.5, label=f"run {run}")
            ax.axhline(0, color="0.7", lw=0.5)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(f"{name} (mm/s)")
            if i == 0:
                ax.set_title(point_labels[j], fontsize=10)
            if i == 2:
                ax.set_xlabel("time (ms)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Surface velocity at screen points: measurement and reconstruction (paper, fig. 8)")
    fig.tight_layout()
    return _save(fig, base, formats)


def glottal_area(t: np.ndarray, area: np.ndarray, windows: dict[str, tuple[float, float]], base: str | Path,
                 formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Glottal area waveform. t : (F,) s; area : (F,) mm^2; windows : run -> (t0, t1) s of its fit."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.2), dpi=110)
    ax.plot(1e3 * t, area, "k-", lw=1)
    for k, (run, (t0, t1)) in enumerate(windows.items()):
        ax.axvspan(1e3 * t0, 1e3 * t1, color=f"C{k}", alpha=0.2, label=f"run {run} window")
    ax.set_xlabel("time (ms)")
    ax.set_ylabel("glottal area (mm²)")
    ax.set_title("Glottal area waveform")
    ax.grid(alpha=0.3)
    if windows:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, base, formats)


def kymogram(t: np.ndarray, lines: np.ndarray, positions: list[str], extent_mm: float, base: str | Path,
             formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Kymogram: the image along lines across the glottis, over time.

    t : (F,) s.  lines : (L, F, S) grey values along L lines of S samples spanning ``extent_mm`` (mm),
    from the left fold (top) to the right fold (bottom).
    """
    plt = _pyplot()
    n = len(lines)
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.9 * n + 0.6), dpi=110, sharex=True, squeeze=False)
    for k in range(n):
        ax = axes[k, 0]
        ax.imshow(lines[k].T, aspect="auto", cmap="gray", origin="upper",
                  extent=(1e3 * t[0], 1e3 * t[-1], extent_mm / 2, -extent_mm / 2))
        ax.set_ylabel("across (mm)")
        ax.set_title(positions[k], fontsize=9, loc="left")
        ax.text(1.005, 0.95, "left", transform=ax.transAxes, fontsize=8, va="top")
        ax.text(1.005, 0.05, "right", transform=ax.transAxes, fontsize=8, va="bottom")
    axes[-1, 0].set_xlabel("time (ms)")
    fig.suptitle("Kymogram across the glottis", fontsize=10)
    fig.tight_layout()
    return _save(fig, base, formats)


def sync_quality_map(grid_index: np.ndarray, quality: np.ndarray, ok: np.ndarray, dropout: np.ndarray,
                     base: str | Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Sync quality of every vibrometer point on its scan grid (rows x cols, e.g. 17 x 22).

    grid_index : (P, 2) (row, col); quality : (P,) in [0, 1]; ok, dropout : (P,) bool.
    """
    plt = _pyplot()
    gi = np.asarray(grid_index, dtype=int)
    shape = (int(gi[:, 0].max()) + 1, int(gi[:, 1].max()) + 1)
    img = np.full(shape, np.nan)
    img[gi[:, 0], gi[:, 1]] = quality
    fig, ax = plt.subplots(figsize=(6.4, 5), dpi=110)
    q = np.asarray(quality, float)
    lo = float(np.floor(10 * np.nanmin(q)) / 10) if np.isfinite(q).any() else 0.0  # spread the colours over the data
    im = ax.imshow(img, cmap="viridis", vmin=min(max(lo, 0.0), 0.9), vmax=1, origin="upper")
    bad = ~np.asarray(ok, bool)
    drop = np.asarray(dropout, bool)
    ax.plot(gi[bad, 1], gi[bad, 0], "rx", ms=6, label="not aligned")
    ax.plot(gi[drop, 1], gi[drop, 0], "o", color="m", ms=6, mfc="none", mew=1.5, label="signal dropout")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("scan column")
    ax.set_ylabel("scan row")
    ax.set_title(f"Sync quality of the {len(quality)} vibrometer points ({shape[0]} x {shape[1]} grid)")
    fig.colorbar(im, ax=ax, label="alignment quality (0..1)")
    if bad.any() or drop.any():
        ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return _save(fig, base, formats)


def uncertainty_on_folds(mesh: FoldMesh, std: np.ndarray, run: str, base: str | Path,
                         formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """The stated uncertainty drawn on the fold geometry: superior view and inferior view (from below).

    std : (T, N, 3) mm; each node shows the RMS over time of |std| (mm). Axes in mm, folds named.
    """
    plt = _pyplot()
    from matplotlib.tri import Triangulation

    sd = np.sqrt(np.mean(np.sum(np.asarray(std, float) ** 2, axis=2), axis=0))
    side = mesh.face_side
    vmax = float(np.nanmax(sd[mesh.node_side > 0])) if np.any(mesh.node_side > 0) else float(np.nanmax(sd))
    # the panels are drawn to scale (equal axes): the figure is as tall as they are, plus titles and labels (at a
    # fixed 4.6 in the folds, 17 x 12 mm, left a band of white above and below them)
    span = np.ptp(mesh.nodes[:, :2], axis=0)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6 * float(span[1] / max(span[0], 1e-9)) + 1.4), dpi=110,
                             sharey=True, layout="constrained")
    node_fold = np.zeros(mesh.n_nodes, int)
    node_fold[mesh.fold_nodes(1)] = 1
    tpc = None
    for ax, s, name in ((axes[0], SIDE_SUPERIOR, "superior surface (seen from above)"),
                        (axes[1], SIDE_INFERIOR, "inferior surface (seen from below)")):
        faces = mesh.faces[side == s]
        tri = Triangulation(mesh.nodes[:, 0], mesh.nodes[:, 1], faces)
        tpc = ax.tripcolor(tri, sd, shading="gouraud", cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x, along the fold (mm)")
        ax.set_aspect("equal")
        if s == SIDE_INFERIOR:
            ax.invert_xaxis()  # seen from below: mirror so the folds keep their sides on the page
        for k, fname in enumerate(FOLD_NAMES):
            nodes = np.unique(faces[np.isin(faces, mesh.fold_nodes(k)).all(axis=1)])
            if nodes.size:
                c = mesh.nodes[nodes, :2].mean(axis=0)
                ax.text(c[0], c[1], f"{fname} fold", ha="center", va="center", fontsize=9, color="w",
                        bbox=dict(facecolor="0.2", alpha=0.6, lw=0))
    axes[0].set_ylabel("y, lateral (mm)")
    fig.colorbar(tpc, ax=axes, shrink=0.85, label="RMS standard deviation over time (mm)")
    fig.suptitle(f"Stated uncertainty of run {run} on the fold geometry", fontsize=10)
    return _save(fig, base, formats)


def residual_rms(rms: np.ndarray, run: str, base: str | Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Where a fitted run and the recording disagree: the RMS residual over the window as the camera sees the folds.

    rms : (H, W, 3) RMS over the window of the measured minus simulated velocity per component, mm/s (NaN where the
        model shows no surface); the picture is the RMS over the three components, ``sqrt(mean_c rms_c^2)``, the
        residual map's first panel (:func:`vfcli.diagnose.maps.residual_map`).
    """
    plt = _pyplot()
    r = np.asarray(rms, float)
    with warnings.catch_warnings():   # a pixel the model never shows is NaN in every component: NaN here too
        warnings.simplefilter("ignore", RuntimeWarning)
        both = np.sqrt(np.nanmean(r**2, axis=2)) if r.ndim == 3 and np.isfinite(r).any() else np.full(r.shape[:2], np.nan)
    fig, ax = plt.subplots(figsize=(5.6, 4.6), dpi=110, layout="constrained")
    im = ax.imshow(both, cmap="magma")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.set_title(f"RMS residual of run {run} over its window", fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.85, label="measured minus simulated velocity, RMS (mm/s)")
    return _save(fig, base, formats)
