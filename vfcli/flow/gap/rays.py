"""Rays across the glottis and the outermost gap silhouette on each: the one implementation.

A ray is a lateral image line: ``lateral_axis=0`` means rows are lateral, so each column
is one ray; ``lateral_axis=1`` means each row is one ray. Pixel centres lie at integer
lateral positions, so the boundary between pixels ``r`` and ``r + 1`` is at ``r + 0.5``.

The silhouette of a gap mask on a ray is the set of boundaries between a gap and a
non-gap pixel; its outermost points (:func:`outermost_silhouette`) serve

* the measured silhouettes of the objective's gap term
  (:func:`vfcli.flow.gap.opening.measured_silhouettes`),
* the opening location of the opening function o(y, t)
  (:func:`vfcli.flow.gap.opening.gap_centers`),
* the starting edges of the sub-pixel edge fit (``border_is_edge=True``: a gap that
  touches the image border ends there; :mod:`vfcli.flow.gap.subpixel`).
"""
from __future__ import annotations

import numpy as np


def as_rays(image: np.ndarray, lateral_axis: int) -> np.ndarray:
    """(n_lateral, n_rays) view of an (H, W) image: one column per ray.

    Parameters
    ----------
    image : (H, W) array
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows, one ray per column).

    Returns
    -------
    (n_lateral, n_rays) array, a view (transposed when ``lateral_axis == 1``).
    """
    if lateral_axis not in (0, 1):
        raise ValueError(f"rays: lateral_axis must be 0 (rows) or 1 (columns), got {lateral_axis}")
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"rays: expected an (H, W) image, got shape {a.shape}")
    return a if lateral_axis == 0 else a.T


def silhouette_points(rays_mask: np.ndarray, border_is_edge: bool = False) -> tuple[np.ndarray, float]:
    """Where the gap starts or ends along each ray.

    Parameters
    ----------
    rays_mask : (n, n_rays) bool
        Gap mask as rays (:func:`as_rays`).
    border_is_edge : bool
        False: the image border is not a silhouette (the opening function's definition).
        True: a gap that touches the border ends at the border pixel's outer boundary.

    Returns
    -------
    crossing : (n - 1, n_rays) bool, or (n + 1, n_rays) with ``border_is_edge``
        True where the gap state changes between two consecutive positions.
    first_px : float
        Lateral position of ``crossing[0]``, px (row ``i`` is at ``i + first_px``):
        0.5, or -0.5 with ``border_is_edge``.
    """
    m = np.asarray(rays_mask, dtype=bool)
    if border_is_edge:
        m = np.pad(m, ((1, 1), (0, 0)))
    return m[1:] != m[:-1], (-0.5 if border_is_edge else 0.5)


def outermost_silhouette(mask: np.ndarray, lateral_axis: int = 0,
                         border_is_edge: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Outermost silhouette points of a gap mask on every ray, lateral px.

    Parameters
    ----------
    mask : (H, W) bool
        Gap mask.
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows, one ray per column).
    border_is_edge : bool
        See :func:`silhouette_points`. With True, ``lo`` and ``hi`` are ``first gap pixel
        - 0.5`` and ``last gap pixel + 0.5``.

    Returns
    -------
    lo, hi : (n_rays,) float64
        First and last silhouette point of each ray (half-integers), px; NaN on rays that
        have none (closed, or all gap without ``border_is_edge``).
    """
    crossing, first_px = silhouette_points(as_rays(mask, lateral_axis), border_is_edge)
    has = crossing.any(axis=0)
    first = np.argmax(crossing, axis=0)
    last = crossing.shape[0] - 1 - np.argmax(crossing[::-1], axis=0)
    return np.where(has, first + first_px, np.nan), np.where(has, last + first_px, np.nan)
