"""Dense optical flow of the high-speed video and the streaming flow step.

The horizontal surface velocity (u_I, v_I) of the paper (section 3.2): OpenCV's
sparse-to-dense Lucas-Kanade flow (``cv2.optflow.calcOpticalFlowSparseToDense``, the
paper's method, run step by step by :func:`sparse_to_dense` so that small or flat frames cannot crash
it; needs opencv-contrib) or, as an option, DIS (``cv2.DISOpticalFlow``),
between consecutive frames; vectors inside the gap set to zero; converted to mm/s.

Conventions
-----------
* Frames are 12-bit counts in uint16. The flow algorithms take 8-bit images: every frame
  of a recording is mapped with the *same* linear scale (:func:`intensity_range`, then
  :func:`to_uint8`), so brightness stays consistent from frame to frame.
* A flow image is ``(H, W, 2)`` float32, px/frame, as (d col, d row) = screen (x, y).
* The flow of the pair (k, k+1) is the *forward* displacement of the material seen at
  each pixel of frame k; it is the mean velocity over [t_k, t_k+1], attributed to the
  midpoint t = (k + 0.5) / fps.
* :func:`flow_stream` attributes velocity to the *frame times* t_k = k / fps, so the
  mask, the area, the opening and the velocity of a frame share one time axis: the
  velocity at frame k is the mean of the two midpoint flows (k-1, k) and (k, k+1) (a
  central difference, second order in time); on the first and last frames the
  midpoint flows are extrapolated linearly (1.5 f(k+1/2) - 0.5 f(k+3/2)). Where pixel y
  was gap at frame k-1 the (k-1, k) flow there is meaningless, so only the forward
  flow (k, k+1) is used. Like any forward flow, the estimate at pixel y refers to the
  material at y at frame k (to second order, the screen velocity half a displacement
  further along its path).
* Velocity (u, v) in mm/s in the model frame: with the camera model
  ``[col, row] = px_per_mm * R(rotation) @ [x, y] + offset``,
  ``[u, v] = R(rotation)^T @ [d col, d row] * fps / px_per_mm``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Iterable, Iterator, Literal

import numpy as np

from vfcli.errors import ConfigError
from vfcli.flow.gap.detect import gap_mask, glottal_area
from vfcli.flow.gap.subpixel import SubpixelGap, segment_stream
from vfcli.flow.gap.opening import OpeningTracker

log = logging.getLogger(__name__)

FlowMethod = Literal["sparse_to_dense", "dis"]
DIS_PRESETS = ("ultrafast", "fast", "medium")


def intensity_range(frames_sample: np.ndarray, low_percentile: float = 0.1, high_percentile: float = 99.9) -> tuple[float, float]:
    """Fixed 12-bit to 8-bit mapping of one recording: (low, high) counts.

    Parameters
    ----------
    frames_sample : (k, H, W) or (H, W) array of counts
        Frames spread over the recording.
    low_percentile, high_percentile : float
        Percentiles (in %) of the pooled sample mapped to 0 and 255.

    Returns
    -------
    (float, float)
        Counts mapped to 0 and to 255.
    """
    x = np.asarray(frames_sample)
    lo, hi = np.percentile(x, [low_percentile, high_percentile])
    if not hi > lo:
        hi = lo + 1.0
    return float(lo), float(hi)


def to_uint8(frame: np.ndarray, counts_range: tuple[float, float]) -> np.ndarray:
    """Map counts linearly to 8 bit with a fixed range, clipping: (H, W) uint8."""
    lo, hi = counts_range
    scaled = (np.asarray(frame, dtype=np.float32) - lo) * (255.0 / (hi - lo))
    return np.clip(scaled + 0.5, 0, 255).astype(np.uint8)


class FlowEstimator:
    """Dense optical flow between two 8-bit frames, (H, W, 2) float32 px/frame.

    Parameters
    ----------
    method : {'sparse_to_dense', 'dis'}
        ``'sparse_to_dense'``: the paper's ``cv2.optflow.calcOpticalFlowSparseToDense``
        (:func:`sparse_to_dense`: pyramidal Lucas-Kanade matches on a grid, locally affine interpolation, fast
        global smoother); ``'dis'``: ``cv2.DISOpticalFlow`` with a preset.
    grid_step, k, sigma, use_post_proc, fgs_lambda, fgs_sigma
        Parameters of ``calcOpticalFlowSparseToDense`` (OpenCV's defaults; a finer
        ``grid_step`` of 4-5 was measured no more accurate on textured folds and 3-5x
        slower).
    dis_preset : {'ultrafast', 'fast', 'medium'}
        DIS preset.
    """

    def __init__(
        self,
        method: FlowMethod = "sparse_to_dense",
        *,
        grid_step: int = 8,
        k: int = 128,
        sigma: float = 0.05,
        use_post_proc: bool = True,
        fgs_lambda: float = 500.0,
        fgs_sigma: float = 1.5,
        dis_preset: str = "medium",
    ) -> None:
        import cv2

        if method not in ("sparse_to_dense", "dis"):
            raise ValueError(f"optical flow: unknown method {method!r} (sparse_to_dense or dis)")
        self.method = method
        self.params = dict(grid_step=int(grid_step), k=int(k), sigma=float(sigma), use_post_proc=bool(use_post_proc),
                           fgs_lambda=float(fgs_lambda), fgs_sigma=float(fgs_sigma))
        self._dis = None
        if method == "sparse_to_dense":
            if not hasattr(cv2, "ximgproc"):
                raise ConfigError("optical flow: sparse_to_dense needs opencv-contrib-python-headless "
                                  "(cv2.ximgproc is missing); install it instead of opencv-python")
        else:
            if dis_preset not in DIS_PRESETS:
                raise ValueError(f"optical flow: unknown DIS preset {dis_preset!r} (one of {DIS_PRESETS})")
            preset = getattr(cv2, f"DISOPTICAL_FLOW_PRESET_{dis_preset.upper()}")
            self._dis = cv2.DISOpticalFlow.create(preset)

    def __call__(self, prev8: np.ndarray, next8: np.ndarray) -> np.ndarray:
        """Forward flow from ``prev8`` to ``next8`` (both (H, W) uint8): (H, W, 2) float32
        px/frame, (d col, d row) of the material at each pixel of ``prev8``."""
        if self._dis is not None:
            return self._dis.calc(prev8, next8, None)
        return sparse_to_dense(prev8, next8, **self.params)


#: OpenCV's cap on the grid's matches (SHRT_MAX): a finer grid is coarsened until it fits
_MAX_MATCHES = 32767


def sparse_to_dense(prev8: np.ndarray, next8: np.ndarray, grid_step: int = 8, k: int = 128, sigma: float = 0.05,
                    use_post_proc: bool = True, fgs_lambda: float = 500.0, fgs_sigma: float = 1.5) -> np.ndarray:
    """OpenCV's ``optflow.calcOpticalFlowSparseToDense``, step by step, with ``k`` kept to the matches found.

    The same steps as the library (pyramidal Lucas-Kanade matches on a grid, 21 x 21 window; the
    edge-aware interpolator of ``ximgproc`` with the same parameters), bit for bit the same flow when
    the grid has at least ``k`` surviving matches (tests/test_optical_flow.py). The library asks the
    interpolator for ``k`` neighbours whatever the number of matches, and reads past its arrays when
    there are fewer (opencv_contrib issue 4195: a segfault, or silently wrong flow, on small or flat
    frames); here ``k`` is at most the number of matches, and with fewer than 3 matches (no affine fit)
    the flow is zero.

    Parameters
    ----------
    prev8, next8 : (H, W) uint8
        The two frames.
    grid_step, k, sigma, use_post_proc, fgs_lambda, fgs_sigma
        As ``calcOpticalFlowSparseToDense``.

    Returns
    -------
    (H, W, 2) float32
        Forward flow, px/frame, (d col, d row).
    """
    import cv2

    h, w = prev8.shape[:2]
    step = int(grid_step)
    while (w // step) * (h // step) > _MAX_MATCHES:
        step *= 2
    rows, cols = np.mgrid[0:h:step, 0:w:step]
    pts = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(np.float32).reshape(-1, 1, 2)
    dst, status, _err = cv2.calcOpticalFlowPyrLK(prev8, next8, pts, None, winSize=(21, 21))
    ok = status.ravel() != 0
    n = int(ok.sum())
    if n < 3:
        return np.zeros((h, w, 2), np.float32)
    interp = cv2.ximgproc.createEdgeAwareInterpolator()
    interp.setK(min(int(k), n))
    interp.setSigma(float(sigma))
    interp.setUsePostProcessing(bool(use_post_proc))
    interp.setFGSLambda(float(fgs_lambda))
    interp.setFGSSigma(float(fgs_sigma))
    return interp.interpolate(prev8, pts[ok].reshape(-1, 2), next8, dst[ok].reshape(-1, 2))


def pixel_to_model_velocity(flow_px: np.ndarray, px_per_mm: float, fps: float, rotation_deg: float = 0.0) -> np.ndarray:
    """Screen flow (px/frame) to horizontal model velocity (u, v), mm/s.

    Parameters
    ----------
    flow_px : (..., 2) float
        (d col, d row) per frame, px/frame.
    px_per_mm : float
        Image scale, px/mm.
    fps : float
        Frame rate, frames/s.
    rotation_deg : float
        In-plane rotation of the camera model (``docs/conventions.md``), degrees.

    Returns
    -------
    (..., 2) float32
        (u, v) = (x, y) velocity components, mm/s.
    """
    if px_per_mm <= 0 or fps <= 0:
        raise ValueError(f"flow conversion: px_per_mm and fps must be positive, got {px_per_mm}, {fps}")
    th = np.deg2rad(rotation_deg)
    c, s = np.cos(th), np.sin(th)
    flow = np.asarray(flow_px, dtype=np.float32)
    k = fps / px_per_mm
    # R^T @ [d col, d row] with R = [[c, -s], [s, c]]
    rt = (np.array([[c, s], [-s, c]]) * k).astype(np.float32)
    return flow @ rt.T


def split_fold_flow(
    estimator: FlowEstimator,
    prev8: np.ndarray,
    next8: np.ndarray,
    divide: np.ndarray,
    lateral_axis: int = 0,
    fill: int = 0,
) -> np.ndarray:
    """Flow of each fold on its own, so the estimator cannot smooth across the gap.

    The dense estimators interpolate matches from both folds across the gap, which
    moves in opposite directions on its two sides (the paper's "oversmoothing" at the
    edges). Here the frame pair is split along a dividing line per ray (the gap centre):
    for each side, the other side is painted ``fill`` (black, like the gap) in both
    frames, the flow is computed, and each pixel takes the flow of its own side. Twice
    the cost of one call. Measured on the synthetic folds (S2D): end-point error within
    3 px of the gap 0.09-0.13 px/frame instead of 0.20-0.48.

    Parameters
    ----------
    estimator : FlowEstimator
    prev8, next8 : (H, W) uint8
        The frame pair.
    divide : (n_rays,) float
        Lateral coordinate of the dividing line on each ray, px (finite).
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows, one ray per column).
    fill : int
        8-bit value painted over the other side.

    Returns
    -------
    (H, W, 2) float32
        Forward flow, px/frame.
    """
    n_lat = prev8.shape[lateral_axis]
    lat = np.arange(n_lat, dtype=float)
    if lateral_axis == 0:
        first = lat[:, None] < np.asarray(divide)[None, :]
    else:
        first = lat[None, :] < np.asarray(divide)[:, None]
    out = np.empty(prev8.shape + (2,), np.float32)
    for side in (first, ~first):
        a = np.where(side, prev8, np.uint8(fill))
        b = np.where(side, next8, np.uint8(fill))
        out[side] = estimator(a, b)[side]
    return out


@dataclass
class FlowFrame:
    """Per-frame result of :func:`flow_stream` (all at the frame time ``time_s``).

    Attributes
    ----------
    index : int
        Frame index in the stream (0-based).
    time_s : float
        Frame time index / fps (+ ``t0_s``), s.
    mask : (H, W) bool
        Glottal gap.
    area_mm2 : float
        Glottal area, mm^2.
    opening_px : (H, W) float32
        Gap opening function o(y, t_k), px.
    flow_px : (H, W, 2) float32
        Displacement per frame at t_k (central estimate), (d col, d row) px/frame; zero
        in the gap.
    velocity_mm_s : (H, W, 2) float32
        The same as model velocity (u, v), mm/s; zero in the gap.
    """

    index: int
    time_s: float
    mask: np.ndarray
    area_mm2: float
    opening_px: np.ndarray
    flow_px: np.ndarray
    velocity_mm_s: np.ndarray


def _single_frames(frames: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    for item in frames:
        a = np.asarray(item)
        if a.ndim == 3:
            yield from a
        elif a.ndim == 2:
            yield a
        else:
            raise ValueError(f"flow: frames must be (H, W) or (k, H, W) arrays, got shape {a.shape}")


def flow_stream(
    frames: Iterable[np.ndarray],
    *,
    fps: float,
    px_per_mm: float,
    threshold: float,
    counts_range: tuple[float, float],
    method: FlowMethod = "sparse_to_dense",
    median_px: int = 5,
    rotation_deg: float = 0.0,
    lateral_axis: int = 0,
    initial_center: np.ndarray | float | None = None,
    midline: float | np.ndarray | None = None,
    t0_s: float = 0.0,
    estimator: FlowEstimator | None = None,
    split_folds: bool = False,
    gap: SubpixelGap | None = None,
    median_along_slit: bool = False,
    exclude: np.ndarray | None = None,
) -> Iterator[FlowFrame]:
    """The whole flow step, streamed: one :class:`FlowFrame` per input frame.

    Holds O(1) frames: the current, previous and next frame with their masks and the
    two adjacent pair flows. A frame is yielded once the next one has been read.

    Parameters
    ----------
    frames : iterable of (H, W) or (k, H, W) arrays of counts
        The video in order (batches are unpacked).
    fps : float
        Frame rate, frames/s.
    px_per_mm : float
        Image scale, px/mm.
    threshold : float
        Gap threshold, counts (:func:`vfcli.flow.gap.detect.gap_threshold` on a sample).
    counts_range : (float, float)
        Fixed 8-bit mapping of the recording (:func:`intensity_range` on a sample).
    method : {'sparse_to_dense', 'dis'}
        Optical flow method (ignored when ``estimator`` is given).
    median_px : int
        Median filter of the gap mask, px (odd).
    rotation_deg : float
        Camera rotation for the conversion to model axes, degrees.
    lateral_axis : {0, 1}
        Image axis that is lateral (0: rows).
    initial_center : float or (n_rays,) float, optional
        Opening locations assumed before the gap is seen (:func:`vfcli.flow.gap.detect.midline_from_masks`).
    midline : float or (n_rays,) float, optional
        Lateral pixel coordinate of the glottal midline (or its coordinate on each ray) for
        :func:`vfcli.flow.gap.detect.gap_mask`.
    t0_s : float
        Time of the first frame, s.
    estimator : FlowEstimator, optional
        A configured estimator; default ``FlowEstimator(method)``.
    split_folds : bool
        Compute each fold's flow separately (:func:`split_fold_flow`), divided at the
        gap centre of the pair (last known location on closed rays): sharper flow next
        to the gap at twice the cost. Default False (the paper's single call).
    gap : SubpixelGap, optional
        Segment the gap with sub-pixel edges (:func:`vfcli.flow.gap.subpixel.segment_stream`; the
        area then comes from the edges); ``threshold``, ``median_px``, ``midline`` and
        ``lateral_axis`` are then taken from it. Default: the paper's binary mask
        (:func:`vfcli.flow.gap.detect.gap_mask`) and its pixel count.
    median_along_slit : bool
        The binary mask's median along the glottis instead of the square one (``gap_mask``'s option; a slit the
        square median erases, :attr:`vfcli.flow.pipeline.FlowCalibration.median_along_slit`).
    exclude : (H, W) bool, optional
        Never gap in the binary mask: the folds' dark surroundings (:attr:`vfcli.flow.pipeline.FlowCalibration.surround`;
        with ``gap`` its own ``exclude`` is used).

    Yields
    ------
    FlowFrame
    """
    est = estimator if estimator is not None else FlowEstimator(method)
    if gap is not None:
        lateral_axis = gap.lateral_axis
        it = segment_stream(_single_frames(frames), gap)  # (frame, GapSegmentation), a few frames behind
    else:
        it = ((f, None) for f in _single_frames(frames))
    tracker: OpeningTracker | None = None
    sides: OpeningTracker | None = None  # gap centres seen so far, to split the folds

    def prepare(item):
        nonlocal sides
        frame, seg = item
        if seg is None:
            m = gap_mask(frame, threshold, median_px, midline=midline, lateral_axis=lateral_axis,
                         median_along_slit=median_along_slit, exclude=exclude)
            area = float(glottal_area(m, px_per_mm))
        else:
            m, area = seg.mask, seg.area_mm2(px_per_mm)
        if split_folds:
            if sides is None:
                sides = OpeningTracker(m.shape, lateral_axis, initial_center)
            sides.observe(m)
        return to_uint8(frame, counts_range), (m, area)  # the 8-bit image and the frame's (mask, area)

    def pair_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if not split_folds:
            return est(a, b)
        return split_fold_flow(est, a, b, sides.fallback_center(), lateral_axis)

    def emit(k: int, gap_k: tuple[np.ndarray, float], flow: np.ndarray) -> FlowFrame:
        nonlocal tracker
        mask, area = gap_k
        if tracker is None:
            tracker = OpeningTracker(mask.shape, lateral_axis, initial_center)
        flow = np.where(mask[..., None], np.float32(0.0), flow).astype(np.float32)
        return FlowFrame(
            index=k,
            time_s=t0_s + k / fps,
            mask=mask,
            area_mm2=area,
            opening_px=tracker.update(mask),
            flow_px=flow,
            velocity_mm_s=pixel_to_model_velocity(flow, px_per_mm, fps, rotation_deg),
        )

    try:
        f0 = next(it)
    except StopIteration:
        return
    try:
        f1 = next(it)
    except StopIteration:
        raise ConfigError("flow: the video needs at least 2 frames (ingest_hsc.n_frames)") from None
    img0, g0 = prepare(f0)
    img1, g1 = prepare(f1)
    fwd0 = pair_flow(img0, img1)  # pair (0, 1)
    try:
        f2 = next(it)
    except StopIteration:
        yield emit(0, g0, fwd0)
        yield emit(1, g1, fwd0)
        return
    img2, g2 = prepare(f2)
    fwd1 = pair_flow(img1, img2)  # pair (1, 2)
    yield emit(0, g0, 1.5 * fwd0 - 0.5 * fwd1)
    # sliding state: frame k = 1 with previous pair flow fwd0 (k-1, k) and mask of k-1
    k, prev_gap, cur_img, cur_gap, back, fwd = 1, g0, img2, g2, fwd0, fwd1
    gap_k = g1
    for f_next in it:
        img_n, g_n = prepare(f_next)
        fwd_next = pair_flow(cur_img, img_n)  # pair (k+1, k+2)
        central = np.where(prev_gap[0][..., None], fwd, 0.5 * (back + fwd))
        yield emit(k, gap_k, central)
        k += 1
        prev_gap, gap_k, back, fwd = gap_k, cur_gap, fwd, fwd_next
        cur_img, cur_gap = img_n, g_n
    # frame k (second to last): pairs (k-1, k) = back and (k, k+1) = fwd
    central = np.where(prev_gap[0][..., None], fwd, 0.5 * (back + fwd))
    yield emit(k, gap_k, central)
    # last frame k+1: extrapolate the midpoint flows to its time
    yield emit(k + 1, cur_gap, 1.5 * fwd - 0.5 * back)
