"""Accuracy figures of a reconstruction against known truth (numpy in, numbers out).

Used by the tests and benchmarks that score vfcli on phantoms; nothing here reads files.
"""
from __future__ import annotations

import numpy as np


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks (pooled over all their elements)."""
    union = np.logical_or(mask, truth).sum()
    return float(np.logical_and(mask, truth).sum() / union) if union else 1.0


def opening_width_px(gap: np.ndarray, axis: np.ndarray, n_pieces: int = 3, piece_px: float = 4.0) -> np.ndarray:
    """(F,) how wide each frame's gap opens, px: its area (pixel count) in each piece of ``piece_px`` px of the
    glottis' length (along ``axis``) over that length, the mean of the ``n_pieces`` widest pieces; 0 in a frame with
    no gap.  Pieces a few pixels long: one pixel long, an oblique glottis' pieces catch one or two lines of the pixel
    lattice in turn, and the widest read up to twice the width.

    gap : (F, H, W) bool, True in the gap.
    axis : (2,) the glottis' direction in the image, (col, row) px, any length.
    """
    gap = np.asarray(gap, bool)
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    out = np.zeros(len(gap))
    for f, frame in enumerate(gap):
        rows, cols = np.nonzero(frame)
        if rows.size:
            along = cols * a[0] + rows * a[1]
            piece = np.floor((along - along.min()) / piece_px + 1e-9).astype(int)      # + 1e-9: a centre on a boundary starts its piece
            counts = np.sort(np.bincount(piece))[::-1][:n_pieces]
            out[f] = float(np.mean(counts)) / piece_px
    return out


def rms(x: np.ndarray) -> float:
    """Root mean square of the finite entries."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def sync_offset_error(offset_s: np.ndarray, true_offset_s: np.ndarray, f0_hz: np.ndarray) -> np.ndarray:
    """(P,) s: each vibrometer epoch's synchronised offset minus the true one, wrapped to half a glottal period
    (an offset is a phase: a whole period apart is the same alignment)."""
    period = 1.0 / np.asarray(f0_hz, float)
    return np.mod(np.asarray(offset_s, float) - true_offset_s + period / 2, period) - period / 2


def sync_frame_error(offset_error_s: np.ndarray, video_phase: np.ndarray, true_frame_phase: np.ndarray,
                     f0_hz: np.ndarray) -> np.ndarray:
    """(P, F) s: the timing error of each epoch's instant matched to each frame.

    An epoch's offset is matched at the first frame, the end of the video's pressure record where its fitted
    phase is least constrained; every other frame is matched through the video's phase at that frame.  With
    each epoch's phase linear in its own time (f0 ``f0_hz``), the instant matched to frame i errs by the offset's
    error plus the change of the video phase's error since the first frame.

    Parameters
    ----------
    offset_error_s : (P,) s
        :func:`sync_offset_error` of each epoch.
    video_phase, true_frame_phase : (F,) cycles
        The video's phase at each frame as sync estimated it (``/sync/video_phase``) and as it was; any constant
        between the two conventions cancels.
    f0_hz : (P,) Hz
        Each epoch's f0.
    """
    drift = (np.asarray(video_phase, float) - video_phase[0]) - (np.asarray(true_frame_phase, float)
                                                                   - true_frame_phase[0])
    return np.asarray(offset_error_s, float)[:, None] + drift[None, :] / np.asarray(f0_hz, float)[:, None]


def end_point_error(flow: np.ndarray, truth: np.ndarray, where: np.ndarray) -> tuple[float, float]:
    """(mean, 95th percentile) of |flow - truth| over ``where``; flow, truth (..., 2)."""
    err = np.linalg.norm(flow - truth, axis=-1)[where]
    err = err[np.isfinite(err)]
    return float(err.mean()), float(np.percentile(err, 95))


