"""Accuracy figures of a reconstruction against known truth (numpy in, numbers out).

Used by the tests and benchmarks that score vfcli on phantoms; nothing here reads files.
"""
from __future__ import annotations

import numpy as np


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks (pooled over all their elements)."""
    union = np.logical_or(mask, truth).sum()
    return float(np.logical_and(mask, truth).sum() / union) if union else 1.0


def rms(x: np.ndarray) -> float:
    """Root mean square of the finite entries."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def end_point_error(flow: np.ndarray, truth: np.ndarray, where: np.ndarray) -> tuple[float, float]:
    """(mean, 95th percentile) of |flow - truth| over ``where``; flow, truth (..., 2)."""
    err = np.linalg.norm(flow - truth, axis=-1)[where]
    err = err[np.isfinite(err)]
    return float(err.mean()), float(np.percentile(err, 95))


def relative_rms_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS(estimate - truth) / RMS(truth) over entries finite in both."""
    ok = np.isfinite(estimate) & np.isfinite(truth)
    return rms((estimate - truth)[ok]) / rms(truth[ok])
