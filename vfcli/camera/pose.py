"""The pose of the fold model in the image, from the glottal gap seen over the recording.

The camera's scale (px/mm) comes from a calibration target, but its in-plane rotation and
the position of the model origin are usually unknown. The glottal midline (model y = 0) is
the line the gap opens along, and the glottis opens symmetrically about mid-length
(model x = L/2, the folds are clamped at both ends), so both follow from the gap masks.
"""
from __future__ import annotations

import numpy as np

from vfcli.errors import InputDataError


def estimate_pose(gap_counts: np.ndarray, px_per_mm: float, length_mm: float) -> tuple[float, tuple[float, float]]:
    """(rotation_deg, offset_px) of the model frame in the image (see docs/conventions.md).

    Parameters
    ----------
    gap_counts : (H, W) number of frames in which each pixel is gap (rows lateral, columns
        longitudinal): the sum of the gap masks, accumulated by the caller frame by frame.
    px_per_mm : image scale.
    length_mm : anterior-posterior length L of the folds.

    Returns
    -------
    rotation_deg, (offset_col_px, offset_row_px): ``[col, row] = s R(rot) [x, y] + offset``.
    """
    counts = np.asarray(gap_counts, float)
    count = counts.sum(axis=0)  # gap pixels per column over the recording
    cols = np.flatnonzero(count > 0)
    if cols.size < 3:
        raise InputDataError("the glottal gap never opens in the selected frames: cannot locate the folds; "
                             "set camera.rotation_deg and camera.offset_px in the config")
    rows = np.arange(counts.shape[0], dtype=float)
    mean_row = (counts * rows[:, None]).sum(axis=0)[cols] / count[cols]
    slope, intercept = np.polyfit(cols.astype(float), mean_row, 1, w=np.sqrt(count[cols]))
    rot = np.arctan(slope)
    weights = count[cols]
    c_mid = float(np.sum(cols * weights) / np.sum(weights))  # where x = L/2
    o_col = c_mid - px_per_mm * (length_mm / 2) * np.cos(rot)
    o_row = intercept + slope * c_mid - px_per_mm * (length_mm / 2) * np.sin(rot)
    return float(np.degrees(rot)), (float(o_col), float(o_row))


def camera_to_model(vectors: np.ndarray, rotation_deg: float) -> np.ndarray:
    """Rotate image-aligned (u, v) components (..., 2) into the model's (x, y) axes."""
    r = np.radians(rotation_deg)
    c, s = np.cos(r), np.sin(r)
    v = np.asarray(vectors)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], axis=-1)