def relative_rms_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS(estimate - truth) / RMS(truth) over entries finite in both."""
    ok = np.isfinite(estimate) & np.isfinite(truth)
    return rms((estimate - truth)[ok]) / rms(truth[ok])


def surface_displacement_at(
    nodes_uv: np.ndarray, nodes_fold: np.ndarray, side_mask: np.ndarray,
    source_uv: np.ndarray, source_fold: np.ndarray, source_disp: np.ndarray,
) -> np.ndarray:
    """Displacements of one mesh's surface side, interpolated at another mesh's (u, v).

    Parameters
    ----------
    nodes_uv, nodes_fold : (N, 2), (N,) target nodes' (u, v) and fold.
    side_mask : (N,) bool, target nodes to fill (e.g. the inferior side).
    source_uv, source_fold : (M, 2), (M,) the source side's nodes.
    source_disp : (T, M, 3) source displacements.

    Returns
    -------
    (T, N, 3): linear interpolation in (u, v) per fold, NaN off ``side_mask`` or outside.
    """
    from scipy.interpolate import LinearNDInterpolator

    out = np.full((source_disp.shape[0], len(nodes_uv), 3), np.nan)
    for fold in (0, 1):
        src = source_fold == fold
        dst = side_mask & (nodes_fold == fold)
        values = np.moveaxis(source_disp[:, src], 0, 1).reshape(int(src.sum()), -1)
        interp = LinearNDInterpolator(source_uv[src], values)
        out[:, dst] = np.moveaxis(interp(nodes_uv[dst]).reshape(int(dst.sum()), source_disp.shape[0], 3), 1, 0)
    return out


def side_truth(mesh_uv: np.ndarray, mesh_side: np.ndarray, truth_uv: np.ndarray, truth_side: np.ndarray,
               truth_disp: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """The phantom's true displacement of one surface side at the reconstruction mesh's nodes.

    Parameters
    ----------
    mesh_uv, mesh_side : (N, 2), (N,) the reconstruction mesh (both folds, fold 0 first).
    truth_uv, truth_side : (M, 2), (M,) the phantom's mesh (both folds, fold 0 first).
    truth_disp : (T, M, 3) true displacements at the compared times, mm.
    side : 1 inferior, 2 superior.

    Returns
    -------
    nodes : (n,) int indices of the side's nodes inside the phantom's (u, v) range.
    reference : (T, n, 3) true displacements there, mm.
    """
    n, m = len(mesh_uv), len(truth_uv)
    sel, src = mesh_side == side, truth_side == side
    ref = surface_displacement_at(mesh_uv, np.repeat([0, 1], n // 2), sel, truth_uv[src],
                                  np.repeat([0, 1], m // 2)[src], truth_disp[:, src])
    nodes = np.flatnonzero(sel & np.all(np.isfinite(ref), axis=(0, 2)))
    return nodes, ref[:, nodes]


def pose_half_turned(rotation_used_deg: float, rotation_true_deg: float) -> bool:
    """True when a fitted camera rotation lies nearer the true one turned by half a turn than the true one.

    The two folds look alike from above, so a pose estimated from the video may come out turned by
    180 deg about the glottis' centre: the same reconstruction in a frame whose left fold is the
    phantom's right (:func:`half_turned` re-expresses the truth in that frame).
    """
    err = np.mod(float(rotation_used_deg) - float(rotation_true_deg) + 180.0, 360.0) - 180.0
    return bool(abs(err) > 90.0)


def half_turned(uv: np.ndarray, side: np.ndarray, disp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A two-fold mesh's surface coordinates and displacements in the frame turned by 180 deg about the
    glottis' centre (the vertical axis through x = L/2, y = 0).

    The turn maps fold 0 onto fold 1, the longitudinal coordinate u onto 1 - u and turns the horizontal
    components of every displacement over (x, y) -> (-x, -y); the vertical one is kept.

    Parameters
    ----------
    uv, side : (N, 2), (N,) surface coordinates and side of a mesh with both folds, fold 0 first (N/2
        nodes each).
    disp : (..., N, 3) displacements there, mm.

    Returns
    -------
    uv, side, disp in the turned frame: node i of the result is the node the turn takes to fold 0's
    i-th place (the arguments of :func:`side_truth`'s phantom).
    """
    uv, side, disp = np.asarray(uv, float), np.asarray(side), np.asarray(disp, float)
    n = len(uv)
    if n % 2:
        raise ValueError(f"half_turned needs both folds' nodes, fold 0 first; got an odd count {n}")
    order = np.r_[np.arange(n // 2, n), np.arange(n // 2)]
    turned_uv = uv[order].copy()
    turned_uv[:, 0] = 1.0 - turned_uv[:, 0]
    turned = disp[..., order, :].copy()
    turned[..., :2] *= -1.0
    return turned_uv, side[order], turned


#: An entry stated with no uncertainty and right to this (mm) is one the model fixes exactly (a clamped node).
EXACT_MM = 1e-9


def interval_coverage(estimate: np.ndarray, std: np.ndarray, truth: np.ndarray, z: float = 1.645) -> float:
    """Fraction of entries whose truth lies within ``estimate +- z std`` (z = 1.645: 90 % intervals).

    Entries the model fixes exactly (stated sd 0 and the estimate right to :data:`EXACT_MM`: the nodes
    the mould clamps, about a quarter of the inferior surface's) have no interval and are left out: a
    zero-width interval around a round-off error (1e-17 mm) counted as a miss or a hit depending on the
    round-off, which moved a widened phantom's coverage by up to 1.7 points either way.  An entry
    stated with sd 0 that is wrong counts as a miss.
    """
    err = np.abs(np.asarray(estimate, dtype=float) - truth)
    std = np.broadcast_to(np.asarray(std, dtype=float), err.shape)
    exact = (std == 0) & (err <= EXACT_MM)
    if exact.all():
        return float("nan")
    return float(np.mean(err[~exact] <= z * std[~exact]))
