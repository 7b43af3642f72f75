"""Aerodynamic loads of the phantom: subglottal pressure and a Bernoulli intraglottal profile.

The folds are loaded by pressure acting normal to the surface, alike on both folds:

- the subglottal pressure ``p_s(t)`` on the inferior surface (entrance arc and inferior slope);
- an intraglottal pressure on the medial surface, from quasi-steady Bernoulli flow through
  the glottal channel of each coronal slice x: with the channel width ``a(x, z)`` (the
  distance between the two medial surfaces at height z), the flow separates at the
  narrowest section ``a_min`` and

  ``p(x, z) = p_s (1 - (a_min / a(x, z))^2)`` upstream of it, ``0`` downstream;

  where the slice is closed (``a <= 0`` somewhere), ``p = p_s`` below the closure, 0 above.
  A convergent channel is thus pushed open, a divergent one is not: the load depends on the
  glottal shape, which is what gives the motion its opening-closing asymmetry.
- no load on the superior surface.

The medial pressure is represented by bilinear "hat" patterns on a (n_x, n_z) grid over the
medial surface, so the structural response to any pressure is a combination of a few
precomputed responses. The glottal width at the grid nodes is a linear function of the
vertex displacements (:func:`width_operator`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay

AIR_DENSITY_KG_M3 = 1.2


@dataclass(frozen=True)
class MedialGrid:
    """Grid of hat-function nodes over the medial surface (one fold's profile frame).

    Attributes
    ----------
    x_mm : (n_x,) longitudinal node positions, mm (include both ends).
    z_mm : (n_z,) vertical node positions from the bottom (upstream) to the top, mm.
    """

    x_mm: np.ndarray
    z_mm: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.x_mm), len(self.z_mm)

    def points(self) -> np.ndarray:
        """(n_x * n_z, 2) (x, z) of the nodes, x-major."""
        xx, zz = np.meshgrid(self.x_mm, self.z_mm, indexing="ij")
        return np.column_stack([xx.ravel(), zz.ravel()])


def medial_grid(length_mm: float, z_bottom_mm: float, z_top_mm: float, n_x: int = 9, n_z: int = 6) -> MedialGrid:
    """A uniform hat grid over ``x in [0, L]``, ``z in [z_bottom, z_top]``."""
    return MedialGrid(np.linspace(0.0, length_mm, n_x), np.linspace(z_bottom_mm, z_top_mm, n_z))


def hat_weights(grid: MedialGrid, x_mm: np.ndarray, z_mm: np.ndarray) -> sp.csr_matrix:
    """Bilinear hat functions of ``grid`` evaluated at points: (n_points, n_x * n_z).

    Points outside the grid get the value of the nearest edge (clamped).
    """
    def axis(nodes: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = np.clip(v, nodes[0], nodes[-1])
        i = np.clip(np.searchsorted(nodes, v, side="right") - 1, 0, len(nodes) - 2)
        t = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
        return i, t

    ix, tx = axis(grid.x_mm, np.asarray(x_mm, float))
    iz, tz = axis(grid.z_mm, np.asarray(z_mm, float))
    n = len(ix)
    nz = grid.shape[1]
    rows = np.repeat(np.arange(n), 4)
    cols = np.stack([ix * nz + iz, ix * nz + iz + 1, (ix + 1) * nz + iz, (ix + 1) * nz + iz + 1], axis=1).ravel()
    vals = np.stack([(1 - tx) * (1 - tz), (1 - tx) * tz, tx * (1 - tz), tx * tz], axis=1).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, grid.shape[0] * grid.shape[1]))


def width_operator(nodes: np.ndarray, medial_nodes: np.ndarray, grid: MedialGrid) -> tuple[np.ndarray, sp.csr_matrix]:
    """Half-width of the glottal channel at the grid nodes as a linear map of displacements.

    Parameters
    ----------
    nodes : (N, 3) rest positions, mm.
    medial_nodes : indices of the right fold's (y > 0) medial-surface nodes.
    grid : the hat grid.

    Returns
    -------
    half_width0 : (n_x * n_z,) rest distance of the right medial surface from the midplane, mm.
    op : (n_x * n_z, N) csr: ``half_width = half_width0 + op @ u_y`` for vertex y-displacements.
    """
    pts = nodes[medial_nodes][:, [0, 2]]
    tri = Delaunay(pts)
    q = grid.points()
    simplex = tri.find_simplex(q)
    if np.any(simplex < 0):  # grid nodes on the boundary: nudge into the hull
        centre = pts.mean(axis=0)
        q = np.where((simplex < 0)[:, None], q + 1e-6 * (centre - q), q)
        simplex = tri.find_simplex(q)
    trans = tri.transform[simplex]
    b = np.einsum("ijk,ik->ij", trans[:, :2], q - trans[:, 2])
    bary = np.column_stack([b, 1 - b.sum(axis=1)])
    verts = medial_nodes[tri.simplices[simplex]]
    rows = np.repeat(np.arange(len(q)), 3)
    op = sp.csr_matrix((bary.ravel(), (rows, verts.ravel())), shape=(len(q), len(nodes)))
    half_width0 = op @ nodes[:, 1]
    return half_width0, op


def bernoulli_profile(width_mm: np.ndarray) -> np.ndarray:
    """Intraglottal pressure as a fraction of the subglottal pressure.

    Parameters
    ----------
    width_mm : (..., n_x, n_z) channel width at the grid nodes, bottom (upstream) to top.

    Returns
    -------
    (..., n_x, n_z) pressure / p_s in [0, 1].
    """
    a = np.asarray(width_mm, float)
    n_z = a.shape[-1]
    z_idx = np.arange(n_z)
    closed = a <= 0.0
    any_closed = closed.any(axis=-1, keepdims=True)
    first_closed = np.where(any_closed, np.argmax(closed, axis=-1)[..., None], n_z)
    closed_profile = (z_idx < first_closed).astype(float)
    i_min = np.argmin(a, axis=-1)[..., None]
    a_min = np.take_along_axis(a, i_min, axis=-1)
    safe = np.where(a > 0, a, np.inf)
    open_profile = np.where(z_idx <= i_min, 1.0 - (np.maximum(a_min, 0) / safe) ** 2, 0.0)
    return np.where(any_closed, closed_profile, np.clip(open_profile, 0.0, 1.0))
