"""Simulated gap silhouettes, from mesh edges (the measured ones, from gap masks, are
:func:`vfcli.flow.gap.opening.measured_silhouettes`).

Rays are the lateral image lines (``lateral_axis == 0``: rows are lateral, one ray
per column, as in :mod:`vfcli.flow.gap.rays`).  A fold's simulated silhouette on a ray
is the lateral screen position of its medial-most point, the extreme over the
crossings of its surface edges with the ray (:func:`edge_crossings`,
:func:`extreme_per_ray`); for a fixed choice of edge it is a smooth function of
the two end vertices, which is what :mod:`vfcli.inverse.problem` differentiates.
"""
from __future__ import annotations

import numpy as np


def surface_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) sorted unique edges of triangles (K, 3)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def edge_crossings(screen: np.ndarray, edges: np.ndarray, ray_comp: int,
                   limits: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of screen-space edges with the integer rays ``screen[:, ray_comp] = c``.

    Parameters
    ----------
    screen : (N, 2) vertex screen positions (col, row), px.
    edges : (E, 2) vertex indices.
    ray_comp : screen component that is constant along a ray (0: columns are rays).
    limits : only the rays ``lo <= c < hi`` (keeps the work bounded when a wildly
        deformed trial mesh stretches edges across thousands of rays).

    Returns
    -------
    edge : (n,) edge index, ray : (n,) int ray coordinate c, lateral : (n,) px
    (half-open: an edge covers the rays c with min <= c < max of its ends).
    """
    lat_comp = 1 - ray_comp
    a, b = screen[edges[:, 0], ray_comp], screen[edges[:, 1], ray_comp]
    c0, c1 = np.ceil(np.minimum(a, b)), np.ceil(np.maximum(a, b))
    if limits is not None:
        c0, c1 = np.maximum(c0, limits[0]), np.minimum(c1, limits[1])
    counts = np.maximum(c1 - c0, 0).astype(np.int64)
    # per-edge values repeated per crossing (the same operands as computing them per crossing)
    la = screen[edges[:, 0], lat_comp]
    dl, dr = screen[edges[:, 1], lat_comp] - la, b - a
    e = np.repeat(np.arange(len(edges)), counts)
    first = np.cumsum(counts) - counts                  # first crossing of each edge
    c = np.repeat(c0 - first, counts) + np.arange(e.size)   # exact integers: c0 + 0, 1, ...
    lam = (c - np.repeat(a, counts)) / np.repeat(dr, counts)
    lam *= np.repeat(dl, counts)
    return e, c.astype(np.int64), np.repeat(la, counts) + lam


def extreme_per_ray(e: np.ndarray, c: np.ndarray, s: np.ndarray, take_max: bool) -> tuple[np.ndarray, np.ndarray]:
    """(rays, edge) with the max (or min) lateral crossing on each ray present.

    e, c, s : (n,) edge index, int ray coordinate and lateral px of crossings (:func:`edge_crossings`).
    Returns the increasing rays present in ``c`` and, per ray, the edge of its extreme crossing;
    among equal extremes the crossing that comes last in the input wins.
    """
    if e.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    c_lo = c.min()
    span = int(c.max() - c_lo) + 1
    if span > 4 * c.size + 1024 or np.isnan(s).any():
        # sparse ray coordinates (or NaN positions, which the sort puts last): sort
        order = np.lexsort((s if take_max else -s, c))
        cs = c[order]
        last = np.flatnonzero(np.r_[cs[1:] != cs[:-1], True])
        return cs[last], e[order[last]]
    # dense ray coordinates: per-ray extreme, then the last crossing attaining it
    k = c - c_lo
    best = np.full(span, -np.inf if take_max else np.inf)
    (np.maximum if take_max else np.minimum).at(best, k, s)
    hit = np.flatnonzero(s == best[k])
    last = np.full(span, -1, np.int64)
    np.maximum.at(last, k[hit], hit)
    rays = np.flatnonzero(last >= 0)
    return (rays + c_lo).astype(c.dtype, copy=False), e[last[rays]]


def crossing_with_gradient(screen: np.ndarray, ends: np.ndarray, rays: np.ndarray,
                           ray_comp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lateral positions where chosen edges cross their rays, and their screen-space derivatives.

    Parameters
    ----------
    screen : (N, 2) vertex screen positions, px.
    ends : (n, 2) the two end vertices of each chosen edge.
    rays : (n,) ray coordinate of each crossing.
    ray_comp : screen component constant along a ray.

    Returns
    -------
    s : (n,) lateral px of the crossings.
    d0, d1 : (n, 2) ds / d(screen position) of the first and second end vertex (px per px).
    """
    lc = 1 - ray_comp
    a, b = screen[ends[:, 0], ray_comp], screen[ends[:, 1], ray_comp]
    la, lb = screen[ends[:, 0], lc], screen[ends[:, 1], lc]
    lam = (rays - a) / (b - a)
    d0 = np.zeros((len(rays), 2))
    d1 = np.zeros((len(rays), 2))
    d0[:, ray_comp], d0[:, lc] = (lb - la) * (lam - 1.0) / (b - a), 1.0 - lam
    d1[:, ray_comp], d1[:, lc] = -(lb - la) * lam / (b - a), lam
    return la + lam * (lb - la), d0, d1
