"""Where on the folds: regions of the superior surface and the names of the residual's parts.

A region is one fold (left: fold 0, y < 0; right: fold 1) times a band across the fold
(medial edge / middle / lateral: thirds of the surface map's v, 1 at the medial split,
0 at the lateral wall) times a band along it (anterior / middle / posterior: thirds of
u = x / L).  The gap's silhouette lies on the medial edge by definition, so its regions are
fold x length band.  Components are the model axes: x longitudinal (anterior to
posterior), y lateral, z vertical.
"""
from __future__ import annotations

import numpy as np

FOLD_NAMES = ("left fold", "right fold")
DEPTH_NAMES = ("medial edge", "middle", "lateral part")
LENGTH_NAMES = ("anterior third", "middle third", "posterior third")
COMPONENT_NAMES = ("longitudinal", "lateral", "vertical")
GAP_COMPONENT_NAMES = ("medial edge position",)
N_REGIONS = len(FOLD_NAMES) * len(DEPTH_NAMES) * len(LENGTH_NAMES)
N_GAP_REGIONS = len(FOLD_NAMES) * len(LENGTH_NAMES)


def region_names() -> tuple[str, ...]:
    """(18,) names of the motion regions, index ``fold * 9 + depth * 3 + length``."""
    return tuple(f"{f}, {d}, {length}" for f in FOLD_NAMES for d in DEPTH_NAMES for length in LENGTH_NAMES)


def gap_region_names() -> tuple[str, ...]:
    """(6,) names of the gap regions, index ``fold * 3 + length``."""
    return tuple(f"{f}, medial edge, {length}" for f in FOLD_NAMES for length in LENGTH_NAMES)


def thirds(x: np.ndarray) -> np.ndarray:
    """0, 1, 2 for x in [0, 1/3), [1/3, 2/3), [2/3, 1] (clipped); -1 where x is NaN."""
    x = np.asarray(x, dtype=float)
    out = np.clip(np.floor(np.nan_to_num(x, nan=0.0) * 3), 0, 2).astype(int)
    out[~np.isfinite(x)] = -1
    return out


def vertex_regions(uv: np.ndarray, vertex_fold: np.ndarray) -> np.ndarray:
    """(N,) motion region of each vertex, -1 off the parameterised surface.

    uv : (N, 2) surface map (u along, v across; NaN off the free surface).  vertex_fold : (N,) 0 or 1.
    """
    uv = np.asarray(uv, dtype=float)
    length = thirds(uv[:, 0])
    depth = 2 - thirds(uv[:, 1])            # v = 1 at the medial edge
    out = np.asarray(vertex_fold, int) * 9 + depth * 3 + length
    out[(length < 0) | ~np.isfinite(uv[:, 1])] = -1
    return out


def vertex_fold(n_vertices: int, tets: np.ndarray, tet_fold: np.ndarray) -> np.ndarray:
    """(N,) fold of each vertex (from its tetrahedra)."""
    out = np.zeros(n_vertices, int)
    out[np.unique(np.asarray(tets)[np.asarray(tet_fold) == 1])] = 1
    return out
