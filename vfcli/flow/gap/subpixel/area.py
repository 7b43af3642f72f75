"""The gap mask and glottal area from sub-pixel edges, and one frame's segmentation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def mask_from_edges(e0: np.ndarray, e1: np.ndarray, shape: tuple[int, int], lateral_axis: int = 0) -> np.ndarray:
    """Gap mask of the pixels whose centres lie strictly between the edges of their ray.

    Parameters
    ----------
    e0, e1 : (n_rays,) float
        Edges per ray, lateral px (pixel centres at integers); NaN on closed rays.
    shape : (H, W)
    lateral_axis : {0, 1}

    Returns
    -------
    (H, W) bool
    """
    n_lat = shape[lateral_axis]
    pos = np.arange(n_lat, dtype=float)[:, None]
    ok = (np.isfinite(e0) & np.isfinite(e1))[None, :]
    m = ok & (pos > np.nan_to_num(e0, nan=np.inf)[None, :]) & (pos < np.nan_to_num(e1, nan=-np.inf)[None, :])
    return m if lateral_axis == 0 else np.ascontiguousarray(m.T)


def area_from_edges(e0: np.ndarray, e1: np.ndarray, px_per_mm: float) -> float:
    """Glottal area from sub-pixel edges, mm^2: sum over rays of the gap's width (1 px per ray).

    Parameters
    ----------
    e0, e1 : (n_rays,) float
        Edges per ray, lateral px; NaN on closed rays.
    px_per_mm : float
        Image scale, px/mm.

    Returns
    -------
    float
    """
    if px_per_mm <= 0:
        raise ValueError(f"glottal area: px_per_mm must be positive, got {px_per_mm}")
    width = np.nan_to_num(np.asarray(e1, float) - np.asarray(e0, float), nan=0.0)
    return float(np.maximum(width, 0.0).sum() / float(px_per_mm) ** 2)


@dataclass(frozen=True)
class GapSegmentation:
    """The gap of one frame (:func:`segment_gap`, :func:`segment_stream`).

    Attributes
    ----------
    mask : (H, W) bool
        Pixels whose centres lie strictly between the sub-pixel edges of their ray.
    e0, e1 : (n_rays,) float
        Sub-pixel edges per ray, lateral px (pixel centres at integers); NaN on closed rays.
    """

    mask: np.ndarray
    e0: np.ndarray
    e1: np.ndarray

    def area_mm2(self, px_per_mm: float) -> float:
        """Glottal area from the sub-pixel edges, mm^2 (:func:`area_from_edges`)."""
        return area_from_edges(self.e0, self.e1, px_per_mm)
